"""Fitting the model participant to logged sessions: estimates, intervals, population.

``vtexp observer fit DATA`` reads sessions (:func:`read_trials`), and for each
participant maximises the likelihood of their answers
(:class:`~vtexp.observer.likelihood.Likelihood`) over the parameters asked for,
the others held at the observer file's values (:func:`fit_participant`). Each
parameter gets a profile-likelihood 95 % interval: the values whose profile
log-likelihood is within 3.84 / 2 of the maximum (likelihood ratio, chi-square
with one degree of freedom). A parameter whose interval reaches both of its bounds
is **not identified** by these data: the answers say nothing about it, and no
estimate is reported. The participants' estimates make the population
(:func:`population`): the centre and the spread that
:func:`~vtexp.observer.params.draw_participant` draws from, written as an
observer file (:func:`observer_yaml`) that ``vtexp simulate --observer`` takes.
The population's centre gets a 95 % interval too, from the same population
likelihood: its profile over the centre (the spread maximised again at each value),
cut where a normal sample's would give the t interval for the participants who
estimate the spread (:func:`centre_cut`: 2.95 below the maximum for four), or at
3.84 / 2 where the spread is the observer file's (:func:`_centre_interval`). The file
records it,
with the parameters whose centre is not identified, in its ``fitted:`` section
(:func:`fitted_record`), so that ``vtexp simulate`` can report power over it.

A percept parameter (integration time, two-point threshold) changes the percept
itself: it is fitted on a grid of percepts (:func:`fit_percept_participant`), computed
once per fit and shared by its participants.

The percept of a trial is that of what the device reported playing (its device
events, the first play, which is what the model participant feels in a session),
never the plan's schedule.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.optimize import brentq, minimize

from ..errors import InputError
from ..model import PlayedPulse, PlayReport, PulseTrain
from .likelihood import DECISION, Likelihood, Trial, batch_values, decision_values
from .model import ObserverModel

#: chi-square(1) 95 % quantile / 2: the drop in log-likelihood at an interval's edge.
HALF_CHI2 = 3.841458820694124 / 2


@dataclass(frozen=True)
class ParamSpec:
    """A parameter a fit can estimate: its bounds and the scale it is searched on."""

    name: str
    low: float
    high: float
    log: bool                # searched on a log scale
    informs: str             # which questions inform it: any, graded, abstain, rating, count
    spread: str | None       # its population field (None: one value for everyone)

    def to_u(self, x: float) -> float:
        return math.log(x) if self.log else x

    def from_u(self, u: float) -> float:
        return math.exp(u) if self.log else u

    @property
    def bounds_u(self) -> tuple[float, float]:
        return self.to_u(self.low), self.to_u(self.high)


PARAMS: dict[str, ParamSpec] = {p.name: p for p in (
    ParamSpec("efficiency", 1e-3, 1.0, True, "graded", "efficiency_cv"),
    ParamSpec("decision_noise", 0.05, 10.0, True, "graded", "decision_noise_cv"),
    ParamSpec("lapse", 0.0, 0.5, False, "any", "lapse_logit_sd"),
    ParamSpec("abstain_criterion", 0.0, 10.0, False, "abstain", None),
    ParamSpec("rating_bias", -5.0, 5.0, False, "rating", "rating_bias_sd"),
    ParamSpec("rating_step", 0.05, 10.0, True, "rating", None),
    ParamSpec("turns_sd", 0.05, 5.0, True, "count", None),
)}
assert set(PARAMS) == set(DECISION)

#: Parameters of the percept itself. The percept is computed anew for each value, so
#: they are fitted on a grid of PERCEPT_POINTS values (log-spaced over their range),
#: one at a time; intensity_levels is held at the observer file's value.
PERCEPT = ("two_point_threshold_mm", "integration_ms", "intensity_levels")
PERCEPT_PARAMS: dict[str, ParamSpec] = {p.name: p for p in (
    ParamSpec("integration_ms", 10.0, 400.0, True, "any", "integration_cv"),
    ParamSpec("two_point_threshold_mm", 2.0, 200.0, True, "any", "two_point_threshold_cv"),
)}
PERCEPT_POINTS = 17
DEFAULT_PARAMS = ("efficiency", "lapse")


def spec_of(name: str) -> ParamSpec:
    return PARAMS.get(name) or PERCEPT_PARAMS[name]


def check_names(names: list[str], model: ObserverModel) -> None:
    """Each name a parameter this fit can estimate, and one the experiment's questions
    inform; otherwise one message saying why."""
    known = ", ".join([*PARAMS, *PERCEPT_PARAMS])
    qs = model.lx.experiment.asked()
    kinds = {q.kind for q in qs}
    abstain = any(q.kind == "choice" and any(o in model.spec.abstain for o in q.options)
                  for q in qs)
    if not names:
        raise InputError("give at least one parameter to fit", key="--params")
    percept = [n for n in names if n in PERCEPT_PARAMS]
    if len(percept) > 1:
        raise InputError(f"{' and '.join(percept)} both shape the percept, which is computed "
                         "anew for each of their values: fit one of them at a time (the other "
                         "at the observer file's value, --observer)", key="--params")
    for n in names:
        if n in PERCEPT and n not in PERCEPT_PARAMS:
            raise InputError(f"{n} shapes the percept itself and takes whole values: it is "
                             "not fitted; set it in the observer file (--observer)",
                             key="--params")
        if n in PERCEPT_PARAMS:
            continue
        if n not in PARAMS:
            raise InputError(f"no parameter {n!r}; the parameters a fit estimates are {known}",
                             key="--params")
        why = {"graded": (not kinds & {"choice", "rating"},
                          "no choice or rating question of the experiment depends on it"),
               "abstain": (not abstain, "no question of the experiment has an abstain option "
                           f"(observer.abstain: {model.spec.abstain or 'none'})"),
               "rating": ("rating" not in kinds, "the experiment asks no rating question"),
               "count": ("number" not in kinds, "the experiment asks no number question"),
               "any": (False, "")}[PARAMS[n].informs]
        if why[0]:
            raise InputError(f"{n}: {why[1]}, so its answers cannot inform it", key="--params")
    if len(set(names)) != len(names):
        raise InputError("a parameter is named twice", key="--params")


# --------------------------------------------------------------------------- fitting

@dataclass
class ParameterFit:
    """One parameter of one participant: the estimate and its 95 % profile interval.

    ``identified`` is False when the profile stays within 3.84 / 2 of the maximum
    from bound to bound: then ``estimate`` is None (the data do not say).
    """

    name: str
    estimate: float | None
    low: float
    high: float
    identified: bool
    #: the profile log-likelihood (less its maximum) at ``grid`` values over the range
    grid: list[float] = field(default_factory=list)
    profile: list[float] = field(default_factory=list)

    def text(self, digits: int = 3) -> str:
        if not self.identified:
            return "not identified"
        def g(x):
            return f"{x:.{digits}g}"
        return f"{g(self.estimate)} [{g(self.low)}, {g(self.high)}]"


@dataclass
class ParticipantFit:
    participant: str
    answers: int
    loglik: float
    params: dict[str, ParameterFit]
    seconds: float
    evaluations: int
    notes: list[str] = field(default_factory=list)


def fit_participant(lik: Likelihood, names: list[str], fixed: dict[str, float], *,
                    participant: str = "", starts: int = 3,
                    profiles: bool = True, cut: float | None = None) -> ParticipantFit:
    """Maximum likelihood over ``names`` (the others at ``fixed``), with profile intervals.

    The search is L-BFGS-B within each parameter's bounds, on the log scale for
    positive scale parameters, from ``starts`` starting points (the fixed values
    and points spread over the bounds); the best is kept. ``profiles=False``: the
    maximum only (every interval is then the whole range). ``cut``: the log-likelihood
    at the intervals' edges (default: this maximum less HALF_CHI2), for a fit that is
    one slice of a larger one (:func:`fit_percept_participant`).
    """
    t0 = time.perf_counter()
    specs = [PARAMS[n] for n in names]
    bounds = [s.bounds_u for s in specs]
    calls = [0]

    base = batch_values([fixed])

    def nll(U) -> np.ndarray:
        """The negative log-likelihood at the rows of U (B, parameters), or at one u."""
        U = np.asarray(U, dtype=float)
        one = U.ndim == 1
        U = np.atleast_2d(U)
        calls[0] += len(U)
        v = {n: np.repeat(x, len(U)) for n, x in base.items()}
        for k, s in enumerate(specs):
            v[s.name] = np.exp(U[:, k]) if s.log else U[:, k].copy()
        out = -lik.batch(v)
        return float(out[0]) if one else out

    def clip(u):
        return np.array([min(max(x, lo), hi) for x, (lo, hi) in zip(u, bounds, strict=True)])

    def lo_hi(i):
        lo, hi = bounds[i]
        return lo + 0.02 * (hi - lo), hi - 0.02 * (hi - lo)

    first = clip([s.to_u(max(fixed[s.name], s.low if not s.log else s.low * 1.01))
                  for s in specs])
    points = [first]
    for k in range(1, starts):
        frac = (k / starts + 0.5 / starts * np.arange(len(specs))) % 1.0
        points.append(np.array([lo_hi(i)[0] + f * (lo_hi(i)[1] - lo_hi(i)[0])
                                for i, f in enumerate(frac)]))
    best, modes = None, []
    for p in points:
        r = _minimize(nll, p, bounds, maxiter=200)
        if best is None or r.fun < best.fun:
            best = r
        if all(np.abs(np.asarray(r.x) - m).max() > 0.05 * _widest(bounds) for m in modes):
            modes.append(np.asarray(r.x))
    u_hat, nll_hat = np.array(best.x), float(best.fun)
    for p in points:        # where the profile's inner searches also start from
        if all(np.abs(p - m).max() > 0.05 * _widest(bounds) for m in modes):
            modes.append(p)

    out: dict[str, ParameterFit] = {}
    if not profiles:
        for i, s in enumerate(specs):
            out[s.name] = ParameterFit(s.name, s.from_u(u_hat[i]), s.low, s.high, True)
        return ParticipantFit(participant, lik.n, -nll_hat, out, time.perf_counter() - t0,
                              calls[0])
    for i, s in enumerate(specs):
        target = None if cut is None else -cut
        low, high, better, grid, prof = _profile(nll, u_hat, nll_hat, i, bounds, modes, target)
        if better is not None and better[1] < nll_hat - 1e-3:      # the profile found higher
            u_hat, nll_hat = better
            low, high, _, grid, prof = _profile(nll, u_hat, nll_hat, i, bounds, modes, target)
        lo_b, hi_b = bounds[i]
        span = hi_b - lo_b
        flat = low <= lo_b + 1e-6 * span and high >= hi_b - 1e-6 * span
        out[s.name] = ParameterFit(s.name, None if flat else s.from_u(u_hat[i]),
                                   s.from_u(low), s.from_u(high), not flat,
                                   [s.from_u(float(g)) for g in grid],
                                   [float(x) for x in prof])
    return ParticipantFit(participant, lik.n, -nll_hat, out, time.perf_counter() - t0, calls[0])


def fit_percept_participant(liks: list[Likelihood], name: str, values: list[float],
                            names: list[str], fixed: dict[str, float], *,
                            participant: str = "") -> ParticipantFit:
    """Maximum likelihood over a percept parameter ``name`` and the decision parameters
    ``names``: ``liks[k]`` is the likelihood with the percept at ``values[k]``.

    At each value the decision parameters are maximised (the profile of ``name`` on
    the grid); between the grid's values the profile is a cubic spline (on the log
    scale), whose maximum is the estimate and whose drops by HALF_CHI2 are the
    interval's edges. The decision
    parameters' estimates are those at the grid value nearest the estimate; their
    intervals are the union, at this fit's cut, of their intervals at every grid value
    whose profile reaches the cut (so they include the percept's uncertainty, to within
    the grid's spacing).
    """
    t0 = time.perf_counter()
    spec = PERCEPT_PARAMS[name]
    u = np.array([spec.to_u(v) for v in values])
    ll, evals = [], 0
    for lik in liks:
        if names:
            f = fit_participant(lik, names, fixed, profiles=False)
            ll.append(f.loglik)
            evals += f.evaluations
        else:
            ll.append(lik(fixed))
            evals += 1
    ll = np.array(ll)
    from scipy.interpolate import CubicSpline
    fine = np.linspace(u[0], u[-1], 2001)
    curve = CubicSpline(u, ll)(fine)                  # the profile between the grid's points
    b = int(np.argmax(curve))
    u_hat, ll_hat = float(fine[b]), float(curve[b])
    cut = ll_hat - HALF_CHI2

    def edge(direction: int) -> float:
        k = b
        while 0 <= k + direction < len(fine):
            if curve[k + direction] < cut:
                x0, x1, y0, y1 = fine[k], fine[k + direction], curve[k], curve[k + direction]
                return float(x0 + (cut - y0) * (x1 - x0) / (y1 - y0))
            k += direction
        return float(fine[-1] if direction > 0 else fine[0])

    low, high = edge(-1), edge(1)
    flat = low <= u[0] + 1e-9 and high >= u[-1] - 1e-9
    near = int(np.argmin(np.abs(u - u_hat)))
    params: dict[str, ParameterFit] = {}
    if names:
        # The decision parameters' intervals cover the percept's uncertainty: the union of
        # their intervals, at the whole fit's cut, over every grid value of the percept
        # whose profile reaches that cut; their profiles the pointwise maximum.
        slices = sorted({near, *np.flatnonzero(ll >= cut - 1e-9).tolist()})
        fits = {k: fit_participant(liks[k], names, fixed, participant=participant,
                                   cut=cut) for k in slices}
        evals += sum(f.evaluations for f in fits.values())
        for n in names:
            est = fits[near].params[n]
            sp = spec_of(n)
            lows = [f.params[n].low for f in fits.values()]
            highs = [f.params[n].high for f in fits.values()]
            lo_n, hi_n = min(lows), max(highs)
            lo_u, hi_u = sp.bounds_u
            tol = 1e-6 * (hi_u - lo_u)
            flat_n = sp.to_u(lo_n) <= lo_u + tol and sp.to_u(hi_n) >= hi_u - tol
            prof = np.max([np.array(f.params[n].profile) + f.loglik for f in fits.values()],
                          axis=0)
            params[n] = ParameterFit(n, None if flat_n else est.estimate, lo_n, hi_n,
                                     not flat_n, est.grid, [float(x) for x in
                                                            prof - max(prof.max(), ll_hat)])
    params = {name: ParameterFit(name, None if flat else spec.from_u(u_hat), spec.from_u(low),
                                 spec.from_u(high), not flat, [float(v) for v in values],
                                 [float(x) for x in ll - ll.max()]), **params}
    return ParticipantFit(participant, liks[0].n, float(ll_hat), params,
                          time.perf_counter() - t0, evals)


#: The finite-difference step of the searches (on the search scale).
FD_STEP = 1e-5
#: A search stops when a step gains less than this share of the log-likelihood (about
#: 1e-4 of a participant's 60-100 log units; scipy's default, 2.2e-9, took up to 40 %
#: more evaluations for changes far below the 1.92 an interval's edge is cut at).
FTOL = 1e-6


def _minimize(nll_rows, x0, bounds, *, maxiter: int):
    """L-BFGS-B on ``nll_rows`` (the negative log-likelihood at the rows of a (B, k)
    array) within ``bounds``: each gradient is the forward difference of step FD_STEP
    (backward at an upper bound), as scipy's own, with the point and its k neighbours
    evaluated in one call of the likelihood (:meth:`Likelihood.batch`)."""
    hi = np.array([b[1] for b in bounds])

    def fun_grad(x):
        x = np.asarray(x, dtype=float)
        h = np.where(x + FD_STEP > hi, -FD_STEP, FD_STEP)
        pts = np.repeat(x[None, :], len(x) + 1, axis=0)
        pts[1:] += np.diag(h)
        dx = np.diagonal(pts[1:]) - x
        f = nll_rows(pts)
        return float(f[0]), (f[1:] - f[0]) / dx

    return minimize(fun_grad, np.asarray(x0, dtype=float), jac=True, method="L-BFGS-B",
                    bounds=bounds, options={"maxiter": maxiter, "ftol": FTOL})


def _widest(bounds) -> float:
    return max(hi - lo for lo, hi in bounds)


#: The population fields' upper bounds (vtexp.observer.params.PopulationSpread).
_SPREAD_MAX = {"efficiency_cv": 3.0, "decision_noise_cv": 3.0, "lapse_logit_sd": 5.0,
               "integration_cv": 2.0, "two_point_threshold_cv": 2.0,
               "rating_bias_sd": 5.0}

#: The smallest spread a population fit considers (on the scale the parameter varies on).
TAU_MIN = 0.02

#: Points of each profile over the parameter's whole range (its search scale), besides
#: the estimate: the population is fitted from them (:func:`population`).
PROFILE_POINTS = 17


def _profile(nll, u_hat, nll_hat, i, bounds, modes=(), target=None):
    """The profile of parameter ``i`` on a grid over its range, and its 95 % interval.

    The grid is walked out from the estimate each way, each point's other parameters
    optimised from the previous point's and from every other local maximum and starting
    point of the fit (``modes``): a likelihood with two modes (a sharp participant who
    lapses often, or a blurred one who never does) is profiled across both. An edge of
    the interval is where the profile has dropped by HALF_CHI2, found by Brent's method
    between the grid points around it; the bound when it never drops so far.

    Returns (low, high, better, grid, profile): ``better`` the best point met (a higher
    maximum than ``u_hat`` if the profile found one), ``profile`` the log-likelihood
    less the maximum at each grid point (search scale). ``target``: the negative
    log-likelihood at the edges, if not ``nll_hat + HALF_CHI2``.
    """
    target = nll_hat + HALF_CHI2 if target is None else target
    others = [j for j in range(len(u_hat)) if j != i]
    better: list = [None]
    lo_b, hi_b = bounds[i]
    span = hi_b - lo_b
    solved: dict[float, np.ndarray] = {float(u_hat[i]): u_hat.copy()}
    far = 0.05 * _widest(bounds)
    # The other local maxima, each followed along the walk from where its last search
    # ended (not searched afresh from the fit's point at every step); a track whose search
    # ends where another's did is dropped.
    tracks: list[np.ndarray] = []

    def distinct(x, among) -> bool:
        return all(np.abs(x - y).max() > far for y in among)

    def prof_at(x: float) -> float:
        near = min(solved, key=lambda k: abs(k - x))
        warm = solved[near]
        if not others:
            u = u_hat.copy()
            u[i] = x
            val = nll(u)
        else:
            def inner(W):
                U = np.repeat(warm[None, :], len(W), axis=0)
                U[:, i] = x
                U[:, others] = W
                return nll(U)
            starts = [warm[others]]
            if len(others) == 1:        # one other parameter: start from the best of a scan
                lo, hi = bounds[others[0]]
                scan = np.array([[v] for v in np.linspace(lo, hi, 9)] + starts)
                starts = [scan[int(np.argmin(inner(scan)))]]
            else:
                for t in tracks:
                    if distinct(t, starts):
                        starts.append(t)
            found = [_minimize(inner, w0, [bounds[j] for j in others], maxiter=100)
                     for w0 in starts]
            r = min(found, key=lambda r: r.fun)
            if len(others) > 1:
                tracks.clear()
                for f in found:
                    if distinct(f.x, [r.x, *tracks]):
                        tracks.append(np.array(f.x))
            u = warm.copy()
            u[i] = x
            u[others] = r.x
            val = float(r.fun)
        solved[float(x)] = u
        if better[0] is None or val < better[0][1]:
            better[0] = (u.copy(), val)
        return val

    grid = np.linspace(lo_b, hi_b, PROFILE_POINTS)
    values = np.empty(len(grid))
    right = np.flatnonzero(grid > u_hat[i])
    left = np.flatnonzero(grid <= u_hat[i])[::-1]
    for idx in (right, left):          # outward from the estimate, each way
        tracks[:] = [m[others].copy() for m in modes]
        for k in idx:
            values[k] = prof_at(float(grid[k]))
    drop = values - target                                    # > 0: outside the interval

    def edge(direction: int) -> float:
        xs = [float(u_hat[i])] + [float(g) for g in (grid[right] if direction > 0
                                                       else grid[left])]
        ds = [nll_hat - target] + [float(d) for d in (drop[right] if direction > 0
                                                else drop[left])]
        for (x0, d0), (x1, d1) in zip(zip(xs, ds), zip(xs[1:], ds[1:])):
            if d1 > 0:
                a, b = sorted((x0, x1))
                if d0 > 0:
                    return x0
                # The ends as the walk found them: searched again from elsewhere, a point's
                # profile can come out a little different, and the signs Brent's method
                # needs would not be certain.
                known = {x0: d0, x1: d1}
                return brentq(lambda x: known[x] if x in known else prof_at(x) - target,
                              a, b, xtol=span * 1e-3)
        return hi_b if direction > 0 else lo_b

    low, high = edge(-1), edge(1)
    return low, high, better[0], grid, -(values - min(nll_hat, values.min()))


# --------------------------------------------------------------------------- reading sessions

@dataclass
class FitData:
    """What a fit reads from sessions: the experiment they ran, the device profile, and
    each participant's trials (answer and what was played)."""

    model: ObserverModel
    trials: dict[str, list[Trial]]
    sessions: int
    notes: list[str]
    experiment_sha256: str
    #: what a worker process rebuilds the model from: (experiment text, its path, the
    #: device profile as JSON, the observer file)
    source: tuple = ()


def read_trials(paths: list, *, params_file=None, include_simulated: bool = False) -> FitData:
    """Sessions under ``paths`` (as ``vtexp analyze`` takes them), with every trial's
    played stimulus rebuilt from the session's device events."""
    from ..analysis.load import events_path, load_sessions
    from ..compile import enumerate_conditions
    from ..experiment import load_experiment_text
    from ..model import DeviceProfile

    notes: list[str] = []
    df, sessions = load_sessions(paths, include_simulated=include_simulated, notes=notes)
    names = sorted({str(s.meta["experiment"]) for s in sessions})
    if len(names) > 1:
        raise InputError("sessions of different experiments are mixed ("
                         + ", ".join(names) + "); fit one experiment's sessions at a time")
    shas = {s.meta["experiment_file"].get("sha256") for s in sessions
            if isinstance(s.meta.get("experiment_file"), dict)}
    if len(shas) > 1:
        raise InputError(f"the sessions of {names[0]} ran different versions of its experiment "
                         "file (their SHA-256 differ); fit the sessions of one version at a time")
    first = sessions[0]
    ef = first.meta.get("experiment_file")
    if not isinstance(ef, dict) or not isinstance(ef.get("text"), str):
        raise InputError("the session record does not hold the experiment's text",
                         path=str(first.record))
    lx = load_experiment_text(ef["text"], ef.get("path") or "experiment.yaml")
    if lx.experiment.adaptive is not None:
        raise InputError(f"{names[0]} chooses its levels adaptively; fitting such sessions is "
                         "not supported yet")
    profiles = {repr(s.meta.get("device_profile")) for s in sessions}
    if len(profiles) > 1:
        raise InputError("the sessions ran on different device profiles; fit the sessions of "
                         "one device at a time")
    try:
        profile = DeviceProfile.model_validate(first.meta["device_profile"])
    except Exception:       # noqa: BLE001 - a record edited by hand
        raise InputError("the session record's device_profile is not a device profile",
                         path=str(first.record)) from None
    model = ObserverModel.for_experiment(lx, profile, params_file=params_file)
    conditions = {tuple(c.levels[f] for f in lx.experiment.factors): c
                  for c in enumerate_conditions(lx)}
    factors = list(lx.experiment.factors)
    trials: dict[str, list[Trial]] = {}
    missing = 0
    for s in sessions:
        ev = events_path(s)
        if ev is None or not ev.is_file():
            raise InputError("this session has no device events (its _events.tsv is missing), "
                             "so what was played in each trial is not known; a fit needs "
                             "them", path=str(s.dir))
        played = _played_by_trial(ev, s.trials)
        t = s.trials
        t = t[(t["practice"].fillna(0) == 0) & (t["status"].astype(str) == "ok")
              & t["answer"].notna()]
        if len(t) and not played and t["n_pulses"].fillna(0).sum() > 0:
            raise InputError("this session's device events are empty: what was played in "
                             "each trial is not known; a fit needs them", path=str(ev))
        who = str(s.meta["participant"])
        for row in t.itertuples(index=False):
            r = row._asdict()
            cond = conditions.get(tuple(str(r[f]) for f in factors))
            report = played.get(int(r["trial"]))
            if report is None and (r.get("n_pulses") or 0) > 0:
                missing += 1
                continue
            if cond is None:
                missing += 1
                continue
            if report is None:
                report = PlayReport(device=profile.name, started_at_ms=0.0, duration_ms=0.0,
                                    pulses=[])
            trials.setdefault(who, []).append(Trial(str(r["question"]), cond, report,
                                                    str(r["answer"])))
    if missing:
        notes.append(f"{missing} answered trial(s) without device events (or of a condition "
                     "the experiment does not declare) left out")
    if not trials:
        raise InputError("no answered trials with device events in these sessions")
    return FitData(model, trials, len(sessions), notes, next(iter(shas), None) or "",
                   (ef["text"], ef.get("path") or "experiment.yaml", profile.model_dump_json(),
                    None if params_file is None else str(params_file)))


def simulated_trials(setup, rows: list[dict]) -> list[Trial]:
    """The trials of a simulated participant (the rows of
    :func:`vtexp.simulate.simulate_participant`: the factors' levels, the question, the
    answer), each with what its condition played in the simulation's ``setup``
    (:class:`vtexp.simulate.Setup`): for recovery, where known parameters are fitted
    back."""
    by_levels = {tuple(c.levels[f] for f in setup.factors): c for c in setup.conditions}
    out = []
    for r in rows:
        c = by_levels[tuple(r[f] for f in setup.factors)]
        out.append(Trial(r["question"], c, setup.played[c.index], r["answer"]))
    return out


def _played_by_trial(path: Path, beh: pd.DataFrame) -> dict[int, PlayReport]:
    """The first play of each trial, from the device events, its onsets from the play's
    start (the trial log's stimulus_onset_ms)."""
    try:
        ev = pd.read_csv(path, sep="\t", na_values=["n/a"], keep_default_na=False)
    except (pd.errors.ParserError, UnicodeDecodeError, OSError) as e:
        raise InputError(f"cannot read the device events: {e}", path=str(path)) from None
    need = {"trial", "play", "row", "col", "onset_ms", "duration_ms"}
    if not need <= set(ev.columns):
        raise InputError("not a device events log as vtexp writes it (it lacks "
                         + ", ".join(sorted(need - set(ev.columns))) + ")", path=str(path))
    ev = ev[ev["play"] == 0]
    start = beh.drop_duplicates("trial").set_index("trial")["stimulus_onset_ms"]
    out: dict[int, PlayReport] = {}
    for trial, g in ev.groupby("trial", sort=False):
        t0 = start.get(int(trial))
        if t0 is None or t0 != t0:
            t0 = float(g["onset_ms"].min())
        pulses = []
        for p in g.itertuples(index=False):
            train = None
            amp = getattr(p, "amplitude_v", float("nan"))
            if amp == amp and amp is not None:
                train = PulseTrain(amplitude_v=float(amp), frequency_hz=float(p.frequency_hz),
                                   pulse_width_ms=float(p.pulse_width_ms))
            level = getattr(p, "level", float("nan"))
            onset = round(float(p.onset_ms) - float(t0), 3)
            pulses.append(PlayedPulse.model_construct(
                row=int(p.row), col=int(p.col),
                scheduled_onset_ms=float(getattr(p, "scheduled_onset_ms", onset)),
                onset_ms=onset, duration_ms=round(float(p.duration_ms), 3),
                level=None if level != level else int(level), train=train))
        end = max(q.onset_ms + q.duration_ms for q in pulses)
        out[int(trial)] = PlayReport.model_construct(device="", started_at_ms=float(t0),
                                                     duration_ms=end, pulses=pulses,
                                                     completed=True)
    return out


# --------------------------------------------------------------------------- the population

@dataclass
class Population:
    """The centre and spread of each fitted parameter across participants.

    ``values``: the parameter's value in the observer file (the median of the
    log-normal for efficiency and decision noise, the logistic of the mean logit for
    the lapse); ``spreads``: the ``population:`` fields. ``used``: the participants
    whose data identify the parameter.
    """

    values: dict[str, float]
    spreads: dict[str, float]
    used: dict[str, int]
    notes: list[str]
    #: the centre's 95 % interval, (low, high), of each parameter whose centre the
    #: participants identify (:func:`_centre_interval`)
    intervals: dict[str, tuple[float, float]] = field(default_factory=dict)
    #: parameters whose population centre these data do not identify
    not_identified: list[str] = field(default_factory=list)
    #: the same intervals cut at the large-sample chi-square (3.84 / 2) for every
    #: parameter, kept to show what the small-sample cut (:func:`centre_cut`) changes
    chi2_intervals: dict[str, tuple[float, float]] = field(default_factory=dict)


def _base_tau(name: str, base) -> float | None:
    """The observer file's spread of ``name`` on the scale the population varies on."""
    if base is None:
        return None
    pop = base.population
    cv = {"efficiency": pop.efficiency_cv, "decision_noise": pop.decision_noise_cv,
          "integration_ms": pop.integration_cv,
          "two_point_threshold_mm": pop.two_point_threshold_cv}.get(name)
    if cv is not None:
        return math.sqrt(math.log1p(cv * cv))
    return {"lapse": pop.lapse_logit_sd, "rating_bias": pop.rating_bias_sd}.get(name)


def population(fits: list[ParticipantFit], names: list[str], base=None) -> Population:
    """The population of :func:`~vtexp.observer.params.draw_participant` that makes the
    participants' answers most likely.

    Each participant's profile likelihood of the parameter (:func:`_profile`) stands
    for their likelihood, and the parameter varies between participants as
    ``draw_participant`` draws it: normal on the log scale (efficiency, decision
    noise), on the logit scale (lapse), or about 0 (rating bias). The centre ``mu`` and
    spread ``tau`` maximise the product over participants of the integral of their
    profile likelihood against that distribution (the marginal likelihood of a
    normal random-effects model): a participant whose profile is flat adds nothing, one
    whose estimate sits at a bound adds what their profile says, not a number. A
    parameter that is one value for everyone in the model (abstain criterion, rating
    step, turns SD) takes the value that maximises the sum of the profiles. With few
    participants ``tau`` is known poorly (and is biased low, as every maximum-likelihood
    variance is). When the participants cannot tell a spread from none, or only one
    identifies the parameter, the spread stays the observer file's (``base``, an
    :class:`~vtexp.observer.params.ObserverParams`) and the centre is fitted with it.
    """
    values, spreads, used, notes = {}, {}, {}, []
    intervals: dict[str, tuple[float, float]] = {}
    chi2_intervals: dict[str, tuple[float, float]] = {}
    unknown: list[str] = []
    for n in names:
        spec = spec_of(n)
        ps = [f.params[n] for f in fits if f.params[n].identified and f.params[n].grid]
        used[n] = len(ps)
        if not ps:
            notes.append(f"{n}: identified for no participant; the observer file keeps its "
                         "value")
            unknown.append(n)
            continue
        lo_u, hi_u = spec.bounds_u
        u = np.linspace(lo_u, hi_u, 401)
        x = np.array([spec.from_u(v) for v in u])
        L = np.array([np.interp(u, [spec.to_u(g) for g in p.grid], p.profile) for p in ps])
        if spec.spread is None:
            total = L.sum(axis=0)
            values[n] = float(x[int(np.argmax(total))])
            lo_c, hi_c = _cut_interval(u, -total, float(-total.max()))
            if lo_c <= u[0] and hi_c >= u[-1]:
                unknown.append(n)
            else:
                intervals[n] = chi2_intervals[n] = (spec.from_u(lo_c), spec.from_u(hi_c))
            continue
        if n == "lapse":        # the scale the population varies on
            t = np.log(np.clip(x, 1e-4, None) / (1 - np.clip(x, None, 1 - 1e-4)))
            nodes = np.linspace(float(t.min()), float(t.max()), MARGINAL_POINTS)
            at = 1 / (1 + np.exp(-nodes))
        else:
            t = u
            nodes = np.linspace(lo_u, hi_u, MARGINAL_POINTS)
            at = nodes
        # Each participant's likelihood at the nodes (their profile, linear between its
        # own points on the scale it was fitted on)
        lik = np.exp(np.array([np.interp(at, [spec.to_u(g) for g in p.grid], p.profile)
                               for p in ps]))

        def neg_marginal(theta, centred=(n == "rating_bias"), nodes=nodes, lik=lik):
            # Each likelihood, linear between the nodes (and its end value beyond them),
            # integrated exactly against the population's normal: right for a spread
            # however narrow or wide against the profiles' own width.
            mu = 0.0 if centred else theta[0]
            tau = math.exp(theta[-1])
            marginal = lik @ _normal_weights(nodes, mu, tau)
            return -float(np.log(np.maximum(marginal, 1e-300)).sum())
        centred = n == "rating_bias"
        tau_lo = math.log(TAU_MIN)
        tau_hi = math.log(max(float(t.max() - t.min()), 0.1))
        # A lapse rate's centre stays above 0.1 %: below it the logit scale has endless room
        # for profiles that are all highest at 0 (Wichmann & Hill 2001: 0-6 %).
        t_min = math.log(0.001 / 0.999) if n == "lapse" else float(t.min())

        def fit_mu_tau(fixed_tau=None):
            if centred and fixed_tau is not None:
                return neg_marginal([math.log(fixed_tau)]), 0.0, fixed_tau
            # Start from the best of a scan: with a small spread the marginal likelihood
            # is as narrow and many-peaked in the centre as the profiles it integrates.
            mus = np.linspace(t_min, float(t.max()), 41)
            taus = np.linspace(tau_lo, tau_hi, 9)
            if fixed_tau is not None:
                def f(th):
                    return neg_marginal([th[0], math.log(fixed_tau)])
                starts = [[min(mus, key=lambda m: f([m]))]]
                bnds = [(t_min, float(t.max()))]
            elif centred:
                f, bnds = neg_marginal, [(tau_lo, tau_hi)]
                starts = [[min(taus, key=lambda a: f([a]))]]
            else:
                f, bnds = neg_marginal, [(t_min, float(t.max())), (tau_lo, tau_hi)]
                starts = [list(min(((m, a) for m in mus for a in taus),
                                   key=lambda th: f(list(th))))]
            r = min((minimize(f, s0, method="L-BFGS-B", bounds=bnds) for s0 in starts),
                    key=lambda r: r.fun)
            mu = 0.0 if centred else float(r.x[0])
            tau = fixed_tau if fixed_tau is not None else math.exp(float(r.x[-1]))
            return float(r.fun), mu, tau

        best, mu, tau = fit_mu_tau()
        # The spread is identified only if no spread at all is unlikely (likelihood ratio);
        # otherwise the centre is the one that goes with the observer file's spread.
        keep = None
        if len(ps) < 2:
            keep = f"{n}: one participant identifies it; its spread is the observer file's"
        elif fit_mu_tau(TAU_MIN)[0] - best < HALF_CHI2:
            keep = (f"{n}: these participants do not tell a spread from none; its spread is "
                    "the observer file's")
        if keep is not None:
            notes.append(keep)
            base_tau = _base_tau(n, base)
            if base_tau is not None and base_tau > 0:
                _, mu, tau = fit_mu_tau(base_tau)
        if n == "lapse":
            values[n] = 1 / (1 + math.exp(-mu))
        elif not centred:
            values[n] = spec.from_u(mu)
        if not centred:
            # The spread estimated from these participants: the small-sample cut; the
            # observer file's spread kept: it is known, and the chi-square is exact.
            half = HALF_CHI2 if keep is not None else centre_cut(len(ps))
            (lo_t, hi_t), chi2 = _centre_interval(
                neg_marginal, mu, tau, t_min, float(t.max()), tau_lo, tau_hi,
                fixed_tau=None if keep is None else tau, halves=(half, HALF_CHI2))
            back = (lambda tt: 1 / (1 + math.exp(-tt))) if n == "lapse" else spec.from_u
            if lo_t <= t_min and hi_t >= float(t.max()):
                unknown.append(n)
            else:
                intervals[n] = (float(back(lo_t)), float(back(hi_t)))
            if not (chi2[0] <= t_min and chi2[1] >= float(t.max())):
                chi2_intervals[n] = (float(back(chi2[0])), float(back(chi2[1])))
        if keep is not None:
            continue
        spread = math.sqrt(math.expm1(tau * tau)) if spec.log else tau
        if spread > _SPREAD_MAX.get(spec.spread, math.inf):
            notes.append(f"{n}: the spread across participants ({spread:.3g}) is beyond what "
                         f"an observer file holds; written as {_SPREAD_MAX[spec.spread]:g}")
            spread = _SPREAD_MAX[spec.spread]
        spreads[spec.spread] = spread
    return Population(values, spreads, used, notes, intervals, unknown, chi2_intervals)


#: Nodes of the integral of a participant's likelihood against the population's normal.
MARGINAL_POINTS = 801


def _normal_weights(nodes: np.ndarray, mu: float, tau: float) -> np.ndarray:
    """Weights ``w`` such that ``f @ w`` is the integral of ``f`` (linear between the
    evenly spaced ``nodes``, constant beyond them) against the normal density N(mu, tau^2),
    exactly: on the segment from a to b, with z = (u - mu) / tau,
    int (f_a + (f_b - f_a)(u - a)/h) phi_tau(u - mu) du = f_a (dPhi - c) + f_b c, where
    c = ((mu - a) dPhi + tau (phi(z_a) - phi(z_b))) / h."""
    from scipy.special import ndtr
    z = (nodes - mu) / tau
    cdf = ndtr(z)
    pdf = np.exp(-0.5 * z * z) / math.sqrt(2 * math.pi)
    h = float(nodes[1] - nodes[0])
    d = np.diff(cdf)
    c = ((mu - nodes[:-1]) * d + tau * (pdf[:-1] - pdf[1:])) / h
    w = np.zeros(len(nodes))
    w[:-1] += d - c
    w[1:] += c
    w[0] += cdf[0]
    w[-1] += 1.0 - cdf[-1]
    return w


def _cut_interval(x: np.ndarray, nll: np.ndarray, best: float,
                  half: float = HALF_CHI2) -> tuple[float, float]:
    """Where the negative log-likelihood ``nll`` (on the grid ``x``) rises by ``half``
    above ``best`` on each side of its minimum, interpolated linearly between the grid's
    points; the grid's end when it never rises so far."""
    best = min(best, float(nll.min()))
    cut = best + half
    k = int(np.argmin(nll))

    def edge(direction: int) -> float:
        j = k
        while 0 <= j + direction < len(x):
            if nll[j + direction] > cut:
                x0, x1, y0, y1 = x[j], x[j + direction], nll[j], nll[j + direction]
                return float(x0 + (cut - y0) * (x1 - x0) / (y1 - y0))
            j += direction
        return float(x[-1] if direction > 0 else x[0])

    return edge(-1), edge(1)


#: Points of the profile of a population's centre over its range.
CENTRE_POINTS = 81


def centre_cut(n: int, level: float = 0.95) -> float:
    """The drop of the log-likelihood that cuts a population centre's ``level`` interval
    when its spread is estimated from ``n`` participants.

    For a normal sample with unknown variance the profile log-likelihood of the mean is
    ``-n/2 log(s2 + (xbar - mu)^2)`` (``s2`` the maximum-likelihood variance), so the
    likelihood-ratio statistic is exactly ``W = n log(1 + T^2 / (n - 1))``, T the
    one-sample t, and the interval with exact coverage is the one where ``W / 2`` stays
    under ``n / 2 log(1 + t^2_{(1+level)/2, n-1} / (n - 1))``: 2.95 for 4 participants, 3.49
    for 3, 2.25 for 10, where the chi-square's 1.92 holds only for many. Participants
    whose own profiles are wide make the spread partly known, where this cut is
    conservative.
    """
    from scipy.stats import chi2, t
    if n < 2:
        return float(chi2.ppf(level, 1) / 2)
    q = float(t.ppf((1 + level) / 2, n - 1))
    return n / 2 * math.log1p(q * q / (n - 1))


def _centre_interval(neg_marginal, mu: float, tau: float, t_lo: float, t_hi: float,
                     tau_lo: float, tau_hi: float, fixed_tau: float | None = None,
                     halves: tuple[float, ...] = (HALF_CHI2,)
                     ) -> list[tuple[float, float]]:
    """The 95 % interval of a population's centre ``mu``: its profile likelihood.

    The population's marginal likelihood (the one :func:`population` maximises) is
    profiled over the centre: at each of CENTRE_POINTS values of ``mu`` over its range
    (the scale the parameter varies on) the spread is maximised again (or held at
    ``fixed_tau`` when the fit kept the observer file's spread), and the interval is
    where that profile is within each of ``halves`` of its maximum (one interval per
    cut: HALF_CHI2, 3.84 / 2, is the likelihood ratio's chi-square with one degree of
    freedom; :func:`centre_cut` the small-sample cut). The spread's own uncertainty is
    thereby taken into account (profiled out), which a Wald interval from the
    curvature at the maximum would not; with four participants it matters.
    """
    from scipy.optimize import minimize_scalar
    grid = np.union1d(np.linspace(t_lo, t_hi, CENTRE_POINTS), [mu])

    def prof(m: float) -> float:
        if fixed_tau is not None:
            return float(neg_marginal([m, math.log(fixed_tau)]))
        r = minimize_scalar(lambda a: neg_marginal([m, a]), bounds=(tau_lo, tau_hi),
                            method="bounded", options={"xatol": 1e-3})
        return float(min(r.fun, neg_marginal([m, math.log(tau)])))

    values = np.array([prof(float(m)) for m in grid])
    best = float(neg_marginal([mu, math.log(tau)]))
    return [_cut_interval(grid, values, best, h) for h in halves]



def observer_yaml(base_file: Path, pop: Population, fits: list[ParticipantFit], names: list[str],
                  *, source: str, experiment: str, site: str | None = None) -> str:
    """The observer file: ``base_file`` with the fitted centres and spreads in place, the
    fit's provenance and every participant's estimate in its header."""
    import yaml

    from ..yamlio import load_yaml
    data = dict(load_yaml(base_file).data or {})
    for n, v in pop.values.items():
        if n == "rating_bias":
            continue                       # the population is centred on 0 (params.py)
        if n == "two_point_threshold_mm":  # the body site's entry
            data[n] = {**dict(data.get(n) or {}), site: round(float(v), 6)}
            continue
        data[n] = round(float(v), 6)
    spreads = dict(data.get("population") or {})
    for k, v in pop.spreads.items():
        spreads[k] = round(float(v), 6)
    data["population"] = spreads
    data["fitted"] = fitted_record(pop, names, len(fits), site=site)
    head = [f"# Fitted by vtexp observer fit to {len(fits)} participant(s) of {experiment}",
            f"# ({source}), from {base_file.name}: fitted {', '.join(names)}; every other",
            "# value is the base file's. Estimates and 95 % profile-likelihood intervals:"]
    for f in fits:
        head.append(f"#   {f.participant}: " + "; ".join(
            f"{n} {f.params[n].text()}" for n in names) + f" ({f.answers} answers)")
    for n in names:
        head.append(f"# {n}: {pop.used.get(n, 0)} of {len(fits)} participants identify it")
    head += [f"# {t}" for t in pop.notes]
    body = yaml.safe_dump(data, sort_keys=False, allow_unicode=True)
    return "\n".join(head) + "\n" + body


def fitted_record(pop: Population, names: list[str], participants: int, *,
                  site: str | None = None) -> dict:
    """The observer file's ``fitted:`` section: what was fitted, for ``vtexp simulate``.

    For each parameter whose population centre the data identify, the centre (the
    value written in the file) and its 95 % interval (profile likelihood of the
    population's marginal likelihood, :func:`_centre_interval`); the parameters whose
    centre they do not identify (the file keeps its value for them) under
    ``not_identified``. ``site``: the body site a fitted two-point threshold is of.
    """
    def r(x: float) -> float:
        return round(float(x), 6)
    params = {n: {"centre": r(pop.values[n]), "low": r(pop.intervals[n][0]),
                  "high": r(pop.intervals[n][1])}
              for n in names if n in pop.intervals and n in pop.values}
    out: dict = {"by": "vtexp observer fit",
                 "interval": "95 % profile likelihood of the population centre "
                             "(likelihood ratio; cut at n/2 log(1 + t^2/(n-1)) for the n "
                             "participants who identify it, or at 3.84 / 2 where the "
                             "spread is the observer file's)",
                 "participants": participants, "params": params,
                 "not_identified": [n for n in names if n in pop.not_identified]}
    if site is not None and "two_point_threshold_mm" in params:
        out["site"] = site
    return out


# --------------------------------------------------------------------------- the whole fit

@dataclass
class FitResult:
    experiment: str
    names: list[str]
    fits: list[ParticipantFit]
    population: Population
    seconds: float
    notes: list[str]


def fit_all(data: FitData, names: list[str], *, workers: int = 1) -> FitResult:
    """Every participant of ``data`` fitted (in ``workers`` processes), and the population."""
    t0 = time.perf_counter()
    model = data.model
    check_names(names, model)
    fixed = decision_values(model)
    who = model.participant(0, "fit", typical=True)
    people = sorted(data.trials)
    fits = []
    jobs = [(who, data.trials[p], names, fixed, p) for p in people]
    if workers > 1 and len(people) > 1 and data.source:
        from concurrent.futures import ProcessPoolExecutor
        with ProcessPoolExecutor(min(workers, len(people)), initializer=_init_worker,
                                 initargs=data.source) as pool:
            fits = list(pool.map(_fit_one, [(None, *j) for j in jobs]))
    else:
        for j in jobs:
            fits.append(_fit_one((model, *j)))
    notes = list(data.notes)
    overridden = [n for n in names if n in model.spec.params]
    if overridden:
        notes.append(f"the experiment's observer.params sets {', '.join(overridden)}, which "
                     "overrides an observer file: vtexp simulate of this experiment keeps the "
                     "experiment's value")
    return FitResult(model.lx.experiment.name, names, fits,
                     population(fits, names, model.params),
                     time.perf_counter() - t0, notes)


_WORKER_MODEL: ObserverModel | None = None


def _init_worker(text: str, path: str, profile_json: str, params_file: str | None) -> None:
    """A worker process's model, rebuilt from the experiment's text (its caches are its own)."""
    global _WORKER_MODEL
    from threadpoolctl import threadpool_limits

    from ..experiment import load_experiment_text
    from ..model import DeviceProfile
    threadpool_limits(limits=1, user_api="blas")        # a process per core already
    lx = load_experiment_text(text, path)
    _WORKER_MODEL = ObserverModel.for_experiment(
        lx, DeviceProfile.model_validate_json(profile_json), params_file=params_file)


def percept_grid(name: str) -> list[float]:
    """The values a percept parameter is fitted at (log-spaced over its range)."""
    spec = PERCEPT_PARAMS[name]
    return [float(v) for v in np.geomspace(spec.low, spec.high, PERCEPT_POINTS)]


def with_percept(who, name: str, value: float):
    """``who`` with a percept parameter set (and the key its percept is cached under)."""
    import dataclasses
    who = dataclasses.replace(who, **{name: value})
    return dataclasses.replace(who, key=(round(who.two_point_threshold_mm, 9),
                                         who.intensity_levels, round(who.integration_ms, 9)))


def _fit_one(args) -> ParticipantFit:
    """One participant's fit, with BLAS on one thread: its matrices are tiny, and on a
    busy machine L-BFGS-B's few-variable steps took milliseconds each, waiting for
    BLAS threads (measured: 66 of 89 s of a fit of four parameters)."""
    from threadpoolctl import threadpool_limits
    with threadpool_limits(limits=1, user_api="blas"):
        return _fit_one_now(args)


def _fit_one_now(args) -> ParticipantFit:
    model, who, trials, names, fixed, participant = args
    model = model or _WORKER_MODEL
    percept = [n for n in names if n in PERCEPT_PARAMS]
    if percept:
        name = percept[0]
        grid = percept_grid(name)
        liks = [Likelihood(model, with_percept(who, name, v), trials) for v in grid]
        fit = fit_percept_participant(liks, name, grid, [n for n in names if n != name],
                                      fixed, participant=participant)
        lik = liks[0]
    else:
        lik = Likelihood(model, who, trials)
        fit = fit_participant(lik, names, fixed, participant=participant)
    if lik.unknown:
        fit.notes.append(f"{lik.unknown} answer(s) that are not an option of their question "
                         "left out")
    return fit
