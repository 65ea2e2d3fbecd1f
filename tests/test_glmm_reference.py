"""The mixed logistic model against lme4::glmer, near the ceiling included.

Expected values: tests/r_reference/expected_glmer.json, written by
tests/r_reference/glmer.R (which also writes tests/data/fhch2010.csv from the
afex package). R is not needed to run these tests.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from vtexp.analysis.glmm import MixedModelWarning, mixed_logit
from vtexp.errors import InputError

HERE = Path(__file__).resolve().parent
EXPECTED = json.loads((HERE / "r_reference" / "expected_glmer.json").read_text())
FITS = EXPECTED["fits"]


def parse(fit):
    lhs, rhs = fit["formula"].split("~")
    fixed = rhs.split("(")[0].strip(" +")
    factors = [t.strip() for t in fixed.split("+")]
    res = [part.split("|")[1].split(")")[0].strip() for part in rhs.split("(")[1:]]
    return factors, res[0], (res[1] if len(res) > 1 else None)


@pytest.fixture(scope="module")
def tables():
    return {n: pd.read_csv(HERE / "data" / f"{n}.csv", dtype=str)
            for n in {f["dataset"] for f in FITS}}


def test_the_reference_holds_a_near_ceiling_fit_and_crossed_items():
    fh = [f for f in FITS if f["dataset"] == "fhch2010"]
    assert fh and fh[0]["estimate"][0] == pytest.approx(6.63, abs=0.01)   # the 6.6
    assert any("item" in f["sd"] for f in FITS)
    d = pd.read_csv(HERE / "data" / "fhch2010.csv")
    assert d["correct"].mean() == pytest.approx(0.98, abs=0.001)


@pytest.mark.parametrize("k", range(len(FITS)),
                         ids=[f"{f['dataset']}-nAGQ{f['nAGQ']}-{'items' if 'item' in f['sd'] else 'subj'}"
                              for f in FITS])
def test_estimates_and_standard_errors_equal_glmer(tables, k):
    fit = FITS[k]
    factors, subject, items = parse(fit)
    with warnings.catch_warnings():
        warnings.simplefilter("error", MixedModelWarning)          # a clean fit: no warning
        m = mixed_logit(tables[fit["dataset"]], factors, subject=subject, items=items,
                        n_quad=fit["nAGQ"])
    fe = m[~m["term"].str.startswith("sd(")]
    se = np.asarray(fit["se"])
    # the estimates within 1 % of glmer's standard error, the standard errors within 1 %
    assert np.abs(fe["estimate"].to_numpy() - fit["estimate"]).max() < 0.01 * se.min()
    assert np.abs(fe["se"].to_numpy() / se - 1).max() < 0.01
    sds = m[m["term"].str.startswith("sd(")].set_index("term")["estimate"]
    for name, want in fit["sd"].items():
        assert sds[f"sd({name})"] == pytest.approx(want, rel=0.01)
    # our optimum is at least as good as glmer's (its Laplace deviance carries its PIRLS
    # tolerance, ~3e-4 here; the quadrature deviances agree to 1e-5)
    assert m.attrs["deviance"] <= fit["deviance"] + 1e-5
    assert m.attrs["converged"] and not m.attrs["problems"]


def test_the_fit_is_the_same_on_every_run(tables):
    d = tables["fhch2010"]
    a = mixed_logit(d, ["stimulus", "frequency"], subject="id")
    b = mixed_logit(d.sample(frac=1.0, random_state=3), ["stimulus", "frequency"], subject="id")
    assert np.allclose(a["estimate"], b["estimate"], rtol=0, atol=1e-6)
    c = mixed_logit(d, ["stimulus", "frequency"], subject="id")
    assert a.equals(c)


def test_complete_separation_is_a_loud_specific_warning_or_a_refusal(tables):
    # seed 001's letters at the ceiling: every answer correct in one condition
    d = tables["trials_glmm"].copy()
    d.loc[d["timing"] == "varied", "correct"] = "1"
    with pytest.warns(MixedModelWarning, match=r"timing\[varied\].*no finite maximum.*"
                                               r"completely separated"):
        m = mixed_logit(d, ["display", "timing"])
    assert m.attrs["problems"]
    with pytest.raises(InputError, match="completely separated"):
        mixed_logit(d, ["display", "timing"], on_failure="error")


def test_bad_input_is_refused_with_the_reason(tables):
    d = tables["trials_glmm"]
    with pytest.raises(InputError, match="one random term"):
        mixed_logit(tables["trials_items"], ["display"], items="item", n_quad=5)
    with pytest.raises(InputError, match="no column"):
        mixed_logit(d, ["nope"])
