"""The plan of a session: what happens, in order, as a generator of steps.

:func:`session_plan` yields the steps of one run of a session (from the first trial the
log does not hold yet); the engine (:mod:`vtexp.session.engine`) carries each out and
sends back, for a trial, the :class:`~vtexp.session.records.TrialDone` it emitted. An
adaptive procedure's tracks learn from those answers, so the next trial's level is
proposed from every answer before it::

    Instructions
    RunTrial | StoppedTrial     per trial (StoppedTrial: its adaptive track had met its
    Wait                        stop rule; its rows say so and nothing is played)
    [Break]                     after every design.break_every main trials
    End

The plan knows nothing of devices, responders or files; the engine knows nothing of
designs, breaks or adaptive procedures.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Generator
from dataclasses import dataclass
from typing import Union

from ..adaptive.spec import parameter_value
from ..adaptive.track import AdaptiveRun
from ..design import Trial
from .records import TrialDone

#: Said to the participant at the end of every run.
FINISH_TEXT = "Thank you. The session is over."


@dataclass(frozen=True)
class Instructions:
    """Show the experiment's instructions (before the first trial of the run)."""

    text: str


@dataclass(frozen=True)
class RunTrial:
    """Play the trial's stimulus and ask its questions; ``total``: the trials planned."""

    trial: Trial
    total: int


@dataclass(frozen=True)
class StoppedTrial:
    """The trial's adaptive track had met its stop rule: its rows, nothing played."""

    trial: Trial
    total: int


@dataclass(frozen=True)
class Wait:
    """The pause between trials, on the device's clock."""

    ms: float


@dataclass(frozen=True)
class Break:
    """A break screen; the participant continues when ready."""

    text: str


@dataclass(frozen=True)
class End:
    """The end screen. ``stopped_early``: why the run ends before the session's last
    trial (``max_trials``), else None (the session is complete)."""

    text: str
    stopped_early: str | None = None


Step = Union[Instructions, RunTrial, StoppedTrial, Wait, Break, End]
Plan = Generator[Step, "TrialDone | None", None]


def session_plan(exp, trials: list[Trial], start: int = 0, *, max_trials: int | None = None,
                 adaptive: AdaptiveRun | None = None) -> Plan:
    """The steps of a run that starts at ``trials[start]`` (the first trial the log lacks)
    and plays at most ``max_trials`` trials. Send each trial step's ``TrialDone`` back."""
    yield Instructions(exp.instructions.strip() or exp.asked()[0].prompt)
    todo = trials[start:] if max_trials is None else trials[start:start + max_trials]
    for planned in todo:
        trial = planned if adaptive is None else adaptive_trial(adaptive, planned)
        stopped = trial.condition.schedule is None and not trial.condition.camera
        done = yield (StoppedTrial if stopped else RunTrial)(trial, len(trials))
        if adaptive is not None and done is not None:
            learn(adaptive, done)
        yield Wait(exp.design.iti_ms)
        text = break_text(exp, trial, trials)
        if text is not None:
            yield Break(text)
    early = None if len(todo) == len(trials) - start else \
        f"stopped after {len(todo)} trials as asked"
    yield End(FINISH_TEXT, early)


def adaptive_trial(adaptive: AdaptiveRun, trial: Trial) -> Trial:
    """The trial at the level its track proposes now, or without a schedule if the track
    has stopped."""
    c = trial.condition
    if not trial.practice and adaptive.finished(trial):
        return dataclasses.replace(trial, condition=dataclasses.replace(c, schedule=None))
    p = adaptive.propose(trial)
    variable = adaptive.spec.variable
    if adaptive.spec.sets == "stimulus":
        cond = dataclasses.replace(c, schedule=c.schedules[p.presented],
                                   pattern=c.patterns[p.presented],
                                   stimulus_params={variable: parameter_value(p.presented)})
    else:
        cond = dataclasses.replace(c, schedule=c.schedules[p.presented],
                                   coding_params={**c.coding_params,
                                                  variable: parameter_value(p.presented)})
    return dataclasses.replace(trial, condition=cond, proposed=p.proposed,
                               presented=p.presented)


def learn(adaptive: AdaptiveRun, done: TrialDone) -> None:
    """The track of the trial learns its answer (a trial played at a proposed level)."""
    trial = done.trial
    if trial.presented is None:
        return
    for rec in done.rows:
        if rec.question == adaptive.question and rec.status == "ok":
            adaptive.record(trial, trial.presented, rec.answer, rec.correct_answer)


def break_text(exp, trial: Trial, trials: list[Trial]) -> str | None:
    """A break after every ``design.break_every`` main trials (not after the last)."""
    every = exp.design.break_every
    if not every or trial.practice or trial.number == trials[-1].number:
        return None
    n_main = sum(1 for t in trials if not t.practice)
    done = sum(1 for t in trials[:trial.number] if not t.practice)
    if done % every:
        return None
    return (f"Time for a break. {done} of {n_main} trials are done. "
            "Continue when you are ready.")
