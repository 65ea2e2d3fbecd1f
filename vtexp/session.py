"""The session engine: plays the trial list, asks, and logs every trial.

Every data folder is a BIDS dataset (:mod:`vtexp.bids`), one per experiment; a
session writes its BIDS files in ``sub-<P>/ses-<N>/beh/`` and vtexp's own record
in ``sourcedata/vtexp/sub-<P>/ses-<N>/``, where BIDS leaves room for it::

    DATA/<experiment>/
        dataset_description.json  README.md  participants.tsv  participants.json
        sub-<P>/ses-<N>/beh/
            sub-<P>_ses-<N>_task-<T>_beh.tsv      one row per trial and question (append + fsync)
            sub-<P>_ses-<N>_task-<T>_beh.json     every column described, TaskName, Instructions
            sub-<P>_ses-<N>_task-<T>_events.tsv   every pulse the device reported playing
                                                  (onset, duration in seconds first)
            sub-<P>_ses-<N>_task-<T>_events.json  every column described
        sourcedata/vtexp/sub-<P>/ses-<N>/
            sub-<P>_ses-<N>_task-<T>_session.json what produced the session, how it ended
            session.lock                          held while the session runs
            stim/                                 camera frames (camera stimuli)

The session record (``..._session.json``) is written with status ``running`` before
the first trial and rewritten at the end with the status (``completed``,
``aborted``, ``failed``), the end time and the SHA-256 of each file; a session
whose process died is marked ``interrupted`` by the next run that finds it
(:func:`mark_dead_sessions`).

A session exists when its record folder does. The record folder is made whole in a
hidden staging folder (``.ses-N.staging-PID``, holding the record and the lock) and
renamed into place, so a run killed while starting leaves either no session or one
that resumes; the BIDS files follow, each created exclusively, and a resume rebuilds
any that a kill left missing or cut short. The participant's row of
``participants.tsv`` is written before the participant's folder appears. While a
session runs, its ``session.lock`` is held (:mod:`vtexp.lock`): a second run of
the same session is refused, naming the process that holds it. Nothing is ever
overwritten.

An experiment with camera stimuli (``camera: N``, ``video: FILE``) also keeps the
frame taken at each such trial in the record folder's ``stim/`` (and a live trial's
record), named in the trial log's ``stim_file`` column (``vtexp.live.trial``).

Data folders of vtexp before the BIDS layout (``sub-<P>/ses-<N>/session.json``
beside the logs) are still read by :mod:`vtexp.analysis.load`; sessions are not
added to them.
"""

from __future__ import annotations

import json
import os
import platform
import re
import shutil
import sys
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path
from typing import Callable, Protocol

from . import __version__
from .adaptive.spec import parameter_value as _number
from .adaptive.track import AdaptiveRun
from .compile import Condition, compile_conditions
from .design import Trial, trial_list
from .devices.base import DeviceBase
from .errors import DeviceError, InputError, SessionAborted, SessionError
from .experiment import LoadedExperiment
from .lock import LOCK_NAME, SessionBusy, SessionLock
from . import bids
from .log import TsvLog, fsync_dir, sha256_file, tmp_name, write_json_atomic
from .model import DeviceProfile, PlayReport, TrialRecord
from .responders.base import Responder, call_hook, correct_answer

PARTICIPANT = re.compile(r"^[A-Za-z0-9]{1,64}$")
FORMAT_VERSION = 2     # 2: the BIDS layout (record in sourcedata/vtexp/)

#: Participant ids that start with this (any case) belong to model participants only,
#: so that a simulated session can never be taken for a person's.
SIMULATED_PREFIX = "sim"


def now_iso() -> str:
    return datetime.now(timezone.utc).astimezone().isoformat(timespec="milliseconds")


def check_participant(participant: str) -> str:
    """A participant id is a BIDS label: letters and digits only (no '/', '..', '_')."""
    if not isinstance(participant, str) or not PARTICIPANT.match(participant):
        raise InputError(f"participant id {participant!r} is not a plain token; use 1-64 "
                         "letters and digits (e.g. 01, P07, anna)", key="--participant")
    return participant


def participant_kind(responder: object) -> str:
    """Who answers: ``person`` (window, console), ``model`` (a model participant) or
    ``scripted`` (answers from a rule or a file)."""
    return str(getattr(responder, "participant_kind", "person"))


def check_participant_kind(participant: str, kind: str) -> None:
    """Model participants and people never share an id: ``sim...`` is the models'."""
    simulated_id = participant.lower().startswith(SIMULATED_PREFIX)
    if kind == "model" and not simulated_id:
        raise InputError(f"a model participant's id starts with '{SIMULATED_PREFIX}' (e.g. "
                         f"{SIMULATED_PREFIX}{participant}), so that its sessions are never "
                         f"taken for a person's; got {participant!r}", key="--participant")
    if kind == "person" and simulated_id:
        raise InputError(f"ids starting with '{SIMULATED_PREFIX}' are kept for model "
                         f"participants; give this person another id (got {participant!r})",
                         key="--participant")


def check_session(session: int) -> int:
    if not isinstance(session, int) or session < 1 or session > 9999:
        raise InputError(f"session must be a whole number from 1 to 9999 (got {session!r})",
                         key="--session")
    return session


def record_of(folder: Path) -> Path | None:
    """The session record in a record folder (``*_session.json``), or None."""
    found = sorted(Path(folder).glob("*_session.json")) if Path(folder).is_dir() else []
    return found[0] if found else None


def legacy_sessions(root: Path | str) -> list[Path]:
    """Sessions in the layout of vtexp before BIDS (``sub-*/ses-*/session.json``)."""
    return sorted(Path(root).glob("sub-*/ses-*/session.json"))


def list_sessions(data, experiment: str, participant: str) -> list[dict]:
    """The sessions of ``participant`` already in the data folder, by number: each a dict
    with ``session``, ``status`` (from the session record, or ``unreadable``), ``logged``,
    ``planned``, ``started`` and ``reason``."""
    found = []
    root = Path(data) / experiment
    folder = root / bids.SOURCE / f"sub-{participant}"
    old = [(sj.parent, sj) for sj in root.glob(f"sub-{participant}/ses-*/session.json")]
    for d, record in [(d, record_of(d)) for d in (folder.glob("ses-*") if folder.is_dir()
                                                   else ())] + old:
        m = re.fullmatch(r"ses-(\d+)", d.name)
        if not (m and d.is_dir()):
            continue
        try:
            meta = json.loads(record.read_text(encoding="utf-8")) if record else {}
        except (OSError, ValueError):
            meta = {}
        meta = meta if isinstance(meta, dict) else {}
        found.append({"session": int(m[1]), "status": meta.get("status") or "unreadable",
                      "logged": meta.get("n_trials_logged"),
                      "planned": meta.get("n_trials_planned"),
                      "started": meta.get("started_at") or "", "reason": meta.get("reason"),
                      "device": meta.get("device_spec") or (meta.get("device") or {}).get(
                          "backend"),
                      "responder": meta.get("responder_spec"),
                      "held_by": SessionLock.probe(d) if (d / LOCK_NAME).exists() else None})
    return sorted(found, key=lambda x: x["session"])


def mark_dead_sessions(data, experiment: str) -> list[dict]:
    """Sessions of ``experiment`` that say ``running`` but whose process has died (no one
    holds their lock) are marked ``interrupted``; staging folders left by a run killed
    while starting (no trial was played) are removed. Returns what was marked: dicts with
    ``participant``, ``session``, ``logged``, ``planned``, ``dir`` (the record folder),
    ``record`` (the record file), ``reason``."""
    marked = []
    root = Path(data) / experiment
    source = root / bids.SOURCE
    if not source.is_dir():
        return marked
    for staging in source.glob("sub-*/.ses-*.staging-*"):
        try:
            lock = SessionLock.acquire(staging)
        except SessionError:
            continue                        # still being made by a live run
        lock.release()
        shutil.rmtree(staging, ignore_errors=True)
    for sj in sorted(source.glob("sub-*/ses-*/*_session.json")):
        d = sj.parent
        try:
            meta = json.loads(sj.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        if not isinstance(meta, dict) or meta.get("status") != "running":
            continue
        try:
            lock = SessionLock.acquire(d)
        except SessionBusy:
            continue                        # really running, in another process
        except SessionError:
            continue
        try:
            meta = json.loads(sj.read_text(encoding="utf-8"))    # read again, under the lock
            if meta.get("status") != "running":
                continue
            who = lock.stale or meta.get("process") or {}
            reason = ("the vtexp process that ran it"
                      + (f" (pid {who['pid']} on {who.get('host', '?')})" if who.get("pid") else "")
                      + " ended without closing it: killed, crashed or the power failed; "
                      f"found at {now_iso()[:19].replace('T', ' ')}")
            meta.update(status="interrupted", reason=reason)
            write_json_atomic(sj, meta)
            marked.append({"participant": meta.get("participant"), "session": meta.get("session"),
                           "logged": meta.get("n_trials_logged"),
                           "planned": meta.get("n_trials_planned"), "dir": d, "record": sj,
                           "reason": reason})
        finally:
            lock.release()
    return marked


def recorded_run(where) -> dict:
    """How a session was run, from its record: ``device`` (the --device spec, or the
    backend for sessions recorded before specs were), ``responder`` (the --responder spec,
    or None), ``data`` (the data folder), ``participant_kind``. Empty if unreadable.
    ``where`` is a :class:`SessionPaths`, a record file or a record folder."""
    if isinstance(where, SessionPaths):
        record = where.session_json
    else:
        where = Path(where)
        record = where if where.is_file() else (record_of(where) or where / "session.json")
    try:
        meta = json.loads(record.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    if not isinstance(meta, dict):
        return {}
    return {"device": meta.get("device_spec") or (meta.get("device") or {}).get("backend"),
            "device_info": meta.get("device") or {},
            "responder": meta.get("responder_spec"),
            "data": meta.get("data_dir"), "participant_kind": meta.get("participant_kind"),
            "status": meta.get("status")}


def device_kind(spec_or_backend: str | None) -> str:
    """``serial:/dev/ttyACM0`` -> ``serial``; ``sim:realtime`` -> ``sim``."""
    return (spec_or_backend or "").partition(":")[0]


@dataclass(frozen=True)
class SessionPaths:
    """Where one session's files are in its dataset (``root``, the experiment's folder)."""

    root: Path
    participant: str
    session: int
    task: str

    @classmethod
    def of(cls, data_dir: Path | str, experiment: str, task: str, participant: str,
           session: int) -> SessionPaths:
        return cls(Path(data_dir) / experiment, participant, session, task)

    @property
    def prefix(self) -> str:
        return f"sub-{self.participant}_ses-{self.session}_task-{self.task}"

    @property
    def dir(self) -> Path:
        """The session's BIDS files: ``sub-<P>/ses-<N>/beh/``."""
        return self.root / f"sub-{self.participant}" / f"ses-{self.session}" / "beh"

    @property
    def record_dir(self) -> Path:
        """vtexp's record, lock and camera frames: ``sourcedata/vtexp/sub-<P>/ses-<N>/``."""
        return self.root / bids.SOURCE / f"sub-{self.participant}" / f"ses-{self.session}"

    @property
    def beh_tsv(self) -> Path:
        return self.dir / f"{self.prefix}_beh.tsv"

    @property
    def beh_json(self) -> Path:
        return self.dir / f"{self.prefix}_beh.json"

    @property
    def events_tsv(self) -> Path:
        return self.dir / f"{self.prefix}_events.tsv"

    @property
    def events_json(self) -> Path:
        return self.dir / f"{self.prefix}_events.json"

    @property
    def session_json(self) -> Path:
        return self.record_dir / f"{self.prefix}_session.json"

    def relative(self, path: Path) -> str:
        """A file's path from the dataset's root, as the record names it."""
        return path.relative_to(self.root).as_posix()


DeviceFaultHandler = Callable[[DeviceError, Trial], str]
"""Asked what to do when the device fails during a trial: "retry", "skip" or "abort"."""


class TrialSink(Protocol):
    """Receives each trial's record after it is safely on disk (progress, preview...).

    A sink may also hear the session as it happens, through methods it has of these
    names (marker outputs do: :class:`vtexp.markers.MarkerSink`): ``session_started``,
    ``trial_started``, ``play_started``, ``answered``, ``trial_logged``,
    ``session_ended``.
    """

    def __call__(self, record: TrialRecord, trial: Trial, total: int) -> None: ...


@dataclass
class SessionResult:
    paths: SessionPaths
    status: str
    records: list[TrialRecord] = field(default_factory=list)
    seed: int = 0


EVENT_COLUMNS = ["onset", "duration", "trial", "play", "row", "col", "scheduled_onset_ms", "onset_ms",
                 "duration_ms", "level", "amplitude_v", "frequency_hz", "pulse_width_ms"]


def trial_columns(factors: list[str], camera: bool = False, adaptive: bool = False
                  ) -> list[str]:
    """The trial log's columns; ``stim_file`` after ``stimulus`` with camera stimuli,
    ``proposed`` and ``presented`` with an adaptive procedure."""
    return (["trial", "practice", "repetition", "block", *factors, "stimulus",
             *(["stim_file"] if camera else []),
             *(["proposed", "presented"] if adaptive else []), "question",
             "answer", "correct_answer", "correct", "rt_s", "replays", "stimulus_onset_ms",
             "stimulus_duration_ms", "n_pulses", "status", "started_at"])


def has_camera(lx: LoadedExperiment) -> bool:
    return any(s.is_camera for s in lx.experiment.stimuli.values())


def log_columns(lx: LoadedExperiment) -> list[str]:
    """The trial log's columns for this experiment."""
    return trial_columns(list(lx.experiment.factors), has_camera(lx),
                         lx.experiment.adaptive is not None)


def task_fields(lx: LoadedExperiment) -> dict:
    """What BIDS asks of every task sidecar (``_beh.json``, ``_events.json``)."""
    exp = lx.experiment
    return {"TaskName": exp.task_label, "TaskFullName": exp.title,
            "TaskDescription": exp.description.strip() or exp.title,
            "Instructions": exp.instructions.strip() or exp.asked()[0].prompt,
            "StimulusPresentation": {
                "SoftwareName": "vtexp", "SoftwareVersion": __version__,
                "OperatingSystem": f"{platform.system()} {platform.release()}".strip(),
                "Code": bids.CODE_URL},
            "vtexpTask": exp.name}


def sidecar(lx: LoadedExperiment) -> dict:
    """The BIDS ``_beh.json``: what each column means."""
    exp = lx.experiment
    cols: dict[str, dict] = {
        "trial": {"Description": "trial number in the session, from 1"},
        "practice": {"Description": "1 for a practice trial (not analysed), else 0"},
        "repetition": {"Description": "presentation number of this condition, from 1 "
                                      "(0 for practice trials)"},
        "block": {"Description": "block number with a blocked design, else 0"},
    }
    for name, f in exp.factors.items():
        cols[name] = {"Description": f.description or f"level of factor '{name}'",
                      "Levels": {lv: (f"sets {f.sets} parameters {f.params_of(lv)}"
                                      if f.params_of(lv) else lv) for lv in f.level_names}}
    cols.update({
        "stimulus": {"Description": "name of the stimulus in the experiment file"},
        **({"proposed": {"Description": f"the level of {exp.adaptive.variable} the adaptive "
                                        f"procedure ({exp.adaptive.procedure.kind}) asked for, "
                                        "from the answers before this trial"},
            "presented": {"Description": f"the level of {exp.adaptive.variable} played: the "
                                         "nearest the device can play to the one proposed"}}
           if exp.adaptive is not None else {}),
        **({"stim_file": {"Description": "camera stimuli: the frame taken at the trial (PNG), "
                                         "relative to the session's record folder "
                                         "sourcedata/vtexp/sub-<P>/ses-<N>/; a live trial's "
                                         "record is the folder of the same name + '-live'"}}
           if has_camera(lx) else {}),
        "question": {"Description": "name of the question answered (one row per question)",
                     "Levels": {q.name: q.prompt for q in exp.asked()}},
        "answer": _answer_description(exp.asked()),
        "correct_answer": {"Description": "the option scored as correct, n/a if unscored"},
        "correct": {"Description": "1 if answer equals correct_answer, 0 if not, n/a if "
                                   "unscored"},
        "rt_s": {"Description": "reaction time from the end of the stimulus",
                 "Units": "s"},
        "replays": {"Description": "times the participant felt the stimulus again"},
        "stimulus_onset_ms": {"Description": "device clock at the stimulus onset",
                              "Units": "ms"},
        "stimulus_duration_ms": {"Description": "duration of the played schedule",
                                 "Units": "ms"},
        "n_pulses": {"Description": "number of actuator pulses in the stimulus"},
        "status": {"Description": "ok, skipped, device_error, or stopped (an adaptive track "
                                  "had met its stop rule: nothing was played)"},
        "started_at": {"Description": "wall-clock start of the trial, ISO 8601"},
    })
    # BIDS: TaskName is the task label of the file names; the title is TaskFullName.
    return {**task_fields(lx), **cols}


def _answer_description(questions: list) -> dict:
    if len(questions) > 1:
        return {"Description": "the answer to the row's question: "
                + "; ".join(f"{q.name}: " + _answer_description([q])["Description"]
                            for q in questions)}
    q = questions[0]
    if q.kind == "rating":
        return {"Description": f"the rating, from {q.low} to {q.high}",
                "Levels": {str(v): q.labels.get(v, str(v)) for v in q.scale}}
    if q.kind == "number":
        return {"Description": f"the number given, from {q.minimum} to {q.maximum}"}
    return {"Description": "the option chosen", "Levels": {o: o for o in q.options}}


def environment() -> dict:
    pkgs = {}
    for name in ("numpy", "pandas", "pydantic", "PyYAML", "statsmodels", "pyserial",
                 "opencv-contrib-python-headless", "opencv-python", "psychopy"):
        try:
            pkgs[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            pass
    return {"vtexp": __version__, "python": sys.version.split()[0],
            "platform": platform.platform(), "machine": platform.machine(),
            "hostname": platform.node(), "packages": pkgs}


def run_session(lx: LoadedExperiment, participant: str, session: int, device: DeviceBase,
                responder: Responder, data_dir: Path | str, *,
                conditions: list[Condition] | None = None,
                sinks: tuple[TrialSink, ...] = (), command: list[str] | None = None,
                on_device_error: DeviceFaultHandler | None = None,
                resume: bool = False, max_trials: int | None = None,
                device_spec: str | None = None, responder_spec: str | None = None,
                force_device: bool = False,
                capture_prompt: Callable[[str], None] | None = None,
                participant_info: dict[str, str] | None = None) -> SessionResult:
    """Run one session and log it. Raises SessionError if the session already exists.

    ``resume=True`` continues a session that did not finish (killed, crashed,
    aborted): the same trial list is rebuilt from the same seed, the trials the
    log already holds are skipped, and the next trial is the first one missing.
    A row cut off mid-write is removed first, and a file missing or cut short
    (a session left by a run killed while starting) is rebuilt from what
    exists. The experiment file must be the one the session started with (same
    SHA-256), and the device of the same kind as the one recorded (``sim``,
    ``serial``, ``emulator``) unless ``force_device``: a session begun on a real
    array is not continued on the simulator by mistake.

    The session is locked while it runs (``session.lock``): a second run of it,
    from another terminal, is refused with the process that holds it.

    When the device fails during a trial (cable pulled, power lost), every
    actuator is already off (the device's watchdog, ``DeviceBase``'s all-off)
    and the session pauses on ``on_device_error(error, trial)``, which answers
    ``"retry"`` (reopen the device and play the trial again), ``"skip"`` (log
    the trial with status ``device_error`` and go on) or ``"abort"`` (end the
    session, status ``failed``, the error re-raised). Without a handler the
    session aborts. The responder's ``device_paused``/``device_resumed`` hooks
    show the participant a pause screen meanwhile.

    ``max_trials=N`` stops after N trials of this run (counted from where a
    resumed session continues): the session ends with status ``aborted`` and
    the reason "stopped after N trials as asked", so that it can be resumed.

    ``device_spec`` and ``responder_spec`` (the ``--device`` and ``--responder``
    given) are recorded so that a resume can use them again.

    ``capture_prompt(text)`` asks the experimenter to place a camera stimulus's object
    and returns when it is in place (``vtexp.live.trial``); camera stimuli without
    ``delay_s`` need it.

    ``participant_info`` (field -> value: group, age, handedness, vision and the
    experiment's ``participants:`` fields) is written to the dataset's
    participants.tsv before the participant's folder appears; a participant already
    there keeps their row (values it lacks are filled; a contradiction is refused).
    """
    exp = lx.experiment
    check_participant(participant)
    check_session(session)
    kind = participant_kind(responder)
    check_participant_kind(participant, kind)
    profile: DeviceProfile = device.profile
    if profile.name != exp.device:
        raise InputError(f"the experiment is declared for device {exp.device!r}, but the "
                         f"device opened is {profile.name!r}", key="--device")
    conditions = conditions or compile_conditions(lx, profile)
    trials, seed = trial_list(exp, conditions, participant, session)
    adaptive = AdaptiveRun.of(lx, conditions, seed)
    paths = SessionPaths.of(data_dir, exp.name, exp.task_label, participant, session)
    fields = bids.participant_fields(exp.participants)
    info_given = bids.check_info(participant_info or {}, fields)
    legacy = legacy_sessions(paths.root)
    if legacy:
        raise SessionError(f"{paths.root} holds sessions in the layout of vtexp before BIDS "
                           f"(e.g. {legacy[0]}); new sessions are not added to it. Give "
                           "another data folder (--data); vtexp analyze still reads this one")
    camera = _CameraTrials.of(lx, paths.record_dir, capture_prompt)
    who = f"session {session} of participant {participant}"
    run_info = {"device_spec": device_spec or getattr(device, "backend", None) or "sim",
                "responder_spec": responder_spec, "participant_kind": kind,
                "data_dir": str(Path(data_dir).resolve()), "process": None}

    factors = list(exp.factors)
    if resume:
        if not paths.record_dir.is_dir():
            rd = paths.record_dir
            raise SessionError(f"there is no {who} in {paths.root} to resume"
                               + (" (a run was stopped while creating it, before any trial; "
                                  "start it without --resume)"
                                  if list(rd.parent.glob(f".{rd.name}.staging-*")) else ""))
    # The dataset exists, and the participant has a row, before their folder appears.
    try:
        bids.ensure_dataset(paths.root, exp.name, exp.title, exp.reference)
        bids.record_participant(paths.root, participant, info_given, fields)
    except OSError as e:
        raise SessionError(f"cannot write the dataset {paths.root}: "
                           f"{e.strerror or e}") from None
    if resume:
        lock = SessionLock.acquire(paths.record_dir, what=who)
        try:
            info = device.open()
            record, beh, events, done = _reopen(paths, lx, participant, session, trials, seed,
                                                factors, info, conditions, device, responder,
                                                command, run_info, force_device,
                                                camera is not None, adaptive)
        except BaseException:
            lock.release()
            raise
    else:
        lock, record, beh, events = _create(paths, lx, participant, session, trials, seed,
                                            conditions, device, responder, command, run_info,
                                            who, camera is not None)
        done = 0
    result = SessionResult(paths, "running", seed=seed)
    status, reason = "failed", None
    clock = _Timeline(record, paths, _last_event_s(paths.events_tsv) if resume else 0.0)

    def notify(hook: str, *args) -> None:
        for sink in sinks:
            call_hook(sink, hook, *args)

    try:
        notify("session_started", {"experiment": exp.name, "participant": participant,
                                   "session": session, "resume": resume, "trials_done": done})
        call_hook(responder, "resume_at", done)
        call_hook(responder, "instructions", exp.instructions.strip() or exp.asked()[0].prompt)
        todo = trials[done:] if max_trials is None else trials[done:done + max_trials]
        for trial in todo:
            if adaptive is not None:
                trial = _adaptive_trial(adaptive, trial)
            wall = time.time()
            if trial.condition.schedule is None and not trial.condition.camera:
                recs, plays = _stopped_records(exp, trial), []      # its track had stopped
            else:
                recs, plays = _run_trial_pausing(exp, trial, device, responder,
                                                 on_device_error, camera, notify)
            if plays:
                clock.anchor(wall, plays[0].started_at_ms)
            # The device events first, the trial's row last: the row is what makes a
            # trial complete, so a trial cut short leaves no row and is played again.
            rows = []
            for i, rep in enumerate(plays):
                for p in rep.pulses:
                    rows.append({"onset": clock.seconds(rep.started_at_ms + p.onset_ms),
                                   "duration": p.duration_ms / 1000.0,
                                   "trial": trial.number, "play": i, "row": p.row, "col": p.col,
                                   "scheduled_onset_ms": p.scheduled_onset_ms,
                                   "onset_ms": rep.started_at_ms + p.onset_ms,
                                   "duration_ms": p.duration_ms, "level": p.level,
                                   "amplitude_v": p.train.amplitude_v if p.train else None,
                                   "frequency_hz": p.train.frequency_hz if p.train else None,
                                   "pulse_width_ms": p.train.pulse_width_ms if p.train else None})
            # A trial's events in one write, in the order of their onsets (BIDS).
            events.append_many(sorted(rows, key=lambda r: r["onset"]))
            extra = ({"proposed": exact_level(trial.proposed),
                      "presented": exact_level(trial.presented)} if adaptive is not None else {})
            for rec in recs:                     # one row per question, the trial's last
                beh.append({**{f: trial.levels[f] for f in factors}, **extra,
                            **rec.model_dump(exclude={"condition"} if camera else
                                             {"condition", "stim_file"})})
            if adaptive is not None and trial.presented is not None:
                for rec in recs:
                    if rec.question == adaptive.question and rec.status == "ok":
                        adaptive.record(trial, trial.presented, rec.answer, rec.correct_answer)
            result.records.extend(recs)
            record["n_trials_logged"] = trial.number
            for rec in recs:
                for sink in sinks:
                    sink(rec, trial, len(trials))
            notify("trial_logged", trial, recs, plays)
            device.wait_ms(exp.design.iti_ms)
            _maybe_break(exp, trial, trials, responder)
        call_hook(responder, "finish", "Thank you. The session is over.")
        status = "completed"
        if len(todo) < len(trials) - done:
            status, reason = "aborted", f"stopped after {len(todo)} trials as asked"
    except (KeyboardInterrupt, SessionAborted) as e:
        status, reason = "aborted", (str(e) if isinstance(e, SessionAborted)
                                     else "interrupted by the experimenter")
        raise
    except BaseException as e:
        status, reason = "failed", f"{type(e).__name__}: {e}"
        raise
    finally:
        try:
            device.all_off()
        finally:
            try:
                try:
                    notify("session_ended", status)
                except Exception:
                    pass            # a sink's trouble must not cost the session its record
                beh.close()
                events.close()
                record.update(status=status, reason=reason, ended_at=now_iso(),
                              n_trials_logged=done + len({r.trial for r in result.records}),
                              checksums={paths.relative(f): sha256_file(f) for f in
                                         (paths.beh_tsv, paths.beh_json, paths.events_tsv,
                                          paths.events_json) if f.is_file()})
                write_json_atomic(paths.session_json, record)
                result.status = status
            finally:
                lock.release()
    return result


def _new_record(lx: LoadedExperiment, participant: str, session: int, trials: list[Trial],
                seed: int, conditions: list[Condition], info, profile: DeviceProfile,
                responder, command, run_info: dict, paths: SessionPaths) -> dict:
    exp = lx.experiment
    return {
        "format": "vtexp-session", "format_version": FORMAT_VERSION,
        "experiment": exp.name, "task": exp.task_label, "participant": participant,
        "session": session, "status": "running", "started_at": now_iso(), "ended_at": None,
        "seed": seed, "seed_source": "design.seed" if exp.design.seed is not None
        else "derived from (experiment, participant, session)",
        "n_trials_planned": len(trials),
        "trial_order": [t.condition.index for t in trials],
        "conditions": [{"index": c.index, "levels": c.levels, "stimulus": c.stimulus,
                        "encoding": c.encoding_params, "coding": c.coding_params}
                       for c in conditions],
        "experiment_file": {"path": str(Path(lx.path).resolve()), "sha256": lx.sha256,
                            "text": lx.source.text},
        "experiment_loaded": exp.model_dump(mode="json"),
        "device": info.model_dump(mode="json"),
        "device_profile": profile.model_dump(mode="json"),
        "responder": getattr(responder, "description", type(responder).__name__),
        **run_info,
        "process": _process(),
        "command": command or sys.argv,
        "environment": environment(),
        # Paths from the dataset's root (the record is in sourcedata/vtexp/sub-P/ses-N/).
        "layout": "bids", "bids_version": bids.BIDS_VERSION,
        "files": {"beh": paths.relative(paths.beh_tsv), "sidecar": paths.relative(paths.beh_json),
                  "events": paths.relative(paths.events_tsv),
                  "events_sidecar": paths.relative(paths.events_json)},
        "acquisition_start": None,
        "checksums": None, "n_trials_logged": 0, "reason": None, "resumes": [],
        # proposed/presented written with repr (every digit), so a resume compares them
        # exactly; sessions without this key wrote them rounded to 6 decimals.
        **({"adaptive_levels": "exact"} if exp.adaptive is not None else {}),
    }


def _process() -> dict:
    return {"pid": os.getpid(), "host": platform.node()}


def _create(paths: SessionPaths, lx, participant, session, trials, seed, conditions, device,
            responder, command, run_info, who, camera: bool = False
            ) -> tuple[SessionLock, dict, TsvLog, TsvLog]:
    """Make a new session: its record folder whole in a staging folder, renamed into place
    (from then on the session exists), then its BIDS files, each created exclusively.

    A run killed before the rename leaves a hidden staging folder and no session: the
    next run removes it (:func:`mark_dead_sessions`) and the session starts afresh. A run
    killed after it leaves a session that resumes: :func:`_reopen` rebuilds any BIDS
    file that is missing or cut short (no trial was played yet).
    """
    if paths.record_dir.exists():
        _refuse_existing(paths, who)
    if paths.dir.parent.exists():
        raise SessionError(f"{paths.dir.parent} exists but vtexp has no record of it "
                           f"(expected {paths.session_json}); nothing was overwritten. Use "
                           "another --session number, or move that folder away")
    rd = paths.record_dir
    staging = rd.with_name(f".{rd.name}.staging-{os.getpid()}")
    try:
        rd.parent.mkdir(parents=True, exist_ok=True)
        shutil.rmtree(staging, ignore_errors=True)
        staging.mkdir()
    except OSError as e:
        raise SessionError(f"cannot create the session folder {rd}: {e.strerror}") from None
    lock = None
    renamed = False
    try:
        lock = SessionLock.acquire(staging, what=who)
        info = device.open()
        record = _new_record(lx, participant, session, trials, seed, conditions, info,
                             device.profile, responder, command, run_info, paths)
        write_json_atomic(staging / paths.session_json.name, record)
        try:
            os.rename(staging, rd)          # atomic: the session exists from here on
        except OSError:
            if rd.exists():
                _refuse_existing(paths, who)
            raise
        renamed = True
        lock.move_to(rd)
        fsync_dir(rd.parent)
        paths.dir.mkdir(parents=True, exist_ok=True)
        write_json_atomic(paths.beh_json, sidecar(lx))
        write_json_atomic(paths.events_json, events_sidecar(lx))
        beh = TsvLog(paths.beh_tsv, log_columns(lx))
        events = TsvLog(paths.events_tsv, EVENT_COLUMNS)
        return lock, record, beh, events
    except BaseException:
        if lock is not None:
            lock.release()
        if not renamed:
            shutil.rmtree(staging, ignore_errors=True)
        raise


def _refuse_existing(paths: SessionPaths, who: str):
    holder = SessionLock.probe(paths.record_dir)
    if holder is not None:
        from .lock import describe_holder
        raise SessionBusy(f"{who} is running now in another vtexp process "
                          f"({describe_holder(holder)}); nothing was touched.", holder)
    raise SessionError(f"{who} already exists in {paths.root}; nothing was overwritten. "
                       "Use --resume to continue it, or another --session number.")


def events_sidecar(lx: LoadedExperiment) -> dict:
    """The BIDS ``_events.json``: the task, and what each column of the device events means."""
    return {**task_fields(lx), **{c: dict(bids.EVENTS_SIDECAR[c]) for c in EVENT_COLUMNS}}


class _Timeline:
    """Event onsets in seconds from the session's first stimulus.

    Within a run the device's clock times the pulses; each run (a resume starts one) is
    placed at the wall-clock time its first trial started, relative to the first run's.
    The first stimulus of the session is recorded as ``acquisition_start``.
    """

    def __init__(self, record: dict, paths: SessionPaths, floor_s: float = 0.0):
        self.record, self.paths, self.floor_s = record, paths, floor_s
        self.offset_s: float | None = None
        self.device_ms = 0.0

    def anchor(self, wall: float, device_ms: float) -> None:
        if self.offset_s is not None:
            return
        start = self.record.get("acquisition_start")
        if not start:
            self.offset_s = 0.0
            self.record["acquisition_start"] = {"wall_time": wall, "at": now_iso()}
        else:
            # Not before the end of what was logged (the simulator's clock runs ahead).
            self.offset_s = round(max(self.floor_s, wall - float(start["wall_time"])), 3)
            if self.record.get("resumes"):
                self.record["resumes"][-1]["onset_offset_s"] = self.offset_s
        self.device_ms = device_ms
        write_json_atomic(self.paths.session_json, self.record)

    def seconds(self, device_ms: float) -> float:
        """Seconds from the session's first stimulus of a device-clock time of this run."""
        return (self.offset_s or 0.0) + (device_ms - self.device_ms) / 1000.0


def _maybe_break(exp, trial: Trial, trials: list[Trial], responder: Responder) -> None:
    """A break screen after every ``design.break_every`` main trials (not after the last)."""
    every = exp.design.break_every
    if not every or trial.practice or trial.number == trials[-1].number:
        return
    n_main = sum(1 for t in trials if not t.practice)
    done = sum(1 for t in trials[:trial.number] if not t.practice)
    if done % every == 0:
        call_hook(responder, "pause", f"Time for a break. {done} of {n_main} trials are done. "
                                      "Continue when you are ready.")


def _reopen(paths: SessionPaths, lx: LoadedExperiment, participant: str, session: int,
            trials: list[Trial], seed: int,
            factors: list[str], info, conditions, device, responder, command, run_info: dict,
            force_device: bool, camera: bool = False, adaptive: AdaptiveRun | None = None
            ) -> tuple[dict, TsvLog, TsvLog, int]:
    """Check that a session can be resumed and reopen its logs; return how many trials it holds.

    What a run killed at any instant can leave is rebuilt from what exists: a
    session.json that is missing or unreadable (from its staged copy, else anew
    from the experiment, noted under ``rebuilt``), a missing sidecar, a trial or
    events log that is missing or was cut off in its header. A trial log's
    rows are never invented: a log of events with no trial log to match is refused.
    """
    rebuilt: list[str] = []
    record = _read_record(paths)
    for f in (paths.beh_json, paths.events_json):      # a sidecar's write cut short
        tmp_name(f).unlink(missing_ok=True)
    if record is None:
        record = _new_record(lx, participant, session, trials, seed, conditions, info,
                             device.profile, responder, command, run_info, paths)
        record["started_at"] = None                 # not known any more
        rebuilt.append(f"{paths.session_json.name} (missing or unreadable; made anew from the "
                       "experiment)")
    tmp_name(paths.session_json).unlink(missing_ok=True)
    if record.get("status") == "completed":
        raise SessionError(f"session in {paths.dir} is already completed; nothing to resume")
    if record.get("experiment_file", {}).get("sha256") != lx.sha256:
        raise SessionError(f"the experiment file {lx.path} is not the one session {paths.dir} "
                           "started with (its SHA-256 differs); resume with that file, or "
                           "start a new session")
    was = ((record.get("experiment_loaded") or {}).get("coding") or {}).get("source") or {}
    now = lx.experiment.coding.model_dump(mode="json").get("source") or {}
    if was.get("sha256") != now.get("sha256"):
        raise SessionError(f"the coding file {now.get('file') or was.get('file')} is not the one "
                           f"session {paths.dir} started with (its SHA-256 differs); restore "
                           "it, or start a new session")
    if record.get("seed") != seed or record.get("trial_order") != \
            [t.condition.index for t in trials]:
        raise SessionError(f"the trial list of {paths.dir} cannot be rebuilt (seed or order "
                           "differ); it cannot be resumed")
    recorded = record.get("device_spec") or (record.get("device") or {}).get("backend")
    if device_kind(recorded) != info.backend and not force_device:
        raise SessionError(
            f"session {paths.dir} ran on {recorded} ({_device_words(record.get('device'))}), "
            f"but the device given is {run_info['device_spec']} ({info.backend}): the "
            f"participant would {_what_they_feel(info.backend)}. Resume on a {device_kind(recorded)} "
            f"device (--device {_device_hint(recorded)}), or add --force-device to continue "
            f"on {run_info['device_spec']} anyway.")
    was_kind = record.get("participant_kind")
    if was_kind and was_kind != run_info["participant_kind"] and \
            "model" in (was_kind, run_info["participant_kind"]):
        raise SessionError(f"session {paths.dir} was answered by a {was_kind}, and cannot be "
                           f"continued by a {run_info['participant_kind']}; start a new session")
    paths.dir.mkdir(parents=True, exist_ok=True)
    if not paths.beh_json.is_file():
        write_json_atomic(paths.beh_json, sidecar(lx))
        rebuilt.append(paths.beh_json.name)
    if not paths.events_json.is_file():
        write_json_atomic(paths.events_json, events_sidecar(lx))
        rebuilt.append(paths.events_json.name)
    cols = trial_columns(factors, camera, adaptive is not None)
    if _needs_header(paths.beh_tsv):
        if _has_rows(paths.events_tsv):
            raise SessionError(f"{paths.beh_tsv} is missing but {paths.events_tsv.name} holds "
                               "played trials: the answers are lost and the session cannot be "
                               "resumed; start a new session (the folder is left as it is)")
        _write_header(paths.beh_tsv, cols)
        rebuilt.append(paths.beh_tsv.name)
    if _needs_header(paths.events_tsv):
        _write_header(paths.events_tsv, EVENT_COLUMNS)
        rebuilt.append(paths.events_tsv.name)
    beh, rows, cut_beh = TsvLog.reopen(paths.beh_tsv, cols)
    per_trial = len(lx.experiment.asked())          # one row per question
    for i, row in enumerate(rows):
        k = i // per_trial + 1
        t = trials[k - 1] if k <= len(trials) else None
        if t is None or row[cols.index("trial")] != str(k) or \
                any(row[cols.index(f)] != t.levels[f] for f in factors):
            beh.close()
            raise SessionError(f"row {i + 1} of {paths.beh_tsv} does not match the planned "
                               f"trial {k}; the log cannot be resumed")
    done = len(rows) // per_trial
    if adaptive is not None:
        problem = _replay_adaptive(adaptive, rows[:done * per_trial], cols, trials,
                                   exact=record.get("adaptive_levels") == "exact")
        if problem:
            beh.close()
            refusal = SessionError(f"{paths.beh_tsv}: {problem}. The log does not follow from "
                                   "the answers it holds (it was changed, or the experiment's "
                                   "procedure differs), so the session cannot be resumed; start "
                                   "a new session (the folder is left as it is)")
            refusal.final = True                 # no "to continue it" hint after this
            raise refusal
    if len(rows) % per_trial:                        # a trial cut short between questions
        beh.truncate_rows(done * per_trial)
    events, erows, cut_ev = TsvLog.reopen(paths.events_tsv, EVENT_COLUMNS)
    keep = sum(1 for r in erows if int(r[EVENT_COLUMNS.index("trial")]) <= done)
    if keep < len(erows):
        events.truncate_rows(keep)          # events of the trial that was cut short
    record.setdefault("resumes", []).append({
        "at": now_iso(), "trials_done": done, "device": info.model_dump(mode="json"),
        "device_spec": run_info["device_spec"], "responder_spec": run_info["responder_spec"],
        "forced_device": bool(force_device and device_kind(recorded) != info.backend),
        "process": _process(), "command": command or sys.argv,
        "removed": {"beh_bytes": cut_beh, "event_rows": len(erows) - keep,
                    "event_bytes": cut_ev},
        "rebuilt": rebuilt,
        "previous_status": record.get("status"), "previous_reason": record.get("reason")})
    record.update(status="running", reason=None, ended_at=None, checksums=None,
                  n_trials_logged=done, process=_process())
    for key in ("device_spec", "responder_spec", "data_dir", "participant_kind"):
        if run_info.get(key) is not None:
            record[key] = run_info[key]
    write_json_atomic(paths.session_json, record)
    return record, beh, events, done




def _adaptive_trial(adaptive: AdaptiveRun, trial: Trial) -> Trial:
    """The trial at the level its track proposes now, or without a schedule if the track
    has stopped."""
    import dataclasses

    c = trial.condition
    if not trial.practice and adaptive.finished(trial):
        return dataclasses.replace(trial, condition=dataclasses.replace(c, schedule=None))
    p = adaptive.propose(trial)
    variable = adaptive.spec.variable
    if adaptive.spec.sets == "stimulus":
        cond = dataclasses.replace(c, schedule=c.schedules[p.presented],
                                   pattern=c.patterns[p.presented],
                                   stimulus_params={variable: _number(p.presented)})
    else:
        cond = dataclasses.replace(c, schedule=c.schedules[p.presented],
                                   coding_params={**c.coding_params,
                                                  variable: _number(p.presented)})
    return dataclasses.replace(trial, condition=cond, proposed=p.proposed,
                               presented=p.presented)


def _stopped_records(exp, trial: Trial) -> list[TrialRecord]:
    """The rows of a trial whose adaptive track had met its stop rule: nothing played."""
    return [TrialRecord(trial=trial.number, repetition=trial.repetition,
                        practice=trial.practice, block=trial.block, stimulus=trial.stimulus,
                        condition=trial.levels, question=q.name, answer=None,
                        correct_answer=correct_answer(q, trial), correct=None,
                        status="stopped", started_at=now_iso()) for q in exp.asked()]


def exact_level(v: float | None) -> str | None:
    """A level as the log keeps it: every digit (``repr``), so that it reads back equal."""
    return None if v is None else repr(float(v))


def _replay_adaptive(adaptive: AdaptiveRun, rows: list[list[str]], cols: list[str],
                     trials: list[Trial], exact: bool = True) -> str | None:
    """Replay the logged answers through the procedure; what differs first, if anything.
    ``exact``: the log holds every digit; else (older sessions) 6 decimals."""
    for i, row in enumerate(rows):
        d = dict(zip(cols, row, strict=False))
        if d.get("question") != adaptive.question:
            continue
        trial = trials[int(d["trial"]) - 1]
        problem = adaptive.replay(trial, d, exact=exact)
        if problem:
            return f"row {i + 1} (trial {trial.number}): {problem}"
    return None


def _last_event_s(path: Path) -> float:
    """When the last logged device event ended, in seconds on the session's timeline."""
    end = 0.0
    try:
        lines = path.read_text(encoding="utf-8").split("\n")[1:]
    except OSError:
        return end
    for ln in lines:
        cells = ln.split("\t")
        try:
            end = max(end, float(cells[0]) + float(cells[1]))
        except (ValueError, IndexError):
            continue
    return end


def _read_record(paths: SessionPaths) -> dict | None:
    """session.json, or its staged copy left by a write cut short; None if neither reads."""
    for f in (paths.session_json, tmp_name(paths.session_json)):
        try:
            data = json.loads(f.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        if isinstance(data, dict) and data.get("format") == "vtexp-session":
            return data
    return None


def _needs_header(path: Path) -> bool:
    """A log that is missing, or was created and cut off before its header was whole."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return True
    return b"\n" not in data


def _has_rows(path: Path) -> bool:
    try:
        return path.read_bytes().count(b"\n") > 1
    except OSError:
        return False


def _write_header(path: Path, columns: list[str]) -> None:
    path.unlink(missing_ok=True)
    TsvLog(path, columns).close()


def _device_words(info: dict | None) -> str:
    info = info or {}
    backend = info.get("backend", "?")
    if backend == "serial":
        return (f"a tactile array on {info.get('port') or 'a serial port'}, firmware "
                f"{info.get('firmware') or '?'}")
    return {"sim": "the simulator, which drives nothing", "emulator":
            "the emulator, which drives nothing"}.get(backend, backend)


def _what_they_feel(backend: str) -> str:
    return ("feel nothing" if backend in ("sim", "emulator")
            else "feel a device the session did not start on")


def _device_hint(recorded: str | None) -> str:
    return recorded if device_kind(recorded) != "serial" or ":" in (recorded or "") \
        else "serial:PORT"


def _no_notify(hook: str, *args) -> None:
    pass


def _run_trial_pausing(exp, trial: Trial, device: DeviceBase, responder: Responder,
                       on_device_error: DeviceFaultHandler | None,
                       camera: _CameraTrials | None = None, notify=_no_notify
                       ) -> tuple[list[TrialRecord], list[PlayReport]]:
    """A trial, with the experimenter's choice when the device fails during it."""
    while True:
        started = now_iso()
        notify("trial_started", trial, time.monotonic() * 1000.0)
        try:
            return _run_trial(exp, trial, device, responder, camera, notify)
        except DeviceError as e:
            error = e
            # The participant sees (and hears) that the session is paused, not "feel it".
            call_hook(responder, "device_paused", trial)
            choice = on_device_error(error, trial) if on_device_error else "abort"
            while choice == "retry":
                try:
                    device.close()
                except DeviceError:
                    pass                # it was lost; closing releases what is left
                try:
                    device.open()
                    break
                except DeviceError as again:    # still unplugged: ask again
                    error = again
                    choice = on_device_error(error, trial)
            if choice != "abort":
                call_hook(responder, "device_resumed", trial)
            if choice == "retry":
                continue
            if choice == "skip":
                return [TrialRecord(trial=trial.number, repetition=trial.repetition,
                                    practice=trial.practice, block=trial.block,
                                    stimulus=trial.stimulus, condition=trial.levels,
                                    question=q.name, answer=None,
                                    correct_answer=correct_answer(q, trial),
                                    correct=None, status="device_error", started_at=started)
                        for q in exp.asked()], []
            raise error


def _run_trial(exp, trial: Trial, device: DeviceBase, responder: Responder,
               camera: _CameraTrials | None = None, notify=_no_notify
               ) -> tuple[list[TrialRecord], list[PlayReport]]:
    """Play the stimulus, then ask each question in turn: one record per question."""
    started = now_iso()
    schedule = trial.condition.schedule
    stim_file = None
    if trial.condition.camera:
        if camera is None:
            raise SessionError(f"trial {trial.number}: stimulus {trial.stimulus!r} is a camera")
        schedule, stim_file, live = camera.take(trial, device)
        if live is not None:
            return camera.live_trial(exp, trial, live, responder, started, stim_file), []
    stop = getattr(responder, "stop_requested", None)

    def play() -> PlayReport:
        # The responder's abort key is read while the stimulus plays: the device
        # turns every actuator off at once and raises SessionAborted.
        try:
            return device.play(schedule, should_stop=stop, on_started=lambda device_ms, host_ms:
                               notify("play_started", device_ms, host_ms))
        except SessionAborted:
            call_hook(responder, "stimulus_stopped", trial)
            raise

    call_hook(responder, "stimulus_starts", trial)
    plays = [play()]
    call_hook(responder, "stimulus_played", trial, plays[0])
    records = []
    for q in exp.asked():
        before = len(plays)

        def replay(q=q, before=before) -> PlayReport:
            if len(plays) - before >= q.replays:
                raise SessionError(f"trial {trial.number}: no replays left "
                                   f"(the question allows {q.replays})")
            plays.append(play())
            call_hook(responder, "stimulus_played", trial, plays[-1])
            return plays[-1]

        asked = time.monotonic() * 1000.0
        resp = responder.ask(q, trial, replay if q.replays > 0 else None)
        notify("answered", trial, q, resp, asked, time.monotonic() * 1000.0)
        right = correct_answer(q, trial)
        records.append(TrialRecord(
            trial=trial.number, repetition=trial.repetition, practice=trial.practice,
            block=trial.block, stimulus=trial.stimulus,
            condition=trial.levels, question=q.name, answer=resp.answer, correct_answer=right,
            correct=None if right is None else resp.answer == right, rt_s=resp.rt_s,
            stim_file=stim_file,
            replays=len(plays) - before, stimulus_onset_ms=plays[0].started_at_ms,
            stimulus_duration_ms=plays[0].duration_ms, n_pulses=len(plays[0].pulses),
            started_at=started))
    return records, plays


@dataclass
class _CameraTrials:
    """What camera trials need from the session: its folder and the experimenter's prompt
    (the work is ``vtexp.live.trial``'s)."""

    lx: LoadedExperiment
    dir: Path
    prompt: Callable[[str], None] | None

    @classmethod
    def of(cls, lx: LoadedExperiment, folder: Path, prompt) -> _CameraTrials | None:
        if not has_camera(lx):
            return None
        from .live.trial import needs_prompt

        asking = needs_prompt(lx)
        if asking and prompt is None:
            raise SessionError(f"stimulus {asking[0]!r} asks the experimenter to place the object "
                               "before the camera, but no one can be asked (no terminal); "
                               "declare delay_s for it, or run from a terminal")
        return cls(lx, folder, prompt)

    def take(self, trial: Trial, device: DeviceBase):
        """The frame of this trial, saved; its schedule, or the live run to start."""
        from .live import trial as camera

        source, name = camera.camera_source(self.lx, trial.stimulus)
        try:
            got = camera.capture(self.lx, trial, self.dir, self.prompt, source, name)
            if self.lx.experiment.stimuli[trial.stimulus].live:
                folder = self.dir / (got.stim_file[:-len(".png")] + "-live")
                live = camera.LiveTrial(self.lx, trial.condition, device, source, folder)
                source = None                       # the live run reads it from here on
                return None, got.stim_file, live
            _, schedule = camera.coded(self.lx, trial.condition, got.image, device.profile)
            return schedule, got.stim_file, None
        finally:
            if source is not None:
                source.close()

    def live_trial(self, exp, trial: Trial, live, responder: Responder, started: str,
                   stim_file: str) -> list[TrialRecord]:
        """The camera felt continuously while the participant answers each question."""
        call_hook(responder, "stimulus_starts", trial)
        live.start()
        answers = []
        try:
            for q in exp.asked():
                answers.append((q, responder.ask(q, trial, None)))
        finally:
            played_ms = live.stop("the participant answered" if answers else "stopped")
        return [TrialRecord(
            trial=trial.number, repetition=trial.repetition, practice=trial.practice,
            block=trial.block, stimulus=trial.stimulus, stim_file=stim_file,
            condition=trial.levels, question=q.name, answer=resp.answer,
            correct_answer=correct_answer(q, trial),
            correct=None if correct_answer(q, trial) is None
            else resp.answer == correct_answer(q, trial),
            rt_s=resp.rt_s, replays=0, stimulus_onset_ms=None,
            stimulus_duration_ms=played_ms, n_pulses=0, started_at=started)
            for q, resp in answers]
