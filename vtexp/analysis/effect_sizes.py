"""Confidence intervals of effect sizes, by inverting noncentral distributions.

Partial η² and Cohen's d_z are estimates with sampling error as large as a p
value's; a report that prints them prints their intervals too.

- Partial η² (:func:`eta2p_ci`): the noncentrality λ of the F distribution on
  (df1, df2) degrees of freedom is found for which the observed F is the
  upper and the lower α/2 quantile (Steiger 2004, the "confidence interval
  transformation principle"); each limit is turned into η²p with the
  function that turns F into η²p, λ → λ / (λ + df2), so the point estimate
  F·df1 / (F·df1 + df2) is the value at λ = F·df1. A limit whose λ would be
  negative is 0. These are the limits of ``effectsize::F_to_eta2(F, df1, df2,
  ci = level, alternative = "two.sided")`` and of MBESS's ``conf.limits.ncf``
  mapped the same way.
- Cohen's d_z (:func:`dz_ci`): the paired t statistic t = d_z √n has a
  noncentral t distribution on n − 1 df with noncentrality δ = d_z(true) √n;
  the δ for which the observed t is the upper and lower α/2 quantile, divided
  by √n, are the limits (Cumming & Finch 2001; ``MBESS::ci.sm`` and
  ``effectsize::cohens_d(..., paired = TRUE)``).

The level is the caller's: the report gives η²p a 90 % interval, which
excludes 0 exactly when the F test's p < .05 (the F test is one-sided;
Steiger 2004), and d_z a 95 % interval like the two-sided t test's.
``tests/r_reference/effect_sizes.R`` computes the reference limits with R's
``pf``/``pt`` and ``uniroot`` (and effectsize's own); the test suite compares
them to 1e-6.

References
----------
Steiger, J. H. (2004). Beyond the F test: effect size confidence intervals and
tests of close fit in the analysis of variance and contrast analysis.
Psychological Methods, 9(2), 164–182.
Cumming, G., & Finch, S. (2001). A primer on the understanding, use, and
calculation of confidence intervals that are based on central and noncentral
distributions. Educational and Psychological Measurement, 61(4), 532–574.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import optimize, stats

__all__ = ["eta2p_ci", "dz_ci", "noncentrality_limits_f", "noncentrality_limits_t",
           "ETA2P_CI_LEVEL", "DZ_CI_LEVEL"]

#: the level of the η²p intervals in tables and sentences (see the module docstring)
ETA2P_CI_LEVEL = 0.90
#: the level of the d_z intervals in tables
DZ_CI_LEVEL = 0.95

_XTOL = 1e-12


def _decreasing_root(fn, target: float, start: float) -> float:
    """λ ≥ 0 where the decreasing function ``fn`` equals ``target`` (fn(0) > target)."""
    hi = max(1.0, start)
    while fn(hi) > target:
        hi *= 2.0
        if hi > 1e9:                          # pragma: no cover - F beyond any data
            return math.nan
    return optimize.brentq(lambda x: fn(x) - target, 0.0, hi, xtol=_XTOL,
                           rtol=4 * np.finfo(float).eps, maxiter=500)


def noncentrality_limits_f(F: float, df1: float, df2: float, level: float = ETA2P_CI_LEVEL
                           ) -> tuple[float, float]:
    """Limits of the noncentrality λ of F(df1, df2, λ) given the observed ``F``.

    The lower limit solves P(F' ≤ F | λ) = 1 − α/2 and the upper P(F' ≤ F | λ)
    = α/2, α = 1 − ``level``; a limit is 0 when even λ = 0 puts F below that
    quantile. NaN for a non-finite F or df.
    """
    if not all(np.isfinite(v) for v in (F, df1, df2)) or df1 <= 0 or df2 <= 0 or F < 0:
        return math.nan, math.nan
    alpha = 1.0 - level

    def cdf(lam: float) -> float:
        if lam == 0.0:
            return float(stats.f.cdf(F, df1, df2))
        return float(stats.ncf.cdf(F, df1, df2, lam))

    p0 = cdf(0.0)
    start = F * df1
    lower = _decreasing_root(cdf, 1 - alpha / 2, start) if p0 > 1 - alpha / 2 else 0.0
    upper = _decreasing_root(cdf, alpha / 2, start) if p0 > alpha / 2 else 0.0
    return lower, upper


def eta2p_ci(F: float, df1: float, df2: float, level: float = ETA2P_CI_LEVEL
             ) -> tuple[float, float]:
    """Two-sided ``level`` confidence interval of partial η² from an F test.

    Parameters
    ----------
    F, df1, df2 : the F statistic and its degrees of freedom (corrected ones, e.g.
        ε·df1 and ε·df2 after Greenhouse–Geisser, give the interval that goes with
        the corrected test).
    level : confidence level, 0.90 by default (module docstring).

    Returns
    -------
    (low, high); NaN, NaN when F is undefined (0/0) or infinite (no error
    variance), where η²p has no sampling distribution to invert.

    Examples
    --------
    >>> low, high = eta2p_ci(28.78, 1, 14)
    >>> round(low, 3), round(high, 3)
    (0.386, 0.806)
    """
    lam_lo, lam_hi = noncentrality_limits_f(float(F), float(df1), float(df2), level)
    if lam_lo != lam_lo:
        return math.nan, math.nan
    return lam_lo / (lam_lo + df2), lam_hi / (lam_hi + df2)


def noncentrality_limits_t(t: float, df: float, level: float = DZ_CI_LEVEL
                           ) -> tuple[float, float]:
    """Limits of the noncentrality δ of t(df, δ) given the observed ``t``.

    P(T ≤ t | δ) is decreasing in δ; the lower limit solves it = 1 − α/2 and the
    upper = α/2. NaN for a non-finite t or df.

    scipy's noncentral t gives NaN far in its tails when t and δ have opposite signs
    (``nct.cdf(-7, 2, 10)``: a pilot of three participants with a large effect takes
    the search there). With t and δ of opposite signs the probability is within
    P(Z > |δ|) of 0 (δ above t) or 1 (δ below t), and scipy's NaN starts at |δ| ≥ 6
    (under 1e-9), so those are the values used.
    """
    if not (np.isfinite(t) and np.isfinite(df)) or df <= 0:
        return math.nan, math.nan
    alpha = 1.0 - level

    def cdf(delta: float) -> float:
        p = float(stats.nct.cdf(t, df, delta))
        if math.isnan(p):
            return 0.0 if delta > t else 1.0
        return p

    def root(target: float) -> float:
        # bracket around t: the quantile moves about one unit per unit of δ
        lo, hi = t - 1.0, t + 1.0
        while cdf(lo) < target:
            lo -= 2.0 * (hi - lo)
        while cdf(hi) > target:
            hi += 2.0 * (hi - lo)
        return optimize.brentq(lambda d: cdf(d) - target, lo, hi, xtol=_XTOL,
                               rtol=4 * np.finfo(float).eps, maxiter=500)

    return root(1 - alpha / 2), root(alpha / 2)


def dz_ci(dz: float, n: int, level: float = DZ_CI_LEVEL) -> tuple[float, float]:
    """Two-sided ``level`` confidence interval of Cohen's d_z of ``n`` paired values.

    d_z = mean difference / SD of the differences; t = d_z √n on n − 1 df.
    NaN, NaN when d_z is undefined (no paired values, or differences that do
    not vary) or n < 2.

    Examples
    --------
    >>> low, high = dz_ci(0.8, 15)
    >>> round(low, 3), round(high, 3)
    (0.204, 1.374)
    """
    if not np.isfinite(dz) or n is None or n < 2:
        return math.nan, math.nan
    root_n = math.sqrt(n)
    lo, hi = noncentrality_limits_t(float(dz) * root_n, n - 1.0, level)
    return lo / root_n, hi / root_n
