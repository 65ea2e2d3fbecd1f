"""Post-hoc paired comparisons with a family-wise correction and effect sizes."""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
from scipy import stats

from ..errors import InputError
from .anova import within_design

__all__ = ["p_adjust", "pairwise_tests"]


def p_adjust(p, method: str = "holm") -> np.ndarray:
    """Adjusted p values, as R's ``p.adjust``.

    ``holm``: Holm (1979) step-down, ``p_(i) (m - i + 1)`` made monotone and
    capped at 1; ``bonferroni``: ``p m`` capped at 1; ``none``: unchanged.
    Missing values stay missing and do not count in ``m``.
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
    else:
        raise InputError(f"p-value correction must be 'holm', 'bonferroni' or 'none', "
                         f"not {method!r}")
    return out


def pairwise_tests(data: pd.DataFrame, dv: str, within: list[str] | str, subject: str, *,
                   factor: str, by: str | list[str] | None = None, padjust: str = "holm",
                   missing: str = "drop") -> pd.DataFrame:
    """Paired t tests between every two levels of ``factor``, corrected for multiplicity.

    Each participant's value at a level is their mean over the cells of the
    other factors (and over the observations in a cell); with ``by``, the
    comparisons are made within each level (combination) of ``by`` and
    corrected within it. Participants lacking a cell are handled as in
    :func:`vtexp.analysis.anova.rm_anova`.

    Returns one row per pair: ``A``, ``B``, ``mean_A``, ``mean_B``,
    ``mean_diff`` (A − B), ``t``, ``df``, ``p``, ``p_adj`` (``padjust``:
    Holm by default, or Bonferroni), ``ci_low``/``ci_high`` (95 % CI of the
    difference), and two effect sizes: ``dz`` = mean difference / SD of the
    differences (Cohen 1988, the paired design's d) and ``dav`` = mean
    difference / mean of the two SDs (Cumming 2012), which does not grow with
    the correlation between the levels. Values match R's
    ``t.test(paired = TRUE)`` and ``p.adjust`` (``tests/r_reference``).
    """
    within = [within] if isinstance(within, str) else list(within)
    by = [] if by is None else ([by] if isinstance(by, str) else list(by))
    if factor not in within:
        raise InputError(f"{factor!r} is not one of the within factors {within}")
    for f in by:
        if f not in within or f == factor:
            raise InputError(f"'by' factor {f!r} must be another of the within factors {within}")
    p_adjust([], padjust)                       # refuse an unknown method before the work
    d = within_design(data, dv, within, subject, missing=missing)
    pos = {f: i for i, f in enumerate(d.factors)}
    n = len(d.subjects)
    Y = d.values.reshape((n, *d.shape))
    keep = [pos[factor], *(pos[f] for f in by)]
    Y = Y.mean(axis=tuple(1 + i for i in range(len(d.factors)) if i not in keep)) \
        if len(keep) < len(d.factors) else Y
    kept = sorted(keep)
    Y = np.moveaxis(Y, [1 + kept.index(pos[factor])] + [1 + kept.index(pos[f]) for f in by],
                    list(range(1, 2 + len(by))))
    levels = d.levels[pos[factor]]
    rows = []
    for combo in itertools.product(*(d.levels[pos[f]] for f in by)):
        sub = Y[(slice(None), slice(None), *(d.levels[pos[f]].index(v)
                                             for f, v in zip(by, combo)))]
        block = []
        for i, j in itertools.combinations(range(len(levels)), 2):
            a, b = sub[:, i], sub[:, j]
            diff = a - b
            md, sd = diff.mean(), diff.std(ddof=1)
            with np.errstate(divide="ignore", invalid="ignore"):
                t = md / (sd / np.sqrt(n))
                dz = md / sd
                dav = md / ((a.std(ddof=1) + b.std(ddof=1)) / 2)
            p = 2 * stats.t.sf(abs(t), n - 1)
            half = stats.t.ppf(0.975, n - 1) * sd / np.sqrt(n)
            block.append({**dict(zip(by, combo)), "factor": factor, "A": levels[i],
                          "B": levels[j], "mean_A": a.mean(), "mean_B": b.mean(),
                          "mean_diff": md, "t": t, "df": float(n - 1), "p": p,
                          "ci_low": md - half, "ci_high": md + half, "dz": dz, "dav": dav,
                          "n": n})
        adj = p_adjust([r["p"] for r in block], padjust)
        for r, pa in zip(block, adj):
            r["p_adj"] = pa
            r["padjust"] = padjust
        rows += block
    out = pd.DataFrame(rows)
    cols = [*by, "factor", "A", "B", "mean_A", "mean_B", "mean_diff", "t", "df", "p", "p_adj",
            "padjust", "ci_low", "ci_high", "dz", "dav", "n"]
    out = out[cols]
    out.attrs.update(dropped=list(d.dropped), dv=dv)
    return out
