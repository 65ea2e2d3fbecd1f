"""``vtexp run``: one participant's session, with the experimenter at the terminal.

Who and which session (asked at a terminal when not given; an unfinished session
is offered to be continued), the device check before the first trial, the
session itself with a progress line per trial, and the experimenter's choices
when the device fails (:mod:`vtexp.cli.prompts`).

A resumed session takes its device and responder from its session record
unless given, and refuses a device of another kind (``sim``, ``serial``,
``emulator``) than the one it ran on without ``--force-device``. Whenever a run
ends before the session does (Escape, Ctrl-C, a device fault, a crash, or a
session found dead at the next start), the command that continues it is printed,
complete and ready to paste.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from datetime import datetime
from pathlib import Path

from ..errors import InputError
from ._io import note, out, program, quote
from .prompts import (ask_experimenter, ask_participant, ask_participant_info, ask_session,
                      place_object, status_of, yes)


def time_left_s(first_start: float, now: float, trials_done: int, trials_left: int,
                iti_s: float) -> float:
    """Seconds the rest of the session should take, from the trials of this run.

    A trial's time is measured from one trial's start to the next's, so it holds
    the answer, the replays and the pause between trials, and nothing from before
    the first trial (instructions, device check). ``now`` is when the last trial
    done was logged, before its pause: that pause is added.
    """
    if trials_done < 1:
        return float("nan")
    per_trial = (now - first_start + iti_s) / trials_done
    return per_trial * trials_left


def format_minutes(seconds: float) -> str:
    if seconds != seconds:          # nan
        return "?"
    if seconds < 60:
        return "<1 min"
    return f"{round(seconds / 60):d} min"


class _Progress:
    """The progress line: a consumer of the session's records that prints a line for each
    row of each trial once it is on disk. ``clock()``: the wall clock's seconds."""

    def __init__(self, quiet: bool, iti_s: float = 0.0, clock=None):
        from ..clock import REAL

        self.quiet = quiet
        self.iti_s = iti_s
        self.clock = clock or REAL.wall
        self.first_start: float | None = None
        self.trials: set[int] = set()
        self.correct = 0
        self.scored = 0

    def __call__(self, record) -> None:
        from ..session import TrialDone

        if isinstance(record, TrialDone):
            for rec in record.rows:
                self._row(rec, record.trial, record.total)

    def _row(self, rec, trial, total) -> None:
        self.trials.add(trial.number)
        if self.first_start is None:
            self.first_start = datetime.fromisoformat(rec.started_at).timestamp() \
                if rec.started_at else self.clock()
        if rec.correct is not None:
            self.scored += 1
            self.correct += int(rec.correct)
        if self.quiet:
            return
        now = self.clock()
        left = time_left_s(self.first_start, now, len(self.trials), total - trial.number,
                           self.iti_s)
        el = now - self.first_start
        acc = f"{self.correct / self.scored:5.1%}" if self.scored else "  n/a"
        print(f"  trial {trial.number:>4}/{total}  {trial.condition.label:<40} "
              f"answer {str(rec.answer):<12} elapsed {int(el // 60):d}:{int(el % 60):02d}  "
              f"left ~{format_minutes(left):<7} acc {acc}", file=sys.stderr, flush=True)


def resume_command(file, participant: str, session: int, device: str | None,
                   responder: str | None, data) -> str:
    """The command that continues a session, complete: it works from any folder."""
    parts = [program(), "run", str(Path(file).resolve()), "--participant", participant,
             "--session", str(session)]
    if device:
        parts += ["--device", device]
    if responder:
        parts += ["--responder", responder]
    parts += ["--data", str(Path(data).resolve()), "--resume"]
    return " ".join(parts[:1] + [quote(p) for p in parts[1:]])


def _prepare(args, lx, conds, participant: str, session: int, resume: bool,
             device_spec: str, responder_spec: str, info: dict[str, str]):
    """The device (made, not opened), the responder and the session's options, checked
    against the experiment before anything is written or opened: a refusal here prints no
    command to continue (there is nothing to continue)."""
    from ..devices import open_device
    from ..model import DeviceProfile
    from ..responders import make_responder
    from ..session import SessionOptions, check_run

    responder = make_responder(responder_spec, participant, session, lx)
    device = open_device(device_spec, DeviceProfile.load(lx.experiment.device))
    options = SessionOptions(
        participant=participant, session=session, data_dir=args.data, conditions=conds,
        command=sys.argv, on_device_error=ask_experimenter if sys.stdin.isatty() else None,
        resume=resume, max_trials=args.max_trials, device_spec=device_spec,
        responder_spec=responder_spec, force_device=args.force_device,
        capture_prompt=place_object if sys.stdin.isatty() else None,
        participant_info=info, warn=_warn)
    check_run(lx, device, responder, options)
    return device, responder, options


def _warn(text: str) -> None:
    print(f"vtexp: warning: {text}", file=sys.stderr, flush=True)


def _run_one(lx, device, responder, options, *, quiet: bool, test_pulse: bool, markers=()):
    """The device checked, then the session, its records to the progress line and the
    markers."""
    from ..session import run_session

    progress = _Progress(quiet, lx.experiment.design.iti_ms / 1000.0, device.clock.wall)
    with device:
        _check_device(device, device.profile, test_pulse)
        return run_session(lx, device, responder, options, consumers=(progress, *markers))


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


def open_marker_outputs(specs, lx, participant: str, session: int, clock=None) -> list:
    """The ``--markers`` outputs, opened before the device: one that cannot be opened
    ends the run in one message, before any trial (those already open are closed)."""
    from ..markers import open_markers

    opened = []
    try:
        for spec in specs or ():
            m = open_markers(spec, experiment=lx.experiment.name, participant=participant,
                             session=session, warn=_warn, clock=clock)
            opened.append(m)
            out(f"markers: {m.description}"
                + (f" (source_id {m.source_id})" if getattr(m, "source_id", None) else ""))
    except BaseException:
        for m in opened:
            m.close()
        raise
    return opened


def _report_dead(args, lx) -> None:
    """Sessions of this experiment whose process died are marked, with how to continue."""
    from ..session import mark_dead_sessions, recorded_run

    for x in mark_dead_sessions(args.data, lx.experiment.name):
        rec = recorded_run(x["record"])
        out(f"Session {x['session']} of participant {x['participant']} did not close "
            f"({x['logged']} of {x['planned']} trials logged): {x['reason']}. It is marked "
            "interrupted. To continue it:\n  "
            + resume_command(args.file, x["participant"], x["session"], rec.get("device"),
                             rec.get("responder"), args.data))


def _who_and_which(args, lx) -> tuple[str, int, bool]:
    """The participant, the session and whether to resume it: from the options, else
    asked at the terminal (which offers to continue an unfinished session)."""
    from ..errors import SessionAborted, SessionError
    from ..session import check_participant, check_session, list_sessions

    participant, session, resume = args.participant, args.session, args.resume
    if participant is None and not sys.stdin.isatty():
        raise InputError("missing: give the participant id (e.g. --participant 01), or run "
                         "'vtexp run' at a terminal to be asked for it", key="--participant")
    exp = lx.experiment
    try:
        if participant is None:
            participant = ask_participant()
            existing = list_sessions(args.data, exp.name, participant)
            if session is None:
                session, resume = ask_session(participant, existing, args, lx)
        else:
            existing = list_sessions(args.data, exp.name, participant)
    except KeyboardInterrupt:
        raise SessionAborted("stopped at the prompt; nothing was played or written") from None
    session = 1 if session is None else session
    check_participant(participant)
    check_session(session)
    clash = next((x for x in existing if x["session"] == session), None)
    if clash and clash.get("held_by"):
        from ..lock import describe_holder
        raise SessionError(f"session {session} of participant {participant} is running now in "
                           f"another vtexp process ({describe_holder(clash['held_by'])}); "
                           "nothing was touched.")
    if clash and not resume:           # say so now, before the device is opened
        free = max(x["session"] for x in existing) + 1
        hint = "" if clash["status"] == "completed" else (
            " To continue it: " + resume_command(args.file, participant, session,
                                                 args.device or clash.get("device"),
                                                 args.responder or clash.get("responder"),
                                                 args.data))
        raise SessionError(f"session {session} of participant {participant} already exists "
                           f"in {Path(args.data) / exp.name / f'sub-{participant}'} "
                           f"({status_of(clash)}); nothing was overwritten. Use "
                           f"--resume to continue it, or another --session number (the "
                           f"next free one is {free}).{hint}")
    return participant, session, resume


def _specs(args, lx, participant: str, session: int, resume: bool) -> tuple[str, str]:
    """The device and responder: as given, else (resuming) as recorded, else the defaults."""
    from ..session import SessionPaths, recorded_run

    device, responder = args.device, args.responder
    if resume:
        rec = recorded_run(SessionPaths.of(args.data, lx.experiment.name, lx.experiment.task_label,
                                           participant, session))
        if device is None and rec.get("device"):
            device = rec["device"]
            out(f"device as recorded in the session record: {device}")
        if responder is None and rec.get("responder"):
            responder = rec["responder"]
            out(f"responder as recorded in the session record: {responder}")
    if responder is None:
        raise InputError("missing: who answers, e.g. --responder window (the participant's "
                         "window) or --responder console"
                         + (" (this session's record does not say)" if resume
                            else ""), key="--responder")
    return device or "sim", responder


def _given_info(args, lx) -> dict[str, str]:
    """What ``--participant-info`` gives, each value checked."""
    from .. import bids

    fields = bids.participant_fields(lx.experiment.participants)
    return bids.check_info(bids.parse_info(args.participant_info), fields)


def _participant_info(args, lx, participant: str, info: dict[str, str]) -> dict[str, str]:
    """What participants.tsv records of the participant: ``info`` (``--participant-info``),
    and at a terminal, for a participant the dataset does not know yet, the fields not
    given (never asked of model participants, nor without a terminal)."""
    from .. import bids
    from ..errors import SessionAborted
    from ..session import SIMULATED_PREFIX

    exp = lx.experiment
    fields = bids.participant_fields(exp.participants)
    root = Path(args.data) / exp.name
    known = bids.known_participant(root, participant)
    if known is not None or not sys.stdin.isatty() or \
            participant.lower().startswith(SIMULATED_PREFIX):
        return info
    try:
        return ask_participant_info(participant, fields, info, root / bids.PARTICIPANTS)
    except KeyboardInterrupt:
        raise SessionAborted("stopped at the prompt; nothing was played or written") from None


def cmd_run(args) -> int:
    from ..compile import load_and_compile
    from ..session import SessionPaths, recorded_run

    if args.max_trials is not None and args.max_trials < 1:
        raise InputError(f"must be 1 or more (got {args.max_trials})", key="--max-trials")
    if args.test_pulse and not sys.stdin.isatty():
        raise InputError("asks the experimenter at a terminal before it plays; standard "
                         "input is not a terminal", key="--test-pulse")
    lx, conds = load_and_compile(args.file)
    for msg in lx.notes:
        note(msg)
    _report_dead(args, lx)
    participant, session, resume = _who_and_which(args, lx)
    device_spec, responder_spec = _specs(args, lx, participant, session, resume)
    given = _given_info(args, lx)
    device, responder, options = _prepare(args, lx, conds, participant, session, resume,
                                          device_spec, responder_spec, given)
    # A participant new to the dataset is asked what was not given (nothing it can
    # contradict): after the checks, so that a run refused asks nothing.
    options = replace(options, participant_info=_participant_info(args, lx, participant,
                                                                  given))
    paths = SessionPaths.of(args.data, lx.experiment.name, lx.experiment.task_label,
                            participant, session)

    def hint() -> str | None:
        """How to continue the session, if this run left it unfinished."""
        rec = recorded_run(paths)
        if not rec or rec.get("status") == "completed":
            return None
        return (f"To continue session {session} of participant {participant} where it "
                "stopped:\n  " + resume_command(args.file, participant, session,
                                                rec.get("device") or device_spec,
                                                rec.get("responder") or responder_spec,
                                                args.data))
    args.after_error = hint
    markers = open_marker_outputs(args.markers, lx, participant, session, device.clock)
    try:
        res = _run_one(lx, device, responder, options, quiet=args.quiet,
                       test_pulse=args.test_pulse, markers=markers)
    finally:
        for m in markers:
            m.close()
            if m.lost:
                out(f"markers: {m.lost} could not be sent to the {m.description}")
    acc = [r.correct for r in res.records if r.correct is not None]
    n = len({r.trial for r in res.records})
    out(f"session {res.status}: {n} trials logged in {res.paths.dir}"
        + (f"; {sum(acc)}/{len(acc)} correct" if acc else ""))
    if res.status == "aborted":             # only --max-trials ends a run this way
        out(f"stopped after {n} trial{'' if n == 1 else 's'} as asked (--max-trials "
            f"{args.max_trials}); to continue: "
            + resume_command(args.file, participant, session, device_spec, responder_spec,
                             args.data))
    return 0


def register(sub) -> None:
    """Add ``vtexp run`` to the ``vtexp`` parser."""
    s = sub.add_parser("run", help="run a session")
    s.add_argument("file", metavar="FILE")
    s.add_argument("--participant", "-p",
                   help="participant id, letters and digits; asked at a terminal if not given "
                        "(ids starting with 'sim' are kept for model participants)")
    s.add_argument("--session", "-s", type=int,
                   help="session number (default 1; asked at a terminal with the participant "
                        "id, showing the sessions that exist)")
    s.add_argument("--device",
                   help="sim (default), sim:realtime, serial:PORT or emulator; checked before "
                        "the first trial (identity, round trip, all actuators off). With "
                        "--resume, the one recorded in the session record unless given")
    s.add_argument("--responder",
                   help="who answers: console (in this terminal) | scripted:correct | "
                        "scripted:random | scripted:accuracy=P | scripted:answers=FILE | "
                        "model[:seed=N,typical] (a model participant, see 'vtexp simulate') | "
                        "window (the participant's PsychoPy window, fullscreen on screen 0; "
                        "options after a colon, comma-separated: windowed, fullscreen, "
                        "screen=N, size=WxH, abort=KEY (default escape), scale=S (text S "
                        "times larger, 1-2.5), audio (every text spoken, answers by keys), "
                        "lang=LANG (espeak-ng's), noise=on|off (masking noise during each "
                        "stimulus), device=NAME (the sound output, see 'vtexp device list "
                        "--audio'), e.g. window:windowed,size=1024x768 or "
                        "window:audio,lang=de; needs the 'gui' extra). Required, except "
                        "with --resume, which takes the one recorded in the session record")
    s.add_argument("--participant-info", metavar="FIELD=VALUE,...",
                   help="what the dataset's participants.tsv records of a new participant, "
                        "e.g. group=blind,age=34,handedness=right,vision=blind (and the "
                        "experiment's own 'participants:' fields); at a terminal the fields "
                        "not given are asked at the participant's first session")
    s.add_argument("--data", default="data",
                   help="data folder (default: ./data); each experiment's sessions form the "
                        "BIDS dataset DATA/<experiment>/")
    s.add_argument("--quiet", "-q", action="store_true", help="no per-trial progress")
    s.add_argument("--resume", action="store_true",
                   help="continue this participant's unfinished session at its next trial, "
                        "with the device and responder recorded in its session record unless "
                        "given")
    s.add_argument("--force-device", action="store_true",
                   help="with --resume, continue on a device of another kind than the one "
                        "the session ran on (e.g. sim after serial)")
    s.add_argument("--max-trials", type=int, metavar="N",
                   help="stop after N trials (status aborted, resumable with --resume)")
    s.add_argument("--markers", action="append", metavar="SPEC",
                   help="send event markers to a recorder (EEG, physiology), opened before "
                        "the first trial: lsl (a Lab Streaming Layer stream of type Markers, "
                        "the 'lsl' extra; pulses stamped with their device-reported onsets), "
                        "serial:PORT[,baud=N,reset_ms=N] (a trigger box: one byte code per "
                        "event) or parallel:ADDRESS (/dev/parport0, 0x378). May be given "
                        "more than once. See docs/markers.md")
    s.add_argument("--test-pulse", action="store_true",
                   help="after the device check, offer one low pulse on actuator (row 0, "
                        "col 0), played only if the experimenter answers y")
    s.set_defaults(func=cmd_run)
