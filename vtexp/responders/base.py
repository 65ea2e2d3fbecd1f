"""The Responder protocol: whoever answers the trial's question."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable
from collections.abc import Callable

from ..design import Trial
from ..experiment import ChoiceQuestion
from ..model import PlayReport


@dataclass(frozen=True)
class Response:
    answer: str
    rt_s: float | None          # from the end of the stimulus; None if not measured
    replays: int = 0


Replay = Callable[[], PlayReport]


def correct_answer(question: ChoiceQuestion, trial: Trial) -> str | None:
    """The option scored as correct on ``trial`` (``question.correct`` resolved)."""
    c = question.correct
    if c is None:
        return None
    if c.startswith("{") and c.endswith("}"):
        ref = c[1:-1]
        return trial.stimulus if ref == "stimulus" else trial.levels[ref]
    return c


@runtime_checkable
class Responder(Protocol):
    """Asks ``question`` about the stimulus just played on ``trial``.

    ``replay`` plays the stimulus again when the participant asks to feel it
    again (None when the question allows no replays); the responder counts
    the replays it used.

    A responder that cannot answer every kind of question may have
    ``check_questions(questions)``: the session calls it with the experiment's
    questions before anything is written or opened, and it raises
    :class:`vtexp.errors.InputError` (naming ``--responder``) for one it cannot answer.
    """

    description: str

    def ask(self, question: ChoiceQuestion, trial: Trial, replay: Replay | None) -> Response: ...


class ScreenResponder(Responder, Protocol):
    """A responder with a screen of its own (the participant's window).

    The session engine calls these, when a responder has them, around the trials:
    ``instructions`` once before the first trial, ``stimulus_starts`` just before
    each stimulus plays (a "ready" or fixation screen), ``pause`` at a break,
    ``finish`` after the last trial, and ``stimulus_played`` with the device's
    report of what it played, after each play (replays too). Raising
    :class:`vtexp.errors.SessionAborted`
    from any of them, or from ``ask``, aborts the session: every actuator off,
    the session marked aborted, completed trials kept.

    While a stimulus plays, the device polls ``stop_requested`` every few ms (the
    ``should_stop`` of :meth:`vtexp.devices.base.Device.play`): a reason (text)
    stops the stimulus with every actuator off at once, then the engine calls
    ``stimulus_stopped`` (to close the screen) and the session aborts with that
    reason.
    """

    def instructions(self, text: str) -> None: ...

    def stimulus_starts(self, trial: Trial) -> None: ...

    def stimulus_played(self, trial: Trial, report: PlayReport) -> None: ...

    def pause(self, text: str) -> None: ...

    def finish(self, text: str) -> None: ...

    def stop_requested(self) -> str | None: ...

    def stimulus_stopped(self, trial: Trial) -> None: ...


def call_hook(responder: object, name: str, *args) -> None:
    """Call ``responder.name(*args)`` if the responder has that screen."""
    hook = getattr(responder, name, None)
    if callable(hook):
        hook(*args)
