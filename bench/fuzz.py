"""Damaged inputs by the thousand: the outcome of every case per family, as a table.

    .venv/bin/python bench/fuzz.py [N] [--family NAME ...] [--start SEED]

N seeded cases (default 1,000) of each family of ``tests/fuzz.py`` (experiment files,
codings, images, statistics tables, dataset folders), each run as the command a user
would run, in this process. Counted per family: refused with a message, accepted whole,
tracebacks, hangs, silent acceptances, and cases per second; the baseline, in the same
run, is the undamaged inputs of each family (every one must be accepted), whose rate
the damaged cases' is given as a ratio of. Writes ``bench/results/fuzz.json`` with every
case that was not refused or accepted (seed and mutations: ``--start SEED`` with N = 1
runs one again). Goal: no traceback, hang or silent case.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT))

import fuzz  # noqa: E402


def _originals(family: str, tmp: Path) -> tuple[int, int, float]:
    """Cases of the family with the mutations undone: (cases, accepted, cases per s)."""
    keep = fuzz.mutate_text, fuzz.mutate_bytes
    fuzz.mutate_text = lambda text, kind, rng, said: text
    fuzz.mutate_bytes = lambda data, rng, said: data
    try:
        t0 = time.perf_counter()
        cases = fuzz.run_family(family, range(8), tmp / "orig")
        rate = len(cases) / (time.perf_counter() - t0)
    finally:
        fuzz.mutate_text, fuzz.mutate_bytes = keep
    return len(cases), sum(c.outcome == "accepted" for c in cases), rate


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("n", nargs="?", type=int, default=1000)
    ap.add_argument("--family", nargs="+", choices=list(fuzz.FAMILIES),
                    default=list(fuzz.FAMILIES))
    ap.add_argument("--start", type=int, default=0, help="first seed")
    args = ap.parse_args()
    rows, found = [], []
    print(f"{'family':<11}{'cases':>7}{'refused':>9}{'accepted':>10}{'traceback':>11}"
          f"{'hang':>6}{'silent':>8}{'cases/s':>9}{'originals':>11}{'ratio':>7}", flush=True)
    for family in args.family:
        with tempfile.TemporaryDirectory(prefix=f"vtexp-fuzz-{family}-") as tmp:
            n_orig, ok_orig, rate_orig = _originals(family, Path(tmp))
            t0 = time.perf_counter()
            cases = fuzz.run_family(family, range(args.start, args.start + args.n), Path(tmp))
            rate = len(cases) / (time.perf_counter() - t0)
        count = Counter(c.outcome for c in cases)
        found += [{"family": c.family, "seed": c.seed, "outcome": c.outcome,
                   "detail": c.detail, "mutations": c.mutations}
                  for c in cases if c.outcome not in ("refused", "accepted")]
        row = {"family": family, "cases": len(cases), **{o: count[o] for o in fuzz.OUTCOMES},
               "cases_per_s": rate, "originals": n_orig, "originals_accepted": ok_orig,
               "originals_per_s": rate_orig, "rate_ratio": rate / rate_orig}
        rows.append(row)
        print(f"{family:<11}{len(cases):>7}{count['refused']:>9}{count['accepted']:>10}"
              f"{count['traceback']:>11}{count['hang']:>6}{count['silent']:>8}{rate:>9.1f}"
              f"{f'{ok_orig}/{n_orig}':>11}{rate / rate_orig:>7.2f}", flush=True)
    for f in found:
        print(f"  {f['family']} seed {f['seed']}: {f['outcome']}: {f['detail']} "
              f"(after {', '.join(f['mutations'])})")
    out = ROOT / "bench" / "results"
    out.mkdir(parents=True, exist_ok=True)
    (out / "fuzz.json").write_text(json.dumps({"n": args.n, "start": args.start,
                                               "families": rows, "found": found}, indent=2))
    print(f"written: {out / 'fuzz.json'}")
    bad = sum(r["traceback"] + r["hang"] + r["silent"] for r in rows)
    return 1 if bad or any(r["originals_accepted"] < r["originals"] for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
