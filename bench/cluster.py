"""Power analyses spread out: studies per second in one process, on 2 local processes
and on a two-worker Dask LocalCluster (loopback), with the power tables compared.

- baseline "1 process": ``vtexp.simulate.run_power(workers=1)``;
- "2 processes": the same with a process per core (``ProcessPoolExecutor``), as
  ``vtexp simulate`` runs by default;
- "Dask, 2 workers": a ``LocalCluster(n_workers=2, threads_per_worker=1)`` on
  127.0.0.1, its client's ``get_executor()`` passed to ``run_power`` (what
  ``vtexp simulate --executor dask://HOST:PORT`` does): each chunk of studies carries
  the experiment's text and SHA-256. The cluster's start is timed apart; its workers'
  first chunk includes preparing the experiment (as a real cluster's would), and a
  second run on the same workers shows the rate once they have it (a sweep's later
  Ns). Every local run prepares the experiment in each process it starts.

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
    from distributed import LocalCluster

    from vtexp.cluster import connect, threads

    rows = []
    base = run_power(EXP, n, studies, workers=1)
    rows.append(("1 process (baseline)", base.seconds, None))
    two = run_power(EXP, n, studies, workers=2)
    assert two.table.equals(base.table), "2 processes: another power table"
    rows.append(("2 local processes", two.seconds, None))
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lc = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                          dashboard_address=None)
    try:
        client = connect(lc.scheduler_address)
        start_s = time.perf_counter() - t0
        try:
            ex = client.get_executor(pure=False)
            dk = run_power(EXP, n, studies, workers=threads(client), executor=ex)
            warm = run_power(EXP, n, studies, workers=threads(client), executor=ex)
        finally:
            client.close()
    finally:
        lc.close()
    assert dk.table.equals(base.table), "Dask: another power table"
    assert warm.table.equals(base.table), "Dask, warm: another power table"
    rows.append(("Dask LocalCluster, 2 workers", dk.seconds, start_s))
    rows.append(("  the same again (workers warm)", warm.seconds, None))

    print(f"{studies} studies of {n} model participants, {EXP.name}, "
          f"{os.cpu_count()} cores; the same power table in every run")
    print(f"{'run':<32} {'seconds':>8} {'studies/s':>10} {'ratio':>7}  note")
    result = {"studies": studies, "participants": n, "experiment": EXP.name,
              "cores": os.cpu_count(), "python": platform.python_version(),
              "machine": platform.machine(), "runs": []}
    for name, sec, start in rows:
        rate = studies / sec
        ratio = rate / (studies / base.seconds)
        note = f"cluster start {start:.1f} s (not counted)" if start is not None else ""
        print(f"{name:<32} {sec:8.2f} {rate:10.1f} {ratio:6.2f}x  {note}")
        result["runs"].append({"run": name, "seconds": round(sec, 3),
                               "studies_per_s": round(rate, 2), "ratio": round(ratio, 3),
                               "cluster_start_s": None if start is None else round(start, 2)})
    out = ROOT / "bench" / "results" / "cluster.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    print(f"wrote {out.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
