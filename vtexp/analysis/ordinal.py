"""Rank tests for ordinal ratings (seed 002's whirlpool 0–4 and circle/rectangle −2…+2 scales).

A rating scale's steps need not be equal, so beside the ANOVA on mean ratings
the report gives Friedman's test (the rank analogue of a one-way
repeated-measures ANOVA) and Wilcoxon signed-rank tests between levels.
"""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
from scipy import stats

from .anova import within_design
from .posthoc import p_adjust

__all__ = ["friedman", "wilcoxon_pairwise"]


def _one_factor(data, dv, factor, subject, missing):
    d = within_design(data, dv, [factor], subject, missing=missing)
    return d, d.values


def friedman(data: pd.DataFrame, dv: str, factor: str, subject: str, *,
             missing: str = "drop") -> pd.DataFrame:
    """Friedman's (1937) rank test of ``factor`` on ``dv``, with Kendall's W.

    Several ratings in a cell are averaged first (each participant gives one
    value per level). The statistic is corrected for ties, as R's
    ``friedman.test`` does (values match it, ``tests/r_reference``). Kendall's
    coefficient of concordance ``W = Q / (n (k − 1))`` is the effect size.

    Returns one row: ``factor``, ``n``, ``k``, ``Q`` (χ² statistic), ``df``,
    ``p``, ``kendall_W``.
    """
    d, Y = _one_factor(data, dv, factor, subject, missing)
    n, k = Y.shape
    ranks = np.apply_along_axis(stats.rankdata, 1, Y)
    # R's friedman.test: tie-corrected statistic
    r = ranks.sum(axis=0)
    ties = 0.0
    for row in Y:
        _, counts = np.unique(row, return_counts=True)
        ties += (counts ** 3 - counts).sum()
    denom = n * k * (k + 1) - ties / (k - 1)
    if denom == 0:
        Q, p = np.nan, np.nan
    else:
        Q = 12 * ((r - n * (k + 1) / 2) ** 2).sum() / denom
        p = stats.chi2.sf(Q, k - 1)
    out = pd.DataFrame([{"factor": factor, "n": n, "k": k, "Q": Q, "df": float(k - 1), "p": p,
                         "kendall_W": Q / (n * (k - 1)) if not np.isnan(Q) else np.nan}])
    out.attrs.update(dropped=list(d.dropped), dv=dv)
    return out


def wilcoxon_pairwise(data: pd.DataFrame, dv: str, factor: str, subject: str, *,
                      padjust: str = "holm", missing: str = "drop") -> pd.DataFrame:
    """Wilcoxon (1945) signed-rank tests between every two levels of ``factor``.

    As R's ``wilcox.test(paired = TRUE)``: zero differences are dropped, the
    exact distribution is used for fewer than 50 pairs without ties or zeros,
    otherwise the normal approximation with tie correction and continuity
    correction. ``V`` is the sum of the ranks of the positive differences
    (A − B). The effect size ``r_rb`` is the matched-pairs rank-biserial
    correlation (Kerby 2014): (sum of positive ranks − sum of negative ranks) /
    total rank sum. p values are corrected with ``padjust`` (Holm by default).
    """
    if padjust not in ("holm", "bonferroni", "none"):
        p_adjust([], padjust)
    d, Y = _one_factor(data, dv, factor, subject, missing)
    levels = d.levels[0]
    rows = []
    for i, j in itertools.combinations(range(len(levels)), 2):
        diff = Y[:, i] - Y[:, j]
        nz = diff[diff != 0]
        if len(nz) == 0:
            V, p, rrb = 0.0, np.nan, np.nan
        else:
            ranks = stats.rankdata(np.abs(nz))
            V = float(ranks[nz > 0].sum())
            rrb = (ranks[nz > 0].sum() - ranks[nz < 0].sum()) / ranks.sum()
            exact = len(nz) < 50 and len(np.unique(np.abs(nz))) == len(nz) and \
                len(nz) == len(diff)
            res = stats.wilcoxon(Y[:, i], Y[:, j], zero_method="wilcox", correction=True,
                                 method="exact" if exact else "approx")
            p = float(res.pvalue)
        rows.append({"factor": factor, "A": levels[i], "B": levels[j], "n": len(diff),
                     "n_nonzero": len(nz), "median_diff": float(np.median(diff)), "V": V,
                     "p": p, "r_rb": rrb})
    out = pd.DataFrame(rows)
    out["p_adj"] = p_adjust(out["p"], padjust)
    out["padjust"] = padjust
    out.attrs.update(dropped=list(d.dropped), dv=dv)
    return out
