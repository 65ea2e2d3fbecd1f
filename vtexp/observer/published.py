"""A paper's published cell rates as data for the model participant.

Papers publish rates per cell of their design, not trials. A table of such rates
(:func:`load_published`, ``protocols/published/*.yaml``) says, for each cell, which of
the experiment's conditions it pools (``where``: factor levels; equal weight, as a
mean over conditions), how many answers it holds (``n``: participants x trials per
participant in the cell, from the paper's methods) and the rate of one or more answers
(``correct``: the answer scored correct in each condition, or an option by name); what
the rates leave of 1 is the answers not named ("other").

The model's expected answer distribution in a cell (:class:`CellRates`) is the mean
over its conditions of the probability of each answer under the model
(:class:`~vtexp.observer.likelihood.Likelihood`, lapses included), from the percept of
what the experiment plays on the simulated device. The cells' rates times their ``n``
are counts, and their likelihood (:class:`AggregateLikelihood`) is multinomial (binomial
where a cell names one answer):

    log L = sum over cells of  log n! - sum_i log k_i! + sum_i k_i log p_i        (A1)

with ``k_i = rate_i n`` (not always a whole number: a printed rate is rounded; the
factorials are Gamma functions) and ``p_i`` the model's probability of answer group
``i`` in the cell. It has the interface of the trial likelihood, so
:func:`~vtexp.observer.fit.fit_participant` and
:func:`~vtexp.observer.fit.fit_percept_participant` fit it with profile-likelihood
intervals, and :func:`fit_published` does both and gives the parameter settings to
predict with (:class:`Setting`: the estimate and each interval's ends).

Such a fit treats the pooled answers of all a paper's participants as answers of one
population-typical participant: it estimates where the typical participant is, not
how participants differ.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.special import gammaln

from ..errors import InputError
from ..model import Condition, PlayReport
from .fit import (
    PARAMS,
    PERCEPT_PARAMS,
    ParticipantFit,
    check_names,
    fit_participant,
    fit_percept_participant,
    percept_grid,
    with_percept,
)
from .likelihood import FLOOR, Likelihood, Trial
from .model import ObserverModel
from .params import Participant

#: The name of a rate of the answer scored correct in each of the cell's conditions.
CORRECT = "correct"
#: The name of the answers a cell's rates leave out.
OTHER = "other"
#: How far a cell's rates may sum above 1 (printed rates are rounded to 0.1 %).
ROUNDING = 0.0015


@dataclass(frozen=True)
class PublishedCell:
    """One cell of a paper's table: the conditions it pools, its answers' rates, its size.

    ``groups`` are the named answers and, when the rates leave some of 1, ``other``;
    ``rates`` has one rate per group. ``n`` is None when the paper does not say how many
    answers the cell holds: the cell can then be predicted, not fitted.
    """

    name: str
    where: dict[str, str]
    groups: tuple[str, ...]
    rates: tuple[float, ...]
    n: float | None
    conditions: tuple[int, ...]

    def rate(self, group: str) -> float:
        return self.rates[self.groups.index(group)]

    @property
    def counts(self) -> np.ndarray:
        return np.asarray(self.rates) * (self.n or 0.0)


@dataclass
class PublishedTable:
    """A paper's table of cell rates, checked against the experiment that reproduces it."""

    name: str
    experiment: str
    reference: str
    question: str
    cells: list[PublishedCell]
    path: str | None = None
    notes: str = ""

    def cell(self, name: str) -> PublishedCell:
        for c in self.cells:
            if c.name == name:
                return c
        raise KeyError(name)

    def select(self, **levels: str | tuple[str, ...]) -> list[PublishedCell]:
        """The cells whose ``where`` has each factor at the level (or one of the levels)
        given."""
        def keep(c: PublishedCell) -> bool:
            for f, want in levels.items():
                want = (want,) if isinstance(want, str) else tuple(want)
                if c.where.get(f) not in want:
                    return False
            return True
        return [c for c in self.cells if keep(c)]


# --------------------------------------------------------------------------- reading tables

def load_published(path: str | Path, lx) -> PublishedTable:
    """A table file (``protocols/published/*.yaml``) checked against experiment ``lx``."""
    from ..yamlio import load_yaml
    loaded = load_yaml(path)
    return published_table(loaded.data, lx, path=str(path), line_of=loaded.line_of)


def published_table(data, lx, *, path: str | None = None, line_of=None) -> PublishedTable:
    """A table from its mapping (as read from YAML): every cell's factor levels, answers,
    rates and size checked against experiment ``lx``; the first mistake is one
    :class:`~vtexp.errors.InputError` naming the cell and key.

    The mapping has ``name``, ``experiment`` (the experiment's name), ``reference``,
    optionally ``question`` (a choice question's name; default the experiment's only
    choice question) and ``notes``, and ``cells``: a mapping of cell name to
    ``{where: {factor: level}, n: answers, rates: {correct | option: rate}}``.
    """
    def error(msg: str, *keys) -> InputError:
        line = line_of(keys) if line_of is not None and keys else None
        return InputError(msg, path=path, line=line,
                          key=".".join(str(k) for k in keys) or None)

    if not isinstance(data, dict):
        raise error("a table of published rates is a mapping with name, experiment, "
                    "reference and cells")
    known = {"name", "experiment", "reference", "question", "notes", "cells"}
    for k in data:
        if k not in known:
            raise error(f"unknown key {k!r}; a table has {', '.join(sorted(known))}", k)
    exp = lx.experiment
    if data.get("experiment") != exp.name:
        raise error(f"this table is of experiment {data.get('experiment')!r}, not "
                    f"{exp.name!r} ({lx.path})", "experiment")
    choices = [q for q in exp.asked() if q.kind == "choice"]
    qname = data.get("question")
    if qname is None:
        if len(choices) != 1:
            raise error(f"{exp.name} asks {len(choices)} choice questions; say which one the "
                        "rates are of (question: NAME)", "question")
        q = choices[0]
    else:
        q = next((x for x in choices if x.name == qname), None)
        if q is None:
            raise error(f"no choice question {qname!r} in {exp.name} (its choice questions: "
                        f"{', '.join(x.name for x in choices) or 'none'})", "question")
    cells_in = data.get("cells")
    if not isinstance(cells_in, dict) or not cells_in:
        raise error("cells: give at least one cell, as NAME: {where: ..., n: ..., rates: ...}",
                    "cells")
    from ..compile import enumerate_conditions
    conditions = enumerate_conditions(lx)
    factors = exp.factors
    cells: list[PublishedCell] = []
    for name, spec in cells_in.items():
        at = ("cells", name)
        if not isinstance(spec, dict):
            raise error("a cell is a mapping {where: ..., n: ..., rates: ...}", *at)
        for k in spec:
            if k not in ("where", "n", "rates"):
                raise error(f"unknown key {k!r}; a cell has where, n and rates", *at, k)
        where = spec.get("where") or {}
        if not isinstance(where, dict):
            raise error("where: a mapping of factor to level", *at, "where")
        where = {str(f): str(v) for f, v in where.items()}
        for f, v in where.items():
            if f not in factors:
                raise error(f"no factor {f!r} in {exp.name} (its factors: "
                            f"{', '.join(factors)})", *at, "where", f)
            if v not in factors[f].level_names:
                raise error(f"factor {f!r} has no level {v!r} (its levels: "
                            f"{', '.join(factors[f].level_names)})", *at, "where", f)
        members = tuple(c.index for c in conditions
                        if all(c.levels.get(f) == v for f, v in where.items()))
        if not members:
            raise error(f"no condition of {exp.name} has these levels", *at, "where")
        n = spec.get("n")
        if n is not None:
            if isinstance(n, bool) or not isinstance(n, (int, float)) or not n > 0 \
                    or not math.isfinite(n):
                raise error(f"n must be the number of answers in the cell (> 0), not {n!r}",
                            *at, "n")
            n = float(n)
        rates = spec.get("rates")
        if not isinstance(rates, dict) or not rates:
            raise error("rates: a mapping of answer (correct, or an option) to its rate",
                        *at, "rates")
        groups, values = [], []
        for a, r in rates.items():
            a = str(a)
            if a != CORRECT and a not in q.options:
                raise error(f"{a!r} is neither 'correct' nor an option of question {q.name!r} "
                            f"({', '.join(q.options)})", *at, "rates", a)
            if a == CORRECT and q.correct is None:
                raise error(f"question {q.name!r} scores no answer correct", *at, "rates", a)
            if isinstance(r, bool) or not isinstance(r, (int, float)) or not 0.0 <= r <= 1.0:
                raise error(f"a rate is a proportion in [0, 1] (82 % is 0.82), not {r!r}",
                            *at, "rates", a)
            groups.append(a)
            values.append(float(r))
        for ci in members:
            named = [_option(q, conditions[ci], g) for g in groups]
            if len(set(named)) < len(named):
                raise error(f"two rates name the same answer in condition "
                            f"{conditions[ci].label} ({', '.join(named)})", *at, "rates")
        total = sum(values)
        if total > 1.0 + ROUNDING:
            raise error(f"the rates sum to {total:.4g}, more than 1", *at, "rates")
        if total < 1.0 - 1e-9:
            groups.append(OTHER)
            values.append(1.0 - total)
        elif total > 1.0:
            values = [v / total for v in values]
        cells.append(PublishedCell(str(name), where, tuple(groups), tuple(values), n, members))
    return PublishedTable(str(data.get("name") or ""), exp.name,
                          str(data.get("reference") or ""), q.name, cells, path,
                          str(data.get("notes") or ""))


def _option(question, condition: Condition, group: str) -> str:
    """The option a rate's name stands for in ``condition``."""
    if group != CORRECT:
        return group
    from ..responders.base import correct_answer
    return str(correct_answer(question, condition))


# --------------------------------------------------------------------------- the model's rates

class CellRates:
    """The model's expected answer distribution in each cell, for participant ``who``.

    ``played[i]`` is what condition ``i`` plays on the simulated device (one play per
    condition, as ``vtexp simulate`` plays them). The percept of each condition is
    computed once, here; :meth:`__call__` then costs one evaluation of the answer
    probabilities.
    """

    def __init__(self, model: ObserverModel, who: Participant, table: PublishedTable,
                 cells: list[PublishedCell], conditions: list[Condition],
                 played: list[PlayReport]):
        q = next(x for x in model.lx.experiment.asked() if x.name == table.question)
        self.cells = list(cells)
        self.who = who
        opts = list(q.options)
        trials, seen = [], set()
        for cell in self.cells:
            for ci in cell.conditions:
                for g in cell.groups:
                    if g == OTHER:
                        continue
                    a = _option(q, conditions[ci], g)
                    if (ci, a) not in seen:      # each answer of interest once per condition
                        seen.add((ci, a))
                        trials.append(Trial(q.name, conditions[ci], played[ci], a))
        self.likelihood = Likelihood(model, who, trials)
        if trials:
            row = {ci: g for g, ci in enumerate(self.likelihood.conditions[0])}
        # rates = W @ P.ravel(): each named group of each cell, the mean over its conditions
        self.slices: list[slice] = []
        entries, k = [], 0
        for cell in self.cells:
            start = k
            for g in cell.groups:
                if g != OTHER:
                    for ci in cell.conditions:
                        col = opts.index(_option(q, conditions[ci], g))
                        entries.append((k, row[ci] * len(opts) + col, 1.0 / len(cell.conditions)))
                    k += 1
            self.slices.append(slice(start, k))
        self.n_named = k
        self.entries = (np.array([e[0] for e in entries], dtype=int),
                        np.array([e[1] for e in entries], dtype=int),
                        np.array([e[2] for e in entries]))

    def __call__(self, values: dict[str, float]) -> list[np.ndarray]:
        """Per cell, the model's probability of each of its groups (``other`` the rest)."""
        if not self.entries[0].size:
            return [np.zeros(0) for _ in self.cells]
        P = self.likelihood.probabilities(values, full=False)[0].ravel()
        named = np.zeros(self.n_named)
        rows, cols, w = self.entries
        np.add.at(named, rows, w * P[cols])
        out = []
        for cell, sl in zip(self.cells, self.slices, strict=True):
            p = named[sl]
            if cell.groups[-1] == OTHER:
                p = np.append(p, max(1.0 - p.sum(), FLOOR))
            out.append(np.maximum(p, FLOOR))
        return out

    def predicted(self, values: dict[str, float]) -> dict[str, dict[str, float]]:
        """Per cell name, the model's rate of each group."""
        return {c.name: dict(zip(c.groups, map(float, p), strict=True))
                for c, p in zip(self.cells, self(values), strict=True)}


class AggregateLikelihood:
    """The multinomial log-likelihood (A1) of cells' published counts under the model,
    as a function of the decision parameters: the interface of
    :class:`~vtexp.observer.likelihood.Likelihood` (``n``, called with values)."""

    def __init__(self, rates: CellRates):
        missing = [c.name for c in rates.cells if c.n is None]
        if missing:
            raise InputError(f"cell(s) {', '.join(missing)} give no number of answers (n): "
                             "they can be predicted, not fitted")
        self.rates = rates
        self.counts = [c.counts for c in rates.cells]
        self.n = float(sum(c.n for c in rates.cells))
        self.unknown = 0
        self.constant = float(sum(gammaln(c.n + 1) - gammaln(k + 1).sum()
                                  for c, k in zip(rates.cells, self.counts, strict=True)))

    def __call__(self, values: dict[str, float]) -> float:
        total = self.constant
        for k, p in zip(self.counts, self.rates(values), strict=True):
            total += float((k * np.log(p)).sum())
        return total

    def batch(self, values: dict[str, np.ndarray]) -> np.ndarray:
        """The log-likelihood at B parameter vectors (each parameter an array of B
        values), as :meth:`~vtexp.observer.likelihood.Likelihood.batch`: one vector at a
        time (a table's cells are few)."""
        b = len(next(iter(values.values())))
        return np.array([self({n: float(v[i]) for n, v in values.items()})
                         for i in range(b)])


# --------------------------------------------------------------------------- fitting

@dataclass
class Setting:
    """Parameter values to predict with: the decision values and the percept parameter's
    value (None: the participant's own)."""

    label: str
    values: dict[str, float]
    percept: float | None = None
    loglik: float = float("nan")


@dataclass
class PublishedFit:
    """A fit to published cells: the estimates with their 95 % profile intervals, and
    the settings to predict with (the estimate, then each parameter's interval ends with
    the other parameters maximised there)."""

    fit: ParticipantFit
    names: list[str]
    percept: str | None
    settings: list[Setting] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def fit_published(model: ObserverModel, who: Participant, table: PublishedTable,
                  cells: list[PublishedCell], conditions: list[Condition],
                  played: list[PlayReport], names: list[str], fixed: dict[str, float]
                  ) -> PublishedFit:
    """Maximum likelihood (A1) of ``cells`` over ``names`` (others at ``fixed``), with
    95 % profile-likelihood intervals; a percept parameter among ``names`` is fitted on
    its grid of percepts (:func:`~vtexp.observer.fit.fit_percept_participant`).

    An unidentified parameter (a flat profile) is predicted with at its ``fixed`` value
    (or ``who``'s, for a percept parameter) and its range's ends.
    """
    check_names(names, model)
    percept = next((n for n in names if n in PERCEPT_PARAMS), None)
    decision = [n for n in names if n in PARAMS]
    notes: list[str] = []

    def lik_at(value: float | None) -> AggregateLikelihood:
        w = who if value is None else with_percept(who, percept, value)
        return AggregateLikelihood(CellRates(model, w, table, cells, conditions, played))

    def best(lik: AggregateLikelihood, free: list[str], base: dict) -> tuple[dict, float]:
        if not free:
            return dict(base), lik(base)
        f = fit_participant(lik, free, base, profiles=False)
        return {**base, **{n: f.params[n].estimate for n in free}}, f.loglik

    if percept is None:
        lik = lik_at(None)
        fit = fit_participant(lik, decision, fixed)
        est = {**fixed, **{n: (p.estimate if p.identified else fixed[n])
                           for n, p in fit.params.items()}}
        settings = [Setting("estimate", est, None, lik(est))]
        for n in decision:
            p = fit.params[n]
            for end, x in (("low", p.low), ("high", p.high)):
                v, ll = best(lik, [m for m in decision if m != n], {**fixed, n: x})
                settings.append(Setting(f"{n} {end}", v, None, ll))
        return PublishedFit(fit, names, None, settings, notes)

    grid = percept_grid(percept)
    liks = [lik_at(v) for v in grid]
    fit = fit_percept_participant(liks, percept, grid, decision, fixed)
    pf = fit.params[percept]
    x_hat = pf.estimate if pf.identified else float(getattr(who, percept))
    if not pf.identified:
        notes.append(f"{percept}: not identified by these cells; predicted at the observer "
                     f"file's {x_hat:g} and at its range's ends")
    settings = []
    for label, x in (("estimate", x_hat), (f"{percept} low", pf.low),
                     (f"{percept} high", pf.high)):
        lik = lik_at(x)
        base = {**fixed, **{n: fit.params[n].estimate for n in decision
                            if fit.params[n].identified}}
        v, ll = best(lik, decision, base)
        settings.append(Setting(label, v, x, ll))
    # fit_percept_participant reports the decision parameters at the grid value nearest
    # the percept's estimate; at the estimate itself they are maximised again (above), and
    # those are the estimates reported and predicted with.
    for n in decision:
        p = fit.params[n]
        if p.identified:
            p.estimate = settings[0].values[n]
            if not p.low <= p.estimate <= p.high:
                notes.append(f"{n}: its estimate at the {percept} estimate, {p.estimate:.3g}, "
                             f"is outside its interval on the grid; the interval is widened "
                             "to hold it")
                p.low, p.high = min(p.low, p.estimate), max(p.high, p.estimate)
    # A decision parameter's ends: the others, and the percept over its grid, maximised.
    for n in decision:
        p = fit.params[n]
        for end, x in (("low", p.low), ("high", p.high)):
            tried = [(*best(lk, [m for m in decision if m != n], {**fixed, n: x}), g)
                     for lk, g in zip(liks, grid, strict=True)]
            v, ll, g = max(tried, key=lambda t: t[1])
            settings.append(Setting(f"{n} {end}", v, g, ll))
    return PublishedFit(fit, names, percept, settings, notes)


def predicted_cells(model: ObserverModel, who: Participant, table: PublishedTable,
                    cells: list[PublishedCell], conditions: list[Condition],
                    played: list[PlayReport], setting: Setting, percept: str | None
                    ) -> dict[str, dict[str, float]]:
    """The model's rates of ``cells`` under ``setting`` (a new percept when it sets one)."""
    w = who if setting.percept is None or percept is None else \
        with_percept(who, percept, setting.percept)
    return CellRates(model, w, table, cells, conditions, played).predicted(setting.values)


def rmse_points(cells: list[PublishedCell], predicted: dict[str, dict[str, float]]) -> float:
    """Root mean square difference, in percentage points, over every named rate (not
    ``other``) of ``cells``."""
    d = [100.0 * (predicted[c.name][g] - c.rate(g)) for c in cells for g in c.groups
         if g != OTHER]
    return float(np.sqrt(np.mean(np.square(d)))) if d else float("nan")
