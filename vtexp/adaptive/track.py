"""An experiment's ``adaptive:`` section at work: one track per condition, on the levels
the device can play.

:func:`check_adaptive` runs when the experiment is loaded: the variable is a parameter
of the coding; every level is one the device can take (whole milliseconds for a
``*_ms`` parameter, whole levels from 0 to the profile's ``max_level`` for a level) and
valid for the coding; a staircase's start and every level its steps can reach are
among the levels. One message, before the first trial. (Each level is then coded and
checked against the device's safety limits by :func:`vtexp.compile.compile_conditions`.)

:class:`AdaptiveRun` holds a procedure per condition. ``propose(trial)`` gives the
level the procedure asks for (``proposed``) and the level played (``presented``: the
nearest level of the set); ``record(trial, presented, answer)`` tells it the answer.
Each proposal is a pure function of the answers so far and the session's seed (QUEST+
drawing among its best levels uses :class:`vtexp.design.HashRandom` keyed by the seed,
the track and the trial), so a resumed session replays its log and must get the same
proposals (:meth:`AdaptiveRun.replay`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import TypeAdapter, ValidationError

from .quest import Quest, QuestRule
from .questplus import QuestPlus, QuestPlusRule
from .spec import AdaptiveSpec, Procedure, StaircaseSpec, grid, value_list
from .staircase import Staircase, StaircaseRule

_PROCEDURE = TypeAdapter(Procedure)
TOL = 1e-9


def procedure_spec(spec: AdaptiveSpec, overrides: dict[str, Any] | None = None):
    """The procedure with a condition's ``sets: adaptive`` settings merged in."""
    if not overrides:
        return spec.procedure
    return _PROCEDURE.validate_python({**spec.procedure.model_dump(exclude_unset=True),
                                       **overrides})


def device_levels(variable: str, values: list[float], profile) -> str | None:
    """Why a level cannot be played by the device (None if every level can)."""
    if variable.endswith("_ms"):
        off = [v for v in values if abs(v - round(v)) > TOL or v < 0]
        if off:
            return (f"{variable} is played in whole milliseconds (0 or more); {off[0]:g} is not "
                    f"one")
    if variable.endswith("_pitches"):
        off = [v for v in values if abs(v - round(v)) > TOL or v < 0]
        if off:
            return (f"{variable} is a distance on the array in whole actuator pitches (0 or "
                    f"more); {off[0]:g} is not one")
    if variable == "level" or variable.endswith("_level"):
        top = profile.limits.max_level
        off = [v for v in values if abs(v - round(v)) > TOL or not 0 <= v <= top]
        if off:
            return (f"{profile.name} plays whole levels from 0 to {top}; {off[0]:g} is not one")
    return None


def staircase_levels(p: StaircaseSpec, values: list[float]) -> tuple[set[float], str | None]:
    """Every level the staircase can reach from its start; why one is not a level, if so."""
    lo = p.minimum if p.minimum is not None else values[0]
    hi = p.maximum if p.maximum is not None else values[-1]
    known = np.asarray(values)

    def on(v: float) -> bool:
        return bool(np.any(np.abs(known - v) <= TOL * max(1.0, abs(v))))

    for name, v in (("minimum", lo), ("maximum", hi), ("start", p.start)):
        if not on(v):
            return set(), (f"{name} {v:g} is not one of the levels the device can play "
                           f"({_describe(values)})")
    if not lo <= p.start <= hi:
        return set(), f"start {p.start:g} is outside minimum..maximum ({lo:g}..{hi:g})"
    steps = sorted(set(p.steps) | set(p.up()))
    seen, todo = {p.start}, [p.start]
    while todo:
        v = todo.pop()
        for s in steps:
            for w in (v - s, v + s):
                w = round(min(max(w, lo), hi), 9)
                if w in seen:
                    continue
                if not on(w):
                    return seen, (f"a step of {s:g} from {v:g} reaches {w:g}, which is not one "
                                  f"of the levels the device can play ({_describe(values)}); "
                                  "make the start and steps multiples of the levels' step")
                seen.add(w)
                todo.append(w)
                if len(seen) > 100000:
                    return seen, "the steps reach more than 100000 levels"
    return seen, None


def _describe(values: list[float]) -> str:
    if len(values) > 2:
        d = np.diff(values)
        if np.allclose(d, d[0]):
            return f"{values[0]:g} to {values[-1]:g} in steps of {d[0]:g}"
    return ", ".join(f"{v:g}" for v in values[:12]) + (" ..." if len(values) > 12 else "")


def check_adaptive(lx, profile, coding_model) -> None:
    """The load-time checks of the module's docstring; raise ``lx.error`` (an InputError
    naming file, line and key) on the first problem."""
    exp = lx.experiment
    spec: AdaptiveSpec = exp.adaptive
    at = ("adaptive",)
    if spec.sets == "stimulus":
        _check_stimulus_variable(lx, profile)
    else:
        fields = coding_model.model_fields
        if spec.variable not in fields:
            raise lx.error(f"{spec.variable!r} is not a parameter of coding "
                           f"{exp.coding.protocol!r} (its parameters: {', '.join(fields)}; a "
                           "stimulus generator's parameter needs 'sets: stimulus')",
                           at + ("variable",))
        for fname, f in exp.factors.items():
            if f.sets == "coding" and any(spec.variable in f.params_of(lv)
                                          for lv in f.level_names):
                raise lx.error(f"factor {fname!r} sets {spec.variable!r}, which the adaptive "
                               "procedure sets", ("factors", fname))
    values = value_list(spec.values)
    if not values:
        raise lx.error("no levels to play", at + ("values",))
    why = device_levels(spec.variable, values, profile)
    if why:
        raise lx.error(why, at + ("values",))
    if spec.sets == "stimulus":
        _check_stimulus_levels(lx, profile, values)
    else:
        for v in (values[0], values[-1]):
            try:
                coding_model.model_validate({**exp.coding.params, spec.variable: _number(v)})
            except ValidationError as e:
                msg = e.errors(include_url=False)[0]["msg"]
                raise lx.error(f"{spec.variable} = {v:g} is not valid for coding "
                               f"{exp.coding.protocol!r}: {msg}", at + ("values",)) from None
    q = spec.response.question
    asked = {qq.name: qq for qq in exp.asked()}
    if q is not None and q not in asked:
        raise lx.error(f"no question {q!r} (questions: {', '.join(asked)})",
                       at + ("response", "question"))
    question = asked[q] if q is not None else exp.asked()[0]
    if spec.response.yes_answers is None:
        if question.correct is None:
            raise lx.error(f"question {question.name!r} has no correct answer: say which "
                           "answers count as yes (response: {yes_answers: [...]})", at + ("response",))
    else:
        bad = [a for a in spec.response.yes_answers if a not in question.options]
        if bad:
            raise lx.error(f"{bad[0]!r} is not one of the options {question.options}",
                           at + ("response", "yes_answers"))
    if spec.tracks is not None:
        for i, name in enumerate(spec.tracks):
            if name not in exp.factors:
                raise lx.error(f"{name!r} is not a factor (factors: {', '.join(exp.factors)})",
                               at + ("tracks", i))
        loose = [n for n, f in exp.factors.items() if f.sets == "adaptive"
                 and n not in spec.tracks]
        if loose:
            raise lx.error(f"factor {loose[0]!r} sets the procedure's settings, so its levels "
                           "are separate tracks: add it to 'tracks'", at + ("tracks",))
    levels = {n: f for n, f in exp.factors.items() if f.sets == "adaptive"}
    cases = [((), None)] + [(("factors", n, "levels", lv), f.params_of(lv))
                            for n, f in levels.items() for lv in f.level_names]
    for where, overrides in cases:
        try:
            p = procedure_spec(spec, overrides)
        except ValidationError as e:
            err = e.errors(include_url=False)[0]
            raise lx.error(f"{'.'.join(map(str, err['loc']))}: {err['msg']}",
                           where or at + ("procedure",)) from None
        key = where or at + ("procedure",)
        stop = p.stop.trials
        budget = exp.design.repetitions * _conditions_per_track(lx)
        if stop is not None and stop > budget:
            raise lx.error(f"stop.trials {stop} is more than the {budget} trials a track has "
                           f"(design.repetitions x the conditions of a track)",
                           key + (("stop", "trials") if not where else ()))
        if isinstance(p, StaircaseSpec):
            _, why = staircase_levels(p, values)
            if why:
                field = "start" if why.startswith("start") else "steps"
                raise lx.error(f"the staircase's {why}",
                               key + ((field,) if not where or field in (overrides or {})
                                      else ()))


def _adaptive_stimuli(lx) -> list[str]:
    """The stimuli the conditions present (those the adaptive level applies to)."""
    exp = lx.experiment
    f = exp.stimulus_factor()
    if f is None:
        return [next(iter(exp.stimuli))]
    if exp.design.conditions is not None:
        return list(dict.fromkeys(c[f] for c in exp.design.conditions))
    return exp.factors[f].level_names


def _check_stimulus_variable(lx, profile) -> None:
    """``sets: stimulus``: the variable is a parameter of every presented stimulus's
    generator, and no stimulus fixes it."""
    from ..stimuli import GENERATORS

    exp = lx.experiment
    var = exp.adaptive.variable
    for name in _adaptive_stimuli(lx):
        st = exp.stimuli[name]
        if st.generator is None:
            raise lx.error(f"stimulus {name!r} is not drawn by a generator, so its "
                           f"{var!r} cannot be set trial by trial", ("adaptive", "sets"))
        fields = GENERATORS[st.generator][1].model_fields
        if var not in fields:
            raise lx.error(f"{var!r} is not a parameter of generator {st.generator!r} "
                           f"(stimulus {name!r}; its parameters: {', '.join(fields)})",
                           ("adaptive", "variable"))
        if var in st.params:
            raise lx.error(f"stimulus {name!r} sets {var!r}, which the adaptive procedure "
                           "sets: remove it here", ("stimuli", name, "params", var))


def _check_stimulus_levels(lx, profile, values: list[float]) -> None:
    """Every level is a valid parameter of each stimulus's generator and, for a generator
    that draws on the array's grid, fits on the device's array."""
    from ..stimuli import GENERATORS

    exp = lx.experiment
    var = exp.adaptive.variable
    for name in _adaptive_stimuli(lx):
        st = exp.stimuli[name]
        model = GENERATORS[st.generator][1]
        base = dict(st.params)
        if "array_rows" in model.model_fields:
            base.setdefault("array_rows", profile.rows)
            base.setdefault("array_cols", profile.cols)
        for v in values:
            try:
                p = model.model_validate({**base, var: _number(v)})
            except ValidationError as e:
                msg = e.errors(include_url=False)[0]["msg"]
                raise lx.error(f"{var} = {v:g} is not valid for generator {st.generator!r} "
                               f"(stimulus {name!r}): {msg}", ("adaptive", "values")) from None
            fits = getattr(p, "array_problem", None)
            why = fits(profile.rows, profile.cols) if fits is not None else None
            if why:
                raise lx.error(f"{var} = {v:g} does not fit on {profile.name} (stimulus "
                               f"{name!r}): {why}; keep the values within the array",
                               ("adaptive", "values"))


def _conditions_per_track(lx) -> int:
    exp = lx.experiment
    tracks = exp.adaptive.tracks
    if tracks is None:
        return 1
    n = 1
    for name, f in exp.factors.items():
        if name not in tracks:
            n *= len(f.level_names)
    if exp.design.conditions is not None:       # a declared list: the largest track
        from collections import Counter
        counts = Counter(tuple(c[t] for t in tracks) for c in exp.design.conditions)
        n = max(counts.values())
    return n


def track_key(spec: AdaptiveSpec, condition) -> tuple:
    """The track a condition's trials go to: its levels of the ``tracks`` factors."""
    if spec.tracks is None:
        return (condition.index,)
    return tuple(condition.levels[f] for f in spec.tracks)


def _number(v: float):
    return int(round(v)) if abs(v - round(v)) <= TOL else v


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
            from ..design import HashRandom, derive_seed
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
