"""An experiment's ``adaptive:`` section at work: one track per condition, on the levels
the device can play.

What is checked when the experiment is loaded is :mod:`vtexp.adaptive.check`'s (the
schema needs it, not the procedures); each level is then coded and checked against the
device's safety limits by :func:`vtexp.compile.compile_conditions`.

:class:`AdaptiveRun` holds a procedure per condition. ``propose(trial)`` gives the
level the procedure asks for (``proposed``) and the level played (``presented``: the
nearest level of the set); ``record(trial, presented, answer)`` tells it the answer.
Each proposal is a pure function of the answers so far and the session's seed (QUEST+
drawing among its best levels uses :class:`vtexp.seeding.HashRandom` keyed by the seed,
the track and the trial), so a resumed session replays its log and must get the same
proposals (:meth:`AdaptiveRun.replay`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..seeding import HashRandom, derive_seed
from .quest import Quest, QuestRule
from .questplus import QuestPlus, QuestPlusRule
from .spec import AdaptiveSpec, StaircaseSpec, grid, procedure_spec, value_list
from .staircase import Staircase, StaircaseRule


def track_key(spec: AdaptiveSpec, condition) -> tuple:
    """The track a condition's trials go to: its levels of the ``tracks`` factors."""
    if spec.tracks is None:
        return (condition.index,)
    return tuple(condition.levels[f] for f in spec.tracks)


@dataclass(frozen=True)
class Proposal:
    proposed: float
    presented: float


class AdaptiveRun:
    """One procedure per condition (a *track*), its levels and its answers."""

    def __init__(self, spec: AdaptiveSpec, conditions, seed: int, question: str,
                 repetitions: int):
        self.spec = spec
        self.seed = int(seed)
        self.question = question
        self.values = np.asarray(value_list(spec.values))
        self.tracks: dict[tuple, Any] = {}
        self.stop_trials: dict[tuple, int] = {}
        self.procedures: dict[tuple, Any] = {}
        self.names: dict[tuple, str] = {}
        self._key = {c.index: track_key(spec, c) for c in conditions}
        sizes: dict[tuple, int] = {}
        for c in conditions:
            sizes[self._key[c.index]] = sizes.get(self._key[c.index], 0) + repetitions
        for c in conditions:
            k = self._key[c.index]
            if k in self.tracks:
                continue
            p = procedure_spec(spec, getattr(c, "adaptive_params", None))
            self.procedures[k] = p
            self.tracks[k] = _make(p, self.values, sizes[k])
            self.stop_trials[k] = min(p.stop.trials or sizes[k], sizes[k])
            self.names[k] = (", ".join(f"{f}={c.levels[f]}" for f in spec.tracks)
                             if spec.tracks is not None else c.label)

    def track_of(self, trial):
        return self.tracks[self._key[trial.condition.index]]

    @classmethod
    def of(cls, lx, conditions, seed: int) -> AdaptiveRun | None:
        exp = lx.experiment
        if exp.adaptive is None:
            return None
        q = exp.adaptive.response.question or exp.asked()[0].name
        return cls(exp.adaptive, conditions, seed, q, exp.design.repetitions)

    def finished(self, trial) -> bool:
        k = self._key[trial.condition.index]
        t = self.tracks[k]
        return t.finished or t.n_trials >= self.stop_trials[k]

    def nearest(self, level: float) -> float:
        i = int(np.argmin(np.abs(self.values - level)))      # ties: the lower level
        return float(self.values[i])

    def propose(self, trial) -> Proposal:
        t = self.track_of(trial)
        if isinstance(t, QuestPlus):
            rng = HashRandom(derive_seed(f"adaptive:{self.names[self._key[trial.condition.index]]}",
                                         str(self.seed), trial.number))
            x = t.propose(rng)
        else:
            x = t.propose()
        x = float(x)
        return Proposal(x, self.nearest(x))

    def is_yes(self, answer: str | None, correct_answer: str | None) -> bool:
        yes = self.spec.response.yes_answers
        return answer in yes if yes is not None else (answer is not None
                                                       and answer == correct_answer)

    def record(self, trial, presented: float, answer: str | None,
               correct_answer: str | None = None) -> None:
        """The answer to the trial at level ``presented`` (practice trials teach nothing)."""
        if trial.practice:
            return
        self.track_of(trial).update(presented, self.is_yes(answer, correct_answer))

    def replay(self, trial, row: dict[str, str], *, exact: bool = True) -> str | None:
        """Check a logged row against what the procedure proposes now, then record it.
        Returns what differs (None if nothing).

        The log writes ``proposed`` and ``presented`` with every digit (``repr``), so they
        must read back equal to what the procedure proposes, bit for bit. With
        ``exact=False`` (sessions begun before that, rounded to 6 decimals) they must
        equal the proposal or the proposal rounded to 6 decimals, also exactly (rows added
        by a resume since then keep every digit).
        """
        status = row.get("status")
        if not trial.practice and self.finished(trial):
            if status != "stopped":
                return (f"its track had stopped, so nothing should have been played, but the "
                        f"log says {status!r}")
            return None
        if status == "stopped":
            return "its track had not stopped, but the log says 'stopped'"
        want = self.propose(trial)
        try:
            proposed, presented = float(row.get("proposed")), float(row.get("presented"))
        except (TypeError, ValueError):
            return (f"proposed/presented are {row.get('proposed')!r}/{row.get('presented')!r}, "
                    "not numbers")

        def same(logged: float, v: float) -> bool:
            # An older session resumed since then holds rows of both kinds.
            return logged == v or (not exact and logged == round(v, 6))
        if not same(proposed, want.proposed):
            return (f"the procedure proposes {want.proposed!r} from the answers before it, "
                    f"the log says {row.get('proposed')}")
        if not same(presented, want.presented):
            return (f"the level presented should be {want.presented!r} (the nearest to "
                    f"{want.proposed!r}), the log says {row.get('presented')}")
        if status in ("ok", None):
            na = ("n/a", "")
            answer, right = row.get("answer"), row.get("correct_answer")
            self.record(trial, want.presented, None if answer in na else answer,
                        None if right in na else right)
        return None


def _make(p, values: np.ndarray, repetitions: int):
    lo, hi = float(values[0]), float(values[-1])
    if isinstance(p, StaircaseSpec):
        return Staircase(StaircaseRule(
            start=p.start, steps_down=tuple(p.steps), steps_up=tuple(p.up()), n_up=p.n_up,
            n_down=p.n_down, minimum=p.minimum if p.minimum is not None else lo,
            maximum=p.maximum if p.maximum is not None else hi,
            max_trials=min(p.stop.trials or repetitions, repetitions),
            max_reversals=p.stop.reversals, initial_one_down=p.initial_one_down,
            harder=p.harder, estimate_reversals=p.estimate_reversals))
    if p.kind == "quest":
        th = tuple(grid(p.thresholds)) if p.thresholds is not None else tuple(values)
        return Quest(QuestRule(thresholds=th, slope=p.slope, guess=p.guess, lapse=p.lapse,
                               function=p.function, prior_mean=p.prior_mean,
                               prior_sd=p.prior_sd, method=p.method, target=p.target,
                               max_trials=p.stop.trials))
    return QuestPlus(QuestPlusRule(
        levels=tuple(values), thresholds=tuple(grid(p.thresholds)), slopes=tuple(grid(p.slopes)),
        lapses=tuple(p.lapses), guess=p.guess, function=p.function,
        select_among=p.select_among, max_trials=p.stop.trials))


def replay_estimate(procedure, values: list[float], levels: list[float],
                    yes: list[bool]) -> dict[str, Any]:
    """The procedure's own estimate after the answers ``yes`` at the ``levels`` presented
    (in trial order), by feeding them to a fresh procedure as the session did.

    Staircase: the mean of the reversal levels :meth:`Staircase.estimate_levels` picks
    (``estimate_reversals``, default all but the first to an even count), their SD, and
    how many there were. QUEST: the posterior mean and SD of the threshold. QUEST+: the
    posterior mean and SD of threshold, slope and lapse (Watson 2017).
    """
    vals = np.asarray(sorted(values), dtype=float)
    proc = _make(procedure, vals, max(len(levels), 1))
    for x, y in zip(levels, yes, strict=True):
        proc.update(float(x), bool(y))
    nan = float("nan")
    out: dict[str, Any] = {"procedure": procedure.kind, "n_trials": len(levels),
                           "threshold": nan, "threshold_sd": nan, "slope": nan,
                           "slope_sd": nan, "lapse": nan, "lapse_sd": nan,
                           "n_reversals": None, "reversals_used": None}
    if isinstance(proc, Staircase):
        use = proc.estimate_levels()
        out.update(method="mean of the last reversals", n_reversals=len(proc.reversal_levels),
                   reversals_used=len(use))
        if use:
            out["threshold"] = float(np.mean(use))
            out["threshold_sd"] = float(np.std(use, ddof=1)) if len(use) > 1 else nan
    elif isinstance(proc, Quest):
        out.update(method="posterior mean", threshold=proc.estimate(), threshold_sd=proc.sd(),
                   slope=procedure.slope, lapse=procedure.lapse)
    else:
        m, sd = proc.mean(), proc.sd()
        out.update(method="posterior mean", threshold=m["threshold"],
                   threshold_sd=sd["threshold"], slope=m["slope"], slope_sd=sd["slope"],
                   lapse=m["lapse"], lapse_sd=sd["lapse"])
    return out
