"""The session engine: plays the trial list, asks, and logs every trial.

One folder per session, following the BIDS behavioural convention::

    DATA/<experiment>/sub-<P>/ses-<N>/
        sub-<P>_ses-<N>_task-<T>_beh.tsv     one row per trial and question (append + fsync)
        sub-<P>_ses-<N>_task-<T>_beh.json    column descriptions, TaskName, Instructions
        sub-<P>_ses-<N>_task-<T>_events.tsv  every pulse the device reported playing
        session.json                         what produced the session, and how it ended

``session.json`` is written with status ``running`` before the first trial and
rewritten at the end with the status (``completed``, ``aborted``, ``failed``),
the end time and the SHA-256 of each file. A session folder is created
exclusively: a run never overwrites an existing session.

An experiment with camera stimuli (``camera: N``, ``video: FILE``) also keeps the
frame taken at each such trial in ``stim/`` (and a live trial's record), named in the
trial log's ``stim_file`` column (``vtexp.live.trial``).
"""

from __future__ import annotations

import json
import platform
import re
import sys
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path
from typing import Callable, Protocol

from . import __version__
from .compile import Condition, compile_conditions
from .design import Trial, trial_list
from .devices.base import DeviceBase
from .errors import DeviceError, InputError, SessionAborted, SessionError
from .experiment import LoadedExperiment
from .log import TsvLog, sha256_file, write_json_atomic
from .model import DeviceProfile, PlayReport, TrialRecord
from .responders.base import Responder, call_hook, correct_answer

PARTICIPANT = re.compile(r"^[A-Za-z0-9]{1,64}$")
FORMAT_VERSION = 1


def now_iso() -> str:
    return datetime.now(timezone.utc).astimezone().isoformat(timespec="milliseconds")


def check_participant(participant: str) -> str:
    """A participant id is a BIDS label: letters and digits only (no '/', '..', '_')."""
    if not isinstance(participant, str) or not PARTICIPANT.match(participant):
        raise InputError(f"participant id {participant!r} is not a plain token; use 1-64 "
                         "letters and digits (e.g. 01, P07, anna)", key="--participant")
    return participant


def check_session(session: int) -> int:
    if not isinstance(session, int) or session < 1 or session > 9999:
        raise InputError(f"session must be a whole number from 1 to 9999 (got {session!r})",
                         key="--session")
    return session


def list_sessions(data, experiment: str, participant: str) -> list[dict]:
    """The sessions of ``participant`` already in the data folder, by number: each a dict
    with ``session``, ``status`` (from session.json, or ``unreadable``), ``logged``,
    ``planned``, ``started`` and ``reason``."""
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


@dataclass(frozen=True)
class SessionPaths:
    dir: Path
    prefix: str

    @classmethod
    def of(cls, data_dir: Path | str, experiment: str, task: str, participant: str,
           session: int) -> SessionPaths:
        d = Path(data_dir) / experiment / f"sub-{participant}" / f"ses-{session}"
        return cls(d, f"sub-{participant}_ses-{session}_task-{task}")

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
    def session_json(self) -> Path:
        return self.dir / "session.json"


DeviceFaultHandler = Callable[[DeviceError, Trial], str]
"""Asked what to do when the device fails during a trial: "retry", "skip" or "abort"."""


class TrialSink(Protocol):
    """Receives each trial's record after it is safely on disk (progress, preview...)."""

    def __call__(self, record: TrialRecord, trial: Trial, total: int) -> None: ...


@dataclass
class SessionResult:
    paths: SessionPaths
    status: str
    records: list[TrialRecord] = field(default_factory=list)
    seed: int = 0


EVENT_COLUMNS = ["trial", "play", "row", "col", "scheduled_onset_ms", "onset_ms",
                 "duration_ms", "level", "amplitude_v", "frequency_hz", "pulse_width_ms"]


def trial_columns(factors: list[str], camera: bool = False) -> list[str]:
    """The trial log's columns; ``stim_file`` after ``stimulus`` with camera stimuli."""
    return (["trial", "practice", "repetition", "block", *factors, "stimulus",
             *(["stim_file"] if camera else []), "question",
             "answer", "correct_answer", "correct", "rt_s", "replays", "stimulus_onset_ms",
             "stimulus_duration_ms", "n_pulses", "status", "started_at"])


def has_camera(lx: LoadedExperiment) -> bool:
    return any(s.is_camera for s in lx.experiment.stimuli.values())


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
        **({"stim_file": {"Description": "camera stimuli: the frame taken at the trial (PNG), "
                                         "relative to the session folder; a live trial's "
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
        "status": {"Description": "ok, skipped, or device_error"},
        "started_at": {"Description": "wall-clock start of the trial, ISO 8601"},
    })
    return {"TaskName": exp.title, "TaskDescription": exp.description.strip(),
            "Instructions": exp.instructions.strip() or exp.asked()[0].prompt,
            "vtexpTask": exp.name, **cols}


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
                capture_prompt: Callable[[str], None] | None = None) -> SessionResult:
    """Run one session and log it. Raises SessionError if the session already exists.

    ``resume=True`` continues a session that did not finish (killed, crashed,
    aborted): the same trial list is rebuilt from the same seed, the trials the
    log already holds are skipped, and the next trial is the first one missing.
    A row cut off mid-write is removed first. The experiment file must be the
    one the session started with (same SHA-256).

    When the device fails during a trial (cable pulled, power lost), every
    actuator is already off (the device's watchdog, ``DeviceBase``'s all-off)
    and the session pauses on ``on_device_error(error, trial)``, which answers
    ``"retry"`` (reopen the device and play the trial again), ``"skip"`` (log
    the trial with status ``device_error`` and go on) or ``"abort"`` (end the
    session, status ``failed``, the error re-raised). Without a handler the
    session aborts.

    ``max_trials=N`` stops after N trials of this run (counted from where a
    resumed session continues): the session ends with status ``aborted`` and
    the reason "stopped after N trials as asked", so that it can be resumed.

    ``capture_prompt(text)`` asks the experimenter to place a camera stimulus's object
    and returns when it is in place (``vtexp.live.trial``); camera stimuli without
    ``delay_s`` need it.
    """
    exp = lx.experiment
    check_participant(participant)
    check_session(session)
    profile: DeviceProfile = device.profile
    if profile.name != exp.device:
        raise InputError(f"the experiment is declared for device {exp.device!r}, but the "
                         f"device opened is {profile.name!r}", key="--device")
    conditions = conditions or compile_conditions(lx, profile)
    trials, seed = trial_list(exp, conditions, participant, session)
    paths = SessionPaths.of(data_dir, exp.name, exp.task_label, participant, session)
    camera = _CameraTrials.of(lx, paths.dir, capture_prompt)

    factors = list(exp.factors)
    if resume:
        if not paths.session_json.is_file():
            raise SessionError(f"there is no session {session} of participant {participant} in "
                               f"{paths.dir} to resume")
        info = device.open()
        record, beh, events, done = _reopen(paths, lx, trials, seed, factors, info,
                                            camera is not None)
    else:
        try:
            paths.dir.parent.mkdir(parents=True, exist_ok=True)
            paths.dir.mkdir()
        except FileExistsError:
            raise SessionError(f"session {session} of participant {participant} already exists "
                               f"in {paths.dir}; nothing was overwritten. Use --resume to "
                               "continue it, or another --session number.") from None
        except OSError as e:
            raise SessionError(f"cannot create the session folder {paths.dir}: "
                               f"{e.strerror}") from None
        info = device.open()
        record = {
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
            "experiment_file": {"path": str(lx.path), "sha256": lx.sha256,
                                "text": lx.source.text},
            "experiment_loaded": exp.model_dump(mode="json"),
            "device": info.model_dump(mode="json"),
            "device_profile": profile.model_dump(mode="json"),
            "responder": getattr(responder, "description", type(responder).__name__),
            "command": command or sys.argv,
            "environment": environment(),
            "files": {"beh": paths.beh_tsv.name, "sidecar": paths.beh_json.name,
                      "events": paths.events_tsv.name},
            "checksums": None, "n_trials_logged": 0, "reason": None, "resumes": [],
        }
        write_json_atomic(paths.session_json, record)
        write_json_atomic(paths.beh_json, sidecar(lx))
        beh = TsvLog(paths.beh_tsv, trial_columns(factors, camera is not None))
        events = TsvLog(paths.events_tsv, EVENT_COLUMNS)
        done = 0
    result = SessionResult(paths, "running", seed=seed)
    status, reason = "failed", None
    try:
        call_hook(responder, "resume_at", done)
        call_hook(responder, "instructions", exp.instructions.strip() or exp.asked()[0].prompt)
        todo = trials[done:] if max_trials is None else trials[done:done + max_trials]
        for trial in todo:
            recs, plays = _run_trial_pausing(exp, trial, device, responder, on_device_error,
                                             camera)
            # The device events first, the trial's row last: the row is what makes a
            # trial complete, so a trial cut short leaves no row and is played again.
            for i, rep in enumerate(plays):
                for p in rep.pulses:
                    events.append({"trial": trial.number, "play": i, "row": p.row, "col": p.col,
                                   "scheduled_onset_ms": p.scheduled_onset_ms,
                                   "onset_ms": rep.started_at_ms + p.onset_ms,
                                   "duration_ms": p.duration_ms, "level": p.level,
                                   "amplitude_v": p.train.amplitude_v if p.train else None,
                                   "frequency_hz": p.train.frequency_hz if p.train else None,
                                   "pulse_width_ms": p.train.pulse_width_ms if p.train else None})
            for rec in recs:                     # one row per question, the trial's last
                beh.append({**{f: trial.levels[f] for f in factors},
                            **rec.model_dump(exclude={"condition"} if camera else
                                             {"condition", "stim_file"})})
            result.records.extend(recs)
            record["n_trials_logged"] = trial.number
            for rec in recs:
                for sink in sinks:
                    sink(rec, trial, len(trials))
            _wait(device, exp.design.iti_ms)
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
            beh.close()
            events.close()
            record.update(status=status, reason=reason, ended_at=now_iso(),
                          n_trials_logged=done + len({r.trial for r in result.records}),
                          checksums={f.name: sha256_file(f) for f in
                                     (paths.beh_tsv, paths.beh_json, paths.events_tsv)})
            write_json_atomic(paths.session_json, record)
            result.status = status
    return result


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


def _reopen(paths: SessionPaths, lx: LoadedExperiment, trials: list[Trial], seed: int,
            factors: list[str], info, camera: bool = False) -> tuple[dict, TsvLog, TsvLog, int]:
    """Check that a session can be resumed and reopen its logs; return how many trials it holds."""
    import json

    try:
        record = json.loads(paths.session_json.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        raise SessionError(f"cannot read {paths.session_json}: {e}") from None
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
    beh, rows, cut_beh = TsvLog.reopen(paths.beh_tsv, trial_columns(factors, camera))
    cols = trial_columns(factors, camera)
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
    if len(rows) % per_trial:                        # a trial cut short between questions
        beh.truncate_rows(done * per_trial)
    events, erows, cut_ev = TsvLog.reopen(paths.events_tsv, EVENT_COLUMNS)
    keep = sum(1 for r in erows if int(r[0]) <= done)
    if keep < len(erows):
        events.truncate_rows(keep)          # events of the trial that was cut short
    record.setdefault("resumes", []).append({
        "at": now_iso(), "trials_done": done, "device": info.model_dump(mode="json"),
        "removed": {"beh_bytes": cut_beh, "event_rows": len(erows) - keep,
                    "event_bytes": cut_ev},
        "previous_status": record.get("status"), "previous_reason": record.get("reason")})
    record.update(status="running", reason=None, ended_at=None, checksums=None,
                  n_trials_logged=done)
    write_json_atomic(paths.session_json, record)
    return record, beh, events, done


def _run_trial_pausing(exp, trial: Trial, device: DeviceBase, responder: Responder,
                       on_device_error: DeviceFaultHandler | None,
                       camera: _CameraTrials | None = None
                       ) -> tuple[list[TrialRecord], list[PlayReport]]:
    """A trial, with the experimenter's choice when the device fails during it."""
    while True:
        started = now_iso()
        try:
            return _run_trial(exp, trial, device, responder, camera)
        except DeviceError as e:
            error = e
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
               camera: _CameraTrials | None = None
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
            return device.play(schedule, should_stop=stop)
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

        resp = responder.ask(q, trial, replay if q.replays > 0 else None)
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


def _wait(device: DeviceBase, ms: float) -> None:
    wait = getattr(device, "wait", None)
    if wait is not None:
        wait(ms)
    elif ms > 0:
        time.sleep(ms / 1000.0)


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
