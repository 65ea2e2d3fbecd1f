"""Scripted responders: answers from a list, a file, or a rule. For tests and demos.

Specs on the command line (``--responder``):

``scripted:correct``            always the correct option
``scripted:random``             a uniformly random option
``scripted:accuracy=P``         correct with probability P, else a random wrong option
``scripted:answers=FILE``       one answer per line, in trial order
``scripted:psychometric:threshold=T[,slope=S,lapse=L,guess=G,function=F]``
                                a model participant of known threshold for adaptive
                                procedures: at the level played, a yes (or the correct
                                option) with probability psi(level) (vtexp.adaptive); the
                                guess rate and function default to the procedure's

Random choices are deterministic: drawn from a stream seeded by
(participant, session, trial), so reruns give the same answers.
"""

from __future__ import annotations

from pathlib import Path
from collections.abc import Callable, Sequence

from ..adaptive.psychometric import FUNCTIONS, psi
from ..design import Trial
from ..errors import InputError
from ..experiment import ChoiceQuestion
from ..seeding import HashRandom, derive_seed
from .base import Replay, Response, correct_answer

Rule = Callable[[ChoiceQuestion, Trial], str]


class ScriptedResponder:
    participant_kind = "scripted"      # not a person: kept apart in analyses
    def __init__(self, rule: Rule | None = None, *, answers: Sequence[str] | None = None,
                 description: str = "scripted", replays: int = 0,
                 needs_correct: bool = False):
        if (rule is None) == (answers is None):
            raise ValueError("give a rule or a list of answers")
        self._rule = rule
        self._answers = list(answers) if answers is not None else None
        self._next = 0
        self.description = description
        self.replays = replays
        self.needs_correct = needs_correct      # the rule answers with the correct option

    def check_questions(self, questions) -> None:
        """Refuse, before a session starts, questions this responder cannot answer: an
        unscored one for ``scripted:correct``, none that an answer of the list is one of."""
        unscored = [q for q in questions if q.correct is None] if self.needs_correct else []
        if unscored:
            q = unscored[0]
            raise InputError(f"{self.description} needs a question with a correct answer, but "
                             f"question {q.name!r} ({getattr(q, 'kind', 'choice')}) has none; "
                             "use scripted:random or scripted:answers=FILE",
                             key="--responder")
        options = {o for q in questions for o in q.options}
        for i, answer in enumerate(self._answers or ()):
            if answer not in options:
                raise InputError(f"answer {i + 1} of the list, {answer!r}, is not an option of "
                                 f"any question ({sorted(options)})", key="--responder")

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


def make_scripted(spec: str, participant: str, session: int, lx=None) -> ScriptedResponder:
    """Build a scripted responder from its command-line spec (see module doc)."""
    if spec.split(":")[0] == "psychometric":
        return _psychometric(spec.partition(":")[2], participant, session, lx)
    rule, _, arg = spec.partition("=")
    if rule == "correct":
        def pick(q, t):
            c = correct_answer(q, t)
            if c is None:
                raise InputError("scripted:correct needs a question with a correct answer",
                                 key="--responder")
            return c
        return ScriptedResponder(pick, description="scripted:correct", needs_correct=True)
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
    raise InputError(f"unknown scripted rule {spec!r}; use correct, random, accuracy=P, "
                     "answers=FILE or psychometric:threshold=T,...", key="--responder")


def _psychometric(arg: str, participant: str, session: int, lx) -> ScriptedResponder:
    """Answers drawn from a psychometric function of the level the trial played."""
    ada = getattr(getattr(lx, "experiment", None), "adaptive", None)
    if ada is None:
        raise InputError("scripted:psychometric answers from the level an adaptive procedure "
                         "played; this experiment has no 'adaptive:' section", key="--responder")
    p = ada.procedure
    opts: dict = {"threshold": None, "slope": 3.0, "lapse": 0.0,
                  "guess": getattr(p, "guess", 0.0), "function": getattr(p, "function", "weibull")}
    for part in filter(None, (x.strip() for x in arg.split(","))):
        key, _, value = part.partition("=")
        if key not in opts:
            raise InputError(f"unknown psychometric option {key!r}; use threshold, slope, "
                             "lapse, guess, function", key="--responder")
        if key == "function":
            if value not in FUNCTIONS:
                raise InputError(f"function must be one of {', '.join(FUNCTIONS)}",
                                 key="--responder")
            opts[key] = value
            continue
        try:
            opts[key] = float(value)
        except ValueError:
            raise InputError(f"psychometric {key} must be a number (got {value!r})",
                             key="--responder") from None
    if opts["threshold"] is None:
        raise InputError("scripted:psychometric needs threshold=T (in the units of "
                         f"{ada.variable})", key="--responder")
    yes = ada.response.yes_answers

    def answer(q, t):
        if t.presented is None or q.name != (ada.response.question or q.name):
            return correct_answer(q, t) or q.options[0]
        rng = _rng(participant, session, t, "psychometric")
        said_yes = rng.random() < float(psi(t.presented, opts["threshold"], opts["slope"],
                                            opts["guess"], opts["lapse"], opts["function"]))
        if yes is not None:
            pool = [o for o in q.options if (o in yes) == said_yes]
            return pool[0]
        c = correct_answer(q, t)
        if said_yes:
            return c
        wrong = [o for o in q.options if o != c]
        return wrong[rng.below(len(wrong))]
    desc = ",".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}"
                    for k, v in opts.items())
    return ScriptedResponder(answer, description=f"scripted:psychometric:{desc}")
