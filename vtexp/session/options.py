"""How a session is to run (:class:`SessionOptions`), and every check of that against the
experiment, the device, the responder and the data folder, made before anything is
written or opened (:func:`check_run`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from .. import bids
from ..adaptive.track import AdaptiveRun
from ..clock import REAL, Clock
from ..compile import compile_conditions
from ..design import Trial, trial_list
from ..errors import DeviceError, InputError, SessionError
from ..experiment import LoadedExperiment
from ..model import Condition, DeviceProfile
from ..responders.base import call_hook
from .camera import CameraTrials
from .paths import (SessionPaths, check_participant, check_participant_kind, check_session,
                    participant_kind)
from .resume import check_resumable
from .store import check_new_place, check_resume_place, legacy_sessions, read_record

DeviceFaultHandler = Callable[[DeviceError, Trial], str]
"""Asked what to do when the device fails during a trial: "retry", "skip" or "abort"."""


@dataclass(frozen=True)
class SessionOptions:
    """How to run one session of an experiment.

    ``participant``, ``session`` and ``data_dir``: who, which, and where the dataset is.
    ``conditions``: the experiment's compiled conditions, if the caller has them.
    ``command``: the command line recorded (default ``sys.argv``).

    ``on_device_error(error, trial)``: asked when the device fails during a trial (every
    actuator is already off): ``"retry"`` (reopen the device, play the trial again),
    ``"skip"`` (log it with status ``device_error``), ``"abort"`` (the session ends
    ``failed`` and the error is raised). Without it, the session aborts.

    ``resume``: continue an unfinished session at the first trial its log lacks.
    ``max_trials=N``: stop after N trials of this run (status ``aborted``, resumable).
    ``device_spec``, ``responder_spec``: the ``--device``/``--responder`` given, recorded
    so that a resume can use them again. ``force_device``: resume on a device of another
    kind than the session ran on.

    ``capture_prompt(text)``: asks the experimenter to place a camera stimulus's object
    and returns when it is in place; camera stimuli without ``delay_s`` need it.
    ``participant_info``: field -> value for participants.tsv (group, age, ...).

    ``clock``: the clock of timestamps, host times and waits (default: the device's).
    ``warn(text)``: told when a consumer of the session's records failed (default: a line
    on stderr); the session goes on.
    """

    participant: str
    data_dir: Path | str
    session: int = 1
    conditions: list[Condition] | None = None
    command: list[str] | None = None
    on_device_error: DeviceFaultHandler | None = None
    resume: bool = False
    max_trials: int | None = None
    device_spec: str | None = None
    responder_spec: str | None = None
    force_device: bool = False
    capture_prompt: Callable[[str], None] | None = None
    participant_info: dict[str, str] | None = None
    clock: Clock | None = None
    warn: Callable[[str], None] | None = None


@dataclass
class SessionSetup:
    """What a run of a session is, once checked (:func:`check_run`)."""

    lx: LoadedExperiment
    options: SessionOptions
    profile: DeviceProfile
    paths: SessionPaths
    conditions: list[Condition]
    trials: list[Trial]
    seed: int
    adaptive: AdaptiveRun | None
    camera: CameraTrials | None
    participant_fields: dict[str, dict]
    participant_info: dict[str, str]
    run_info: dict
    clock: Clock

    @property
    def who(self) -> str:
        return f"session {self.paths.session} of participant {self.paths.participant}"


def check_run(lx: LoadedExperiment, device, responder, options: SessionOptions
              ) -> SessionSetup:
    """Check a run of a session before anything is written or opened, and say what it is.

    Refused here: a participant id or session number that is not one, a model participant
    without a ``sim`` id (or a person with one), a device whose profile is not the
    experiment's, ``max_trials`` below 1, a responder that cannot answer the questions
    (its ``check_questions``), participant info the dataset contradicts, a data folder of
    the layout before BIDS, a camera stimulus that would ask no one, a new session that
    exists, a session to resume that does not or whose record says it cannot be (see
    :func:`~vtexp.session.resume.check_resumable`). Nothing is written, nothing opened.
    """
    exp, o = lx.experiment, options
    check_participant(o.participant)
    check_session(o.session)
    kind = participant_kind(responder)
    check_participant_kind(o.participant, kind)
    profile: DeviceProfile = device.profile
    if profile.name != exp.device:
        raise InputError(f"the experiment is declared for device {exp.device!r}, but the "
                         f"device opened is {profile.name!r}", key="--device")
    if o.max_trials is not None and not (isinstance(o.max_trials, int) and o.max_trials >= 1):
        raise InputError(f"must be 1 or more (got {o.max_trials})", key="--max-trials")
    call_hook(responder, "check_questions", exp.asked())
    conditions = o.conditions or compile_conditions(lx, profile)
    trials, seed = trial_list(exp, conditions, o.participant, o.session)
    paths = SessionPaths.of(o.data_dir, exp.name, exp.task_label, o.participant, o.session)
    fields = bids.participant_fields(exp.participants)
    info = bids.check_info(o.participant_info or {}, fields)
    bids.check_participant_info(paths.root, o.participant, info)
    legacy = legacy_sessions(paths.root)
    if legacy:
        raise SessionError(f"{paths.root} holds sessions in the layout of vtexp before BIDS "
                           f"(e.g. {legacy[0]}); new sessions are not added to it. Give "
                           "another data folder (--data); vtexp analyze still reads this one")
    setup = SessionSetup(
        lx, o, profile, paths, conditions, trials, seed, AdaptiveRun.of(lx, conditions, seed),
        CameraTrials.of(lx, paths.record_dir, o.capture_prompt), fields, info,
        {"device_spec": o.device_spec or getattr(device, "backend", None) or "sim",
         "responder_spec": o.responder_spec, "participant_kind": kind,
         "data_dir": str(Path(o.data_dir).resolve()), "process": None},
        o.clock or getattr(device, "clock", None) or REAL)
    _check_place(setup, getattr(device, "backend", None))
    return setup


def _check_place(setup: SessionSetup, backend: str | None) -> None:
    """A new session must not exist yet; one to resume must, and its record allow it
    (read without its lock: checked again under it as the session is reopened)."""
    if not setup.options.resume:
        check_new_place(setup.paths, setup.who)
        return
    check_resume_place(setup.paths, setup.who)
    record = read_record(setup.paths)
    if record is not None:                  # else rebuilt as the session is reopened
        check_resumable(record, setup, backend)
