"""What crash safety costs per trial: vtexp's fsync'd append against two baselines.

- vtexp: one row appended with a single write and fsync'd (TsvLog.append).
- baseline "rewrite": the whole table rewritten with pandas after every trial
  (crash-safe only between rewrites, and O(n) per trial).
- baseline "memory": rows kept in memory and written once at the end, as
  PsychoPy's ExperimentHandler does (fast, but SIGKILL loses every trial).

Prints a table, writes JSON to bench/results/session_log.json. Ratios are
against vtexp in the same run. Usage: python bench/session_log.py [N_TRIALS]
"""

from __future__ import annotations

import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vtexp.log import TsvLog  # noqa: E402
from vtexp.session import trial_columns  # noqa: E402

COLUMNS = trial_columns(["shape", "timing"])


def row(i: int) -> dict:
    return {"trial": i, "practice": False, "repetition": 1, "shape": "circle",
            "timing": "300/200", "stimulus": "circle", "question": "response",
            "answer": "square", "correct_answer": "circle", "correct": False, "rt_s": 1.234,
            "replays": 0, "stimulus_onset_ms": 1000.0 * i, "stimulus_duration_ms": 3300.0,
            "n_pulses": 16, "status": "ok", "started_at": "2026-11-22T08:00:00.000+00:00"}


def bench_vtexp(d: Path, n: int) -> list[float]:
    times = []
    with TsvLog(d / "beh.tsv", COLUMNS) as log:
        for i in range(1, n + 1):
            t = time.perf_counter()
            log.append(row(i))
            times.append(time.perf_counter() - t)
    return times


def bench_rewrite(d: Path, n: int) -> list[float]:
    rows, times = [], []
    for i in range(1, n + 1):
        t = time.perf_counter()
        rows.append(row(i))
        f = d / "rewrite.tsv"
        pd.DataFrame(rows, columns=COLUMNS).to_csv(f, sep="\t", index=False)
        with open(f, "rb+") as fh:
            os.fsync(fh.fileno())
        times.append(time.perf_counter() - t)
    return times


def bench_memory(d: Path, n: int) -> list[float]:
    rows, times = [], []
    for i in range(1, n + 1):
        t = time.perf_counter()
        rows.append(row(i))
        times.append(time.perf_counter() - t)
    t = time.perf_counter()
    pd.DataFrame(rows, columns=COLUMNS).to_csv(d / "memory.tsv", sep="\t", index=False)
    times[-1] += time.perf_counter() - t          # the final save belongs to the last trial
    return times


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 500
    results = {}
    with tempfile.TemporaryDirectory(dir=ROOT / "bench") as tmp:
        for name, fn in (("vtexp append+fsync", bench_vtexp), ("rewrite table+fsync", bench_rewrite),
                         ("in memory, save at end", bench_memory)):
            ts = fn(Path(tmp), n)
            results[name] = {"median_ms": statistics.median(ts) * 1e3,
                             "p99_ms": sorted(ts)[int(0.99 * (len(ts) - 1))] * 1e3,
                             "total_ms": sum(ts) * 1e3}
    ref = results["vtexp append+fsync"]["median_ms"]
    print(f"per-trial logging cost, {n} trials")
    print(f"{'method':<26}{'median ms':>11}{'p99 ms':>10}{'total ms':>11}{'median / vtexp':>16}"
          f"  survives SIGKILL")
    for name, r in results.items():
        r["ratio_to_vtexp"] = r["median_ms"] / ref
        safe = {"vtexp append+fsync": "every trial", "rewrite table+fsync": "not if killed mid-rewrite",
                "in memory, save at end": "no trial"}[name]
        print(f"{name:<26}{r['median_ms']:>11.3f}{r['p99_ms']:>10.3f}{r['total_ms']:>11.1f}"
              f"{r['ratio_to_vtexp']:>16.2f}  {safe}")
    out = ROOT / "bench" / "results"
    out.mkdir(exist_ok=True)
    (out / "session_log.json").write_text(json.dumps({"n_trials": n, "results": results},
                                                     indent=2))
    print(f"\nwritten: {out / 'session_log.json'}")


if __name__ == "__main__":
    main()
