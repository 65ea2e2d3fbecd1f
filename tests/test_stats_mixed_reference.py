"""Mixed designs (between- and within-participant factors) against R (afex, emmeans, stats).

The expected values are in tests/r_reference/expected_mixed.json, written by
tests/r_reference/mixed.R from tests/data/mixed_*.csv (made by
tests/r_reference/make_datasets.py). R is not needed to run these tests.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from vtexp.analysis.anova import MissingCellsWarning, rm_anova, simple_effects
from vtexp.analysis.posthoc import p_adjust, pairwise_tests, trend_contrasts
from vtexp.errors import InputError

HERE = Path(__file__).resolve().parent
EXPECTED = json.loads((HERE / "r_reference" / "expected_mixed.json").read_text())
D = EXPECTED["datasets"]
TOL = 1e-6


def L(v):
    return v if isinstance(v, list) else [v]


def close(got, want, what):
    got = np.atleast_1d(np.asarray(got, dtype=float))
    want = np.asarray(L(want), dtype=float)
    assert got.shape == want.shape, f"{what}: shape {got.shape} vs {want.shape}"
    assert np.all(np.abs(got - want) <= TOL * np.maximum(1.0, np.abs(want))), \
        f"{what}: got {got}, R gives {want}"


def rname(level: str) -> str:
    """A level as emmeans prints it: X100 for 100, (18-30) for 18-30."""
    level = str(level)
    if level[:1].isdigit() and level.replace(".", "").isdigit():
        return "X" + level
    return f"({level})" if "-" in level else level


def load(name):
    return pd.read_csv(HERE / "data" / f"{name}.csv", dtype=str)


def anova_of(name, **kw):
    e = D[name]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MissingCellsWarning)
        return e, rm_anova(load(name), e["dv"], L(e["within"]), e["subject"],
                           between=L(e["between"]), **kw)


def check_anova(t, e, what):
    assert list(t["effect"]) == L(e["none"]["effect"]), what
    assert (t["n"] == e["n"]).all()
    for col in ("df1", "df2", "MSE", "F", "pes", "ges", "p"):
        if col in t.columns:
            close(t[col], e["none"][col], f"{what} {col}")
    if "SS" in e and "SS" in t.columns:
        close(t["SS"], e["SS"]["SS"], f"{what} SS")
        close(t["SS_error"], e["SS"]["SS_error"], f"{what} SS_error")
    if "GG" in e and "p_gg" in t.columns:
        close(t["p_gg"], e["GG"]["p"], f"{what} p GG")
        close(t["p_hf"], e["HF"]["p"], f"{what} p HF")
        close(t["df2"] * t["eps_gg"], e["GG"]["df2"], f"{what} df2 GG")
        close(t["df1"] * np.minimum(t["eps_hf"], 1), e["HF"]["df1"], f"{what} df1 HF")
    if "sphericity" in e:
        sp = e["sphericity"]
        sub = t.set_index("effect").loc[L(sp["effect"])]
        for col, key in (("mauchly_W", "W"), ("mauchly_p", "p"), ("eps_gg", "eps_gg"),
                         ("p_gg", "p_gg"), ("eps_hf", "eps_hf"), ("p_hf", "p_hf")):
            close(sub[col], sp[key], f"{what} {col}")


@pytest.mark.parametrize("name", list(D))
def test_mixed_anova_matches_afex_type3(name):
    e, t = anova_of(name, observed=e_obs if (e_obs := D[name].get("observed")) else None)
    check_anova(t, e, name)


def test_observed_factor_changes_generalised_eta_squared_only():
    e, t = anova_of("mixed_2b2w")
    close(t["ges"], e["no_observed"]["ges"], "ges without observed")
    close(t["F"], e["no_observed"]["F"], "F")
    _, t_obs = anova_of("mixed_2b2w", observed="age")
    assert not np.allclose(t["ges"], t_obs["ges"])


def test_between_only_anova_matches_afex():
    e = D["mixed_group_soa"]
    t = rm_anova(load("mixed_group_soa"), "score", [], "participant", between="group")
    check_anova(t, e["between_only"], "between only")


def test_a_missing_value_in_a_replicated_cell_drops_the_participant_as_afex():
    e = D["mixed_2b2w"]
    assert any("07" in w for w in L(e["warnings"]))             # what afex said
    with pytest.warns(MissingCellsWarning, match=r"07: a missing value of 'rate' in square × "
                                                 r"slow.*afex"):
        t = rm_anova(load("mixed_2b2w"), "rate", ["shape", "timing"], "participant",
                     between=["group", "age"])
    assert t.attrs["dropped"] == ["07"] and t["n"].iloc[0] == 29


@pytest.mark.parametrize("name,k", [(n, k) for n in D for k in range(len(D[n]["simple"]))])
def test_simple_effects_across_and_within_groups_match_afex_and_emmeans(name, k):
    e = D[name]
    s = e["simple"][k]
    kw = dict(effect=s["effect"], by=s["by"], between=L(e["between"]))
    df = load(name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MissingCellsWarning)
        sep = simple_effects(df, e["dv"], L(e["within"]), e["subject"], method="separate", **kw)
        pooled = simple_effects(df, e["dv"], L(e["within"]), e["subject"], method="pooled",
                                **kw)
    for level in s["separate"]:
        rows = sep[[level["by"] in (str(v), rname(v)) for v in sep[s["by"]]]]
        assert len(rows)
        check_anova(rows.reset_index(drop=True), level, f"{name} separate at {level['by']}")
    for r in s["pooled"]:
        row = pooled[(np.array([rname(v) for v in pooled[s["by"]]]) == r["by"])
                     & (pooled["effect"] == r["effect"])]
        assert len(row) == 1
        for col in ("df1", "df2", "F", "p"):
            close(row[col], r[col], f"{name} pooled {r['effect']} at {r['by']} {col}")


@pytest.mark.parametrize("name,k", [(n, k) for n in D for k in range(len(D[n]["posthoc_pooled"]))])
def test_pooled_error_comparisons_match_emmeans_pairs(name, k):
    e = D[name]
    ph = e["posthoc_pooled"][k]
    by = ph["by"] or None
    df = load(name)
    for adj, key in (("none", "p"), ("holm", "p_holm"), ("bonferroni", "p_bonferroni"),
                     ("BH", "p_fdr"), ("sidak", "p_sidak")):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", MissingCellsWarning)
            t = pairwise_tests(df, e["dv"], L(e["within"]), e["subject"], factor=ph["factor"],
                               by=by, between=L(e["between"]), error="pooled", padjust=adj)
        assert [f"{rname(a)} - {rname(b)}" for a, b in zip(t["A"], t["B"])] == \
            L(ph["contrast"])
        if by:
            assert [rname(v) for v in t[by]] == L(ph["by_level"])
        close(t["p_adj"], ph[key], f"{name} {ph['factor']} | {by} {adj}")
    close(t["mean_diff"], ph["estimate"], "estimate")
    close(t["se"], ph["se"], "SE")
    close(t["df"], ph["df"], "df")
    close(t["t"], ph["t"], "t")
    close(t["p"], ph["p"], "p")
    close(t["ci_low"], ph["ci_low"], "CI low")
    close(t["ci_high"], ph["ci_high"], "CI high")


@pytest.mark.parametrize("k", range(len(D["mixed_group_soa"]["posthoc_paired"])))
def test_per_participant_comparisons_match_t_test(k):
    e = D["mixed_group_soa"]
    ph = e["posthoc_paired"][k]
    by = ph["by"] or None
    df = load("mixed_group_soa")
    for adj, key in (("holm", "p_holm"), ("bonferroni", "p_bonferroni"), ("BH", "p_BH")):
        t = pairwise_tests(df, "score", "soa", "participant", factor=ph["factor"], by=by,
                           between="group", error="paired", padjust=adj)
        rows = ph["rows"]
        assert len(t) == len(rows)
        close(t["p_adj"], [r[key] for r in rows], f"paired {adj}")
    for col in ("t", "df", "p", "ci_low", "ci_high"):
        close(t[col], [r[col] for r in rows], f"paired {ph['factor']} | {by} {col}")
    if by:
        assert list(t[by].astype(str)) == [r["group"] for r in rows]


@pytest.mark.parametrize("k", [0, 1])
def test_polynomial_trends_match_emmeans_and_t_test(k):
    e = D["mixed_group_soa"]
    tr = e["trend"][k]
    df = load("mixed_group_soa")
    kw = dict(factor="soa", by="group", between="group", scores=tr["scores"])
    pooled = trend_contrasts(df, "score", "soa", "participant", error="pooled", **kw)
    close(np.array(pooled.attrs["coefficients"]), np.squeeze(tr["coefficients"]).tolist(), "coefficients")
    assert list(pooled["contrast"]) == L(tr["pooled"]["contrast"])
    for col, key in (("estimate", "estimate"), ("se", "se"), ("df", "df"), ("t", "t"),
                     ("p", "p")):
        close(pooled[col], tr["pooled"][key], f"trend pooled {col}")
    paired = trend_contrasts(df, "score", "soa", "participant", error="paired", **kw)
    for col in ("estimate", "t", "df", "p"):
        close(paired[col], [r[col] for r in tr["paired"]], f"trend paired {col}")


def test_p_adjust_bh_and_sidak():
    p = np.array([0.01, 0.04, 0.03, 0.2, np.nan])
    close(p_adjust(p, "BH")[:4], [0.04, 0.16 / 3, 0.16 / 3, 0.2], "BH")   # R's p.adjust
    close(p_adjust(p, "sidak")[:4], (1 - (1 - p[:4]) ** 4).tolist(), "sidak")
    assert np.isnan(p_adjust(p, "BH")[4])


def test_groups_are_checked_with_clear_messages():
    df = load("mixed_group_soa")
    bad = df.copy()
    bad.loc[bad.index[0], "group"] = "sighted"          # participant 01 in two groups
    with pytest.raises(InputError, match=r"participant 01 has more than one value of the "
                                         r"between-participant factor 'group'"):
        rm_anova(bad, "score", "soa", "participant", between="group")
    one = df[df["group"] == "blind"]
    with pytest.raises(InputError, match=r"'group' has 1 level"):
        rm_anova(one, "score", "soa", "participant", between="group")
    with pytest.raises(InputError, match=r"both within and between"):
        rm_anova(df, "score", "soa", "participant", between="soa")
