"""Confidence intervals of partial η² and d_z against R (pf/pt inverted by uniroot, and
effectsize), from tests/r_reference/expected_effect_sizes.json (written by
tests/r_reference/effect_sizes.R; R is not needed to run these tests)."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from vtexp.analysis.anova import MissingCellsWarning, rm_anova
from vtexp.analysis.effect_sizes import dz_ci, eta2p_ci, noncentrality_limits_f
from vtexp.analysis.pipeline import apa_anova
from vtexp.analysis.posthoc import pairwise_tests

HERE = Path(__file__).resolve().parent
EXPECTED = json.loads((HERE / "r_reference" / "expected_effect_sizes.json").read_text())
TOL = 1e-6            # against R's pf/pt inverted with uniroot
TOL_EFFECTSIZE = 1e-4  # effectsize finds the limits with optim(), usually to about 1e-7


def assert_like_effectsize(got, theirs, prob, targets):
    """``got`` equals effectsize's limits to 1e-4, except where effectsize's own limit
    misses its defining probability (R's pf/pt there, ``prob``) by more than 1e-4:
    there optim() stopped short and the exact limits are the reference."""
    for g, e, p, target in zip(got, theirs, prob, targets):
        if p is not None and abs(p - target) > TOL_EFFECTSIZE:
            continue
        assert g == pytest.approx(e, abs=TOL_EFFECTSIZE), (got, theirs, prob)


@pytest.mark.parametrize("case", EXPECTED["eta2p"],
                         ids=lambda c: f"F{c['F']}({c['df1']},{c['df2']})")
def test_eta2p_interval_equals_r(case):
    for level in (90, 95):
        got = eta2p_ci(case["F"], case["df1"], case["df2"], level / 100)
        ref = case[f"ci{level}"]
        assert got == pytest.approx(ref["exact"], abs=TOL)
        a = 1 - level / 100
        assert_like_effectsize(got, ref["effectsize"], ref["effectsize_prob"],
                               (1 - a / 2, a / 2))


def test_effectsize_stops_short_where_we_do_not():
    # F = 1.2 on (12, 240), 95 %: effectsize's upper limit .1047 leaves P(F' <= F) at .0036
    # instead of .025; the exact limit (R's uniroot) is .0759, and so is ours.
    case = next(c for c in EXPECTED["eta2p"] if (c["F"], c["df1"], c["df2"]) == (1.2, 12, 240))
    ref = case["ci95"]
    assert abs(ref["effectsize_prob"][1] - 0.025) > 0.02
    assert eta2p_ci(1.2, 12, 240, 0.95)[1] == pytest.approx(ref["exact"][1], abs=TOL)
    assert abs(ref["effectsize"][1] - ref["exact"][1]) > 0.02


def test_eta2p_interval_inverts_the_noncentral_f():
    # brute force, independent of the root finder: the F cdf at the limits found
    from scipy import stats
    F, df1, df2 = 6.024, 3.0, 39.0
    lo, hi = noncentrality_limits_f(F, df1, df2, 0.90)
    assert stats.ncf.cdf(F, df1, df2, lo) == pytest.approx(0.95, abs=1e-10)
    assert stats.ncf.cdf(F, df1, df2, hi) == pytest.approx(0.05, abs=1e-10)
    grid = np.linspace(0.01, 60, 60_000)
    p = stats.ncf.cdf(F, df1, df2, grid)
    assert abs(grid[np.argmin(abs(p - 0.95))] - lo) < 2e-3
    assert abs(grid[np.argmin(abs(p - 0.05))] - hi) < 2e-3
    # the 90 % interval excludes 0 exactly when the F test's p < .05
    for F in (2.5, 2.9, 2.85, 3.0, 3.5):
        p = stats.f.sf(F, df1, df2)
        assert (eta2p_ci(F, df1, df2)[0] > 0) == (p < 0.05)


def test_undefined_f_has_no_interval():
    assert all(np.isnan(eta2p_ci(float("nan"), 2, 20)))
    assert all(np.isnan(eta2p_ci(float("inf"), 2, 20)))
    assert eta2p_ci(0.0, 2, 20) == (0.0, 0.0)
    assert all(np.isnan(dz_ci(float("nan"), 12)))
    assert all(np.isnan(dz_ci(0.5, 1)))
    from vtexp.analysis.pipeline import eta2p_interval
    assert eta2p_interval(float("inf"), 1, 10) == "90% CI n/a (no error variance)"
    assert eta2p_interval(float("nan"), 1, 10) == "90% CI n/a (F is not defined)"
    assert eta2p_interval(0.01, 2, 20) == "90% CI [0, 0]"


@pytest.mark.parametrize("n", [2, 3, 4, 5, 10])
def test_dz_interval_of_a_small_pilot_with_a_large_effect(n):
    """Three participants, a large effect: the interval's search reached scipy's NaN tail
    of the noncentral t (``nct.cdf(-7, 2, 10)``) and `vtexp analyze` crashed. A negative
    effect's interval is the positive one's mirror; each limit leaves α/2 in its tail."""
    from vtexp.analysis.effect_sizes import noncentrality_limits_t
    for dz in (2.0, 4.0, 4.04, 8.0, 20.0):
        lo, hi = dz_ci(dz, n)
        assert np.isfinite(lo) and np.isfinite(hi) and lo < dz < hi, (dz, n, lo, hi)
        assert dz_ci(-dz, n) == pytest.approx((-hi, -lo), rel=1e-9)
        t, df = dz * np.sqrt(n), n - 1.0
        d_lo, d_hi = noncentrality_limits_t(-t, df)
        assert stats.nct.cdf(-t, df, d_lo) == pytest.approx(0.975, abs=1e-6)
        assert stats.nct.cdf(-t, df, d_hi) == pytest.approx(0.025, abs=1e-6)


@pytest.mark.parametrize("case", EXPECTED["dz"], ids=lambda c: f"dz{c['dz']}n{c['n']}")
def test_dz_interval_equals_r(case):
    assert dz_ci(case["dz"], case["n"], 0.95) == pytest.approx(case["ci95"], abs=TOL)


@pytest.mark.parametrize("des", EXPECTED["designs"], ids=lambda d: d["name"])
def test_anova_tables_carry_the_interval_r_gives(des):
    d = pd.read_csv(HERE / "data" / f"{des['name']}.csv", dtype=str)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MissingCellsWarning)
        t = rm_anova(d, des["dv"], des["within"], des["id"], between=des["between"] or None)
    ref = des["none"]
    assert list(t["effect"]) == ref["effect"]
    assert np.allclose(t["pes_ci90_low"], ref["ci90_low"], rtol=0, atol=TOL)
    assert np.allclose(t["pes_ci90_high"], ref["ci90_high"], rtol=0, atol=TOL)
    for k in range(len(t)):
        assert_like_effectsize(
            (t["pes_ci90_low"].iloc[k], t["pes_ci90_high"].iloc[k]),
            (ref["effectsize_low"][k], ref["effectsize_high"][k]),
            (ref["effectsize_prob_low"][k], ref["effectsize_prob_high"][k]), (0.95, 0.05))
    # the sentence's interval goes with its Greenhouse-Geisser df
    gg = des["GG"]
    for k, (_, row) in enumerate(t.iterrows()):
        s, used = apa_anova(row, "GG")
        lo, hi = gg["ci90_low"][k], gg["ci90_high"][k]
        fmt = lambda x: "0" if x == 0 else f"{x:.2f}".lstrip("0")  # noqa: E731
        assert f"90% CI [{fmt(lo)}, {fmt(hi)}]" in s, (row["effect"], s, lo, hi)


def test_paired_comparisons_carry_the_dz_interval_r_gives():
    ref = EXPECTED["pairs"]
    d = pd.read_csv(HERE / "data" / f"{ref['data']}.csv", dtype=str)
    t = pairwise_tests(d, "score", ["shape", "soa"], "participant", factor=ref["factor"])
    assert [(a, b) for a, b in zip(t["A"], t["B"])] == [(r["A"], r["B"]) for r in ref["rows"]]
    assert np.allclose(t["dz"], [r["dz"] for r in ref["rows"]], rtol=0, atol=1e-12)
    assert np.allclose(t["dz"], [r["effectsize_dz"] for r in ref["rows"]], rtol=0, atol=1e-12)
    for col, k in (("dz_ci95_low", 0), ("dz_ci95_high", 1)):
        assert np.allclose(t[col], [r["ci95"][k] for r in ref["rows"]], rtol=0, atol=TOL)
    for (_, row), r in zip(t.iterrows(), ref["rows"]):
        assert_like_effectsize((row["dz_ci95_low"], row["dz_ci95_high"]), r["effectsize"],
                               r["effectsize_prob"], (0.975, 0.025))
    # a between-group comparison has no d_z, and so no interval
    g = pd.read_csv(HERE / "data" / "mixed_group_soa.csv", dtype=str)
    b = pairwise_tests(g, "score", ["soa"], "participant", factor="group", between=["group"])
    assert b[["dz", "dz_ci95_low", "dz_ci95_high"]].isna().all().all()
