"""The ``vtexp`` command line.

Every input mistake ends in one message on stderr naming the file, line and
key (no traceback) and a non-zero exit status: 2 for bad input, 3 for device
faults, 4 for a broken installation, 130 when interrupted.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import sys
import time
from pathlib import Path

from . import __version__
from .errors import InputError, VtexpError

DEMO_MARKER = ".vtexp-demo"
DEMO_EXPERIMENT = "duration_interval_grid"


def _out(msg: str = "") -> None:
    print(msg, flush=True)


def _err(msg: str) -> None:
    print(f"vtexp: error: {msg}", file=sys.stderr, flush=True)


# --------------------------------------------------------------------------- commands

def cmd_validate(args) -> int:
    from .compile import compile_conditions
    from .experiment import load_experiment

    for f in args.files:
        lx = load_experiment(f, check_stimuli=False)
        conds = compile_conditions(lx)
        exp = lx.experiment
        n = len(conds) * exp.design.repetitions
        _out(f"{f}: OK — {exp.name}: {len(conds)} conditions x {exp.design.repetitions} "
             f"repetitions = {n} trials per session on {exp.device}; every stimulus within "
             "the device's safety limits")
    return 0


def cmd_schema(args) -> int:
    """Write the experiment files' JSON Schema, for editors that complete and check YAML."""
    import json

    from .coding import CODINGS
    from .encoding import PIPELINES
    from .experiment import Experiment
    from .model import available_profiles
    from .stimuli import GENERATORS

    schema = Experiment.model_json_schema()
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["title"] = "vtexp experiment"
    defs = schema.get("$defs", {})
    # The names the registries accept, as enums an editor can offer.
    for model, key, names in (("EncodingSpec", "pipeline", PIPELINES),
                              ("CodingSpec", "protocol", CODINGS),
                              ("StimulusSpec", "generator", GENERATORS)):
        prop = defs.get(model, {}).get("properties", {}).get(key)
        if prop is not None:
            prop.pop("anyOf", None)
            prop.update({"type": "string", "enum": sorted(names)})
    schema["properties"]["device"]["enum"] = available_profiles()
    text = json.dumps(schema, indent=2, ensure_ascii=False) + "\n"
    if args.out:
        Path(args.out).write_text(text, encoding="utf-8")
        _out(f"written: {args.out}")
    else:
        sys.stdout.write(text)
    return 0


def cmd_plan(args) -> int:
    from .compile import compile_conditions
    from .design import trial_list
    from .experiment import load_experiment
    from .responders.base import correct_answer
    from .session import check_participant, check_session

    check_participant(args.participant)
    check_session(args.session)
    lx = load_experiment(args.file, check_stimuli=False)
    exp = lx.experiment
    conds = compile_conditions(lx)
    trials, seed = trial_list(exp, conds, args.participant, args.session)
    factors = list(exp.factors)
    cols = ["trial", *factors, "stimulus", "repetition", "correct_answer", "duration_ms"]
    rows = [[str(t.number), *(t.levels[f] for f in factors), t.stimulus, str(t.repetition),
             correct_answer(exp.asked()[0], t) or "n/a", f"{t.condition.schedule.duration_ms:.0f}"]
            for t in trials]
    if args.format == "tsv":
        _out("\t".join(cols))
        for r in rows:
            _out("\t".join(r))
        return 0
    total_ms = sum(t.condition.schedule.duration_ms for t in trials)
    _out(f"{exp.name}: participant {args.participant}, session {args.session}, seed {seed} "
         f"({'design.seed' if exp.design.seed is not None else 'derived'}), {len(trials)} "
         f"trials, {total_ms / 60000:.1f} min of stimulation")
    widths = [max(len(c), *(len(r[i]) for r in rows)) for i, c in enumerate(cols)]
    _out("  ".join(c.ljust(w) for c, w in zip(cols, widths)).rstrip())
    for r in rows:
        _out("  ".join(v.ljust(w) for v, w in zip(r, widths)).rstrip())
    return 0


class _Progress:
    def __init__(self, quiet: bool):
        self.quiet = quiet
        self.t0 = time.monotonic()
        self.correct = 0
        self.scored = 0
        self.played = 0

    def __call__(self, rec, trial, total) -> None:
        self.played += 1
        if rec.correct is not None:
            self.scored += 1
            self.correct += int(rec.correct)
        if self.quiet:
            return
        el = time.monotonic() - self.t0
        eta = el / self.played * (total - trial.number)     # a resumed run starts midway
        acc = f"{self.correct / self.scored:5.1%}" if self.scored else "  n/a"
        print(f"  trial {trial.number:>4}/{total}  {trial.condition.label:<40} "
              f"answer {rec.answer:<12} elapsed {el:6.1f}s  left ~{eta:5.1f}s  acc {acc}",
              file=sys.stderr, flush=True)


def _run_one(lx, participant, session, device_spec, responder_spec, data, quiet, conds=None,
             resume=False):
    from .devices import open_device
    from .model import DeviceProfile
    from .responders import make_responder
    from .session import check_participant, check_session, run_session

    check_participant(participant)
    check_session(session)
    profile = DeviceProfile.load(lx.experiment.device)
    responder = make_responder(responder_spec, participant, session)
    device = open_device(device_spec, profile)
    with device:
        return run_session(lx, participant, session, device, responder, data, conditions=conds,
                           sinks=(_Progress(quiet),), command=sys.argv,
                           on_device_error=_ask_experimenter if sys.stdin.isatty() else None,
                           resume=resume)


def _ask_experimenter(error, trial) -> str:
    """The session pauses on a device fault until the experimenter chooses what to do."""
    print(f"\nThe device failed during trial {trial.number} ({trial.condition.label}):\n"
          f"  {error}\nEvery actuator is off. The session is paused.", file=sys.stderr)
    while True:
        try:
            answer = input("[r]etry the trial (reconnect first), [s]kip it, or [a]bort the "
                           "session? ").strip().lower()
        except EOFError:
            return "abort"
        for choice in ("retry", "skip", "abort"):
            if answer in (choice, choice[0]):
                return choice


def cmd_run(args) -> int:
    from .experiment import load_experiment

    lx = load_experiment(args.file)
    res = _run_one(lx, args.participant, args.session, args.device, args.responder,
                   args.data, args.quiet, resume=args.resume)
    acc = [r.correct for r in res.records if r.correct is not None]
    n = len({r.trial for r in res.records})
    _out(f"session {res.status}: {n} trials logged in {res.paths.dir}"
         + (f"; {sum(acc)}/{len(acc)} correct" if acc else ""))
    return 0


def cmd_analyze(args) -> int:
    from .analysis import load_sessions, recognition_rates
    from .analysis.report import markdown_table, write_reports

    trials, sessions = load_sessions(args.dirs, strict=args.strict)
    for s in sessions:
        for w in s.warnings:
            kind = "WARNING: CHECKSUM MISMATCH" if "checksum differs" in w else "warning"
            print(f"vtexp: {kind}: {w}", file=sys.stderr)
    specs = {}
    if args.experiment:
        from .experiment import load_experiment
        exp = load_experiment(args.experiment, check_stimuli=False).experiment
        if exp.analysis is None:
            raise InputError("has no 'analysis:' section to use", path=args.experiment)
        specs[exp.name] = exp.analysis
    if args.out:
        out = Path(args.out)
    else:
        first = Path(args.dirs[0])
        out = (first if not (first / "session.json").exists() else Path(".")) / "report"
    rep, full = write_reports(trials, sessions, out, specs=specs)
    for exp in sorted(trials["experiment"].unique()):
        sub = trials[trials["experiment"] == exp]
        factors = next(s.factors for s in sessions if s.meta["experiment"] == exp)
        if sub["correct"].notna().any():
            per = recognition_rates(sub, factors, per_participant=True)
            wide = per.pivot_table(index=factors, columns="participant", values="rate",
                                   observed=True)
            wide.columns = [f"sub-{c}" for c in wide.columns]
            wide["mean"] = recognition_rates(sub, factors).set_index(factors)["rate"]
            _out(f"\n{exp}: recognition rate per condition (rows) and participant (columns)")
            _out(markdown_table(wide.reset_index()))
        a = full[exp]["analysis"]
        for w in a.warnings:
            print(f"vtexp: warning: {exp}: {w}", file=sys.stderr)
        if a.sentences:
            _out(f"\n{exp}: results")
            for line in a.sentences:
                _out(f"  {line}")
        _out(f"\n{exp}: report {full[exp]['html']} (+ report.md and CSV tables in "
             f"{full[exp]['html'].parent}/)")
    _out(f"\n{len(sessions)} session(s), {len(trials)} trials. Tables and report in {out}/ "
         f"(report: {rep.markdown})")
    return 0


def cmd_demo(args) -> int:
    from .analysis import load_sessions
    from .analysis.report import markdown_table, write_reports
    from .compile import compile_conditions
    from .experiment import load_experiment
    from .resources import experiments_dir

    root = Path(args.data)
    if root.exists():
        if not (root / DEMO_MARKER).exists():
            raise InputError(f"{root} exists and was not made by 'vtexp demo'; it is left "
                             "alone. Pass --data DIR to choose another folder.")
        shutil.rmtree(root)
    root.mkdir(parents=True)
    (root / DEMO_MARKER).write_text("made by 'vtexp demo'; the next demo replaces it\n")
    path = experiments_dir() / f"{DEMO_EXPERIMENT}.yaml"
    lx = load_experiment(path)
    conds = compile_conditions(lx)
    exp = lx.experiment
    _out(f"vtexp demo — {exp.title}")
    _out(f"  experiment: {path}  ({exp.reference})")
    _out(f"  device: sim backend with profile {exp.device}; {len(conds)} conditions x "
         f"{exp.design.repetitions} repetitions per participant")
    _out("  answers: scripted responders, correct with the probability shown "
         "(a stand-in for people; no perception is modelled)")
    accuracies = [0.9, 0.8, 0.7, 0.6][: args.participants] if args.participants <= 4 else \
        [0.9 - 0.3 * i / (args.participants - 1) for i in range(args.participants)]
    for i, p_correct in enumerate(accuracies, start=1):
        pid = f"{i:02d}"
        res = _run_one(lx, pid, 1, "sim", f"scripted:accuracy={p_correct}", root, True, conds)
        stim_s = sum(r.stimulus_duration_ms or 0 for r in res.records) / 1000
        _out(f"  participant {pid}: p(correct)={p_correct:.2f}, {len(res.records)} trials, "
             f"{sum(1 for r in res.records if r.correct)} correct, {stim_s:.0f} s of "
             f"stimulation played on the simulated vest")
    trials, sessions = load_sessions([root / exp.name])
    rep, full = write_reports(trials, sessions, root / "report")
    _out("\nRecognition rate by duration/SOA (mean over participants ± SE):")
    _out(markdown_table(rep.tables[f"{exp.name}/by_timing"].drop(columns="experiment")))
    sentences = full[exp.name]["analysis"].sentences
    main = [x for x in sentences if not x.startswith("Simple effect")]
    if main:
        _out("\nThe analyses the experiment declares (seed 001 §4.1), main results:")
        for line in main:
            _out(f"  {line}")
        if len(main) < len(sentences):
            _out(f"  ... and {len(sentences) - len(main)} simple effects in the report.")
    _out(f"\nData:   {root / exp.name}/sub-*/ses-1/  (trial log .tsv, sidecar .json, "
         "device events .tsv, session.json)")
    _out(f"Report: {full[exp.name]['html']}  (+ report.md and CSV tables beside it)")
    _out(f"Next:   vtexp plan {path} --participant 01   |   vtexp analyze {root / exp.name}")
    return 0


# --------------------------------------------------------------------------- parser

def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="vtexp", description="Psychophysics experiments on tactile shape displays.")
    p.add_argument("--version", action="version", version=f"vtexp {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", required=True)

    s = sub.add_parser("validate", help="check experiment files")
    s.add_argument("files", nargs="+", metavar="FILE")
    s.set_defaults(func=cmd_validate)

    s = sub.add_parser("schema", help="write the JSON Schema of experiment files")
    s.add_argument("--out", metavar="FILE", help="write to FILE instead of standard output")
    s.set_defaults(func=cmd_schema)

    s = sub.add_parser("plan", help="print a participant's trial list")
    s.add_argument("file", metavar="FILE")
    s.add_argument("--participant", "-p", required=True)
    s.add_argument("--session", "-s", type=int, default=1)
    s.add_argument("--format", choices=["table", "tsv"], default="table")
    s.set_defaults(func=cmd_plan)

    s = sub.add_parser("run", help="run a session")
    s.add_argument("file", metavar="FILE")
    s.add_argument("--participant", "-p", required=True)
    s.add_argument("--session", "-s", type=int, default=1)
    s.add_argument("--device", default="sim", help="device backend (default: sim)")
    s.add_argument("--responder", required=True,
                   help="who answers: console (in this terminal) | scripted:correct | "
                        "scripted:random | scripted:accuracy=P | scripted:answers=FILE | "
                        "window (the "
                        "participant's PsychoPy window, fullscreen on screen 0; options "
                        "after a colon, comma-separated: windowed, fullscreen, screen=N, "
                        "size=WxH, abort=KEY (default escape), e.g. "
                        "window:windowed,size=1024x768 or window:screen=1; needs the "
                        "'gui' extra)")
    s.add_argument("--data", default="data", help="data folder (default: ./data)")
    s.add_argument("--quiet", "-q", action="store_true", help="no per-trial progress")
    s.add_argument("--resume", action="store_true",
                   help="continue this participant's unfinished session at its next trial")
    s.set_defaults(func=cmd_run)

    s = sub.add_parser("analyze", help="statistics and reports from logged sessions")
    s.add_argument("dirs", nargs="+", metavar="DIR",
                   help="session folders, or folders holding them (any mix)")
    s.add_argument("--out", help="folder for the tables and report")
    s.add_argument("--experiment", metavar="FILE",
                   help="use this experiment file's 'analysis:' section instead of the one "
                        "recorded in the sessions")
    s.add_argument("--strict", action="store_true",
                   help="refuse sessions whose files changed since they ended (checksum "
                        "mismatch) instead of warning")
    s.set_defaults(func=cmd_analyze)

    from .analysis.cli import register as register_stats
    register_stats(sub)

    from .encode_cli import register as register_encode
    register_encode(sub)

    from .devices.cli import register as register_device
    register_device(sub)

    s = sub.add_parser("demo", help="run, log and analyse a short study on the simulator")
    s.add_argument("--data", default="data/demo", help="demo folder (default: ./data/demo)")
    s.add_argument("--participants", type=int, default=4, choices=range(1, 21),
                   metavar="N", help="simulated participants (1-20, default 4)")
    s.set_defaults(func=cmd_demo)
    return p


def _sigterm(signum, frame):
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    signal.signal(signal.SIGTERM, _sigterm)     # turn the actuators off on 'kill' too
    try:
        return args.func(args)
    except VtexpError as e:
        _err(str(e))
        return e.exit_code
    except KeyboardInterrupt:
        _err("interrupted; every actuator was turned off and completed trials are kept")
        return 130
    except BrokenPipeError:                     # e.g. 'vtexp plan ... | head'
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":
    sys.exit(main())
