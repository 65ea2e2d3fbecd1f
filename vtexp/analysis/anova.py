"""Repeated-measures ANOVA for any number of within-participant factors.

Every function takes a tidy table (one row per observation; factors, the
participant and the dependent variable as columns) and returns a tidy table,
as pingouin does. The numbers are those of R's ``afex::aov_ez`` (which calls
``car::Anova`` on a multivariate linear model) and, for simple effects with a
pooled error term, of ``emmeans::joint_tests`` on afex's univariate model; the
test suite checks them against values computed with R (``tests/r_reference``).

Method
------
The cell means of each participant form a matrix ``Y`` (participants × cells,
cells in the order of the factors' levels, the first factor slowest). Each
effect (a set of factors) has an orthonormal contrast matrix ``C``: the
Kronecker product, over the factors, of the normalised Helmert contrasts for a
factor in the effect and of ``1/sqrt(k)`` for a factor averaged over. With
``Z = Y C`` (participants × df of the effect),

- ``SS_effect = n |mean(Z)|²`` and ``S`` = the sums of squares and products of
  ``Z`` about its mean, ``SS_error = tr S``; ``F = (SS_effect/df) /
  (SS_error/(df (n-1)))`` on ``df`` and ``df (n-1)`` degrees of freedom;
- Greenhouse–Geisser ``ε = tr(S)² / (df tr(S²))`` (Greenhouse & Geisser 1959);
- Huynh–Feldt ``ε = (n df ε_GG - 2) / (df (n - 1 - df ε_GG))`` as car computes it
  (Lecoutre's 1991 correction of Huynh & Feldt 1976); reported uncapped, as R
  prints it, and capped at 1 for its corrected p (afex: "HF eps > 1 treated as 1");
- Mauchly's ``W = det(S) / (tr(S)/df)^df`` with the χ² approximation and the
  second-order term of Anderson (1958), as ``stats::mauchly.test`` and car use;
- partial η² = SS_effect / (SS_effect + SS_error); generalised η² (Olejnik &
  Algina 2003; Bakeman 2005) = SS_effect / (SS_effect + Σ SS_error of every
  stratum, the participants' stratum included), as afex reports it for designs
  with no between-participant or observed factors.

The arithmetic is written on stacks of datasets (leading axes), so a batch of
thousands of simulated studies is analysed in one vectorised pass
(:func:`rm_anova_batch`), which power analyses need.
"""

from __future__ import annotations

import itertools
import warnings
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import stats

from ..errors import InputError

__all__ = ["MissingCellsWarning", "WithinDesign", "within_design", "rm_anova",
           "rm_anova_batch", "simple_effects", "anova_arrays"]


class MissingCellsWarning(UserWarning):
    """Participants without a value in every cell were left out of an ANOVA."""


# --------------------------------------------------------------------------- design

@dataclass
class WithinDesign:
    """Participants × cells matrix of cell means, with its factors and levels.

    ``values`` has shape (participants, cells); cell ``j`` is the combination
    of levels ``itertools.product(*levels)[j]`` (the first factor slowest).
    """

    factors: list[str]
    levels: list[list]
    subjects: list
    values: np.ndarray
    dropped: list = field(default_factory=list)
    aggregated: bool = False

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(len(lv) for lv in self.levels)

    @property
    def cells(self) -> list[tuple]:
        return list(itertools.product(*self.levels))


def _levels_of(col: pd.Series) -> list:
    if isinstance(col.dtype, pd.CategoricalDtype):
        present = set(col.dropna().unique())
        return [c for c in col.cat.categories if c in present]
    return sorted(col.dropna().unique(), key=lambda v: (str(type(v)), v))


def _check_columns(data: pd.DataFrame, cols: list[str], what: str = "column") -> None:
    if not isinstance(data, pd.DataFrame):
        raise InputError(f"expected a table (pandas DataFrame), got {type(data).__name__}")
    missing = [c for c in cols if c not in data.columns]
    if missing:
        raise InputError(f"no {what} {', '.join(map(repr, missing))} in the table; its columns "
                         f"are {', '.join(map(str, data.columns))}")
    if len(set(cols)) != len(cols):
        raise InputError(f"a column is named twice among {cols}")


def within_design(data: pd.DataFrame, dv: str, within: list[str] | str, subject: str, *,
                  missing: str = "drop") -> WithinDesign:
    """Cell means per participant; participants lacking a cell dropped or refused.

    Several observations in a cell are averaged (afex's ``fun_aggregate = mean``).
    A participant without an observation in some cell is left out of the analysis
    with a :class:`MissingCellsWarning` naming them (as afex does) when
    ``missing="drop"``, or raises :class:`InputError` when ``missing="error"``.
    Rows whose ``dv`` is missing do not count as observations.
    """
    within = [within] if isinstance(within, str) else list(within)
    if not within:
        raise InputError("give at least one within-participant factor")
    if missing not in ("drop", "error"):
        raise InputError(f"missing must be 'drop' or 'error', not {missing!r}")
    _check_columns(data, [dv, subject, *within])
    y = pd.to_numeric(data[dv], errors="coerce")
    bad = data[dv].notna() & y.isna()
    if bad.any():
        i = bad.idxmax()
        raise InputError(f"column {dv!r} holds a non-numeric value {data[dv][i]!r} "
                         f"(row {i})")
    keep = y.notna()
    for c in [subject, *within]:
        keep &= data[c].notna()
    d = data.loc[keep, [subject, *within]]
    y = y[keep].to_numpy(dtype=float)
    if len(d) == 0:
        raise InputError(f"no observations of {dv!r} to analyse")
    levels = [_levels_of(d[f]) for f in within]
    for f, lv in zip(within, levels):
        if len(lv) < 2:
            raise InputError(f"factor {f!r} has {len(lv)} level(s) in the data; an ANOVA "
                             "needs at least 2")
    subjects = _levels_of(d[subject])
    codes = [pd.Categorical(d[f], categories=lv).codes for f, lv in zip(within, levels)]
    shape = tuple(len(lv) for lv in levels)
    cell = np.ravel_multi_index(codes, shape) if len(codes) > 1 else codes[0]
    subj = pd.Categorical(d[subject], categories=subjects).codes
    n, c = len(subjects), int(np.prod(shape))
    flat = subj.astype(np.int64) * c + cell
    count = np.bincount(flat, minlength=n * c).reshape(n, c)
    total = np.bincount(flat, weights=y, minlength=n * c).reshape(n, c)
    with np.errstate(invalid="ignore", divide="ignore"):
        values = total / count
    incomplete = (count == 0).any(axis=1)
    dropped = [subjects[i] for i in np.flatnonzero(incomplete)]
    if dropped:
        cells = list(itertools.product(*levels))
        detail = "; ".join(
            f"{s}: no {' × '.join(map(str, cells[j]))}"
            + (f" (and {int((count[i] == 0).sum()) - 1} more)" if (count[i] == 0).sum() > 1
               else "")
            for s, i in zip(dropped, np.flatnonzero(incomplete))
            for j in [int(np.flatnonzero(count[i] == 0)[0])])
        if missing == "error":
            raise InputError(f"participant(s) without a value of {dv!r} in every cell of "
                             f"{' × '.join(within)}: {detail}")
        warnings.warn(MissingCellsWarning(
            f"Missing values for following participant(s): {', '.join(map(str, dropped))} "
            f"({detail}). Removing those participants from the analysis."), stacklevel=3)
    values = values[~incomplete]
    subjects = [s for s, bad in zip(subjects, incomplete) if not bad]
    if len(subjects) < 2:
        raise InputError(f"{len(subjects)} participant(s) with a value in every cell; "
                         "a repeated-measures ANOVA needs at least 2")
    return WithinDesign(within, levels, subjects, values, dropped,
                        aggregated=bool((count[~incomplete] > 1).any()))


# --------------------------------------------------------------------------- arithmetic

def _helmert(k: int) -> np.ndarray:
    """k × (k-1) orthonormal contrasts (normalised Helmert), orthogonal to the constant."""
    h = np.zeros((k, k - 1))
    for j in range(1, k):
        h[:j, j - 1] = 1.0
        h[j, j - 1] = -j
        h[:, j - 1] /= np.sqrt(j * (j + 1))
    return h


def effects_of(n_factors: int) -> list[tuple[int, ...]]:
    """Effects in afex's order: main effects, then two-way interactions, ..."""
    return [e for r in range(1, n_factors + 1) for e in itertools.combinations(range(n_factors), r)]


def contrast_matrix(shape: tuple[int, ...], effect: tuple[int, ...]) -> np.ndarray:
    """Orthonormal basis (cells × df) of the effect's subspace of the cell space."""
    m = np.ones((1, 1))
    for f, k in enumerate(shape):
        part = _helmert(k) if f in effect else np.full((k, 1), 1 / np.sqrt(k))
        m = np.kron(m, part)
    return m


def _mauchly(S: np.ndarray, n: np.ndarray | int, cells: int) -> tuple[np.ndarray, np.ndarray]:
    """Mauchly's W and p for SSP matrices ``S`` (..., p, p) with n participants.

    The p value adds Anderson's (1958, §10.7) second-order term to the χ²
    approximation, as ``stats:::mauchly.test.SSD`` and ``car`` do. Both write
    one term of that correction as ``3 * p`` with ``p`` the number of cells of
    the whole design, not the effect's df (Anderson's formula has the df); we
    follow R so that the numbers are the ones R users see. The difference is
    in the second-order term only (under 0.002 in p in the reference designs).
    """
    p = S.shape[-1]
    df = np.asarray(n) - 1.0
    tr = np.trace(S, axis1=-2, axis2=-1)
    sign, logdet = np.linalg.slogdet(S)
    logW = np.where(sign > 0, logdet, -np.inf) - p * np.log(tr / p)
    rho = 1 - (2 * p ** 2 + p + 2) / (6 * p * df)
    w2 = ((p + 2) * (p - 1) * (p - 2) * (2 * p ** 3 + 6 * p ** 2 + 3 * cells + 2)
          / (288 * (df * p * rho) ** 2))
    z = -df * rho * logW
    f = p * (p + 1) / 2 - 1
    pr1 = stats.chi2.sf(z, f)
    pr2 = stats.chi2.sf(z, f + 4)
    return np.exp(logW), pr1 + w2 * (pr2 - pr1)


def anova_arrays(values: np.ndarray, shape: tuple[int, ...]) -> dict[str, np.ndarray]:
    """The ANOVA of one or many datasets given as arrays.

    ``values`` has shape (..., participants, cells); the leading axes index
    datasets. Returns arrays of shape (..., effects) keyed ``SS``, ``SS_error``,
    ``df1``, ``df2``, ``F``, ``p``, ``pes``, ``ges``, ``eps_gg``, ``eps_hf``,
    ``p_gg``, ``p_hf``, ``W``, ``p_mauchly`` (the last two NaN for effects with
    one degree of freedom, where sphericity holds trivially).
    """
    Y = np.asarray(values, dtype=float)
    n = Y.shape[-2]
    c = Y.shape[-1]
    if c != int(np.prod(shape)):
        raise ValueError(f"{c} cells, but the factors' levels {shape} make {int(np.prod(shape))}")
    effects = effects_of(len(shape))
    out = {k: [] for k in ("SS", "SS_error", "df1", "df2", "F", "eps_gg", "eps_hf", "W",
                           "p_mauchly")}
    # Participants' stratum (the intercept's error), for generalised eta squared.
    u = Y.mean(axis=-1) * np.sqrt(c)
    ss_subjects = ((u - u.mean(axis=-1, keepdims=True)) ** 2).sum(axis=-1)
    for e in effects:
        C = contrast_matrix(shape, e)
        p = C.shape[1]
        Z = Y @ C                                     # (..., n, p)
        zbar = Z.mean(axis=-2)                        # (..., p)
        D = Z - zbar[..., None, :]
        S = np.swapaxes(D, -1, -2) @ D                # (..., p, p)
        ss = n * (zbar ** 2).sum(axis=-1)
        sse = np.trace(S, axis1=-2, axis2=-1)
        df1, df2 = float(p), float(p * (n - 1))
        with np.errstate(divide="ignore", invalid="ignore"):
            F = (ss / df1) / (sse / df2)
        if p > 1:
            with np.errstate(divide="ignore", invalid="ignore"):
                gg = sse ** 2 / (p * np.trace(S @ S, axis1=-2, axis2=-1))
                hf = (n * p * gg - 2) / (p * (n - 1 - p * gg))
                W, pm = _mauchly(S, n, c)
            if n - 1 < p:
                # S is singular: Mauchly's test is undefined (R prints W = 0, p = 0)
                W = np.full_like(ss, np.nan)
                pm = np.full_like(ss, np.nan)
        else:
            gg = hf = np.ones_like(ss)
            W = pm = np.full_like(ss, np.nan)
        for k, v in zip(out, (ss, sse, np.full_like(ss, df1), np.full_like(ss, df2), F,
                              gg, hf, W, pm)):
            out[k].append(v)
    res = {k: np.stack(v, axis=-1) for k, v in out.items()}
    F, df1, df2 = res["F"], res["df1"], res["df2"]
    res["p"] = stats.f.sf(F, df1, df2)
    res["p_gg"] = stats.f.sf(F, df1 * res["eps_gg"], df2 * res["eps_gg"])
    hf = np.minimum(res["eps_hf"], 1.0)
    res["p_hf"] = stats.f.sf(F, df1 * hf, df2 * hf)
    with np.errstate(divide="ignore", invalid="ignore"):
        res["pes"] = res["SS"] / (res["SS"] + res["SS_error"])
        all_error = res["SS_error"].sum(axis=-1, keepdims=True) + ss_subjects[..., None]
        res["ges"] = res["SS"] / (res["SS"] + all_error)
    res["MSE"] = res["SS_error"] / df2
    return res


COLUMNS = ["effect", "df1", "df2", "SS", "SS_error", "MSE", "F", "p", "pes", "ges",
           "mauchly_W", "mauchly_p", "eps_gg", "p_gg", "eps_hf", "p_hf", "n"]


def _table(res: dict[str, np.ndarray], factors: list[str], n: int) -> pd.DataFrame:
    names = [":".join(factors[i] for i in e) for e in effects_of(len(factors))]
    t = pd.DataFrame({"effect": names, "df1": res["df1"], "df2": res["df2"], "SS": res["SS"],
                      "SS_error": res["SS_error"], "MSE": res["MSE"], "F": res["F"],
                      "p": res["p"], "pes": res["pes"], "ges": res["ges"],
                      "mauchly_W": res["W"], "mauchly_p": res["p_mauchly"],
                      "eps_gg": res["eps_gg"], "p_gg": res["p_gg"],
                      "eps_hf": res["eps_hf"], "p_hf": res["p_hf"]})
    t["n"] = n
    return t[COLUMNS]


# --------------------------------------------------------------------------- public

def rm_anova(data: pd.DataFrame, dv: str, within: list[str] | str, subject: str, *,
             missing: str = "drop") -> pd.DataFrame:
    """Repeated-measures ANOVA with sphericity tests, corrections and effect sizes.

    Parameters
    ----------
    data : tidy table, one row per observation (several per cell are averaged).
    dv : the dependent variable's column (e.g. ``rate``, or ``correct`` per trial).
    within : the within-participant factors' columns, any number.
    subject : the participant's column.
    missing : ``"drop"`` (default) leaves out participants without a value in
        every cell, with a :class:`MissingCellsWarning` naming them, as
        ``afex::aov_ez`` does; ``"error"`` raises :class:`InputError` instead.

    Returns
    -------
    DataFrame, one row per effect (main effects, then interactions, in afex's
    order): ``df1``, ``df2``, ``SS``, ``SS_error``, ``MSE``, ``F``, ``p``
    (sphericity assumed), ``pes`` (partial η²), ``ges`` (generalised η²),
    ``mauchly_W``, ``mauchly_p`` (NaN for one-df effects, and when there are
    fewer participants than the effect's df + 1, where the test is undefined
    and R prints W = 0, p = 0), ``eps_gg``, ``p_gg``, ``eps_hf`` (uncapped),
    ``p_hf`` (ε capped at 1), ``n`` (participants analysed). ``attrs`` holds
    ``dropped`` (participants left out) and ``levels``.

    References
    ----------
    The method is in the module docstring; the values match ``afex::aov_ez``
    (``anova(fit, es = c("pes", "ges"), correction = ...)`` and
    ``summary(fit)`` for Mauchly's test and ε) to 1e-6, for designs with one,
    two and three factors and with missing cells (``tests/r_reference``).
    Seed 000 §4 reports its 2 × 2 (timing × intensity) results in this form:
    F(1,14) = 9.787, 5.530 and 4.822.
    """
    d = within_design(data, dv, within, subject, missing=missing)
    res = anova_arrays(d.values, d.shape)
    t = _table(res, d.factors, len(d.subjects))
    t.attrs.update(dropped=list(d.dropped), levels=dict(zip(d.factors, d.levels)),
                   dv=dv, subject=subject, aggregated=d.aggregated)
    return t


def rm_anova_batch(data: pd.DataFrame, dv: str, within: list[str] | str, subject: str,
                   dataset: str, *, missing: str = "drop") -> pd.DataFrame:
    """:func:`rm_anova` of many datasets at once (e.g. simulated studies for power).

    ``data`` stacks the datasets in one tidy table told apart by the ``dataset``
    column. The datasets are reshaped together and analysed in one vectorised
    pass; the numbers are those :func:`rm_anova` gives for each dataset alone.
    Returns the ANOVA tables stacked, with the ``dataset`` column first.
    Participants with missing cells are dropped per dataset (one warning for all).
    """
    within = [within] if isinstance(within, str) else list(within)
    _check_columns(data, [dataset, dv, subject, *within])
    if missing not in ("drop", "error"):
        raise InputError(f"missing must be 'drop' or 'error', not {missing!r}")
    y = pd.to_numeric(data[dv], errors="coerce").to_numpy(dtype=float)
    keep = ~np.isnan(y)
    for col in [dataset, subject, *within]:
        keep &= data[col].notna().to_numpy()
    sets, set_code = np.unique(data[dataset].to_numpy()[keep], return_inverse=True)
    levels = [_levels_of(data.loc[keep, f]) for f in within]
    shape = tuple(len(lv) for lv in levels)
    if any(k < 2 for k in shape):
        raise InputError(f"every factor needs at least 2 levels; got {dict(zip(within, shape))}")
    c = int(np.prod(shape))
    codes = [pd.Categorical(data.loc[keep, f], categories=lv).codes
             for f, lv in zip(within, levels)]
    cell = np.ravel_multi_index(codes, shape)
    # participants numbered within their dataset
    pair = pd.MultiIndex.from_arrays([set_code, data.loc[keep, subject].to_numpy()])
    pair_code, pairs = pd.factorize(pair, sort=True)
    pair_set = pairs.get_level_values(0).to_numpy()
    n_pairs = len(pairs)
    flat = pair_code.astype(np.int64) * c + cell
    count = np.bincount(flat, minlength=n_pairs * c).reshape(n_pairs, c)
    total = np.bincount(flat, weights=y[keep], minlength=n_pairs * c).reshape(n_pairs, c)
    complete = (count > 0).all(axis=1)
    if not complete.all():
        bad = [(sets[pair_set[i]], pairs[i][1]) for i in np.flatnonzero(~complete)]
        msg = (f"{len(bad)} participant(s) without a value in every cell, e.g. "
               + ", ".join(f"{s}/{p}" for s, p in bad[:5]))
        if missing == "error":
            raise InputError(msg)
        warnings.warn(MissingCellsWarning(msg + "; removed from their dataset's analysis"),
                      stacklevel=2)
    values = total[complete] / count[complete]
    owner = pair_set[complete]
    n_per = np.bincount(owner, minlength=len(sets))
    tables = []
    names = [":".join(within[i] for i in e) for e in effects_of(len(within))]
    order = np.argsort(owner, kind="stable")
    values, owner = values[order], owner[order]
    start = np.concatenate([[0], np.cumsum(n_per)])
    for n in np.unique(n_per):
        idx = np.flatnonzero(n_per == n)
        if n < 2:
            raise InputError(f"dataset(s) {', '.join(map(str, sets[idx][:5]))} have fewer "
                             "than 2 complete participants")
        rows = (start[idx][:, None] + np.arange(n)[None, :]).ravel()
        Y = values[rows].reshape(len(idx), n, c)
        res = anova_arrays(Y, shape)
        k = len(names)
        t = pd.DataFrame({key: res[key].ravel() for key in
                          ("df1", "df2", "SS", "SS_error", "MSE", "F", "p", "pes", "ges", "W",
                           "p_mauchly", "eps_gg", "p_gg", "eps_hf", "p_hf")})
        t.insert(0, "effect", np.tile(names, len(idx)))
        t.insert(0, dataset, np.repeat(sets[idx], k))
        t["n"] = n
        tables.append(t)
    out = pd.concat(tables, ignore_index=True).rename(
        columns={"W": "mauchly_W", "p_mauchly": "mauchly_p"})
    out["_o"] = out[dataset].map({s: i for i, s in enumerate(sets)})
    out["_e"] = out["effect"].map({e: i for i, e in enumerate(names)})
    out = out.sort_values(["_o", "_e"]).drop(columns=["_o", "_e"]).reset_index(drop=True)
    return out[[dataset, *COLUMNS]]


def simple_effects(data: pd.DataFrame, dv: str, within: list[str] | str, subject: str, *,
                   effect: str | list[str], by: str | list[str], method: str = "separate",
                   missing: str = "drop") -> pd.DataFrame:
    """Simple effects of ``effect`` at each level (combination) of ``by``.

    Factors in ``within`` that are neither ``effect`` nor ``by`` are averaged over.

    ``method="separate"``
        A repeated-measures ANOVA of ``effect`` on the data of each level of
        ``by`` alone, with that level's own error term (its df are those of a
        one-way ANOVA, n - 1 per effect df), sphericity tests and corrections.
        This is the convention of seed 000 Table 3 (F(1,14) = 0.21 at A1 and
        12.04 at A2 from 15 participants), and what ``afex::aov_ez`` gives on
        each subset.
    ``method="pooled"``
        One model for all the data: the simple effect's contrasts are tested
        against the error terms of the full ANOVA's strata (participant ×
        effect, participant × effect × by-factors) in the proportions that the
        contrasts span them, with Satterthwaite's (1946) degrees of freedom.
        These are the numbers of ``emmeans::joint_tests(fit, by = ...)`` on an
        ``afex::aov_ez(..., include_aov = TRUE)`` fit with
        ``afex_options(emmeans_model = "univariate")``; for balanced data the
        pooled mean square equals Kirk's (1995) pooled error, but the df are
        Satterthwaite's rather than the summed error df.

    Returns one row per level (combination) of ``by`` and effect term:
    ``method``, the ``by`` columns, ``effect``, ``df1``, ``df2``, ``F``, ``p``,
    and for ``separate`` also ``pes``, ``ges``, ``eps_gg``, ``p_gg``, ``eps_hf``,
    ``p_hf``, ``mauchly_W``, ``mauchly_p``; ``n`` is the participants analysed.
    """
    within = [within] if isinstance(within, str) else list(within)
    eff = [effect] if isinstance(effect, str) else list(effect)
    by = [by] if isinstance(by, str) else list(by)
    for f in eff + by:
        if f not in within:
            raise InputError(f"{f!r} is not one of the within factors {within}")
    if set(eff) & set(by):
        raise InputError(f"a factor cannot be both the effect and the 'by' factor: "
                         f"{sorted(set(eff) & set(by))}")
    if method not in ("separate", "pooled"):
        raise InputError(f"method must be 'separate' or 'pooled', not {method!r}")
    _check_columns(data, [dv, subject, *within])
    by_level_lists = [_levels_of(data[f]) for f in by]
    by_levels = list(itertools.product(*by_level_lists))
    rows = []
    dropped: list = []
    if method == "separate":
        # Each level of `by` alone, as afex::aov_ez on the subset: the other factors
        # are averaged over their observations, and a participant is dropped only if
        # they lack a cell of this level.
        for combo in by_levels:
            mask = np.ones(len(data), dtype=bool)
            for f, lv in zip(by, combo):
                mask &= (data[f] == lv).to_numpy()
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", MissingCellsWarning)
                sub = within_design(data[mask], dv, eff, subject, missing=missing)
            for w in caught:
                warnings.warn(MissingCellsWarning(
                    f"at {', '.join(f'{f} = {v}' for f, v in zip(by, combo))}: {w.message}"),
                    stacklevel=2)
            t = _table(anova_arrays(sub.values, sub.shape), eff, len(sub.subjects))
            for f, lv in zip(by, combo):
                t.insert(0, f, lv)
            rows.append(t)
        out = pd.concat(rows, ignore_index=True)
        out.insert(0, "method", "separate")
        cols = ["method", *by, "effect", "df1", "df2", "F", "p", "pes", "ges", "mauchly_W",
                "mauchly_p", "eps_gg", "p_gg", "eps_hf", "p_hf", "n"]
        out = out[cols]
    else:
        design = within_design(data, dv, within, subject, missing=missing)
        dropped = list(design.dropped)
        shape = design.shape
        pos = {f: i for i, f in enumerate(design.factors)}
        n = len(design.subjects)
        res = anova_arrays(design.values, shape)
        effects = effects_of(len(shape))
        mse = dict(zip(effects, res["SS_error"] / res["df2"]))
        dfe = dict(zip(effects, res["df2"]))
        eff_idx = tuple(sorted(pos[f] for f in eff))
        by_idx = [pos[f] for f in by]
        means = design.values.mean(axis=0)
        # every term made of the effect's factors (A, B, A:B for effect [A, B])
        terms = [t for r in range(1, len(eff_idx) + 1)
                 for t in itertools.combinations(eff_idx, r)]
        for combo in by_levels:
            for term in terms:
                L = np.ones((1, 1))
                for f, k in enumerate(shape):
                    if f in term:
                        part = _helmert(k)
                    elif f in by_idx:
                        part = np.zeros((k, 1))
                        part[design.levels[f].index(combo[by_idx.index(f)]), 0] = 1.0
                    else:
                        part = np.full((k, 1), 1.0 / k)
                    L = np.kron(L, part)
                theta = means @ L
                # Var(theta_i) = (1/n) sum over strata s ⊇ term, s ⊆ term ∪ by, of
                # MSE_s * prod_{f in s∩by}(1-1/k_f) * prod_{f in by\s}(1/k_f) * prod_{rest}(1/k_f)
                parts = []
                for r in range(0, len(by_idx) + 1):
                    for extra in itertools.combinations(by_idx, r):
                        s = tuple(sorted(term + extra))
                        w = 1.0
                        for f, k in enumerate(shape):
                            if f in term:
                                continue
                            if f in extra:
                                w *= 1 - 1 / k
                            elif f in by_idx:
                                w *= 1 / k
                            else:
                                w *= 1 / k          # averaged over: (1/k)1'(J/k)1(1/k) = 1/k
                        parts.append((w * mse[s], dfe[s]))
                v = sum(p for p, _ in parts)
                df2 = v ** 2 / sum(p ** 2 / d for p, d in parts)
                df1 = L.shape[1]
                F = float(n * (theta ** 2).sum() / (df1 * v))
                row = {"method": "pooled", **dict(zip(by, combo)),
                       "effect": ":".join(design.factors[i] for i in term),
                       "df1": float(df1), "df2": df2, "F": F,
                       "p": float(stats.f.sf(F, df1, df2)), "n": n}
                rows.append(row)
        out = pd.DataFrame(rows)
    for f, lv in zip(by, by_level_lists):
        out[f] = pd.Categorical(out[f], categories=lv)
    out.attrs.update(dropped=dropped, dv=dv)
    return out
