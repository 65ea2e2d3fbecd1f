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
    """

    description: str

    def ask(self, question: ChoiceQuestion, trial: Trial, replay: Replay | None) -> Response: ...
