"""Post-hoc comparisons and trend contrasts, with a family-wise correction and effect sizes.

Two conventions for the error of a comparison, as labs use them:

- ``error="paired"`` (per participant): each comparison is a test on the
  participants' own values: a paired t test for two levels of a within factor
  (R's ``t.test(paired = TRUE)``), Welch's t test for two groups (R's
  ``t.test``). Nothing is assumed about the other cells.
- ``error="pooled"`` (the model's error): the comparison is a linear function
  of the cell means of the whole design, with the univariate model's error
  strata pooled in the proportions it spans them and Satterthwaite's df; the
  numbers of ``emmeans::pairs(emmeans(fit, ...))`` on an ``afex::aov_ez`` fit
  with ``afex_options(emmeans_model = "univariate")``
  (:class:`vtexp.analysis.anova.PooledModel`).
"""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
from scipy import stats

from ..errors import InputError
from .anova import PooledModel, _as_list, grid_function, within_design
from .effect_sizes import DZ_CI_LEVEL, dz_ci
from .spec import PADJUST_METHODS

__all__ = ["p_adjust", "pairwise_tests", "trend_contrasts", "polynomial_contrasts",
           "PADJUST_METHODS"]


def p_adjust(p, method: str = "holm") -> np.ndarray:
    """Adjusted p values, as R's ``p.adjust`` (and emmeans for Šidák).

    ``holm``: Holm (1979) step-down, ``p_(i) (m - i + 1)`` made monotone and
    capped at 1; ``bonferroni``: ``p m`` capped at 1; ``BH`` (or ``fdr``):
    Benjamini & Hochberg (1995) false discovery rate, ``p_(i) m / i`` made
    monotone from the largest down; ``sidak``: Šidák (1967) single step,
    ``1 − (1 − p)^m``, as ``emmeans``' ``adjust = "sidak"``; ``none``:
    unchanged. Missing values stay missing and do not count in ``m``.
    """
    p = np.asarray(p, dtype=float)
    out = np.full_like(p, np.nan)
    ok = ~np.isnan(p)
    q = p[ok]
    m = len(q)
    if method == "none":
        out[ok] = q
    elif method == "bonferroni":
        out[ok] = np.minimum(q * m, 1.0)
    elif method == "holm":
        order = np.argsort(q, kind="stable")
        adj = np.maximum.accumulate(q[order] * (m - np.arange(m)))
        res = np.empty(m)
        res[order] = np.minimum(adj, 1.0)
        out[ok] = res
    elif method in ("BH", "fdr"):
        order = np.argsort(q, kind="stable")[::-1]
        adj = np.minimum.accumulate(q[order] * m / (m - np.arange(m)))
        res = np.empty(m)
        res[order] = np.minimum(adj, 1.0)
        out[ok] = res
    elif method == "sidak":
        out[ok] = 1.0 - (1.0 - q) ** m
    else:
        raise InputError(f"p-value correction must be one of {', '.join(PADJUST_METHODS)}, "
                         f"not {method!r}")
    return out


def _split(within, between, factor, by):
    within, between, by = _as_list(within), _as_list(between), _as_list(by)
    factors = within + between
    if factor not in factors:
        raise InputError(f"{factor!r} is not one of the factors {factors}")
    for f in by:
        if f not in factors or f == factor:
            raise InputError(f"'by' factor {f!r} must be another of the factors {factors}")
    return within, between, by


def _participant_values(d, keep: list[str]) -> tuple[np.ndarray, list[str]]:
    """Each participant's mean at each combination of the within factors in ``keep``."""
    n = len(d.subjects)
    Y = d.values.reshape((n, *d.shape))
    pos = {f: i for i, f in enumerate(d.factors)}
    drop = tuple(1 + i for f, i in pos.items() if f not in keep)
    if drop:
        Y = Y.mean(axis=drop)
    kept = [f for f in d.factors if f in keep]
    return Y, kept


def pairwise_tests(data: pd.DataFrame, dv: str, within: list[str] | str | None, subject: str,
                   *, factor: str, by: str | list[str] | None = None, padjust: str = "holm",
                   between: list[str] | str | None = None, error: str = "paired",
                   missing: str = "drop") -> pd.DataFrame:
    """Comparisons between every two levels of ``factor``, corrected for multiplicity.

    ``factor`` and ``by`` may be within- or between-participant factors: SOAs
    compared within each group, groups compared at each SOA, or SOAs compared
    over all participants (no ``by``). The p values are corrected within each
    level (combination) of ``by`` with ``padjust`` (:func:`p_adjust`).

    ``error="paired"``: each participant's value at a level is their mean over
    the cells of the other within factors (and over the observations in a
    cell); a within factor's levels are compared with paired t tests on the
    participants in the ``by`` group, a between factor's with Welch's t test.
    ``error="pooled"``: the univariate model's pooled error as ``emmeans``
    (module docstring); factors not in ``by`` are averaged with equal weights
    (emmeans' default), so with unequal groups a comparison over all
    participants weighs each group equally.

    Returns one row per pair: the ``by`` columns, ``factor``, ``A``, ``B``,
    ``mean_A``, ``mean_B``, ``mean_diff`` (A − B), ``se``, ``t``, ``df``,
    ``p``, ``p_adj``, ``padjust``, ``ci_low``/``ci_high`` (95 % CI of the
    difference, not adjusted), ``error``, and two effect sizes from the
    participants' values: ``dz`` = mean difference / SD of the differences
    (Cohen 1988, paired comparisons only) with its 95 % interval from the
    noncentral t (``dz_ci95_low``, ``dz_ci95_high``; :func:`.effect_sizes.dz_ci`)
    and ``dav`` = mean difference / mean
    of the two SDs (Cumming 2012), which does not grow with the correlation
    between the levels; ``n`` participants.

    References
    ----------
    R's ``t.test`` and ``p.adjust``; ``emmeans::pairs`` with ``adjust = "holm",
    "bonferroni", "fdr", "sidak"``; matched to 1e-6 in ``tests/r_reference``.
    """
    within, between, by = _split(within, between, factor, by)
    if error not in ("paired", "pooled"):
        raise InputError(f"error must be 'paired' (per participant) or 'pooled' (the "
                         f"model's), not {error!r}")
    p_adjust([], padjust)                       # refuse an unknown method before the work
    d = within_design(data, dv, within, subject, missing=missing, between=between)
    lv_of = dict(zip(d.between + d.factors, d.between_levels + d.levels))
    levels = lv_of[factor]
    by_combos = list(itertools.product(*(lv_of[f] for f in by)))
    model = PooledModel.of(d) if error == "pooled" else None
    keep_w = [f for f in [factor, *by] if f in d.factors]
    Y, kept = _participant_values(d, keep_w)
    gtab = pd.DataFrame(np.array(list(itertools.product(*d.between_levels)), dtype=object)
                        [d.groups] if d.between else np.empty((len(d.subjects), 0)),
                        columns=d.between)
    rows = []
    for combo in by_combos:
        at = dict(zip(by, combo))
        # participants in the by-group (between factors of by), values at the within levels
        who = np.ones(len(d.subjects), bool)
        for f, v in at.items():
            if f in d.between:
                who &= (gtab[f] == v).to_numpy()

        def values(level):
            idx = [slice(None)]
            sel = who.copy()
            for f in kept:
                if f == factor:
                    idx.append(lv_of[f].index(level))
                else:
                    idx.append(lv_of[f].index(at[f]))
            if factor in d.between:
                sel &= (gtab[factor] == level).to_numpy()
            return Y[tuple(idx)][sel]

        block = []
        for i, j in itertools.combinations(range(len(levels)), 2):
            a, b = values(levels[i]), values(levels[j])
            row = {**at, "factor": factor, "A": levels[i], "B": levels[j],
                   "mean_A": a.mean(), "mean_B": b.mean()}
            paired = factor in d.factors
            sd_a, sd_b = a.std(ddof=1), b.std(ddof=1)
            with np.errstate(divide="ignore", invalid="ignore"):
                dav = (a.mean() - b.mean()) / ((sd_a + sd_b) / 2)
            if error == "paired":
                if paired:
                    diff = a - b
                    n = len(diff)
                    md, sd = diff.mean(), diff.std(ddof=1)
                    se, df = sd / np.sqrt(n), float(n - 1)
                    with np.errstate(divide="ignore", invalid="ignore"):
                        dz = md / sd
                else:
                    md = a.mean() - b.mean()
                    va, vb = sd_a ** 2 / len(a), sd_b ** 2 / len(b)
                    se = np.sqrt(va + vb)
                    with np.errstate(divide="ignore", invalid="ignore"):
                        df = (va + vb) ** 2 / (va ** 2 / (len(a) - 1) + vb ** 2 / (len(b) - 1))
                    dz = np.nan
                    n = len(a) + len(b)
            else:
                parts = {f: np.eye(len(lv_of[f]))[:, [lv_of[f].index(v)]] for f, v in at.items()}
                col = np.zeros((len(levels), 1))
                col[i, 0], col[j, 0] = 1.0, -1.0
                parts[factor] = col
                L = grid_function(d, parts)
                md = float(model.estimate(L)[0][0])
                var, df = model.satterthwaite(L[:, 0])
                se = np.sqrt(var)
                dz = (a - b).mean() / (a - b).std(ddof=1) if paired else np.nan
                n = int(who.sum())
            with np.errstate(divide="ignore", invalid="ignore"):
                t = md / se
            p = 2 * stats.t.sf(abs(t), df)
            half = stats.t.ppf(0.975, df) * se
            row.update({"mean_diff": md, "se": se, "t": t, "df": float(df), "p": p,
                        "ci_low": md - half, "ci_high": md + half, "error": error,
                        "dz": dz, "dav": dav, "n": n})
            block.append(row)
        for r in block:
            r["dz_ci95_low"], r["dz_ci95_high"] = dz_ci(r["dz"], r["n"], DZ_CI_LEVEL)
        adj = p_adjust([r["p"] for r in block], padjust)
        for r, pa in zip(block, adj):
            r["p_adj"] = pa
            r["padjust"] = padjust
        rows += block
    out = pd.DataFrame(rows)
    cols = [*by, "factor", "A", "B", "mean_A", "mean_B", "mean_diff", "se", "t", "df", "p",
            "p_adj", "padjust", "ci_low", "ci_high", "error", "dz", "dz_ci95_low",
            "dz_ci95_high", "dav", "n"]
    out = out[cols]
    out.attrs.update(dropped=list(d.dropped), dv=dv)
    return out


DEGREE_NAMES = ("linear", "quadratic", "cubic", "quartic", "quintic")


def polynomial_contrasts(scores) -> np.ndarray:
    """Orthonormal polynomial contrasts for levels at ``scores`` (k × (k − 1)).

    R's ``contr.poly(k, scores)``: the QR decomposition of the Vandermonde
    matrix of the centred scores, columns scaled to unit length, with the sign
    that makes each column's leading coefficient positive. Unequal spacing
    (SOAs of 100, 200, 400 ms) gives contrasts for that spacing.
    """
    x = np.asarray(scores, dtype=float)
    k = len(x)
    if k < 2:
        raise InputError("a trend needs at least 2 levels")
    if len(np.unique(x)) != k:
        raise InputError(f"the scores of a trend must differ: {list(scores)}")
    X = np.vander(x - x.mean(), k, increasing=True)
    Q, R = np.linalg.qr(X)
    Z = Q * np.diag(R)                  # R's make.poly: qr.qy(QR, diag(diag(R)))
    Z = Z / np.sqrt((Z ** 2).sum(axis=0))
    return Z[:, 1:]


def _scores_of(levels: list, scores) -> list[float]:
    if scores is not None:
        if len(scores) != len(levels):
            raise InputError(f"{len(scores)} scores for {len(levels)} levels ({levels})")
        return [float(s) for s in scores]
    try:
        return [float(v) for v in levels]
    except (TypeError, ValueError):
        return [float(i + 1) for i in range(len(levels))]


def trend_contrasts(data: pd.DataFrame, dv: str, within: list[str] | str | None, subject: str,
                    *, factor: str, by: str | list[str] | None = None,
                    between: list[str] | str | None = None, error: str = "paired",
                    scores=None, max_degree: int | None = None,
                    missing: str = "drop") -> pd.DataFrame:
    """Polynomial trends (linear, quadratic, ...) across the levels of a graded factor.

    For intensity, frequency or SOA: does the measure rise with the level
    (linear), rise then level off (quadratic)? The contrasts are orthonormal
    polynomials of the levels' ``scores`` (default: the levels read as
    numbers, so 100, 200, 400 ms are spaced as they are; equally spaced if they
    are not numbers), :func:`polynomial_contrasts`. ``error`` as in
    :func:`pairwise_tests`: ``paired`` tests each participant's contrast score
    with a one-sample t test (within each ``by`` group), ``pooled`` uses the
    univariate model's error as ``emmeans::contrast(emm, method = poly)``.

    Returns one row per ``by`` level and degree: ``contrast`` (``linear``...),
    ``degree``, ``estimate`` (the contrast of the means with the orthonormal
    coefficients), ``se``, ``t``, ``df``, ``p``, ``error``, ``n``.
    ``attrs["coefficients"]`` holds the coefficients.
    """
    within, between, by = _split(within, between, factor, by)
    if factor not in within:
        raise InputError(f"a trend is across the levels of a within-participant factor; "
                         f"{factor!r} is not one of {within}")
    if error not in ("paired", "pooled"):
        raise InputError(f"error must be 'paired' or 'pooled', not {error!r}")
    d = within_design(data, dv, within, subject, missing=missing, between=between)
    lv_of = dict(zip(d.between + d.factors, d.between_levels + d.levels))
    levels = lv_of[factor]
    sc = _scores_of(levels, scores)
    P = polynomial_contrasts(sc)
    if max_degree is not None:
        P = P[:, :max_degree]
    model = PooledModel.of(d) if error == "pooled" else None
    keep_w = [f for f in [factor, *by] if f in d.factors]
    Y, kept = _participant_values(d, keep_w)
    groups = np.array(list(itertools.product(*d.between_levels)), dtype=object)[d.groups] \
        if d.between else np.empty((len(d.subjects), 0), dtype=object)
    rows = []
    for combo in itertools.product(*(lv_of[f] for f in by)):
        at = dict(zip(by, combo))
        who = np.ones(len(d.subjects), bool)
        for f, v in at.items():
            if f in d.between:
                who &= groups[:, d.between.index(f)] == v
        idx: list = [slice(None)]
        for f in kept:
            idx.append(slice(None) if f == factor else lv_of[f].index(at[f]))
        V = Y[tuple(idx)][who]                       # participants × levels of factor
        for deg in range(P.shape[1]):
            c = P[:, deg]
            if error == "paired":
                sc_i = V @ c
                n = len(sc_i)
                est, se, df = sc_i.mean(), sc_i.std(ddof=1) / np.sqrt(n), float(n - 1)
            else:
                parts = {f: np.eye(len(lv_of[f]))[:, [lv_of[f].index(v)]] for f, v in at.items()}
                parts[factor] = c[:, None]
                L = grid_function(d, parts)
                est = float(model.estimate(L)[0][0])
                var, df = model.satterthwaite(L[:, 0])
                se = np.sqrt(var)
                n = int(who.sum())
            with np.errstate(divide="ignore", invalid="ignore"):
                t = est / se
            rows.append({**at, "factor": factor,
                         "contrast": DEGREE_NAMES[deg] if deg < len(DEGREE_NAMES)
                         else f"degree {deg + 1}", "degree": deg + 1, "estimate": est,
                         "se": se, "t": t, "df": float(df), "p": 2 * stats.t.sf(abs(t), df),
                         "error": error, "n": n})
    out = pd.DataFrame(rows)
    out.attrs.update(dropped=list(d.dropped), dv=dv, scores=sc,
                     coefficients=P.tolist())
    return out
