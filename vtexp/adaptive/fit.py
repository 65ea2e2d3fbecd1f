"""Maximum-likelihood fits of a psychometric function, with parametric-bootstrap intervals.

The answers (1 yes / 0 no, or correct / wrong) at levels :math:`x_i` are binomial with
probability :math:`\\psi(x_i; \\alpha, \\beta, \\gamma, \\lambda)` (:mod:`.psychometric`);
the fit maximises

.. math::

    \\ell(\\alpha, \\beta, \\lambda) = \\sum_i k_i \\log \\psi(x_i) + (n_i - k_i) \\log(1 - \\psi(x_i))

over threshold and slope, and over the lapse rate within ``[0, max_lapse]`` when it is
free (Wichmann & Hill 2001a, eq. 2-3; the guess rate is the task's). A coarse grid
gives the start, L-BFGS-B the optimum. The interval is the parametric bootstrap's
(Wichmann & Hill 2001b): answers are drawn anew from the fitted function at the same
levels, refitted, and the 2.5 and 97.5 percentiles of the refitted thresholds taken.
The draws come from numpy's PCG64 keyed by SHA-256 of a name (the participant), so a
report is the same on every run.

References
----------
Wichmann, F. A., & Hill, N. J. (2001a). The psychometric function: I. Fitting, sampling,
and goodness of fit. Perception & Psychophysics, 63(8), 1293-1313.
Wichmann, F. A., & Hill, N. J. (2001b). The psychometric function: II. Bootstrap-based
confidence intervals and sampling. Perception & Psychophysics, 63(8), 1314-1329.
"""

from __future__ import annotations

import hashlib
import warnings
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from .psychometric import core_and_slopes, psi


@dataclass
class Fit:
    threshold: float
    slope: float
    lapse: float
    guess: float
    function: str
    loglik: float
    n_trials: int
    threshold_ci: tuple[float, float] = (float("nan"), float("nan"))
    slope_ci: tuple[float, float] = (float("nan"), float("nan"))
    n_bootstrap: int = 0
    converged: bool = True


def keyed_rng(name: str) -> np.random.Generator:
    """numpy's PCG64 seeded by SHA-256 of ``name``: the same draws on every machine."""
    seed = int.from_bytes(hashlib.sha256(f"vtexp-fit\x00{name}".encode()).digest()[:16], "big")
    return np.random.Generator(np.random.PCG64(seed))


def _aggregate(x, yes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    x = np.asarray(x, dtype=float)
    yes = np.asarray(yes, dtype=float)
    levels, inv = np.unique(x, return_inverse=True)
    k = np.bincount(inv, weights=yes, minlength=levels.size)
    n = np.bincount(inv, minlength=levels.size).astype(float)
    return levels, k, n


def _nll(theta, levels, k, n, guess, function, lapse_fixed):
    """The negative log-likelihood (eq. 2-3 of Wichmann & Hill 2001a) and its gradient in
    ``(a, log b[, lapse])``: the chain rule through ``psi = g + (1 - g - lapse) F``."""
    a, b = theta[0], np.exp(theta[1])
    lam = theta[2] if lapse_fixed is None else lapse_fixed
    f, df_da, df_db = core_and_slopes(levels, a, b, function)
    scale = 1.0 - guess - lam
    raw = guess + scale * f
    p = np.clip(raw, 1e-12, 1 - 1e-12)
    inside = (raw == p)                       # where the clip holds p, it has no slope
    dl_dp = np.where(inside, k / p - (n - k) / (1.0 - p), 0.0)
    grad = [-np.sum(dl_dp * scale * df_da), -np.sum(dl_dp * scale * df_db) * b]
    if lapse_fixed is None:
        grad.append(np.sum(dl_dp * f))
    value = -float(np.sum(k * np.log(p) + (n - k) * np.log1p(-p)))
    return value, np.nan_to_num(np.asarray(grad, float))


def _fit_counts(levels, k, n, *, function, guess, lapse, max_lapse, start=None):
    span = float(levels.max() - levels.min()) or max(abs(float(levels.max())), 1.0)
    lo = levels.min() - span if function != "weibull" else max(levels.min() * 0.1, 1e-6)
    hi = levels.max() + span
    lapse_fixed = None if lapse == "free" else float(lapse)
    if start is None:
        # Slopes on a log grid scaled to the levels' span: 1/span is shallow, 50/span steep
        # (for the Weibull the slope is unitless: 0.5 to 20).
        slopes = (np.geomspace(0.5, 20, 12) if function == "weibull"
                  else np.geomspace(0.5, 50, 12) / span)
        if function == "gumbel":
            slopes = np.geomspace(0.5, 50, 12) * 20 / span
        alphas = np.linspace(lo if function != "weibull" else levels.min(), levels.max(), 25)
        A, B = np.meshgrid(alphas, slopes, indexing="ij")
        lam0 = 0.02 if lapse_fixed is None else lapse_fixed
        p = np.clip(psi(levels[:, None, None], A, B, guess, lam0, function), 1e-12, 1 - 1e-12)
        ll = np.sum(k[:, None, None] * np.log(p) + (n - k)[:, None, None] * np.log1p(-p), axis=0)
        i, j = np.unravel_index(int(np.argmax(ll)), ll.shape)
        start = [A[i, j], np.log(B[i, j])] + ([lam0] if lapse_fixed is None else [])
    bounds = [(lo, hi), (np.log(1e-4 / span if function != "weibull" else 0.05), np.log(1e4))]
    if lapse_fixed is None:
        bounds.append((0.0, max_lapse))
    start = [min(max(s, b[0]), b[1]) for s, b in zip(start, bounds, strict=True)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        res = minimize(_nll, np.asarray(start, float),
                       args=(levels, k, n, guess, function, lapse_fixed),
                       method="L-BFGS-B", jac=True, bounds=bounds)
    a, b = float(res.x[0]), float(np.exp(res.x[1]))
    lam = float(res.x[2]) if lapse_fixed is None else lapse_fixed
    return a, b, lam, -float(res.fun), bool(res.success)


def fit_psychometric(x, yes, *, function: str = "weibull", guess: float = 0.0,
                     lapse: float | str = "free", max_lapse: float = 0.1,
                     bootstrap: int = 200, name: str = "", level: float = 0.95) -> Fit:
    """Fit ``psi`` to the answers ``yes`` (booleans) at levels ``x`` by maximum likelihood.

    ``lapse`` is a fixed rate or ``"free"`` (fitted within ``[0, max_lapse]``). With
    ``bootstrap = B > 0`` the threshold and slope get percentile intervals from ``B``
    parametric bootstrap samples drawn with :func:`keyed_rng` ``(name)``.
    """
    levels, k, n = _aggregate(x, yes)
    if levels.size == 0:
        raise ValueError("no answers to fit")
    a, b, lam, ll, ok = _fit_counts(levels, k, n, function=function, guess=guess,
                                    lapse=lapse, max_lapse=max_lapse)
    fit = Fit(a, b, lam, guess, function, ll, int(n.sum()), converged=ok)
    if bootstrap > 0:
        rng = keyed_rng(name)
        p = psi(levels, a, b, guess, lam, function)
        draws = rng.binomial(n.astype(np.int64)[None, :], p[None, :], size=(bootstrap, levels.size))
        start = [a, np.log(b)] + ([lam] if lapse == "free" else [])
        boot = np.array([_fit_counts(levels, d.astype(float), n, function=function, guess=guess,
                                     lapse=lapse, max_lapse=max_lapse, start=start)[:2]
                         for d in draws])
        q = [(1 - level) / 2 * 100, (1 + level) / 2 * 100]
        fit.threshold_ci = tuple(float(v) for v in np.percentile(boot[:, 0], q))
        fit.slope_ci = tuple(float(v) for v in np.percentile(boot[:, 1], q))
        fit.n_bootstrap = bootstrap
    return fit
