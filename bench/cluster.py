"""Power analyses spread out: studies per second in one process, on 2 local processes
and on a two-worker Dask LocalCluster (loopback), with the power tables compared.

- baseline "1 process": ``vtexp.simulate.run_power(workers=1)``;
- "2 processes": the same with a process per core (``ProcessPoolExecutor``), as
  ``vtexp simulate`` runs by default;
- "Dask, 2 workers": a ``LocalCluster(n_workers=2, threads_per_worker=1)`` on
  127.0.0.1, its client's ``get_executor()`` passed to ``run_power`` (what
  ``vtexp simulate --executor dask://HOST:PORT`` does): each chunk of studies carries
  the experiment's text and SHA-256. The cluster's start is timed apart; its workers'
  first chunk includes preparing the experiment (as a real cluster's would).

Each is run twice: cold (every process prepares the experiment: compiles its
conditions and renders the model participant's answer templates, several seconds
for this study) and warm (the same processes again, as a sweep's later Ns find them).

Every run must give the same power table as the baseline (asserted). Prints a table,
writes JSON to bench/results/cluster.json; ratios are studies per second against the
1-process run in the same invocation. Usage: python bench/cluster.py [STUDIES] [N]
(default 400 studies of 10 participants of the duration/interval study).
"""

from __future__ import annotations

import json
import os
import platform
import sys
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vtexp.simulate import run_power

EXP = ROOT / "experiments" / "duration_interval_grid.yaml"


def main() -> int:
    studies = int(sys.argv[1]) if len(sys.argv) > 1 else 400
    n = int(sys.argv[2]) if len(sys.argv) > 2 else 10
    from concurrent.futures import ProcessPoolExecutor

    from distributed import LocalCluster

    from vtexp.cluster import connect, threads
    from vtexp.simulate import ExperimentSource

    src = ExperimentSource.of(EXP)

    def twice(workers, executor=None):
        """A cold run (every process prepares the experiment) and a warm one after it."""
        return [run_power(EXP, n, studies, workers=workers, executor=executor, source=src)
                for _ in range(2)]

    rows = []
    base = twice(1)
    rows.append(("1 process (baseline)", base, None))
    with ProcessPoolExecutor(2) as pool:
        rows.append(("2 local processes", twice(2, pool), None))
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lc = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                          dashboard_address=None)
    try:
        client = connect(lc.scheduler_address)
        start_s = time.perf_counter() - t0
        try:
            rows.append(("Dask LocalCluster, 2 workers",
                         twice(threads(client), client.get_executor(pure=False)), start_s))
        finally:
            client.close()
    finally:
        lc.close()
    for name, runs, _ in rows:
        for r in runs:
            assert r.table.equals(base[0].table), f"{name}: another power table"

    print(f"{studies} studies of {n} model participants, {EXP.name}, "
          f"{os.cpu_count()} cores; the same power table in every run")
    print("cold: the first run, each process prepares the experiment; warm: the same again")
    print(f"{'run':<30} {'cold s':>7} {'warm s':>7} {'studies/s':>10} {'warm':>6} "
          f"{'ratio':>6} {'warm':>6}")
    result = {"studies": studies, "participants": n, "experiment": EXP.name,
              "cores": os.cpu_count(), "python": platform.python_version(),
              "machine": platform.machine(), "runs": []}
    rate0 = [studies / r.seconds for r in base]
    for name, (cold, warm), start in rows:
        rate = [studies / cold.seconds, studies / warm.seconds]
        ratio = [rate[0] / rate0[0], rate[1] / rate0[1]]
        print(f"{name:<30} {cold.seconds:7.2f} {warm.seconds:7.2f} {rate[0]:10.1f} "
              f"{rate[1]:6.1f} {ratio[0]:5.2f}x {ratio[1]:5.2f}x")
        result["runs"].append({"run": name, "cold_s": round(cold.seconds, 3),
                               "warm_s": round(warm.seconds, 3),
                               "studies_per_s": [round(x, 2) for x in rate],
                               "ratio": [round(x, 3) for x in ratio],
                               "cluster_start_s": None if start is None else round(start, 2)})
    print(f"the cluster started in {rows[-1][2]:.1f} s (not counted)")
    out = ROOT / "bench" / "results" / "cluster.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    print(f"wrote {out.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
