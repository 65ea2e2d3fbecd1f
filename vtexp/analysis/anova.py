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
from .effect_sizes import ETA2P_CI_LEVEL, eta2p_ci

__all__ = ["MissingCellsWarning", "WithinDesign", "within_design", "rm_anova",
           "rm_anova_batch", "simple_effects", "anova_arrays", "mixed_anova_arrays"]


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
    between: list[str] = field(default_factory=list)
    between_levels: list[list] = field(default_factory=list)
    group: np.ndarray | None = None     # each participant's between cell (product order)

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(len(lv) for lv in self.levels)

    @property
    def between_shape(self) -> tuple[int, ...]:
        return tuple(len(lv) for lv in self.between_levels)

    @property
    def groups(self) -> np.ndarray:
        return np.zeros(len(self.subjects), dtype=np.int64) if self.group is None else self.group

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


def _as_list(v) -> list:
    return [] if v is None else ([v] if isinstance(v, str) else list(v))


def participant_groups(data: pd.DataFrame, subject: str, between: list[str]) -> pd.DataFrame:
    """Each participant's level of every between-participant factor (one row each).

    A between factor is a property of the participant (their group), so it must
    be the same on all of a participant's rows; a participant whose rows
    disagree, or who has no value, is refused with :class:`InputError` naming
    them.
    """
    _check_columns(data, [subject, *between])
    d = data[[subject, *between]].dropna(subset=[subject])
    rows = []
    for s, g in d.groupby(subject, sort=True, observed=True):
        row = {subject: s}
        for f in between:
            vals = g[f].dropna().unique()
            if len(vals) == 0:
                raise InputError(f"participant {s} has no value of the between-participant "
                                 f"factor {f!r}")
            if len(vals) > 1:
                raise InputError(f"participant {s} has more than one value of the "
                                 f"between-participant factor {f!r} "
                                 f"({', '.join(map(str, vals[:3]))}); a group is the same on "
                                 "all of a participant's rows")
            row[f] = vals[0]
        rows.append(row)
    return pd.DataFrame(rows, columns=[subject, *between])


def within_design(data: pd.DataFrame, dv: str, within: list[str] | str, subject: str, *,
                  missing: str = "drop", between: list[str] | str | None = None
                  ) -> WithinDesign:
    """Cell means per participant; participants lacking a cell dropped or refused.

    Several observations in a cell are averaged (afex's ``fun_aggregate = mean``).
    A participant without an observation in some cell is left out of the analysis
    with a :class:`MissingCellsWarning` naming them (as afex does) when
    ``missing="drop"``, or raises :class:`InputError` when ``missing="error"``.
    Rows whose ``dv`` is missing do not count as observations: a participant
    whose only rows in a cell have a missing value lacks that cell, and is
    dropped (afex's rule) with the warning saying so.

    ``between`` names between-participant factors (columns constant within a
    participant, see :func:`participant_groups`); every combination of their
    levels must hold at least one participant, since type 3 tests are
    undefined with an empty group.
    """
    within = _as_list(within)
    between = _as_list(between)
    if not within and not between:
        raise InputError("give at least one within- or between-participant factor")
    if set(within) & set(between):
        raise InputError(f"a factor cannot be both within and between participants: "
                         f"{sorted(set(within) & set(between))}")
    if missing not in ("drop", "error"):
        raise InputError(f"missing must be 'drop' or 'error', not {missing!r}")
    _check_columns(data, [dv, subject, *within, *between])
    groups = participant_groups(data, subject, between) if between else None
    y = pd.to_numeric(data[dv], errors="coerce")
    bad = data[dv].notna() & y.isna()
    if bad.any():
        i = bad.idxmax()
        raise InputError(f"column {dv!r} holds a non-numeric value {data[dv][i]!r} "
                         f"(row {i})")
    infinite = np.isinf(y.to_numpy(dtype=float))
    if infinite.any():
        i = y.index[int(np.argmax(infinite))]
        raise InputError(f"column {dv!r} holds an infinite value {data[dv][i]!r} (row {i}); "
                         "a mean with it is not a number")
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
    if not codes:
        cell = np.zeros(len(d), dtype=np.int64)
    else:
        cell = np.ravel_multi_index(codes, shape) if len(codes) > 1 else codes[0]
    subj = pd.Categorical(d[subject], categories=subjects).codes
    n, c = len(subjects), int(np.prod(shape))
    flat = subj.astype(np.int64) * c + cell
    count = np.bincount(flat, minlength=n * c).reshape(n, c)
    total = np.bincount(flat, weights=y, minlength=n * c).reshape(n, c)
    # Rows with the participant and the cell but no value: afex averages a cell with
    # mean(), so one missing value makes the cell's mean missing and the participant
    # is dropped. Follow it, and say which value.
    nan_rows = data[[subject, *within]].notna().all(axis=1) & data[dv].isna()
    nan_count = np.zeros((n, c), dtype=np.int64)
    if nan_rows.any():
        nd = data.loc[nan_rows]
        ns = pd.Categorical(nd[subject], categories=subjects).codes
        ncodes = [pd.Categorical(nd[f], categories=lv).codes for f, lv in zip(within, levels)]
        ok = (ns >= 0) & np.all([nc >= 0 for nc in ncodes], axis=0) if ncodes else ns >= 0
        if not ncodes:
            ncell = np.zeros(len(nd), dtype=np.int64)
        else:
            ncell = np.ravel_multi_index([nc.clip(0) for nc in ncodes], shape)
        nflat = ns.astype(np.int64).clip(0) * c + ncell
        nan_count = np.bincount(nflat[ok], minlength=n * c).reshape(n, c)
    with np.errstate(invalid="ignore", divide="ignore"):
        values = total / count
    lacking = (count == 0) | (nan_count > 0)
    incomplete = lacking.any(axis=1)
    dropped = [subjects[i] for i in np.flatnonzero(incomplete)]
    if dropped:
        cells = list(itertools.product(*levels))

        def why(i: int, j: int) -> str:
            name = " × ".join(map(str, cells[j])) or "their data"
            if count[i, j] == 0 and nan_count[i, j] == 0:
                return f"no {name}"
            return (f"a missing value of {dv!r} in {name}, so the cell's mean is missing "
                    f"(afex's rule)")
        detail = "; ".join(
            f"{s}: {why(i, j)}"
            + (f" (and {int(lacking[i].sum()) - 1} more)" if lacking[i].sum() > 1 else "")
            for s, i in zip(dropped, np.flatnonzero(incomplete))
            for j in [int(np.flatnonzero(lacking[i])[0])])
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
    out = WithinDesign(within, levels, subjects, values, dropped,
                       aggregated=bool((count[~incomplete] > 1).any()))
    if between:
        gt = groups.set_index(subject).loc[subjects]
        blevels = [_levels_of(gt[f]) for f in between]
        for f, lv in zip(between, blevels):
            if len(lv) < 2:
                raise InputError(f"between-participant factor {f!r} has {len(lv)} level(s) "
                                 "among the participants analysed; it needs at least 2")
        bcodes = [pd.Categorical(gt[f], categories=lv).codes for f, lv in zip(between, blevels)]
        bshape = tuple(len(lv) for lv in blevels)
        group = np.ravel_multi_index(bcodes, bshape).astype(np.int64)
        sizes = np.bincount(group, minlength=int(np.prod(bshape)))
        if (sizes == 0).any():
            empty = [" × ".join(map(str, c)) for c, k in
                     zip(itertools.product(*blevels), sizes) if k == 0]
            raise InputError(f"no participant in the group(s) {', '.join(empty)} of "
                             f"{' × '.join(between)}; type 3 tests need every group")
        if len(subjects) - len(sizes) < 1:
            raise InputError(f"{len(subjects)} participants in {len(sizes)} groups leave no "
                             "degrees of freedom for the error; each group needs more")
        out.between, out.between_levels, out.group = between, blevels, group
    return out


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
    res = _p_values({k: np.stack(v, axis=-1) for k, v in out.items()})
    df2 = res["df2"]
    with np.errstate(divide="ignore", invalid="ignore"):
        all_error = res["SS_error"].sum(axis=-1, keepdims=True) + ss_subjects[..., None]
        res["ges"] = res["SS"] / (res["SS"] + all_error)
    res["MSE"] = res["SS_error"] / df2
    return res


def _p_values(res: dict) -> dict:
    """Add to a table of F tests (``F``, ``df1``, ``df2``, ``eps_gg``, ``eps_hf``, ``SS``,
    ``SS_error``) the uncorrected, Greenhouse–Geisser and Huynh–Feldt p values (the
    Huynh–Feldt ε capped at 1) and partial η² = SS / (SS + SS_error)."""
    F, df1, df2 = res["F"], res["df1"], res["df2"]
    res["p"] = stats.f.sf(F, df1, df2)
    res["p_gg"] = stats.f.sf(F, df1 * res["eps_gg"], df2 * res["eps_gg"])
    hf = np.minimum(res["eps_hf"], 1.0)
    res["p_hf"] = stats.f.sf(F, df1 * hf, df2 * hf)
    with np.errstate(divide="ignore", invalid="ignore"):
        res["pes"] = res["SS"] / (res["SS"] + res["SS_error"])
    return res


def _between_contrast(bshape: tuple[int, ...], term: tuple[int, ...]) -> np.ndarray:
    """Groups × q matrix: Helmert contrasts for the term's factors, unweighted means else."""
    m = np.ones((1, 1))
    for f, k in enumerate(bshape):
        part = _helmert(k) if f in term else np.full((k, 1), 1.0 / k)
        m = np.kron(m, part)
    return m


def mixed_terms(n_between: int, n_within: int) -> list[tuple[tuple[int, ...], tuple[int, ...]]]:
    """(between term, within term) of every effect, in car's and afex's order.

    For each within term (none first: the between-participant stratum), every
    between term (none first); the term with neither (the intercept) is left out.
    """
    bt = [()] + effects_of(n_between)
    wt = [()] + effects_of(n_within)
    return [(b, w) for w in wt for b in bt if b or w]


def mixed_anova_arrays(values: np.ndarray, shape: tuple[int, ...], group: np.ndarray,
                       bshape: tuple[int, ...]) -> dict[str, np.ndarray]:
    """The mixed ANOVA (between and within factors) of one dataset, type 3 sums of squares.

    ``values`` is participants × within cells (one column if there is no within
    factor), ``group`` each participant's between cell (the between factors'
    levels in product order) and ``bshape`` the between factors' numbers of
    levels. This is ``car::Anova(mlm, type = 3, idata, idesign)`` as
    ``afex::aov_ez`` calls it, written with orthonormal contrasts:

    - for each within term ``W`` (none = the participants' mean, ``1/sqrt(c)``),
      ``Z = Y C_W``; the group means ``M`` (groups × p) and the pooled
      within-group SSP ``E = Σ (Z_i − M_g(i))ᵀ (Z_i − M_g(i))`` on ``N − G``
      degrees of freedom are the multivariate linear model's;
    - for each between term ``B`` the type 3 hypothesis is that the contrasts
      ``K_B`` (Helmert for B's factors, unweighted means over the others) of the
      group means vanish: ``H = (K_Bᵀ M)ᵀ (K_Bᵀ D⁻¹ K_B)⁻¹ (K_Bᵀ M)``, ``D`` the
      group sizes. With sum-to-zero coding this is the hypothesis of
      ``contr.sum`` that afex sets, for balanced and unbalanced groups alike;
    - ``SS = tr H``, ``SS_error = tr E``, ``F = (SS/(p q)) / (SS_error/(p (N−G)))``;
      GG and HF ε and Mauchly's test from ``E`` with ``N − G`` error df (car's
      ``GG``, ``HF`` and ``mauchly`` with ``error.df``).

    Returns arrays (one value per effect of :func:`mixed_terms`) keyed as
    :func:`anova_arrays`, plus ``stratum`` (the within term's index, for
    generalised η²) and ``terms``.
    """
    Y = np.asarray(values, dtype=float)
    n, c = Y.shape
    if c != int(np.prod(shape)):
        raise ValueError(f"{c} cells, but the factors' levels {shape} make {int(np.prod(shape))}")
    G = int(np.prod(bshape))
    sizes = np.bincount(group, minlength=G).astype(float)
    dfe = float(n - G)
    onehot = np.zeros((n, G))
    onehot[np.arange(n), group] = 1.0
    terms = mixed_terms(len(bshape), len(shape))
    wterms = [()] + effects_of(len(shape))
    keys = ("SS", "SS_error", "df1", "df2", "F", "eps_gg", "eps_hf", "W", "p_mauchly",
            "stratum")
    out = {k: [] for k in keys}
    per_w = {}
    for wi, w in enumerate(wterms):
        C = contrast_matrix(shape, w) if w else np.full((c, 1), 1 / np.sqrt(c))
        Z = Y @ C
        M = (onehot.T @ Z) / sizes[:, None]
        D = Z - M[group]
        E = D.T @ D
        p = C.shape[1]
        sse = float(np.trace(E))
        if p > 1:
            with np.errstate(divide="ignore", invalid="ignore"):
                gg = sse ** 2 / (p * np.trace(E @ E))
                hf = ((dfe + 1) * p * gg - 2) / (p * (dfe - p * gg))
            if dfe < p:
                Wm = pm = np.nan
            else:
                Wm, pm = _mauchly(E, dfe + 1, c)
                Wm, pm = float(Wm), float(pm)
        else:
            gg = hf = 1.0
            Wm = pm = np.nan
        per_w[w] = (M, sse, p, gg, hf, Wm, pm, wi)
    for b, w in terms:
        M, sse, p, gg, hf, Wm, pm, wi = per_w[w]
        K = _between_contrast(bshape, b)
        theta = K.T @ M                                   # q × p
        V = K.T @ (K / sizes[:, None])                    # q × q
        H = theta.T @ np.linalg.solve(V, theta)
        q = K.shape[1]
        ss = float(np.trace(H))
        df1, df2 = float(p * q), float(p * dfe)
        with np.errstate(divide="ignore", invalid="ignore"):
            F = (ss / df1) / (sse / df2)
        for k, v in zip(keys, (ss, sse, df1, df2, F, gg, hf, Wm, pm, wi)):
            out[k].append(v)
    res = _p_values({k: np.asarray(v, dtype=float) for k, v in out.items()})
    df2 = res["df2"]
    # every stratum's error once: the participants' (within term none) and one per within term
    res["SS_strata"] = np.array([per_w[w][1] for w in wterms])
    res["MSE"] = res["SS_error"] / df2
    res["terms"] = terms
    return res


@dataclass
class PooledModel:
    """The univariate (sphericity-assuming) model of a design, as emmeans sees afex's fit.

    Cell means ``M`` (groups × within cells), group sizes, and per stratum (the
    participants' one and one per within term) the projector ``C Cᵀ`` onto its
    contrasts, its mean square and its df. Linear functions of the cell means are
    estimated with :meth:`estimate`.
    """

    M: np.ndarray
    sizes: np.ndarray
    strata: list[tuple[np.ndarray, float, float]]

    @classmethod
    def of(cls, d: WithinDesign) -> "PooledModel":
        Y = d.values
        n, c = Y.shape
        group = d.groups
        G = int(np.prod(d.between_shape)) if d.between else 1
        sizes = np.bincount(group, minlength=G).astype(float)
        onehot = np.zeros((n, G))
        onehot[np.arange(n), group] = 1.0
        M = (onehot.T @ Y) / sizes[:, None]
        dfe = float(n - G)
        strata = []
        for w in [()] + effects_of(len(d.shape)):
            C = contrast_matrix(d.shape, w) if w else np.full((c, 1), 1 / np.sqrt(c))
            Z = Y @ C
            D = Z - ((onehot.T @ Z) / sizes[:, None])[group]
            p = C.shape[1]
            strata.append((C @ C.T, float((D ** 2).sum()) / (p * dfe), p * dfe))
        return cls(M, sizes, strata)

    def estimate(self, L: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
        """Estimates ``Lᵀ vec(M)``, their covariance, and each stratum's share of it.

        ``L`` has a row per (group, within cell), groups slowest, and a column
        per linear function. Under the univariate model the cell means'
        covariance is ``Σ_strata MSE_s Σ_g L_gᵀ P_s L_g / n_g`` (Searle 1971,
        §5; what ``emmeans`` computes for an ``aovlist`` fit).
        """
        G, c = self.M.shape
        Lg = L.reshape(G, c, -1)
        theta = np.einsum("gj,gjr->r", self.M, Lg)
        parts = []
        for P, mse, _ in self.strata:
            A = np.einsum("gjr,jk,gks,g->rs", Lg, P, Lg, 1 / self.sizes)
            parts.append(mse * A)
        return theta, sum(parts), parts

    def satterthwaite(self, l: np.ndarray) -> tuple[float, float]:
        """Variance of one linear function and its Satterthwaite (1946) df."""
        _, V, parts = self.estimate(l[:, None])
        terms = [(float(pv[0, 0]), s[2]) for pv, s in zip(parts, self.strata)]
        v = float(V[0, 0])
        den = sum(t ** 2 / df for t, df in terms if t > 0)
        return v, (v ** 2 / den if den > 0 else np.nan)

    def joint_test(self, L: np.ndarray) -> dict[str, float]:
        """F test that every column of ``L`` is zero (emmeans' joint test).

        The df of the denominator is the smallest Satterthwaite df of an
        orthonormal basis of the functions, as ``emmeans::test(joint = TRUE)``.
        """
        Q, R = np.linalg.qr(L)
        r = int(np.linalg.matrix_rank(L))
        Q = Q[:, :r]
        theta, V, _ = self.estimate(Q)
        F = float(theta @ np.linalg.solve(V, theta)) / r
        df2 = min(self.satterthwaite(Q[:, i])[1] for i in range(r))
        return {"df1": float(r), "df2": df2, "F": F, "p": float(stats.f.sf(F, r, df2))}


def grid_function(d: WithinDesign, parts: dict[str, np.ndarray]) -> np.ndarray:
    """A matrix of linear functions of the cell means from one matrix per factor.

    ``parts`` maps a factor (between or within) to its levels × columns matrix;
    a factor not named is averaged over (``1/k``). The result has a row per
    (group, within cell) and the Kronecker product of the parts' columns.
    """
    Lb = np.ones((1, 1))
    for f, lv in zip(d.between, d.between_levels):
        Lb = np.kron(Lb, parts.get(f, np.full((len(lv), 1), 1 / len(lv))))
    Lw = np.ones((1, 1))
    for f, lv in zip(d.factors, d.levels):
        Lw = np.kron(Lw, parts.get(f, np.full((len(lv), 1), 1 / len(lv))))
    return np.kron(Lb, Lw)


def generalised_eta_squared(ss: np.ndarray, ss_strata_total: float,
                            observed: np.ndarray) -> np.ndarray:
    """η²G (Olejnik & Algina 2003, Table 2; Bakeman 2005) as ``afex`` computes it.

    ``SS / (SS + Σ SS_error of every stratum + Σ SS of the effects that involve
    an observed (measured, not manipulated) factor − the effect's own SS if it is
    one of them)``; ``observed`` flags those effects.
    """
    ss = np.asarray(ss, dtype=float)
    obs = np.asarray(observed, dtype=bool)
    obs_total = float(ss[obs].sum())
    with np.errstate(divide="ignore", invalid="ignore"):
        return ss / (ss + ss_strata_total + obs_total - ss * obs)


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

def _mixed_table(d: WithinDesign, observed: list[str]) -> pd.DataFrame:
    res = mixed_anova_arrays(d.values, d.shape, d.groups, d.between_shape)
    names = [":".join([d.between[i] for i in b] + [d.factors[i] for i in w])
             for b, w in res["terms"]]
    obs = np.array([any(f in name.split(":") for f in observed) for name in names])
    ges = generalised_eta_squared(res["SS"], float(res["SS_strata"].sum()), obs)
    t = pd.DataFrame({"effect": names, "df1": res["df1"], "df2": res["df2"], "SS": res["SS"],
                      "SS_error": res["SS_error"], "MSE": res["MSE"], "F": res["F"],
                      "p": res["p"], "pes": res["pes"], "ges": ges,
                      "mauchly_W": res["W"], "mauchly_p": res["p_mauchly"],
                      "eps_gg": res["eps_gg"], "p_gg": res["p_gg"],
                      "eps_hf": res["eps_hf"], "p_hf": res["p_hf"]})
    t["n"] = len(d.subjects)
    return t[COLUMNS]


def _rounding_to_zero(t: pd.DataFrame, scale: float) -> None:
    """Sums of squares that are rounding noise (< 1e-12 of Σy²) are 0, and what follows.

    A measure that does not vary gives SS = 1e-31 rather than 0; its F would be
    a number made of rounding. With the zeros exact, F is NaN (0/0: not
    applicable) or infinite (no error variance), and the report says so.
    """
    tiny = 1e-12 * max(scale, np.finfo(float).tiny)
    for col in ("SS", "SS_error"):
        t.loc[t[col].abs() < tiny, col] = 0.0
    zero_err = t["SS_error"] == 0
    if zero_err.any():
        with np.errstate(divide="ignore", invalid="ignore"):
            F = (t["SS"] / t["df1"]) / (t["SS_error"] / t["df2"])
            t.loc[zero_err, "F"] = F[zero_err]
            t.loc[zero_err, "MSE"] = 0.0
            t.loc[zero_err, "pes"] = (t["SS"] / (t["SS"] + t["SS_error"]))[zero_err]
        for c in ("p", "p_gg", "p_hf"):
            t.loc[zero_err, c] = np.where(np.isnan(t.loc[zero_err, "F"]), np.nan, 0.0)
        for c in ("eps_gg", "eps_hf", "mauchly_W", "mauchly_p"):
            t.loc[zero_err & (t["df1"] > 1), c] = np.nan
        t.loc[zero_err & (t["SS"] == 0), "ges"] = np.nan


def _with_pes_interval(t: pd.DataFrame) -> None:
    """Insert ``pes_ci90_low``/``pes_ci90_high`` after ``pes``: the 90 % interval of
    partial η² on the table's (sphericity-assumed) df (:func:`.effect_sizes.eta2p_ci`)."""
    lims = [eta2p_ci(F, d1, d2, ETA2P_CI_LEVEL) for F, d1, d2 in
            zip(t["F"].to_numpy(float), t["df1"].to_numpy(float), t["df2"].to_numpy(float))]
    at = t.columns.get_loc("pes") + 1
    t.insert(at, "pes_ci90_low", [lo for lo, _ in lims])
    t.insert(at + 1, "pes_ci90_high", [hi for _, hi in lims])


def rm_anova(data: pd.DataFrame, dv: str, within: list[str] | str | None, subject: str, *,
             between: list[str] | str | None = None, observed: list[str] | str | None = None,
             missing: str = "drop") -> pd.DataFrame:
    """Repeated-measures or mixed ANOVA with sphericity tests, corrections and effect sizes.

    Parameters
    ----------
    data : tidy table, one row per observation (several per cell are averaged).
    dv : the dependent variable's column (e.g. ``rate``, or ``correct`` per trial).
    within : the within-participant factors' columns, any number (none for a
        between-participants ANOVA).
    subject : the participant's column.
    between : between-participant factors' columns (groups: blind vs sighted,
        trained vs untrained), any number; a participant's rows must agree on
        them. With groups the tests are type 3 (sum-to-zero contrasts), as
        ``afex::aov_ez(..., between = ...)`` gives, for equal and unequal
        group sizes; see :func:`mixed_anova_arrays`.
    observed : factors that were measured rather than manipulated (e.g. age
        group); they change generalised η² only (afex's ``observed``).
    missing : ``"drop"`` (default) leaves out participants without a value in
        every cell, with a :class:`MissingCellsWarning` naming them, as
        ``afex::aov_ez`` does; ``"error"`` raises :class:`InputError` instead.

    Returns
    -------
    DataFrame, one row per effect (main effects, then interactions, in afex's
    order): ``df1``, ``df2``, ``SS``, ``SS_error``, ``MSE``, ``F``, ``p``
    (sphericity assumed), ``pes`` (partial η²), ``pes_ci90_low`` and
    ``pes_ci90_high`` (its two-sided 90 % interval from the noncentral F on
    ``df1``, ``df2``, :func:`.effect_sizes.eta2p_ci`; NaN where F is
    undefined or infinite), ``ges`` (generalised η²),
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
    between = _as_list(between)
    observed = _as_list(observed)
    for f in observed:
        if f not in _as_list(within) + between:
            raise InputError(f"observed factor {f!r} is not one of the factors "
                             f"{_as_list(within) + between}")
    d = within_design(data, dv, within, subject, missing=missing, between=between)
    if between or observed:
        t = _mixed_table(d, observed)
    else:
        res = anova_arrays(d.values, d.shape)
        t = _table(res, d.factors, len(d.subjects))
    _rounding_to_zero(t, float((d.values ** 2).sum()))
    _with_pes_interval(t)
    t.attrs.update(dropped=list(d.dropped), dv=dv, subject=subject, aggregated=d.aggregated,
                   levels=dict(zip(d.between + d.factors, d.between_levels + d.levels)),
                   between=list(d.between), observed=observed,
                   group_sizes={" × ".join(map(str, c)): int(k) for c, k in zip(
                       itertools.product(*d.between_levels),
                       np.bincount(d.groups, minlength=int(np.prod(d.between_shape))))})
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


def simple_effects(data: pd.DataFrame, dv: str, within: list[str] | str | None, subject: str, *,
                   effect: str | list[str], by: str | list[str], method: str = "separate",
                   between: list[str] | str | None = None,
                   missing: str = "drop") -> pd.DataFrame:
    """Simple effects of ``effect`` at each level (combination) of ``by``.

    ``effect`` and ``by`` may be within- or between-participant factors (the
    effect of group at each SOA, or of SOA in each group). Factors that are
    neither ``effect`` nor ``by`` are averaged over.

    ``method="separate"``
        An ANOVA of ``effect`` on the data of each level of ``by`` alone, with
        that level's own error term (its df are those of a one-way ANOVA, n - 1
        per effect df for a within effect, n − groups for a between one),
        sphericity tests and corrections. This is the convention of seed 000
        Table 3 (F(1,14) = 0.21 at A1 and 12.04 at A2 from 15 participants),
        and what ``afex::aov_ez`` gives on each subset.
    ``method="pooled"``
        One model for all the data: the simple effect's contrasts are tested
        against the error terms of the full ANOVA's strata in the proportions
        that the contrasts span them (:class:`PooledModel`), with
        Satterthwaite's (1946) degrees of freedom. These are the numbers of
        ``emmeans::joint_tests(fit, by = ...)`` on an ``afex::aov_ez(...,
        include_aov = TRUE)`` fit with ``afex_options(emmeans_model =
        "univariate")``; for balanced within designs the pooled mean square
        equals Kirk's (1995) pooled error, but the df are Satterthwaite's
        rather than the summed error df.

    Returns one row per level (combination) of ``by`` and effect term:
    ``method``, the ``by`` columns, ``effect``, ``df1``, ``df2``, ``F``, ``p``,
    and for ``separate`` also ``pes`` with its 90 % interval (``pes_ci90_low``,
    ``pes_ci90_high``), ``ges``, ``eps_gg``, ``p_gg``, ``eps_hf``,
    ``p_hf``, ``mauchly_W``, ``mauchly_p``; ``n`` is the participants analysed.
    """
    within = _as_list(within)
    between = _as_list(between)
    eff = _as_list(effect)
    by = _as_list(by)
    factors = within + between
    for f in eff + by:
        if f not in factors:
            raise InputError(f"{f!r} is not one of the factors {factors}")
    if set(eff) & set(by):
        raise InputError(f"a factor cannot be both the effect and the 'by' factor: "
                         f"{sorted(set(eff) & set(by))}")
    if method not in ("separate", "pooled"):
        raise InputError(f"method must be 'separate' or 'pooled', not {method!r}")
    _check_columns(data, [dv, subject, *factors])
    by_level_lists = [_levels_of(data[f]) for f in by]
    by_levels = list(itertools.product(*by_level_lists))
    rows = []
    dropped: list = []
    if method == "separate":
        # Each level of `by` alone, as afex::aov_ez on the subset: the other factors
        # are averaged over their observations, and a participant is dropped only if
        # they lack a cell of this level.
        eff_w = [f for f in eff if f in within]
        eff_b = [f for f in eff if f in between]
        for combo in by_levels:
            mask = np.ones(len(data), dtype=bool)
            for f, lv in zip(by, combo):
                mask &= (data[f] == lv).to_numpy()
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", MissingCellsWarning)
                t = rm_anova(data[mask], dv, eff_w, subject, between=eff_b, missing=missing)
            for w in caught:
                warnings.warn(MissingCellsWarning(
                    f"at {', '.join(f'{f} = {v}' for f, v in zip(by, combo))}: {w.message}"),
                    stacklevel=2)
            for f, lv in zip(by, combo):
                t.insert(0, f, lv)
            rows.append(t)
        out = pd.concat(rows, ignore_index=True)
        out.insert(0, "method", "separate")
        cols = ["method", *by, "effect", "df1", "df2", "F", "p", "pes", "pes_ci90_low",
                "pes_ci90_high", "ges", "mauchly_W",
                "mauchly_p", "eps_gg", "p_gg", "eps_hf", "p_hf", "n"]
        out = out[cols]
    else:
        design = within_design(data, dv, within, subject, missing=missing, between=between)
        dropped = list(design.dropped)
        model = PooledModel.of(design)
        lv_of = dict(zip(design.between + design.factors,
                         design.between_levels + design.levels))
        order = design.between + design.factors
        # every term made of the effect's factors (A, B, A:B for effect [A, B])
        eff_sorted = [f for f in order if f in eff]
        terms = [t for r in range(1, len(eff_sorted) + 1)
                 for t in itertools.combinations(eff_sorted, r)]
        for combo in by_levels:
            for term in terms:
                parts = {}
                for f in term:
                    parts[f] = _helmert(len(lv_of[f]))
                for f, v in zip(by, combo):
                    e = np.zeros((len(lv_of[f]), 1))
                    if v in lv_of[f]:
                        e[lv_of[f].index(v), 0] = 1.0
                    parts[f] = e
                L = grid_function(design, parts)
                row = {"method": "pooled", **dict(zip(by, combo)), "effect": ":".join(term),
                       **model.joint_test(L), "n": len(design.subjects)}
                rows.append(row)
        out = pd.DataFrame(rows)
    for f, lv in zip(by, by_level_lists):
        out[f] = pd.Categorical(out[f], categories=lv)
    out.attrs.update(dropped=dropped, dv=dv)
    return out
