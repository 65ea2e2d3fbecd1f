"""Scripted responders: answers from a list, a file, or a rule. For tests and demos.

Specs on the command line (``--responder``):

``scripted:correct``            always the correct option
``scripted:random``             a uniformly random option
``scripted:accuracy=P``         correct with probability P, else a random wrong option
``scripted:answers=FILE``       one answer per line, in trial order

Random choices are deterministic: drawn from a stream seeded by
(participant, session, trial), so reruns give the same answers.
"""

from __future__ import annotations

from pathlib import Path
from collections.abc import Callable, Sequence

from ..design import HashRandom, Trial, derive_seed
from ..errors import InputError
from ..experiment import ChoiceQuestion
from .base import Replay, Response, correct_answer

Rule = Callable[[ChoiceQuestion, Trial], str]


class ScriptedResponder:
    participant_kind = "scripted"      # not a person: kept apart in analyses
    def __init__(self, rule: Rule | None = None, *, answers: Sequence[str] | None = None,
                 description: str = "scripted", replays: int = 0):
        if (rule is None) == (answers is None):
            raise ValueError("give a rule or a list of answers")
        self._rule = rule
        self._answers = list(answers) if answers is not None else None
        self._next = 0
        self.description = description
        self.replays = replays

    def resume_at(self, trials_done: int) -> None:
        """A resumed session continues with the answer for the next trial."""
        if self._answers is not None:
            self._next = trials_done

    def ask(self, question: ChoiceQuestion, trial: Trial, replay: Replay | None) -> Response:
        used = 0
        while replay is not None and used < min(self.replays, question.replays):
            replay()
            used += 1
        if self._answers is not None:
            if self._next >= len(self._answers):
                raise InputError(f"the answer list has {len(self._answers)} answers, but trial "
                                 f"{trial.number} needs another", key="--responder")
            answer = self._answers[self._next]
            self._next += 1
        else:
            answer = self._rule(question, trial)
        if answer not in question.options:
            raise InputError(f"scripted answer {answer!r} for trial {trial.number} is not one "
                             f"of the options {question.options}", key="--responder")
        return Response(answer=answer, rt_s=None, replays=used)


def _rng(participant: str, session: int, trial: Trial, salt: str) -> HashRandom:
    return HashRandom(derive_seed(f"responder:{salt}", participant, session * 1_000_003
                                  + trial.number))


def make_scripted(spec: str, participant: str, session: int) -> ScriptedResponder:
    """Build a scripted responder from its command-line spec (see module doc)."""
    rule, _, arg = spec.partition("=")
    if rule == "correct":
        def pick(q, t):
            c = correct_answer(q, t)
            if c is None:
                raise InputError("scripted:correct needs a question with a correct answer",
                                 key="--responder")
            return c
        return ScriptedResponder(pick, description="scripted:correct")
    if rule == "random":
        return ScriptedResponder(
            lambda q, t: q.options[_rng(participant, session, t, "random").below(len(q.options))],
            description="scripted:random")
    if rule == "accuracy":
        try:
            p = float(arg)
        except ValueError:
            p = -1.0
        if not 0.0 <= p <= 1.0:
            raise InputError(f"accuracy must be a number from 0 to 1 (got {arg!r})",
                             key="--responder")

        def noisy(q, t):
            rng = _rng(participant, session, t, "accuracy")
            c = correct_answer(q, t)
            if c is not None and rng.random() < p:
                return c
            wrong = [o for o in q.options if o != c]
            return wrong[rng.below(len(wrong))]
        return ScriptedResponder(noisy, description=f"scripted:accuracy={p}")
    if rule == "answers":
        f = Path(arg)
        try:
            lines = [ln.strip() for ln in f.read_text(encoding="utf-8").splitlines()]
        except OSError as e:
            raise InputError(f"cannot read the answer file: {e.strerror}", path=str(f)) from None
        return ScriptedResponder(answers=[ln for ln in lines if ln],
                                 description=f"scripted:answers={f}")
    raise InputError(f"unknown scripted rule {spec!r}; use correct, random, accuracy=P or "
                     "answers=FILE", key="--responder")
