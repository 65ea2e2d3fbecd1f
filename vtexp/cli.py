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
             resume=False, *, check_device=False, test_pulse=False, max_trials=None):
    from .devices import open_device
    from .model import DeviceProfile
    from .responders import make_responder
    from .session import check_participant, check_session, run_session

    check_participant(participant)
    check_session(session)
    profile = DeviceProfile.load(lx.experiment.device)
    responder = make_responder(responder_spec, participant, session, lx)
    device = open_device(device_spec, profile)
    with device:
        if check_device:
            _check_device(device, profile, test_pulse)
        return run_session(lx, participant, session, device, responder, data, conditions=conds,
                           sinks=(_Progress(quiet),), command=sys.argv,
                           on_device_error=_ask_experimenter if sys.stdin.isatty() else None,
                           resume=resume, max_trials=max_trials)


def _check_device(device, profile, test_pulse: bool) -> None:
    """Before the first trial: the device is the profile's, its link answers, all is off.

    Nothing is played unless the experimenter agrees to a test pulse (``--test-pulse``).
    """
    from .devices.cli import _low_pulse, check_ready
    from .errors import DeviceError
    from .model import Schedule

    _out("device check before the first trial:")
    try:
        check_ready(device, profile, say=lambda line: _out(f"  {line}"))
    except DeviceError as e:
        raise DeviceError(f"device check failed, before any trial: {e}. No trial was "
                          "played and no session data were written.") from None
    if test_pulse:
        on_ms = min(300.0, profile.limits.max_on_ms)
        pulse = _low_pulse(profile, 0, 0, on_ms)
        what = (f"level {pulse.level}" if pulse.level is not None else
                f"{pulse.train.amplitude_v:g} V, {pulse.train.frequency_hz:g} Hz")
        if _yes(f"Play a test pulse on actuator (row 0, col 0), {what} for {on_ms:g} ms? "
                "[y/N] "):
            device.play(Schedule(device=profile.name, pulses=[pulse]))
            if not _yes("Was it felt (or seen to move)? [y/N] "):
                raise DeviceError("the test pulse on actuator (row 0, col 0) was not felt; "
                                  "the session was not started. Check the device with "
                                  "'vtexp device check'.")
        else:
            _out("  no test pulse played")
    _out("device check passed; no actuator is on")


def _yes(prompt: str) -> bool:
    try:
        return input(prompt).strip().lower() in ("y", "yes")
    except (EOFError, OSError):     # input ended, or the terminal went away
        return False


def _existing_sessions(data, experiment: str, participant: str) -> list[dict]:
    """The sessions of ``participant`` already in the data folder, by number."""
    import json
    import re

    found = []
    folder = Path(data) / experiment / f"sub-{participant}"
    for d in folder.glob("ses-*") if folder.is_dir() else ():
        m = re.fullmatch(r"ses-(\d+)", d.name)
        if not (m and d.is_dir()):
            continue
        try:
            meta = json.loads((d / "session.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            meta = {}
        meta = meta if isinstance(meta, dict) else {}
        found.append({"session": int(m[1]), "status": meta.get("status") or "unreadable",
                      "logged": meta.get("n_trials_logged"),
                      "planned": meta.get("n_trials_planned"),
                      "started": meta.get("started_at") or "", "reason": meta.get("reason")})
    return sorted(found, key=lambda x: x["session"])


def _status_of(x: dict) -> str:
    status = "did not close (killed?)" if x["status"] == "running" else x["status"]
    if x["planned"] is None:
        return f"{status}, no session.json"
    return f"{status}, {x['logged']} of {x['planned']} trials"


def _describe_session(x: dict) -> str:
    line = f"ses-{x['session']}  {_status_of(x)}"
    if x["started"]:
        line += f", started {x['started'][:16].replace('T', ' ')}"
    return line + (f" ({x['reason']})" if x["reason"] else "")


def _who_and_which(args, lx) -> tuple[str, int]:
    """The participant and session: from the options, else asked at the terminal."""
    from .errors import SessionAborted, SessionError
    from .session import check_participant, check_session

    participant, session = args.participant, args.session
    if participant is None and not sys.stdin.isatty():
        raise InputError("missing: give the participant id (e.g. --participant 01), or run "
                         "'vtexp run' at a terminal to be asked for it", key="--participant")
    exp = lx.experiment
    try:
        if participant is None:
            participant = _ask_participant()
            existing = _existing_sessions(args.data, exp.name, participant)
            if session is None:
                session = _ask_session(participant, existing, args, lx)
        else:
            existing = _existing_sessions(args.data, exp.name, participant)
    except KeyboardInterrupt:
        raise SessionAborted("stopped at the prompt; nothing was played or written") from None
    session = 1 if session is None else session
    check_participant(participant)
    check_session(session)
    clash = next((x for x in existing if x["session"] == session), None)
    if clash and not args.resume:           # say so now, before the device is opened
        free = max(x["session"] for x in existing) + 1
        raise SessionError(f"session {session} of participant {participant} already exists "
                           f"in {Path(args.data) / exp.name / f'sub-{participant}'} "
                           f"({_status_of(clash)}); nothing was overwritten. Use "
                           f"--resume to continue it, or another --session number (the "
                           f"next free one is {free}).")
    return participant, session


def _ask_participant() -> str:
    from .session import check_participant

    while True:
        try:
            answer = input("Participant id: ").strip()
        except (EOFError, OSError):     # input ended, or the terminal went away
            raise InputError("missing: no participant id was given",
                             key="--participant") from None
        try:
            return check_participant(answer)
        except InputError as e:
            print(f"  {e.message}", flush=True)


def _ask_session(participant: str, existing: list[dict], args, lx) -> int:
    from .errors import SessionError
    from .session import check_session

    where = Path(args.data) / lx.experiment.name / f"sub-{participant}"
    unfinished = [x for x in existing if x["status"] != "completed"]
    if existing:
        _out(f"Sessions of participant {participant} already in {where}:")
        for x in existing:
            _out(f"  {_describe_session(x)}")
    else:
        _out(f"Participant {participant} has no sessions yet in {where.parent}.")
    if args.resume:
        if not unfinished:
            raise SessionError(f"participant {participant} has no unfinished session in "
                               f"{where.parent} to resume (--resume)")
        default, prompt = unfinished[-1]["session"], "Session to resume"
    else:
        default = max((x["session"] for x in existing), default=0) + 1
        prompt = "Session"
        if existing and existing[-1]["status"] != "completed":
            last = existing[-1]["session"]
            _out(f"Session {last} did not finish. To continue it, stop here (Ctrl-C) and run "
                 f"'vtexp run {args.file} --participant {participant} --session {last} "
                 "--resume'.")
    while True:
        try:
            answer = input(f"{prompt} [{default}]: ").strip()
        except (EOFError, OSError):     # input ended, or the terminal went away
            raise InputError("missing: no session number was given", key="--session") from None
        try:
            session = check_session(int(answer) if answer else default)
        except ValueError:
            print(f"  {answer!r} is not a whole number", flush=True)
            continue
        except InputError as e:
            print(f"  {e.message}", flush=True)
            continue
        known = next((x for x in existing if x["session"] == session), None)
        if args.resume and known not in unfinished:
            print(f"  session {session} is not an unfinished session of participant "
                  f"{participant}; sessions to resume: "
                  + ", ".join(str(x["session"]) for x in unfinished), flush=True)
        elif not args.resume and known is not None:
            print(f"  session {session} already exists ({_status_of(known)}); choose another "
                  "number, or stop (Ctrl-C) and continue it with --resume", flush=True)
        else:
            return session


def _ask_experimenter(error, trial) -> str:
    """The session pauses on a device fault until the experimenter chooses what to do."""
    print(f"\nThe device failed during trial {trial.number} ({trial.condition.label}):\n"
          f"  {error}\nEvery actuator is off. The session is paused.", file=sys.stderr)
    while True:
        try:
            answer = input("[r]etry the trial (reconnect first), [s]kip it, or [a]bort the "
                           "session? ").strip().lower()
        except (EOFError, OSError):     # input ended, or the terminal went away
            return "abort"
        for choice in ("retry", "skip", "abort"):
            if answer in (choice, choice[0]):
                return choice


def cmd_run(args) -> int:
    from .experiment import load_experiment

    if args.max_trials is not None and args.max_trials < 1:
        raise InputError(f"must be 1 or more (got {args.max_trials})", key="--max-trials")
    if args.test_pulse and not sys.stdin.isatty():
        raise InputError("asks the experimenter at a terminal before it plays; standard "
                         "input is not a terminal", key="--test-pulse")
    lx = load_experiment(args.file)
    participant, session = _who_and_which(args, lx)
    res = _run_one(lx, participant, session, args.device, args.responder,
                   args.data, args.quiet, resume=args.resume, check_device=True,
                   test_pulse=args.test_pulse, max_trials=args.max_trials)
    acc = [r.correct for r in res.records if r.correct is not None]
    n = len({r.trial for r in res.records})
    _out(f"session {res.status}: {n} trials logged in {res.paths.dir}"
         + (f"; {sum(acc)}/{len(acc)} correct" if acc else ""))
    if res.status == "aborted":             # only --max-trials ends a run this way
        _out(f"stopped after {n} trial{'' if n == 1 else 's'} as asked (--max-trials "
             f"{args.max_trials}); to continue: vtexp run {args.file} --participant "
             f"{participant} --session {session} --resume")
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


#: The four studies of the papers, with the repetitions of the demo's short version.
DEMO_STUDIES = [("six_mode_ball", 3), ("duration_interval_grid", 1), ("whirlpool", 2),
                ("circle_vs_rectangle", 3)]


def _short_version(src: Path, dest: Path, repetitions: int) -> Path:
    """A copy of an experiment file with fewer repetitions, saying so at its top."""
    import re

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
    import pandas as pd

    from .analysis import load_sessions
    from .analysis.report import write_reports
    from .compile import compile_conditions
    from .devices.sim import SimDevice
    from .experiment import load_experiment
    from .observer import ModelObserver, ObserverModel
    from .resources import experiments_dir
    from .session import run_session

    t0 = time.perf_counter()
    root = Path(args.data)
    if root.exists():
        if not (root / DEMO_MARKER).exists():
            raise InputError(f"{root} exists and was not made by 'vtexp demo'; it is left "
                             "alone. Pass --data DIR to choose another folder.")
        shutil.rmtree(root)
    (root / "experiments").mkdir(parents=True)
    (root / DEMO_MARKER).write_text("made by 'vtexp demo'; the next demo replaces it\n")
    _out("vtexp demo: the four studies of the papers, each run by "
         f"{args.participants} model participants on the simulated device\n")
    _out("A model participant feels what the device reports it played: blurred by the skin's "
         "two-point\nthreshold, limited to 7-8 intensity levels, integrated over ~40 ms; it "
         "answers by comparing\nthat percept with every answer option rendered the same way "
         "(protocols/observers/default.yaml).\n")
    summary = []
    for name, reps in DEMO_STUDIES:
        src = experiments_dir() / f"{name}.yaml"
        path = _short_version(src, root / "experiments" / f"{name}.yaml", reps)
        lx = load_experiment(path)
        exp = lx.experiment
        model = ObserverModel.for_experiment(lx)
        conds = compile_conditions(lx, model.profile)
        n_trials = 0
        for i in range(1, args.participants + 1):
            pid = f"m{i:02d}"
            res = run_session(lx, pid, 1, SimDevice(model.profile),
                              ModelObserver(model, pid, 1, seed=args.seed), root,
                              conditions=conds, command=sys.argv)
            n_trials = len({r.trial for r in res.records})
        _out(f"  {exp.title}\n    {exp.reference}; {exp.device}; {len(conds)} conditions x "
             f"{reps} repetition{'s' if reps > 1 else ''} = {n_trials} trials per participant: logged")
        summary.append((name, exp, n_trials))
    names = [n for n, _ in DEMO_STUDIES]
    trials, sessions = load_sessions([root / n for n in names])
    _, full = write_reports(trials, sessions, root / "report")
    _out("\nWhat the model participants did, and the first test each study declares:")
    for name, exp, n_trials in summary:
        a = full[name]["analysis"]
        sub = trials[trials["experiment"] == name]
        if sub["correct"].notna().any():
            what = f"recognition rate {sub['correct'].astype(float).mean():.0%}"
        else:
            parts = []
            for q, g in sub.groupby("question"):
                parts.append(f"mean {q} {pd.to_numeric(g['answer']).mean():.2f}")
            what = ", ".join(parts)
        _out(f"  {name:<24} {args.participants} x {n_trials} trials, {what}")
        _out(f"  {'':<24} {_headline(a)}")
    _out(f"\nTook {time.perf_counter() - t0:.0f} s. Everything is in {root}/:")
    _out(f"  {root}/<study>/sub-*/ses-1/   the logs a real session writes (trials .tsv, "
         "sidecar .json, device events .tsv, session.json)")
    _out(f"  {root}/experiments/           the short versions that were run")
    _out(f"  {root}/report/                the report: {root}/report/report.md, and per "
         "study an HTML page with figures and tables:")
    for name, _, _ in summary:
        _out(f"      {full[name]['html']}")
    _out("\nNext: how many participants would a study need?")
    _out("  vtexp simulate experiments/six_mode_ball.yaml --participants 15 --studies 1000 "
         "--target-power 0.8")
    _out("Or run a person: README.md, \"Running a session with a participant\".")
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
    s.add_argument("--participant", "-p",
                   help="participant id, letters and digits; asked at a terminal if not given")
    s.add_argument("--session", "-s", type=int,
                   help="session number (default 1; asked at a terminal with the participant "
                        "id, showing the sessions that exist)")
    s.add_argument("--device", default="sim",
                   help="sim (default), sim:realtime, serial:PORT or emulator; checked before "
                        "the first trial (identity, round trip, all actuators off)")
    s.add_argument("--responder", required=True,
                   help="who answers: console (in this terminal) | scripted:correct | "
                        "scripted:random | scripted:accuracy=P | scripted:answers=FILE | "
                        "model[:seed=N,typical] (a model participant, see 'vtexp simulate') | "
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
    s.add_argument("--max-trials", type=int, metavar="N",
                   help="stop after N trials (status aborted, resumable with --resume)")
    s.add_argument("--test-pulse", action="store_true",
                   help="after the device check, offer one low pulse on actuator (row 0, "
                        "col 0), played only if the experimenter answers y")
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

    s = sub.add_parser("demo", help="the four studies run by model participants, analysed")
    s.add_argument("--data", default="data/demo", help="demo folder (default: ./data/demo)")
    s.add_argument("--participants", type=int, default=6, choices=range(2, 21),
                   metavar="N", help="model participants per study (2-20, default 6)")
    s.add_argument("--seed", type=int, default=0, help="model participants' seed (default 0)")
    s.set_defaults(func=cmd_demo)

    from .simulate_cli import add_parser as add_simulate
    from .simulate_cli import cmd_simulate
    add_simulate(sub)
    sub.choices["simulate"].set_defaults(func=cmd_simulate)
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
