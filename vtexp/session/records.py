"""The records a session emits as it runs, and the one place a trial's rows are made.

The engine (:mod:`vtexp.session.engine`) plays, asks and emits one record per thing that
happened, in this order for a session::

    SessionStarted
      TrialStarted  PlayStarted  Answered...  TrialDone       (per trial; a replay is
      [DevicePaused  DeviceResumed]                             another PlayStarted)
    SessionEnded

Every record goes to every consumer (a callable taking one record): the BIDS writer
first, which has a trial's rows on disk before any other consumer hears of it, then the
responder's screens, the progress line and the markers. ``host_ms`` are the session
clock's monotonic milliseconds (:meth:`vtexp.clock.Clock.now_ms`) when it happened.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Union

from ..errors import DeviceError
from ..model import PlayReport, TrialRecord
from ..responders.base import Response, correct_answer
from ..design import Trial


@dataclass(frozen=True)
class SessionStarted:
    """The run starts, before its first trial; ``trials_done``: what the log already held."""

    experiment: str
    participant: str
    session: int
    resume: bool
    trials_done: int
    trials_planned: int
    host_ms: float


@dataclass(frozen=True)
class TrialStarted:
    """An attempt at a trial starts (a retry after a device fault starts it again)."""

    trial: Trial
    started_at: str             # wall clock, ISO 8601: the rows' started_at
    host_ms: float


@dataclass(frozen=True)
class PlayStarted:
    """A play starts on the device: its start on the device's clock and on the host's
    (None when the device cannot map its clock). ``play``: 0, then 1... for replays."""

    trial: Trial
    play: int
    device_ms: float
    host_ms: float | None


@dataclass(frozen=True)
class Answered:
    """A question was answered: when it was asked and when the responder returned."""

    trial: Trial
    question: object
    response: Response
    asked_host_ms: float
    answered_host_ms: float


@dataclass(frozen=True)
class TrialDone:
    """A trial ended: its rows (one per question) and what the device reported playing.

    ``plays``: every play of the trial the device reported, in order, over all its
    attempts: a play the device stopped part-way (``completed`` false) holds the pulses it
    played, and a retry's plays follow it. ``total``: the trials the session plans;
    ``wall_s``: the wall clock when the trial's first attempt started (where a run's
    events are placed on the session's timeline).
    """

    trial: Trial
    rows: tuple[TrialRecord, ...]
    plays: tuple[PlayReport, ...]
    total: int
    wall_s: float
    host_ms: float

    @property
    def status(self) -> str:
        return self.rows[0].status if self.rows else "ok"


@dataclass(frozen=True)
class DevicePaused:
    """The device failed during a trial; every actuator is off and the session waits for
    the experimenter's choice (retry, skip, abort)."""

    trial: Trial
    error: DeviceError
    host_ms: float


@dataclass(frozen=True)
class DeviceResumed:
    """The experimenter chose to go on after a device fault: ``retry`` or ``skip``."""

    trial: Trial
    choice: str
    host_ms: float


@dataclass(frozen=True)
class SessionEnded:
    """The run ended: ``completed``, ``aborted`` or ``failed``, and why."""

    status: str
    reason: str | None
    host_ms: float


Record = Union[SessionStarted, TrialStarted, PlayStarted, Answered, TrialDone, DevicePaused,
               DeviceResumed, SessionEnded]

#: Whatever takes the session's records: the BIDS writer, the progress line, the markers.
Consumer = Callable[[Record], None]


@dataclass(frozen=True)
class Felt:
    """What the participant felt in a trial, as its rows say: the first play's onset on the
    device's clock, its duration and pulses, and the camera frame it was made from."""

    onset_ms: float | None = None
    duration_ms: float | None = None
    n_pulses: int = 0
    stim_file: str | None = None

    @classmethod
    def played(cls, report: PlayReport, stim_file: str | None = None) -> Felt:
        return cls(report.started_at_ms, report.duration_ms, len(report.pulses), stim_file)


def trial_rows(trial: Trial, questions: list, started_at: str, *,
               answers: Mapping[str, tuple[Response, int]] | None = None, status: str = "ok",
               felt: Felt = Felt()) -> tuple[TrialRecord, ...]:
    """A trial's rows, one per question: with ``answers`` (question name -> response and
    replays used) for a trial that was asked, else none (status ``device_error``: skipped
    after a device fault; ``stopped``: its adaptive track had met its stop rule)."""
    rows = []
    for q in questions:
        response, replays = (answers or {}).get(q.name, (None, 0))
        right = correct_answer(q, trial)
        answer = None if response is None else response.answer
        rows.append(TrialRecord(
            trial=trial.number, repetition=trial.repetition, practice=trial.practice,
            block=trial.block, stimulus=trial.stimulus, stim_file=felt.stim_file,
            condition=trial.levels, question=q.name, answer=answer, correct_answer=right,
            correct=None if right is None or response is None else answer == right,
            rt_s=None if response is None else response.rt_s, replays=replays,
            stimulus_onset_ms=felt.onset_ms, stimulus_duration_ms=felt.duration_ms,
            n_pulses=felt.n_pulses, status=status, started_at=started_at))
    return tuple(rows)
