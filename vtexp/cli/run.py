"""``vtexp run``: one participant's session, with the experimenter at the terminal.

Who and which session (asked at a terminal when not given), the device check
before the first trial, the session itself with a progress line per trial, and
the experimenter's choices when the device fails (:mod:`vtexp.cli.prompts`).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from ..errors import InputError
from ._io import out
from .prompts import (ask_experimenter, ask_participant, ask_session, place_object,
                      status_of, yes)


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
    from ..devices import open_device
    from ..model import DeviceProfile
    from ..responders import make_responder
    from ..session import check_participant, check_session, run_session

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
                           on_device_error=ask_experimenter if sys.stdin.isatty() else None,
                           resume=resume, max_trials=max_trials,
                           capture_prompt=place_object if sys.stdin.isatty() else None)


def _check_device(device, profile, test_pulse: bool) -> None:
    """Before the first trial: the device is the profile's, its link answers, all is off.

    Nothing is played unless the experimenter agrees to a test pulse (``--test-pulse``).
    """
    from ..devices.check import check_ready, low_pulse
    from ..errors import DeviceError
    from ..model import Schedule

    out("device check before the first trial:")
    try:
        check_ready(device, profile, say=lambda line: out(f"  {line}"))
    except DeviceError as e:
        raise DeviceError(f"device check failed, before any trial: {e}. No trial was "
                          "played and no session data were written.") from None
    if test_pulse:
        on_ms = min(300.0, profile.limits.max_on_ms)
        pulse = low_pulse(profile, 0, 0, on_ms)
        what = (f"level {pulse.level}" if pulse.level is not None else
                f"{pulse.train.amplitude_v:g} V, {pulse.train.frequency_hz:g} Hz")
        if yes(f"Play a test pulse on actuator (row 0, col 0), {what} for {on_ms:g} ms? "
                "[y/N] "):
            device.play(Schedule(device=profile.name, pulses=[pulse]))
            if not yes("Was it felt (or seen to move)? [y/N] "):
                raise DeviceError("the test pulse on actuator (row 0, col 0) was not felt; "
                                  "the session was not started. Check the device with "
                                  "'vtexp device check'.")
        else:
            out("  no test pulse played")
    out("device check passed; no actuator is on")


def _who_and_which(args, lx) -> tuple[str, int]:
    """The participant and session: from the options, else asked at the terminal."""
    from ..errors import SessionAborted, SessionError
    from ..session import check_participant, check_session, list_sessions

    participant, session = args.participant, args.session
    if participant is None and not sys.stdin.isatty():
        raise InputError("missing: give the participant id (e.g. --participant 01), or run "
                         "'vtexp run' at a terminal to be asked for it", key="--participant")
    exp = lx.experiment
    try:
        if participant is None:
            participant = ask_participant()
            existing = list_sessions(args.data, exp.name, participant)
            if session is None:
                session = ask_session(participant, existing, args, lx)
        else:
            existing = list_sessions(args.data, exp.name, participant)
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
                           f"({status_of(clash)}); nothing was overwritten. Use "
                           f"--resume to continue it, or another --session number (the "
                           f"next free one is {free}).")
    return participant, session


def cmd_run(args) -> int:
    from ..compile import load_and_compile

    if args.max_trials is not None and args.max_trials < 1:
        raise InputError(f"must be 1 or more (got {args.max_trials})", key="--max-trials")
    if args.test_pulse and not sys.stdin.isatty():
        raise InputError("asks the experimenter at a terminal before it plays; standard "
                         "input is not a terminal", key="--test-pulse")
    lx, conds = load_and_compile(args.file)
    participant, session = _who_and_which(args, lx)
    res = _run_one(lx, participant, session, args.device, args.responder,
                   args.data, args.quiet, conds, resume=args.resume, check_device=True,
                   test_pulse=args.test_pulse, max_trials=args.max_trials)
    acc = [r.correct for r in res.records if r.correct is not None]
    n = len({r.trial for r in res.records})
    out(f"session {res.status}: {n} trials logged in {res.paths.dir}"
        + (f"; {sum(acc)}/{len(acc)} correct" if acc else ""))
    if res.status == "aborted":             # only --max-trials ends a run this way
        out(f"stopped after {n} trial{'' if n == 1 else 's'} as asked (--max-trials "
            f"{args.max_trials}); to continue: vtexp run {args.file} --participant "
            f"{participant} --session {session} --resume")
    return 0


def register(sub) -> None:
    """Add ``vtexp run`` to the ``vtexp`` parser."""
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
