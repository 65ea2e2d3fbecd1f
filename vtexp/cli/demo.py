"""``vtexp demo``: the four studies of the papers run by model participants, analysed."""

from __future__ import annotations

import re
import shutil
import sys
import time
from pathlib import Path

from ..errors import InputError
from ._io import out

DEMO_MARKER = ".vtexp-demo"


#: The four studies of the papers, with the repetitions of the demo's short version.
DEMO_STUDIES = [("six_mode_ball", 3), ("duration_interval_grid", 1), ("whirlpool", 2),
                ("circle_vs_rectangle", 3)]


def _short_version(src: Path, dest: Path, repetitions: int) -> Path:
    """A copy of an experiment file with fewer repetitions, saying so at its top."""
    text = src.read_text(encoding="utf-8")
    short, n = re.subn(r"(?m)^(  repetitions:\s*)\d+", rf"\g<1>{repetitions}", text, count=1)
    if n != 1:
        raise InputError("cannot find design.repetitions to shorten", path=str(src))
    dest.write_text(f"# Short version of {src} written by 'vtexp demo': design.repetitions "
                    f"set to {repetitions}.\n" + short, encoding="utf-8")
    return dest


def _headline(analysis) -> str:
    """The first effect the experiment's analysis tests, as one sentence."""
    for x in analysis.sentences:
        if ": effect of " in x or x.startswith("Friedman"):
            return x
    return analysis.sentences[0] if analysis.sentences else "(no test declared)"


def cmd_demo(args) -> int:
    t0 = time.perf_counter()
    root = Path(args.data)
    if root.exists():
        if not (root / DEMO_MARKER).exists():
            raise InputError(f"{root} exists and was not made by 'vtexp demo'; it is left "
                             "alone. Pass --data DIR to choose another folder.")
        shutil.rmtree(root)
    (root / "experiments").mkdir(parents=True)
    (root / DEMO_MARKER).write_text("made by 'vtexp demo'; the next demo replaces it\n")
    out("vtexp demo: the four studies of the papers, each run by "
        f"{args.participants} model participants on the simulated device\n")
    out("A model participant feels what the device reports it played: blurred by the skin's "
        "two-point\nthreshold, limited to 7-8 intensity levels, integrated over ~40 ms; it "
        "answers by comparing\nthat percept with each answer as it was told about it, played "
        "the same way\n(protocols/observers/default.yaml, docs/model-predictions.md).\n")
    import scipy.signal  # noqa: F401  (scipy's own BLAS, loaded now so as to be limited too)
    from threadpoolctl import threadpool_limits
    # the model's and the analyses' matrices are small: a second BLAS thread only spins
    # (the whole demo: 9.5 s of CPU on one thread, 13.4 s on two, in the same time)
    with threadpool_limits(limits=1, user_api="blas"):
        summary = [_run_study(root, name, reps, args) for name, reps in DEMO_STUDIES]
        full, trials = _analyse(root)
    out("\nWhat the model participants did, and the first test each study declares:")
    for name, _, n_trials in summary:
        out(f"  {name:<24} {args.participants} x {n_trials} trials, "
            f"{_what_they_did(trials[trials['experiment'] == name])}")
        out(f"  {'':<24} {_headline(full[name]['analysis'])}")
    out(f"\nTook {time.perf_counter() - t0:.0f} s. Everything is in {root}/:")
    out(f"  {root}/<study>/               a BIDS dataset per study, as a real session "
        "writes it:")
    out(f"  {'':<28}participants.tsv, sub-*/ses-1/beh/ (trials, device events, sidecars),")
    out(f"  {'':<28}sourcedata/vtexp/ (session records)")
    out(f"  {root}/<study>/derivatives/vtexp/  the report: report.md, and an HTML page with "
        "figures and tables:")
    for name, _, _ in summary:
        out(f"      {full[name]['html']}")
    out("\nNext: how many participants would a study need?")
    out("  vtexp simulate experiments/six_mode_ball.yaml --participants 15 --studies 1000 "
        "--target-power 0.8")
    out("Or run a person: README.md, \"Running a session with a participant\".")
    return 0


def _run_study(root: Path, name: str, reps: int, args) -> tuple:
    """The short version of study ``name`` run by every model participant; says so and
    returns ``(name, experiment, trials per participant)``."""
    from ..compile import compile_conditions
    from ..devices.sim import SimDevice
    from ..experiment import load_experiment
    from ..observer import ModelObserver, ObserverModel
    from ..resources import experiments_dir
    from ..session import SessionOptions, run_session

    src = experiments_dir() / f"{name}.yaml"
    path = _short_version(src, root / "experiments" / f"{name}.yaml", reps)
    lx = load_experiment(path)
    exp = lx.experiment
    model = ObserverModel.for_experiment(lx)
    conds = compile_conditions(lx, model.profile)
    n_trials = 0
    for i in range(1, args.participants + 1):
        pid = f"sim{i:02d}"
        res = run_session(lx, SimDevice(model.profile),
                          ModelObserver(model, pid, 1, seed=args.seed),
                          SessionOptions(participant=pid, data_dir=root,
                                         conditions=conds, command=sys.argv))
        n_trials = len({r.trial for r in res.records})
    out(f"  {exp.title}\n    {exp.reference}; {exp.device}; {len(conds)} conditions x "
        f"{reps} repetition{'s' if reps > 1 else ''} = {n_trials} trials per participant: "
        "logged")
    return name, exp, n_trials


def _analyse(root: Path):
    """Each study's sessions are a BIDS dataset; its report is a derivative of it. Returns
    what ``write_reports`` says of each study, and every study's trials in one table."""
    import pandas as pd

    from .. import bids
    from ..analysis import load_sessions
    from ..analysis.report import write_reports

    full = {}
    frames = []
    for name, _ in DEMO_STUDIES:
        trials, sessions = load_sessions([root / name])
        reports = root / name / bids.DERIVATIVE
        bids.ensure_derivative(reports, name)
        full.update(write_reports(trials, sessions, reports)[1])
        frames.append(trials)
    return full, pd.concat(frames, ignore_index=True)


def _what_they_did(sub) -> str:
    """A study's recognition rate, or the mean answer to each question without a right one."""
    import pandas as pd

    if sub["correct"].notna().any():
        return f"recognition rate {sub['correct'].astype(float).mean():.0%}"
    return ", ".join(f"mean {q} {pd.to_numeric(g['answer']).mean():.2f}"
                     for q, g in sub.groupby("question"))


def register(sub) -> None:
    """Add ``vtexp demo`` to the ``vtexp`` parser."""
    s = sub.add_parser("demo", help="the four studies run by model participants, analysed")
    s.add_argument("--data", default="data/demo", help="demo folder (default: ./data/demo)")
    s.add_argument("--participants", type=int, default=6, choices=range(2, 21),
                   metavar="N", help="model participants per study (2-20, default 6)")
    s.add_argument("--seed", type=int, default=0, help="model participants' seed (default 0)")
    s.set_defaults(func=cmd_demo)
