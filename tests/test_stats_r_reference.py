"""vtexp's statistics against values computed with R (afex, emmeans, stats).

The expected values are in tests/r_reference/expected.json, written by
tests/r_reference/rm_anova.R from the datasets in tests/data/ (made by
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
from vtexp.analysis.ordinal import friedman, wilcoxon_pairwise
from vtexp.analysis.posthoc import pairwise_tests

HERE = Path(__file__).resolve().parent
EXPECTED = json.loads((HERE / "r_reference" / "expected.json").read_text())
TOL = 1e-6


def listify(v):
    return v if isinstance(v, list) else [v]


def close(got, want, what):
    got = np.atleast_1d(np.asarray(got, dtype=float))
    want = np.asarray(listify(want), dtype=float)
    assert got.shape == want.shape, what
    assert np.all(np.abs(got - want) <= TOL * np.maximum(1.0, np.abs(want))), \
        f"{what}: got {got}, R gives {want}"


def load(name: str) -> pd.DataFrame:
    df = pd.read_csv(HERE / "data" / f"{name}.csv", dtype=str)
    return df


def spec(name):
    e = EXPECTED["datasets"][name]
    return e, load(name), e["dv"], listify(e["within"]), e["subject"]


DESIGNS = list(EXPECTED["datasets"])


def test_the_reference_covers_the_designs_the_issue_names():
    shapes = {n: len(listify(EXPECTED["datasets"][n]["within"])) for n in DESIGNS}
    assert shapes["oneway_sphericity"] == 1 and shapes["threeway"] == 3
    sp = EXPECTED["datasets"]["oneway_sphericity"]["sphericity"]
    assert listify(sp["p"])[0] < 0.05                       # sphericity is violated
    assert EXPECTED["datasets"]["missing_cell"]["n"] == 10   # two participants dropped


@pytest.mark.parametrize("name", DESIGNS)
def test_rm_anova_matches_afex(name):
    e, df, dv, within, subject = spec(name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MissingCellsWarning)
        t = rm_anova(df, dv, within, subject)
    assert list(t["effect"]) == listify(e["none"]["effect"])
    assert (t["n"] == e["n"]).all()
    none = e["none"]
    for col in ("df1", "df2", "MSE", "F", "pes", "ges", "p"):
        close(t[col], none[col], f"{name} {col}")
    close(t["SS"], e["SS"]["SS"], f"{name} SS")
    close(t["SS_error"], e["SS"]["SS_error"], f"{name} SS_error")
    # corrected p, and the corrected dfs afex prints (df × epsilon, HF capped at 1)
    close(t["p_gg"], e["GG"]["p"], f"{name} p GG")
    close(t["p_hf"], e["HF"]["p"], f"{name} p HF")
    close(t["df1"] * t["eps_gg"], e["GG"]["df1"], f"{name} df1 GG")
    close(t["df2"] * t["eps_gg"], e["GG"]["df2"], f"{name} df2 GG")
    close(t["df1"] * np.minimum(t["eps_hf"], 1), e["HF"]["df1"], f"{name} df1 HF")
    if "sphericity" in e:
        sp = e["sphericity"]
        sub = t.set_index("effect").loc[listify(sp["effect"])]
        for col, key in (("mauchly_W", "W"), ("mauchly_p", "p"), ("eps_gg", "eps_gg"),
                         ("p_gg", "p_gg"), ("eps_hf", "eps_hf"), ("p_hf", "p_hf")):
            close(sub[col], sp[key], f"{name} {col}")


def test_missing_cells_drop_participants_with_a_warning_naming_them():
    e, df, dv, within, subject = spec("missing_cell")
    assert "04, 09" in listify(e["warnings"])[0]                     # what afex said
    with pytest.warns(MissingCellsWarning, match=r"04, 09.*Removing those participants"):
        t = rm_anova(df, dv, within, subject)
    assert t.attrs["dropped"] == ["04", "09"]
    from vtexp.errors import InputError
    with pytest.raises(InputError, match=r"04: no square × 300/500; 09: no circle × 200/100"):
        rm_anova(df, dv, within, subject, missing="error")


@pytest.mark.parametrize("name", [n for n in DESIGNS if "simple" in EXPECTED["datasets"][n]])
def test_simple_effects_separate_match_afex_per_level(name):
    e, df, dv, within, subject = spec(name)
    s = e["simple"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MissingCellsWarning)
        t = simple_effects(df, dv, within, subject, effect=s["effect"], by=s["by"],
                           method="separate")
    for level in s["separate"]:
        rows = t[t[s["by"]] == level["by"]]
        assert list(rows["effect"]) == listify(level["none"]["effect"])
        for col in ("df1", "df2", "F", "pes", "ges", "p"):
            close(rows[col], level["none"][col], f"{name} at {level['by']} {col}")
        close(rows["p_gg"], level["GG"]["p"], f"{name} at {level['by']} p_gg")
        if "sphericity" in level:
            sub = rows.set_index("effect").loc[listify(level["sphericity"]["effect"])]
            close(sub["mauchly_W"], level["sphericity"]["W"], "W")
            close(sub["eps_hf"], level["sphericity"]["eps_hf"], "eps_hf")


@pytest.mark.parametrize("name", [n for n in DESIGNS if "simple" in EXPECTED["datasets"][n]])
def test_simple_effects_pooled_match_emmeans_joint_tests(name):
    e, df, dv, within, subject = spec(name)
    s = e["simple"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MissingCellsWarning)
        t = simple_effects(df, dv, within, subject, effect=s["effect"], by=s["by"],
                           method="pooled")
    assert len(t) == len(s["pooled"])
    for r in s["pooled"]:
        row = t[(t[s["by"]] == r["by"]) & (t["effect"] == r["effect"])]
        assert len(row) == 1, (r["by"], r["effect"])
        for col in ("df1", "df2", "F", "p"):
            close(row[col], r[col], f"{name} {r['effect']} at {r['by']} {col}")
        assert round(float(row["F"].iloc[0]), 3) == pytest.approx(r["joint_tests_F"])


def test_seed000_table3_layout_fixed_versus_varied():
    # The 2x2 with seed 000's cell means: intensity matters under varied timing only,
    # as Table 3 reports (F(1,14) small at A1, large at A2).
    e, df, dv, within, subject = spec("seed000_2x2")
    t = simple_effects(df, dv, within, subject, effect="intensity", by="timing")
    fixed, varied = t.set_index("timing").loc[["fixed", "varied"], "p"]
    assert fixed > 0.05 > varied
    assert set(t["df2"]) == {14.0}


@pytest.mark.parametrize("name", [n for n in DESIGNS if "posthoc" in EXPECTED["datasets"][n]])
def test_pairwise_paired_t_tests_match_r(name):
    e, df, dv, within, subject = spec(name)
    ph = e["posthoc"]
    t = pairwise_tests(df, dv, within, subject, factor=ph["factor"])
    b = pairwise_tests(df, dv, within, subject, factor=ph["factor"], padjust="bonferroni")
    rows = ph["rows"] if isinstance(ph["rows"], list) else [ph["rows"]]
    assert len(t) == len(rows)
    for got, gotb, want in zip(t.itertuples(), b.itertuples(), rows):
        assert (got.A, got.B) == (want["A"], want["B"])
        close(got.mean_diff, want["mean_diff"], "mean_diff")
        close(got.t, want["t"], "t")
        close(got.p, want["p"], "p")
        close(got.p_adj, want["p_holm"], "holm")
        close(gotb.p_adj, want["p_bonferroni"], "bonferroni")
        close(got.dz, want["dz"], "dz")
        close([got.ci_low, got.ci_high], [want["ci_low"], want["ci_high"]], "ci")


def test_friedman_and_wilcoxon_match_r():
    o = EXPECTED["ordinal"]
    df = load(o["dataset"])
    f = friedman(df, o["dv"], o["factor"], o["subject"])
    close(f["Q"], o["friedman"]["statistic"], "friedman Q")
    close(f["df"], o["friedman"]["df"], "friedman df")
    close(f["p"], o["friedman"]["p"], "friedman p")
    w = wilcoxon_pairwise(df, o["dv"], o["factor"], o["subject"])
    for got, want in zip(w.itertuples(), o["wilcoxon"]):
        assert (got.A, got.B) == (want["A"], want["B"])
        close(got.V, want["V"], "V")
        close(got.p, want["p"], "wilcoxon p")
        close(got.p_adj, want["p_holm"], "wilcoxon holm")
