"""How long a power analysis takes: M studies of N model participants of the six-mode study.

- vtexp: ``vtexp.simulate.run_power`` on every core (the fast path: conditions
  compiled and played once, answers from the same observer model, all studies'
  ANOVAs in one vectorised pass).
- baseline "one core": the same, in one process.
- baseline "sessions": each participant run as a real session (``run_session``
  with the ModelObserver responder on the sim device, fsync'd BIDS logs), then
  the log read back with ``load_sessions``; timed on a few participants and
  extrapolated to M x N.

Prints a table, writes JSON to bench/results/simulate.json. Ratios are against
vtexp in the same run. Usage: python bench/simulate.py [STUDIES] [N]
(default 1000 studies of 15 participants, the issue's figure: < 60 s).
"""

from __future__ import annotations

import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vtexp.analysis.load import load_sessions
from vtexp.compile import compile_conditions
from vtexp.devices.sim import SimDevice
from vtexp.experiment import load_experiment
from vtexp.observer import ModelObserver, ObserverModel
from vtexp.session import SessionOptions, run_session
from vtexp.simulate import run_power

EXP = ROOT / "experiments" / "six_mode_ball.yaml"


def sessions_per_participant(k: int = 6) -> float:
    lx = load_experiment(EXP)
    model = ObserverModel.for_experiment(lx)
    conds = compile_conditions(lx, model.profile)
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        for i in range(k):
            run_session(lx, SimDevice(model.profile), ModelObserver(model, f"sim{i}", seed=0),
                        SessionOptions(participant=f"sim{i}", data_dir=d, conditions=conds))
        load_sessions([d])
        return (time.perf_counter() - t0) / k


def main() -> None:
    studies = int(sys.argv[1]) if len(sys.argv) > 1 else 1000
    n = int(sys.argv[2]) if len(sys.argv) > 2 else 15
    cores = os.cpu_count() or 1
    fast = run_power(EXP, n, studies, workers=cores)
    one = run_power(EXP, n, studies, workers=1)
    one_s = one.seconds
    assert one.table["power"].tolist() == fast.table["power"].tolist()   # same studies
    per = sessions_per_participant()
    sess_s = per * studies * n
    rows = [(f"vtexp, {cores} processes", fast.seconds, "measured"),
            ("one process", one_s, "measured; the same power to the last study"),
            ("real sessions + load", sess_s, f"{per * 1000:.0f} ms per participant, scaled")]
    print(f"\n{studies} studies x {n} participants of six_mode_ball "
          f"({studies * n * 60:,} trials), {cores} cores\n")
    print(f"{'method':<26} {'seconds':>9} {'ratio':>8}  note")
    for name, s, note in rows:
        print(f"{name:<26} {s:9.1f} {s / fast.seconds:8.2f}  {note}")
    print("\npower at this N:")
    for _, r in fast.table.iterrows():
        print(f"  {r['effect']:<50} {r['power']:.3f} [{r['ci_low']:.3f}, {r['ci_high']:.3f}]")
    out = ROOT / "bench" / "results" / "simulate.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps({
        "studies": studies, "participants": n, "cores": cores,
        "machine": platform.platform(), "python": platform.python_version(),
        "seconds": {name: round(s, 2) for name, s, _ in rows},
        "ratio_to_vtexp": {name: round(s / fast.seconds, 2) for name, s, _ in rows},
        "goal_seconds": 60, "power": fast.table.to_dict(orient="records")}, indent=2) + "\n")
    print(f"\nwrote {out.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
