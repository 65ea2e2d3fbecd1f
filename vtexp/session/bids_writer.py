"""The BIDS writer: a session's files, written from the records the engine emits.

It is the first consumer of every record. It makes a new session whole (its record
folder staged and renamed into place, then its BIDS files, each created exclusively)
or reopens one to resume (:mod:`vtexp.session.resume`), and says how many trials it
holds. Then, for each :class:`~vtexp.session.records.TrialDone`, it writes the trial's
device events first and its rows last (the row is what makes a trial complete), each
in one ``write`` and ``fsync``'d before the next trial starts; at
:class:`~vtexp.session.records.SessionEnded` it closes the logs, rewrites the session
record with the status, the end time and the SHA-256 of each file, and releases the
session's lock.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from pathlib import Path

from .. import bids
from ..clock import Clock, iso
from ..errors import SessionError
from ..lock import SessionLock
from ..log import TsvLog, fsync_dir, sha256_file, write_json_atomic
from ..model import DeviceInfo
from .files import EVENT_COLUMNS, events_sidecar, exact_level, log_columns, new_record, sidecar
from .records import SessionEnded, TrialDone
from .resume import reopen
from .store import check_new_place, refuse_existing

OpenDevice = Callable[[], DeviceInfo]


class BidsWriter:
    """Writes one session (see the module docstring); ``held``: the trials its log held
    when it was opened, where the run starts."""

    def __init__(self, setup, lock: SessionLock, record: dict, beh: TsvLog, events: TsvLog,
                 held: int, clock: Clock):
        self.setup, self.paths, self.clock = setup, setup.paths, clock
        self.lock, self.record, self.beh, self.events = lock, record, beh, events
        self.held = held
        self.written = 0
        floor = _last_event_s(self.paths.events_tsv) if setup.options.resume else 0.0
        self.timeline = Timeline(record, self.paths, clock, floor)
        exp = setup.lx.experiment
        self._factors = list(exp.factors)
        self._adaptive = exp.adaptive is not None
        self._exclude = {"condition"} if setup.camera is not None else {"condition",
                                                                        "stim_file"}

    @classmethod
    def open(cls, setup, open_device: OpenDevice, responder) -> BidsWriter:
        """The session's files, made or (``setup.options.resume``) reopened. The session
        is locked first, then ``open_device()`` gives the device's info for the record."""
        _ensure_dataset(setup)
        clock = setup.clock
        if not setup.options.resume:
            lock, record, beh, events = _create(setup, open_device, responder, clock)
            return cls(setup, lock, record, beh, events, 0, clock)
        lock = SessionLock.acquire(setup.paths.record_dir, what=setup.who)
        try:
            record, beh, events, done = reopen(setup, open_device(), responder, clock)
        except BaseException:
            lock.release()
            raise
        return cls(setup, lock, record, beh, events, done, clock)

    def __call__(self, record) -> None:
        if isinstance(record, TrialDone):
            self.write_trial(record)
        elif isinstance(record, SessionEnded):
            self.close(record)

    def write_trial(self, done: TrialDone) -> None:
        """The trial's device events in one write, then its rows, the last one last."""
        trial = done.trial
        if done.plays:
            self.timeline.anchor(done.wall_s, done.plays[0].started_at_ms)
        self.events.append_many(sorted(self._event_rows(done), key=lambda r: r["onset"]))
        extra = ({"proposed": exact_level(trial.proposed),
                  "presented": exact_level(trial.presented)} if self._adaptive else {})
        levels = {f: trial.levels[f] for f in self._factors}
        for rec in done.rows:                     # one row per question
            self.beh.append({**levels, **extra, **rec.model_dump(exclude=self._exclude)})
        self.written += 1

    def _event_rows(self, done: TrialDone) -> list[dict]:
        rows = []
        for i, rep in enumerate(done.plays):
            for p in rep.pulses:
                rows.append({"onset": self.timeline.seconds(rep.started_at_ms + p.onset_ms),
                             "duration": p.duration_ms / 1000.0,
                             "trial": done.trial.number, "play": i, "row": p.row, "col": p.col,
                             "scheduled_onset_ms": p.scheduled_onset_ms,
                             "onset_ms": rep.started_at_ms + p.onset_ms,
                             "duration_ms": p.duration_ms, "level": p.level,
                             "amplitude_v": p.train.amplitude_v if p.train else None,
                             "frequency_hz": p.train.frequency_hz if p.train else None,
                             "pulse_width_ms": p.train.pulse_width_ms if p.train else None})
        return rows

    def close(self, ended: SessionEnded) -> None:
        """The logs closed; the record says how the session ended; the lock released."""
        paths = self.paths
        try:
            self.beh.close()
            self.events.close()
            self.record.update(status=ended.status, reason=ended.reason, ended_at=iso(self.clock),
                               n_trials_logged=self.held + self.written,
                               checksums={paths.relative(f): sha256_file(f) for f in
                                          (paths.beh_tsv, paths.beh_json, paths.events_tsv,
                                           paths.events_json) if f.is_file()})
            write_json_atomic(paths.session_json, self.record)
        finally:
            self.lock.release()


def _ensure_dataset(setup) -> None:
    """The dataset exists, and the participant has a row, before their folder appears."""
    paths, exp = setup.paths, setup.lx.experiment
    try:
        bids.ensure_dataset(paths.root, exp.name, exp.title, exp.reference)
        bids.record_participant(paths.root, paths.participant, setup.participant_info,
                                setup.participant_fields)
    except OSError as e:
        raise SessionError(f"cannot write the dataset {paths.root}: "
                           f"{e.strerror or e}") from None


def _create(setup, open_device: OpenDevice, responder, clock: Clock
            ) -> tuple[SessionLock, dict, TsvLog, TsvLog]:
    """Make a new session: its record folder whole in a staging folder, renamed into place
    (from then on the session exists), then its BIDS files, each created exclusively.

    A run killed before the rename leaves a hidden staging folder and no session: the
    next run removes it (:func:`~vtexp.session.store.mark_dead_sessions`) and the session
    starts afresh. A run killed after it leaves a session that resumes:
    :func:`~vtexp.session.resume.reopen` rebuilds any BIDS file that is missing or cut
    short (no trial was played yet).
    """
    paths, rd = setup.paths, setup.paths.record_dir
    check_new_place(paths, setup.who)          # again: another run may have begun it since
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
        lock = SessionLock.acquire(staging, what=setup.who)
        record = new_record(setup, open_device(), responder, clock)
        write_json_atomic(staging / paths.session_json.name, record)
        try:
            os.rename(staging, rd)          # atomic: the session exists from here on
        except OSError:
            if rd.exists():
                refuse_existing(paths, setup.who)
            raise
        renamed = True
        lock.move_to(rd)
        fsync_dir(rd.parent)
        return (lock, record, *_create_files(setup))
    except BaseException:
        if lock is not None:
            lock.release()
        if not renamed:
            shutil.rmtree(staging, ignore_errors=True)
        raise


def _create_files(setup) -> tuple[TsvLog, TsvLog]:
    paths, lx = setup.paths, setup.lx
    paths.dir.mkdir(parents=True, exist_ok=True)
    write_json_atomic(paths.beh_json, sidecar(lx))
    write_json_atomic(paths.events_json, events_sidecar(lx))
    beh = TsvLog(paths.beh_tsv, log_columns(lx))
    try:
        return beh, TsvLog(paths.events_tsv, EVENT_COLUMNS)
    except BaseException:
        beh.close()
        raise


class Timeline:
    """Event onsets in seconds from the session's first stimulus.

    Within a run the device's clock times the pulses; each run (a resume starts one) is
    placed at the wall-clock time its first trial started, relative to the first run's.
    The first stimulus of the session is recorded as ``acquisition_start``.
    """

    def __init__(self, record: dict, paths, clock: Clock, floor_s: float = 0.0):
        self.record, self.paths, self.clock, self.floor_s = record, paths, clock, floor_s
        self.offset_s: float | None = None
        self.device_ms = 0.0

    def anchor(self, wall: float, device_ms: float) -> None:
        if self.offset_s is not None:
            return
        start = self.record.get("acquisition_start")
        if not start:
            self.offset_s = 0.0
            self.record["acquisition_start"] = {"wall_time": wall, "at": iso(self.clock)}
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
