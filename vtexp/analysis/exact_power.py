"""Exact power of repeated-measures and mixed ANOVA effects from stated means, SDs and correlations.

This is Superpower's ``ANOVA_exact`` (Lakens & Caldwell 2021, "Simulation-Based Power
Analysis for Factorial Analysis of Variance Designs", *Advances in Methods and Practices
in Psychological Science* 4(1); R package Superpower, ``R/ANOVA_exact.R``), run on
vtexp's own ANOVA (:func:`vtexp.analysis.anova.rm_anova`):

1. **One exact dataset.** ``n`` participants (``n`` per group when there are
   between-participant factors) whose sample means are exactly the stated cell means
   ``μ`` and whose sample covariance matrix (denominator ``n − 1``) is exactly
   ``Σ = D R D`` (``D`` the cells' SDs on the diagonal, ``R`` the correlations): an
   *empirical* multivariate normal, as ``MASS::mvrnorm(empirical = TRUE)`` draws it
   (:func:`empirical_normal`). Every statistic of the ANOVA is a function of the
   sample means and covariances only, so the draws themselves do not matter.
2. **The ANOVA of that dataset**, uncorrected univariate F tests, and from it each
   effect's partial eta squared ``η²p = SS_effect / (SS_effect + SS_error)``.
3. **Power from the noncentral F**::

       f² = η²p / (1 − η²p)
       λ  = f² · df_error                       (Superpower's default; not the
                                                 "liberal" f² (df_error + df_effect + 1))
       power = P( F'(df_effect, df_error, λ) > F_{1−α}(df_effect, df_error) )

   with ``F'`` the noncentral F distribution (``scipy.stats.ncf``).

**Which sphericity assumption.** The power is that of the *uncorrected* univariate F test
(Superpower's default, ``correction = "none"``), and it is exact when that test's F is
noncentral-F distributed: for effects with one degree of freedom always, and for effects
with more when the covariance of the effect's orthonormal contrasts, ``Cᵀ Σ C``, is
spherical (``σ² I``), as under compound symmetry (one SD, one correlation ``r`` for
every pair of cells). ``λ`` above is then ``n |Cᵀ μ|² / σ²``, the true noncentrality. With
unequal SDs or correlations and more than one degree of freedom it is Superpower's
approximation (``λ`` from the average error variance ``tr(Cᵀ Σ C) / df``); a
Greenhouse–Geisser or Huynh–Feldt corrected test has no such closed form.

**N.** With equal group sizes both ``λ`` and ``df_error`` grow in proportion to
participants: for an effect of the exact dataset at ``n₀``, ``λ(n) = λ(n₀) · n / n₀`` and
``df_error(n) = df_error(n₀) · (n − 1) / (n₀ − 1)``. :func:`smallest_n` uses this to
find the smallest ``n`` whose power reaches a target without a dataset per ``n``; the
dataset itself needs ``n`` above the number of within cells (a covariance matrix of
``k`` cells has full rank only with ``k + 1`` participants), so below that
:func:`exact_anova` reads the values off the dataset at ``k + 1`` the same way.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import stats

from ..errors import InputError
from .anova import rm_anova

__all__ = ["ExactDesign", "empirical_normal", "exact_dataset", "exact_anova", "ncf_power",
           "smallest_n", "correlation_matrix"]


def correlation_matrix(r, k: int) -> np.ndarray:
    """A ``k × k`` correlation matrix: every pair ``r`` (a number), or ``r`` itself (a matrix)."""
    if np.ndim(r) == 0:
        R = np.full((k, k), float(r))
        np.fill_diagonal(R, 1.0)
        return R
    R = np.asarray(r, dtype=float)
    if R.shape != (k, k):
        raise InputError(f"a correlation matrix of {k} cells must be {k} × {k}, not "
                         f"{' × '.join(map(str, R.shape))}")
    return R


def check_covariance(cov: np.ndarray) -> None:
    """Refuse a covariance matrix that is not symmetric positive definite."""
    if not np.allclose(cov, cov.T, rtol=0, atol=1e-12 * max(1.0, float(np.abs(cov).max()))):
        raise InputError("the correlations are not symmetric")
    lowest = float(np.linalg.eigvalsh(cov).min())
    if not lowest > 1e-12 * float(np.trace(cov)):
        raise InputError("the correlations are not positive definite (no participants can "
                         "have them: with k cells one r must be above -1/(k-1))")


def empirical_normal(mean: np.ndarray, cov: np.ndarray, n: int, *, seed: int = 0) -> np.ndarray:
    """``n`` draws (rows) whose sample mean is exactly ``mean`` and whose sample covariance
    (denominator ``n − 1``) is exactly ``cov``, as ``MASS::mvrnorm(empirical = TRUE)``.

    Standard normal draws ``Z`` are centred and whitened, ``W = Z_c S^{-1/2}`` with
    ``S = Z_cᵀ Z_c / (n − 1)`` (so ``Wᵀ W / (n − 1) = I``), and coloured,
    ``X = 1 μᵀ + W Lᵀ`` with ``cov = L Lᵀ`` (Cholesky). Needs ``n > k`` (``k`` cells).
    """
    mean = np.asarray(mean, dtype=float)
    cov = np.asarray(cov, dtype=float)
    k = mean.size
    if n <= k:
        raise InputError(f"an exact dataset of {k} cells needs at least {k + 1} participants, "
                         f"not {n}")
    Z = np.random.default_rng(seed).standard_normal((n, k))
    Z -= Z.mean(axis=0)
    vals, vecs = np.linalg.eigh(Z.T @ Z / (n - 1))
    W = Z @ (vecs / np.sqrt(vals)) @ vecs.T
    return mean + W @ np.linalg.cholesky(cov).T


@dataclass(frozen=True)
class ExactDesign:
    """A design whose power is known: cell means, SDs and correlations.

    ``within`` and ``between`` map each factor to its levels (the first factor slowest,
    as :class:`vtexp.analysis.anova.WithinDesign` orders cells). ``means`` has shape
    (between cells, within cells) (one row without between factors); ``cov`` is the
    covariance of a participant's within cells, one matrix for all groups, or one per
    group (shape (between cells, within cells, within cells)).
    """

    within: dict[str, list[str]]
    means: np.ndarray
    cov: np.ndarray
    between: dict[str, list[str]] = field(default_factory=dict)

    def __post_init__(self):
        means = np.atleast_2d(np.asarray(self.means, dtype=float))
        k = int(np.prod([len(v) for v in self.within.values()])) if self.within else 1
        g = int(np.prod([len(v) for v in self.between.values()])) if self.between else 1
        if means.shape != (g, k):
            raise InputError(f"expected {g} × {k} cell means (between × within cells), got "
                             f"{' × '.join(map(str, means.shape))}")
        cov = np.asarray(self.cov, dtype=float)
        cov = np.broadcast_to(cov, (g, k, k)) if cov.ndim == 2 else cov
        if cov.shape != (g, k, k):
            raise InputError(f"expected a {k} × {k} covariance matrix per group")
        for c in cov:
            check_covariance(c)
        object.__setattr__(self, "means", means)
        object.__setattr__(self, "cov", np.array(cov))

    @classmethod
    def from_sd_r(cls, within: dict[str, list[str]], means, sd, r,
                  between: dict[str, list[str]] | None = None) -> ExactDesign:
        """From SDs (one number, or one per cell in ``means``' shape) and correlations
        between a participant's within cells (one ``r``, or a matrix)."""
        means = np.atleast_2d(np.asarray(means, dtype=float))
        k = means.shape[1]
        sd = np.broadcast_to(np.asarray(sd, dtype=float), means.shape)
        if not (sd > 0).all():
            raise InputError("every SD must be above 0")
        R = correlation_matrix(r, k)
        cov = sd[:, :, None] * R[None] * sd[:, None, :]
        return cls(dict(within), means, cov, dict(between or {}))

    @property
    def groups(self) -> int:
        return self.means.shape[0]

    @property
    def cells(self) -> int:
        return self.means.shape[1]


def exact_dataset(design: ExactDesign, n: int) -> pd.DataFrame:
    """The exact dataset of ``n`` participants per group, as a tidy table
    (``participant``, the between factors, the within factors, ``y``)."""
    wf, bf = list(design.within), list(design.between)
    wcells = list(itertools.product(*design.within.values())) if wf else [()]
    bcells = list(itertools.product(*design.between.values())) if bf else [()]
    frames = []
    for gi, bc in enumerate(bcells):
        X = empirical_normal(design.means[gi], design.cov[gi], n)
        ids = np.repeat([f"g{gi + 1}p{i + 1}" for i in range(n)], len(wcells))
        d = pd.DataFrame({"participant": ids, "y": X.ravel()})
        for j, f in enumerate(bf):
            d[f] = bc[j]
        for j, f in enumerate(wf):
            d[f] = np.tile([c[j] for c in wcells], n)
        frames.append(d)
    out = pd.concat(frames, ignore_index=True)
    for f, lv in {**design.between, **design.within}.items():
        out[f] = pd.Categorical(out[f], categories=lv, ordered=True)
    return out


def ncf_power(df1, df2, lam, alpha: float = 0.05):
    """``P(F'(df1, df2, λ) > F_{1−α}(df1, df2))``: the power of an F test (λ = 0: α)."""
    df1, df2, lam = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (df1, df2, lam)))
    crit = stats.f.isf(alpha, df1, df2)
    p = np.asarray(stats.f.sf(crit, df1, df2), dtype=float).copy()
    on = lam > 0
    if on.any():
        p[on] = stats.ncf.sf(crit[on], df1[on], df2[on], lam[on])
    return p if p.ndim else float(p)


def exact_anova(design: ExactDesign, n: int, alpha: float = 0.05) -> pd.DataFrame:
    """The exact power of every effect with ``n`` participants (per group).

    Returns one row per effect in :func:`rm_anova`'s order: ``effect``, ``df1``,
    ``df2``, ``pes`` (partial η² of the exact dataset), ``f2``, ``lambda``,
    ``F_crit``, ``power``, ``n``. Below ``cells + 1`` participants (no exact dataset)
    ``lambda`` and ``df2`` are scaled from the dataset at ``cells + 1`` (module doc).
    """
    if n < 2:
        raise InputError("power needs at least 2 participants per group")
    n0 = max(n, design.cells + 1)
    data = exact_dataset(design, n0)
    within = list(design.within) or None
    t = rm_anova(data, "y", within, "participant", between=list(design.between) or None)
    pes = t["pes"].to_numpy(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        f2 = np.where(pes < 1, pes / (1 - pes), np.inf)
    df1 = t["df1"].to_numpy(float)
    df2_0 = t["df2"].to_numpy(float)
    lam0 = f2 * df2_0
    # exact zero effects come out as rounding noise (1e-30): they are zero
    lam0 = np.where(t["SS"].to_numpy(float) == 0, 0.0, lam0)
    df2 = df2_0 * (n - 1) / (n0 - 1)
    lam = lam0 * n / n0
    out = pd.DataFrame({"effect": t["effect"], "df1": df1, "df2": df2, "pes": pes,
                        "f2": f2, "lambda": lam, "F_crit": stats.f.isf(alpha, df1, df2),
                        "power": ncf_power(df1, df2, lam, alpha)})
    out["n"] = n
    return out


def smallest_n(design: ExactDesign, target: float, alpha: float = 0.05, *,
               n_max: int = 100_000) -> pd.DataFrame:
    """For each effect, the smallest ``n`` (per group) whose exact power reaches ``target``.

    Power rises with ``n`` (λ and df_error both grow), so the first ``n`` found by
    doubling and then bisection is the smallest; λ and df_error at each ``n`` are
    scaled from one exact dataset (module doc). ``n`` is None where ``n_max`` does
    not reach the target (an effect of zero size never does). Returns ``effect``,
    ``n``, ``power`` (at that ``n``, or at ``n_max``).
    """
    if not 0 < target < 1:
        raise InputError("the target power must be between 0 and 1")
    base = exact_anova(design, design.cells + 1, alpha)
    n0 = design.cells + 1

    def power(i: int, n: int) -> float:
        r = base.iloc[i]
        df2 = r["df2"] * (n - 1) / (n0 - 1)
        return float(ncf_power(r["df1"], df2, r["lambda"] * n / n0, alpha))

    rows = []
    for i, effect in enumerate(base["effect"]):
        lo, hi = 1, 2
        while power(i, hi) < target and hi < n_max:
            lo, hi = hi, min(2 * hi, n_max)
        if power(i, hi) < target:
            rows.append({"effect": effect, "n": None, "power": power(i, n_max)})
            continue
        while hi - lo > 1:          # power(lo) < target <= power(hi)
            mid = (lo + hi) // 2
            lo, hi = (lo, mid) if power(i, mid) >= target else (mid, hi)
        rows.append({"effect": effect, "n": hi, "power": power(i, hi)})
    return pd.DataFrame(rows)
