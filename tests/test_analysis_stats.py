"""Statistics beyond the R reference: confusion, information transfer, kappa,
the mixed logistic model, batches, corrections, and errors for people."""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vtexp.analysis.anova import MissingCellsWarning, rm_anova, rm_anova_batch
from vtexp.analysis.confusion import agreement, confusion_matrix, information_transfer
from vtexp.analysis.posthoc import p_adjust
from vtexp.errors import InputError

HERE = Path(__file__).resolve().parent
EXPECTED = json.loads((HERE / "r_reference" / "expected.json").read_text())


def trials(pairs, by=None):
    rows = [{"correct_answer": s, "answer": r, **({"cond": by} if by else {})} for s, r in pairs]
    return pd.DataFrame(rows)


def test_confusion_rows_sum_to_one_and_count_every_trial():
    t = trials([("a", "a")] * 3 + [("a", "b")] + [("b", "b")] * 2 + [("b", "a")] * 2)
    m = confusion_matrix(t)
    assert m["count"].sum() == 8
    wide = m.pivot_table(index="stimulus", columns="response", values="count", observed=False)
    assert wide.loc["a", "a"] == 3 and wide.loc["a", "b"] == 1 and wide.loc["b", "a"] == 2
    assert m.groupby("stimulus", observed=True)["proportion"].sum().tolist() == [1.0, 1.0]


def test_information_transfer_of_perfect_and_chance_identification():
    perfect = trials([(s, s) for s in "abcd" for _ in range(20)])
    it = information_transfer(perfect).iloc[0]
    assert it["IT_bits"] == pytest.approx(2.0) and it["relative_IT"] == pytest.approx(1.0)
    # Responses independent of the stimulus: no information, but the estimate is biased up
    # by about (k-1)^2 / (2 N ln 2) (Miller 1955), which the table reports.
    rng = np.random.default_rng(3)
    chance = trials([(s, "abcd"[rng.integers(4)]) for s in "abcd" for _ in range(40)])
    it = information_transfer(chance).iloc[0]
    assert it["bias_bits"] == pytest.approx(9 / (2 * 160 * math.log(2)))
    assert 0 < it["IT_bits"] < 0.2 and it["IT_corrected"] < it["IT_bits"]


def test_information_transfer_hand_computed():
    # 2x2 with p = [[.4, .1], [.1, .4]]: IT = 1 - H(0.2) bits
    t = trials([("a", "a")] * 4 + [("a", "b")] + [("b", "a")] + [("b", "b")] * 4)
    h = -(0.2 * math.log2(0.2) + 0.8 * math.log2(0.8))
    assert information_transfer(t).iloc[0]["IT_bits"] == pytest.approx(1 - h)


def test_kappa_equals_statsmodels():
    from statsmodels.stats.inter_rater import cohens_kappa
    rng = np.random.default_rng(7)
    pairs = [(s, s if rng.random() < 0.6 else "abc"[rng.integers(3)]) for s in "abc"
             for _ in range(30)]
    t = trials(pairs)
    got = agreement(t).iloc[0]
    m = confusion_matrix(t).pivot_table(index="stimulus", columns="response", values="count",
                                        observed=False).to_numpy()
    ref = cohens_kappa(m)
    assert got["kappa"] == pytest.approx(ref.kappa, abs=1e-12)
    assert got["kappa_se"] == pytest.approx(ref.std_kappa, abs=1e-12)
    assert got["accuracy"] == pytest.approx(np.trace(m) / m.sum())


def test_confusion_by_condition_keeps_conditions_apart():
    t = pd.concat([trials([("a", "a")] * 4, "x"), trials([("a", "b")] * 4, "y")])
    t = pd.concat([t, trials([("b", "b")] * 4, "x"), trials([("b", "b")] * 4, "y")])
    ag = agreement(t, "cond").set_index("cond")
    assert ag.loc["x", "accuracy"] == 1.0 and ag.loc["y", "accuracy"] == 0.5


def test_mixed_logit_agrees_with_lme4_glmer():
    from vtexp.analysis.glmm import mixed_logit
    ref = EXPECTED["glmer"]
    d = pd.read_csv(HERE / "data" / "trials_glmm.csv", dtype=str)
    d["correct"] = d["correct"].astype(int)
    d["display"] = pd.Categorical(d["display"], ["static", "dynamic"])
    d["timing"] = pd.Categorical(d["timing"], ["fixed", "slow", "varied"])
    m = mixed_logit(d, ["display", "timing"])
    assert list(m["term"]) == ["Intercept", "display[dynamic]", "timing[slow]",
                               "timing[varied]", "sd(participant)"]
    fe = m.iloc[:4]
    # maximum likelihood (Laplace) as glmer: within 1 % of its standard errors
    assert np.abs(fe["estimate"].to_numpy() - ref["estimate"]).max() < 0.01 * min(ref["se"])
    assert np.abs(fe["se"].to_numpy() / ref["se"] - 1).max() < 0.01
    assert m.iloc[4]["estimate"] == pytest.approx(ref["sd_participant"], rel=0.01)
    assert m.attrs["n_trials"] == 1440 and "Laplace" in m.attrs["method"]


def test_mixed_logit_refuses_non_binary_outcomes():
    from vtexp.analysis.glmm import mixed_logit
    d = pd.DataFrame({"participant": ["1", "2"], "a": ["x", "y"], "correct": [0.5, 1]})
    with pytest.raises(InputError, match="must be 0 or 1"):
        mixed_logit(d, ["a"])


def test_p_adjust_equals_statsmodels():
    from statsmodels.stats.multitest import multipletests
    p = np.array([0.01, 0.04, 0.03, 0.2, 0.005, 0.5])
    for ours, theirs in (("holm", "holm"), ("bonferroni", "bonferroni"), ("BH", "fdr_bh"),
                         ("fdr", "fdr_bh"), ("sidak", "sidak")):
        assert np.allclose(p_adjust(p, ours), multipletests(p, method=theirs)[1])
    with pytest.raises(InputError, match="holm"):
        p_adjust(p, "hommel")


def _simulate(n_sets, n=15, seed=0):
    rng = np.random.default_rng(seed)
    rows = []
    for s in range(n_sets):
        for i in range(n):
            u = rng.normal()
            for a in ("a1", "a2"):
                for b in ("b1", "b2", "b3"):
                    rows.append((s, f"s{i}", a, b, u + rng.normal() + (a == "a2") * 0.3))
    return pd.DataFrame(rows, columns=["dataset", "subject", "A", "B", "y"])


def test_batch_gives_the_numbers_of_each_dataset_alone():
    d = _simulate(6)
    d = d.drop(index=d.index[(d["dataset"] == 2) & (d["subject"] == "s3") & (d["B"] == "b2")])
    with pytest.warns(MissingCellsWarning, match="2/s3"):
        batch = rm_anova_batch(d, "y", ["A", "B"], "subject", "dataset")
    assert list(batch["dataset"].unique()) == list(range(6))
    for s, g in d.groupby("dataset"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", MissingCellsWarning)
            one = rm_anova(g, "y", ["A", "B"], "subject")
        got = batch[batch["dataset"] == s].reset_index(drop=True)
        for col in ("F", "p", "ges", "pes", "eps_gg", "p_hf", "mauchly_W"):
            assert np.allclose(got[col], one[col], rtol=1e-12, atol=1e-15, equal_nan=True)
        assert got["n"].iloc[0] == (14 if s == 2 else 15)


@settings(max_examples=25, deadline=None)
@given(st.integers(2, 4), st.integers(2, 3), st.integers(3, 9), st.integers(0, 10_000))
def test_anova_decomposes_the_total_sum_of_squares(ka, kb, n, seed):
    # Effects, their errors and the participants' stratum add up to the total SS about
    # the grand mean, for any shape (a property of the orthonormal contrasts).
    rng = np.random.default_rng(seed)
    y = rng.normal(size=(n, ka, kb))
    d = pd.DataFrame([(f"p{i}", f"a{j}", f"b{k}", y[i, j, k]) for i in range(n)
                      for j in range(ka) for k in range(kb)], columns=["s", "A", "B", "y"])
    t = rm_anova(d, "y", ["A", "B"], "s")
    subjects = ka * kb * ((y.mean(axis=(1, 2)) - y.mean()) ** 2).sum()
    total = ((y - y.mean()) ** 2).sum()
    assert t["SS"].sum() + t["SS_error"].sum() + subjects == pytest.approx(total)
    assert ((t["eps_gg"] >= 1 / t["df1"] - 1e-12) & (t["eps_gg"] <= 1 + 1e-12)).all()


def test_errors_name_the_column_and_the_problem():
    d = pd.DataFrame({"s": ["1", "1", "2", "2"], "A": ["x", "y", "x", "y"], "y": [1, 2, 3, 4]})
    with pytest.raises(InputError, match="no column 'B'"):
        rm_anova(d, "y", ["A", "B"], "s")
    with pytest.raises(InputError, match="non-numeric value 'lots'"):
        rm_anova(d.assign(y=["1", "2", "lots", "4"]), "y", ["A"], "s")
    with pytest.raises(InputError, match="'A' has 1 level"):
        rm_anova(d.assign(A="x"), "y", ["A"], "s")
