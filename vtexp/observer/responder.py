"""The model participant as a Responder: it answers from what the device reported playing."""

from __future__ import annotations

import numpy as np

from ..design import Trial
from ..errors import SessionError
from ..model import PlayReport
from ..responders.base import Replay, Response
from .model import ObserverModel, question_columns


class ModelObserver:
    """Answers each question as :class:`ObserverModel` predicts for one simulated participant.

    The percept is that of the first play of the trial as the device reported it
    (``stimulus_played``); the model never asks to feel a stimulus again.
    """

    participant_kind = "model"         # ids start with 'sim'; never pooled with people

    def __init__(self, model: ObserverModel, participant: str, session: int = 1, *,
                 seed: int = 0, typical: bool = False):
        self.model = model
        self.who = model.participant(seed, participant, typical=typical)
        self._seed, self._participant, self._session = seed, participant, session
        self._u = np.zeros((0, 0))
        self._played: dict[int, PlayReport] = {}
        p = self.who
        self.description = (f"model observer (seed {seed}{', typical' if typical else ''}; "
                            f"TPT {p.two_point_threshold_mm:.1f} mm, {p.intensity_levels} levels, "
                            f"tau {p.integration_ms:.0f} ms, efficiency {p.efficiency:.3f}, "
                            f"decision noise {p.decision_noise:.2f}, lapse {p.lapse:.3f})")

    def stimulus_played(self, trial: Trial, report: PlayReport) -> None:
        self._played.setdefault(trial.number, report)

    def _row(self, trial: Trial) -> np.ndarray:
        if trial.number > len(self._u):
            self._u = self.model.uniforms(self._seed, self._participant, self._session,
                                          max(trial.number, 2 * len(self._u), 64))
        return self._u[trial.number - 1]

    def ask(self, question, trial: Trial, replay: Replay | None) -> Response:
        played = self._played.get(trial.number)
        if played is None:
            raise SessionError(f"trial {trial.number}: the model observer was not told what "
                               "the device played")
        row, off = self._row(trial), 0
        for q in self.model.lx.experiment.asked():
            if q.name == question.name:
                break
            off += question_columns(q)
        n = question_columns(question)
        answer = self.model.answer(question, trial.condition, played, self.who,
                                   row[off:off + n])
        return Response(answer=answer, rt_s=None, replays=0)
