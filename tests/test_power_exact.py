"""Exact ANOVA power (analysis/exact_power.py) against published values and closed forms, and
``vtexp simulate``'s Monte-Carlo power and N search against it, on stated designs."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import ROOT
from scipy import stats

from vtexp.analysis.exact_power import (
    ExactDesign,
    empirical_normal,
    exact_anova,
    exact_dataset,
    smallest_n,
)
from vtexp.errors import InputError
from vtexp.experiment import load_experiment
from vtexp.observer.stated import load_stated
from vtexp.simulate import Setup, StatedSetup, run_power
from vtexp.simulate import smallest_n as simulated_smallest_n

BALL = ROOT / "experiments" / "six_mode_ball.yaml"
CVR = ROOT / "experiments" / "circle_vs_rectangle.yaml"
BALL_STATED = ROOT / "protocols" / "observers" / "six_mode_ball_paper_stated.yaml"
CVR_STATED = ROOT / "protocols" / "observers" / "circle_vs_rectangle_stated.yaml"


def power_of(design: ExactDesign, n: int) -> list[float]:
    return [float(p) for p in exact_anova(design, n)["power"]]


# --------------------------------------------------------------------------- the exact dataset

def test_the_exact_dataset_has_exactly_the_stated_means_and_covariance():
    mean = np.array([1.0, -2.0, 0.5])
    R = np.array([[1, 0.3, 0.6], [0.3, 1, -0.2], [0.6, -0.2, 1]])
    sd = np.array([1.0, 2.0, 0.5])
    cov = sd[:, None] * R * sd[None, :]
    X = empirical_normal(mean, cov, 7)
    assert np.allclose(X.mean(axis=0), mean, atol=1e-12)
    assert np.allclose(np.cov(X, rowvar=False), cov, atol=1e-12)
    with pytest.raises(InputError, match="at least 4 participants"):
        empirical_normal(mean, cov, 3)


# --------------------------------------------------------------------------- published values

def test_between_design_matches_superpowers_printed_anova_exact_values():
    """Superpower's vignette "Introduction to Superpower" (arcaldwell49/Superpower,
    docs/articles/intro_to_superpower.html, "Power in a Two Group One-Way ANOVA") prints
    ``ANOVA_exact(design_result)$main_results$power`` for design "2b", mu = (24, 26.2),
    sd = 6.4: 67.68572 (n = 100 per group), 84.3127 (150), 89.37347 (175), 90.18863
    (180), and says 180 is where power first passes 90 % among the Ns it tried."""
    d = ExactDesign.from_sd_r({}, [[24.0], [26.2]], 6.4, 0.0,
                              between={"condition": ["control", "pet"]})
    for n, printed in [(100, 67.68572), (150, 84.3127), (175, 89.37347), (180, 90.18863)]:
        assert 100 * power_of(d, n)[0] == pytest.approx(printed, abs=1e-4), n
    n90 = int(smallest_n(d, 0.9)["n"].iloc[0])
    assert 175 < n90 <= 180 and power_of(d, n90 - 1)[0] < 0.9 <= power_of(d, n90)[0]


def test_within_and_mixed_designs_match_superpowers_documented_power():
    """Within and mixed designs whose power Superpower documents (values in percent):

    - "3w", n = 20, r = 0.8, sd = 1, mu = (-0.3061862, 0, 0.3061862) (Cohen's f = 0.25):
      96.9 (vignette "More ANOVA designs", "Power in Repeated Measures ANOVA with More
      than 2 Groups"; tests/testthat/test-anova_exact.R, test "3w");
    - "2w", n = 21, r = 0.55, sd = 1, mu = (0, 0.65): 84.7 (test-anova_exact.R, "2w",
      written to one decimal and compared there with a 10 % tolerance; the paired t test
      gives 84.76, see test_two_levels_within_is_the_paired_t_test);
    - "2w", n = 34, r = 0.5, d = 0.5: 80.777, G*Power's dependent t test, which the
      vignette says the exact simulation reproduces ("Two within conditions");
    - "2w*2b", n = 23 per group, sd = 1, mu = (-0.25, 0.25, 0.25, -0.25), interaction:
      91.25 with r = 0.5 and 98.98 with r = 0.7, G*Power's within-between interaction
      the vignette reproduces ("2x2 ANOVA, within-between design");
    - "2b*4w", n = 9, r = 0.71, sd = 2: b, w, b:w = 8.7, 5, 5 with mu = (0,0,0,0,
      .5,.5,.5,.5) and 7.1, 9.2, 9.2 with mu = (0,0,0,0, 0,.5,.5,.5)
      (test-anova_exact.R, the two "2b*4w" tests).

    test-anova_exact.R writes its values to one decimal (rounded or cut: 84.76 is
    written 84.7, 9.26 is 9.2) and compares them with a relative tolerance of 10 %; they
    are checked here to 0.1 points. G*Power's are checked to their last digit.
    """
    d = ExactDesign.from_sd_r({"speed": ["f", "m", "s"]}, [-0.3061862, 0.0, 0.3061862], 1, 0.8)
    assert 100 * power_of(d, 20)[0] == pytest.approx(96.9, abs=0.1)
    d = ExactDesign.from_sd_r({"speed": ["f", "s"]}, [0.0, 0.65], 1, 0.55)
    assert 100 * power_of(d, 21)[0] == pytest.approx(84.7, abs=0.1)
    d = ExactDesign.from_sd_r({"speed": ["f", "s"]}, [-0.25, 0.25], 1, 0.5)
    assert 100 * power_of(d, 34)[0] == pytest.approx(80.777, abs=1e-3)
    for r, printed in [(0.5, 91.25), (0.7, 98.98)]:
        d = ExactDesign.from_sd_r({"a": ["a1", "a2"]}, [[-0.25, 0.25], [0.25, -0.25]], 1, r,
                                  between={"b": ["b1", "b2"]})
        t = exact_anova(d, 23)
        assert list(t["effect"]) == ["b", "a", "b:a"]
        assert 100 * t["power"].iloc[2] == pytest.approx(printed, abs=0.005)
        assert t["power"].iloc[:2].to_numpy() == pytest.approx([0.05, 0.05], abs=1e-9)
    for mu, printed in [([[0, 0, 0, 0], [.5, .5, .5, .5]], [8.7, 5, 5]),
                        ([[0, 0, 0, 0], [0, .5, .5, .5]], [7.1, 9.2, 9.2])]:
        d = ExactDesign.from_sd_r({"w": ["1", "2", "3", "4"]}, mu, 2, 0.71,
                                  between={"b": ["1", "2"]})
        assert [100 * p for p in power_of(d, 9)] == pytest.approx(printed, abs=0.1)


# --------------------------------------------------------------------------- closed forms

def paired_t_power(n: int, delta: float, sd_diff: float, alpha: float = 0.05) -> float:
    """Two-sided paired t test: P(|T'| > t_crit), T' noncentral t, δ = d_z √n."""
    df, nc = n - 1, delta / sd_diff * math.sqrt(n)
    tc = stats.t.isf(alpha / 2, df)
    return float(stats.nct.sf(tc, df, nc) + stats.nct.cdf(-tc, df, nc))


@pytest.mark.parametrize("n,diff,sd,r", [(8, 0.5, 1.0, 0.5), (15, 0.3, 0.8, 0.7),
                                         (30, 1.0, 2.0, 0.0), (5, 0.9, 1.0, -0.3)])
def test_two_levels_within_is_the_paired_t_test(n, diff, sd, r):
    """A 2-level within factor: the RM-ANOVA F is the paired t², so its power is the
    noncentral t's with d_z = Δ / (σ √(2(1 − r)))."""
    d = ExactDesign.from_sd_r({"x": ["a", "b"]}, [0.0, diff], sd, r)
    expected = paired_t_power(n, diff, sd * math.sqrt(2 * (1 - r)))
    assert power_of(d, n)[0] == pytest.approx(expected, abs=1e-9)


def test_one_df_effects_of_a_2x2_are_paired_t_tests_under_any_correlations():
    """Each effect of a 2 × 2 within design has one df, so it is a paired t test on its
    contrast c (main effect A: (1, 1, −1, −1)/2, ..., interaction (1, −1, −1, 1)/2) whatever
    the correlations: d_z = cᵀμ / √(cᵀΣc). The design is Superpower's README example
    ("2w*2w", n = 80, mu = 1.1-1.4, sd = 2, correlations 0.91-0.96)."""
    mu = np.array([1.1, 1.2, 1.3, 1.4])
    R = np.array([[1, .91, .92, .93], [.91, 1, .94, .95], [.92, .94, 1, .96],
                  [.93, .95, .96, 1]])
    d = ExactDesign.from_sd_r({"a": ["a1", "a2"], "b": ["b1", "b2"]}, mu, 2.0, R)
    cov = 4.0 * R
    contrasts = [np.array([1, 1, -1, -1]) / 2, np.array([1, -1, 1, -1]) / 2,
                 np.array([1, -1, -1, 1]) / 2]
    got = power_of(d, 80)
    for c, p in zip(contrasts, got, strict=True):
        assert p == pytest.approx(paired_t_power(80, float(c @ mu), math.sqrt(c @ cov @ c)),
                                  abs=1e-9)


def test_the_smallest_n_is_the_first_n_whose_exact_dataset_reaches_the_target():
    """smallest_n scales λ and df_error from one dataset; checked against a dataset built at
    every N (within: a 3 × 2 with compound symmetry; mixed: 2b × 3w)."""
    within = ExactDesign.from_sd_r({"a": ["1", "2", "3"], "b": ["1", "2"]},
                                   [0.0, 0.3, 0.2, 0.6, 0.1, 0.2], 1.0, 0.6)
    mixed = ExactDesign.from_sd_r({"w": ["1", "2", "3"]}, [[0, .2, .4], [.1, .1, .1]], 1.0,
                                  0.5, between={"g": ["1", "2"]})
    for design in (within, mixed):
        found = smallest_n(design, 0.8, n_max=39)
        curve = {n: power_of(design, n) for n in range(2, 40)}
        for i, row in found.iterrows():
            scan = next((n for n in range(2, 40) if curve[n][i] >= 0.8), None)
            if row["n"] is None or row["n"] != row["n"]:
                assert scan is None and row["power"] < 0.8
                continue
            assert row["n"] == scan, (row["effect"], row["n"], scan)
            if scan is not None:
                assert row["power"] == pytest.approx(curve[scan][i], abs=1e-12)
        # power rises with N
        for i in range(len(found)):
            p = [curve[n][i] for n in range(2, 40)]
            assert all(b >= a - 1e-12 for a, b in zip(p, p[1:]))


def test_a_null_effect_has_power_alpha_and_no_n():
    d = ExactDesign.from_sd_r({"a": ["1", "2"], "b": ["1", "2"]}, [0, 0, 1, 1], 1.0, 0.5)
    t = exact_anova(d, 12)
    assert t.loc[t["effect"] == "b", "power"].iloc[0] == pytest.approx(0.05, abs=1e-12)
    row = smallest_n(d, 0.8, n_max=500).set_index("effect").loc["b"]
    assert row["n"] is None or row["n"] != row["n"]


def test_the_exact_dataset_is_a_tidy_table_rm_anova_reads():
    d = ExactDesign.from_sd_r({"w": ["x", "y"]}, [[0, 1], [1, 1]], [[1, 2], [1, 1]], 0.3,
                              between={"g": ["p", "q"]})
    t = exact_dataset(d, 5)
    assert len(t) == 2 * 5 * 2 and set(t.columns) == {"participant", "g", "w", "y"}
    g = t[t["g"] == "p"].pivot(index="participant", columns="w", values="y")
    assert np.allclose(g.std(ddof=1), [1, 2])


# --------------------------------------------------------------------------- simulate vs exact

def test_the_shipped_stated_designs_load_with_their_conditions():
    s = Setup.load(BALL, params_file=BALL_STATED)
    assert isinstance(s, StatedSetup)
    assert [c["timing"] for c in s.stated.conditions] == ["none", "none", "fixed", "fixed",
                                                         "varied", "varied"]
    assert s.stated.means[4] == pytest.approx(0.747)
    c = Setup.load(CVR, params_file=CVR_STATED)
    assert c.question == "shape_rating" and len(c.stated.conditions) == 4


def test_simulated_power_lies_within_its_interval_of_the_exact_power():
    """seed 000's six modes with the paper's rates, SD 0.25, r 0.5 (the shipped stated
    file), 15 participants fewer than the paper: 2000 studies of 8. Each declared ANOVA
    effect's simulated power (the real run_power: rm_anova_batch, the declared
    corrections, Wilson intervals) must hold the exact power in its 95 % interval. The
    intervals are narrow enough to tell N = 8 from N = 6 or 10. The display effect, whose
    cells average unequal numbers of modes, is checked at N = 4, where it is not 1."""
    setup = Setup.load(BALL, params_file=BALL_STATED)
    n = 8
    exact = setup.exact(n).set_index("effect")["exact_power"]
    res = run_power(BALL, n, 2000, seed=21, workers=1, params_file=BALL_STATED)
    sim = res.table.set_index("effect")
    assert list(sim.index) == list(exact.index)
    assert 0.2 < exact.iloc[1] < 0.8 and 0.2 < exact.iloc[3] < 0.8   # room both ways
    for effect, p in exact.items():
        row = sim.loc[effect]
        assert row["ci_low"] <= p <= row["ci_high"], (effect, p, row["power"])
    for m in (6, 10):                     # the neighbours' exact power lies outside
        other = setup.exact(m).set_index("effect")["exact_power"]
        effect = exact.index[1]
        assert not sim.loc[effect, "ci_low"] <= other[effect] <= sim.loc[effect, "ci_high"]
    # the means drawn are the stated ones
    means = res.means.set_index(["display", "timing", "intensity"])["predicted"]
    assert means[("dynamic", "varied", "linear")] == pytest.approx(0.747, abs=0.01)
    # display averages 2 static against 4 dynamic modes: at N = 4 its power is mid-range
    display = exact.index[0]
    p4 = setup.exact(4).set_index("effect").loc[display, "exact_power"]
    assert 0.6 < p4 < 0.95
    row = run_power(BALL, 4, 1000, seed=22, workers=1, params_file=BALL_STATED).table \
        .set_index("effect").loc[display]
    assert row["ci_low"] <= p4 <= row["ci_high"], (p4, row["power"])


def test_effects_with_several_df_are_exact_under_compound_symmetry(tmp_path):
    """seed 001's 4 × 8 grid (shape: 3 df, timing: 7, interaction: 21) with one SD and one r
    for all 32 conditions (compound symmetry: sphericity holds) and the ANOVA declared
    with correction: none: the simulated power of every effect holds the exact power in
    its interval. (With the shipped correction: auto the simulation applies
    Greenhouse-Geisser whenever Mauchly's test rejects or cannot be computed, and its
    power is then below the uncorrected exact value; docs/model-predictions.md.)"""
    grid = ROOT / "experiments" / "duration_interval_grid.yaml"
    exp = tmp_path / "grid.yaml"
    text = grid.read_text(encoding="utf-8")
    assert "      correction: auto\n" in text
    exp.write_text(text.replace("      correction: auto\n", "      correction: none\n"),
                   encoding="utf-8")
    lx = load_experiment(exp)
    shape = dict(zip(lx.experiment.factors["shape"].level_names, [0.0, 0.03, 0.05, 0.0]))
    timing = dict(zip(lx.experiment.factors["timing"].level_names,
                      [-0.06, 0, 0, 0.02, 0, 0.03, 0.02, 0.0]))
    lines = ["kind: stated", "means:"]
    for s, a in shape.items():
        bump = {t: 0.04 if (s, t) == ("circle", "200/100") else 0.0 for t in timing}
        cells = ", ".join(f"'{t}': {0.8 + a + b + bump[t]:.3f}" for t, b in timing.items())
        lines.append(f"  {s}: {{{cells}}}")
    stated = tmp_path / "grid_stated.yaml"
    stated.write_text("\n".join(lines + ["sd: 0.15", "r: 0.5", ""]), encoding="utf-8")
    setup = Setup.load(exp, params_file=stated)
    exact = setup.exact(8).set_index("effect")
    assert list(exact["df1"]) == [3, 7, 21]
    res = run_power(exp, 8, 1500, seed=3, workers=1, params_file=stated)
    sim = res.table.set_index("effect")
    for effect, row in exact.iterrows():
        s = sim.loc[effect]
        assert s["ci_low"] <= row["exact_power"] <= s["ci_high"], (effect, row["exact_power"],
                                                                  s["power"])
    assert 0.3 < exact["exact_power"].iloc[0] < 0.9 and 0.3 < exact["exact_power"].iloc[1] < 0.9


STEEP = """\
kind: stated
description: larger effects than seed 000's, so that power rises steeply near 0.8
means:
  static:
    none: {linear: 0.30, nonlinear: 0.25}
  dynamic:
    fixed: {linear: 0.45, nonlinear: 0.40}
    varied: {linear: 0.75, nonlinear: 0.45}
sd: 0.2
r: 0.5
"""


def test_target_power_finds_the_exact_n(tmp_path):
    """--target-power's search (simulate.smallest_n: N doubled from 4, then bisection, each
    N simulated afresh) finds, for each effect, the N that is exactly the smallest with
    power >= 0.8; or one off, and then only where the two disagree about N' = the smaller
    of the two Ns (the simulation said "reached" at N' where the exact power is below
    the target, or "not reached" at N' where it is at or above), with the exact power at
    N' inside the simulation's 95 % Wilson interval there, i.e. where 500 studies cannot
    tell N' from the target. The search never looks below 4, so the exact N is compared as
    max(exact N, 4)."""
    stated = tmp_path / "steep.yaml"
    stated.write_text(STEEP, encoding="utf-8")
    setup = Setup.load(BALL, params_file=stated)
    exact = setup.exact_smallest_n(0.8, n_max=64).set_index("effect")
    table, results = simulated_smallest_n(BALL, 0.8, 500, seed=5, n_max=64, workers=1,
                                          params_file=stated)
    for _, row in table.iterrows():
        n_sim = int(row["smallest_n"])
        n_exact = max(4, int(exact.loc[row["effect"], "smallest_n"]))
        if n_sim == n_exact:
            continue
        assert abs(n_sim - n_exact) == 1, (row["effect"], n_sim, n_exact)
        at = min(n_sim, n_exact)
        sim = results[at].table.set_index("effect").loc[row["effect"]]
        p = setup.exact(at).set_index("effect").loc[row["effect"], "exact_power"]
        assert sim["ci_low"] <= p <= sim["ci_high"], (row["effect"], at, p, sim["power"])
    assert (table["smallest_n"].astype(int).to_numpy()
            == np.maximum(4, exact["smallest_n"].astype(int).to_numpy())).sum() >= 2


# --------------------------------------------------------------------------- the CLI and bad files

def test_exact_is_printed_beside_the_simulated_power(cli):
    r = cli("simulate", str(BALL), "--observer", str(BALL_STATED), "--exact", "-n", "6",
            "-m", "300", "--workers", "1", "--quiet")
    assert r.returncode == 0, r.stderr
    out = r.stdout
    assert "Exact power at N = 6" in out
    exact = out[out.index("Exact power at N = 6"):]
    line = next(x for x in exact.splitlines() if x.strip().startswith("timing (rate"))
    assert line.split()[-1] in ("yes", "no") and "[" in line
    r = cli("simulate", str(BALL), "--exact", "-m", "2", "--quiet")
    assert r.returncode == 2 and "--exact" in r.stderr and "kind: stated" in r.stderr


GOOD = {"means": "{circle: {plain: 1, emphasised: 1}, rectangle: {plain: 0, emphasised: 0}}",
        "sd": "1", "r": "0.5"}


@pytest.mark.parametrize("change,line,key,words", [
    ({"means": "{circle: {plain: 1, emphasised: 1}, rectangle: {plain: 0, round: 0}}"},
     2, "means.rectangle.round", "not a level of corners"),
    ({"means": "{circle: {plain: 1, emphasised: 1}, rectangle: {plain: 0}}"},
     2, "means", "shape = rectangle, corners = emphasised"),
    ({"means": "{circle: {plain: 1, emphasised: x}, rectangle: {plain: 0, emphasised: 0}}"},
     2, "means.circle.emphasised", "expected a number"),
    ({"r": "-0.5"}, 4, "r", "not positive definite"),
    ({"r": "[[1, .9, .9, .9], [.9, 1, -0.9, .9], [.9, -0.9, 1, .9], [.9, .9, .9, 1]]"},
     4, "r", "not positive definite"),
    ({"r": "[[1, .5], [.5, 1]]"}, 4, "r", "4 × 4"),
    ({"r": "1.5"}, 4, "r", "between -1 and 1"),
    ({"sd": "0"}, 3, "sd", "above 0"),
    ({"sd": "{circle: {plain: 1, emphasised: 1}, rectangle: {plain: -1, emphasised: 1}}"},
     3, "sd.rectangle.plain", "above 0"),
])
def test_a_bad_stated_file_is_one_message_naming_file_line_and_key(tmp_path, change, line,
                                                                    key, words):
    v = {**GOOD, **change}
    p = tmp_path / "stated.yaml"
    p.write_text(f"kind: stated\nmeans: {v['means']}\nsd: {v['sd']}\nr: {v['r']}\n",
                 encoding="utf-8")
    with pytest.raises(InputError) as e:
        load_stated(p, load_experiment(CVR))
    assert (e.value.path, e.value.line, e.value.key) == (str(p), line, key), e.value
    assert words in e.value.message


def test_bad_stated_files_through_the_cli_are_one_line_without_traceback(cli, tmp_path):
    p = tmp_path / "stated.yaml"
    cases = [
        ("kind: stated\nmeans: {circle: {plain: 1}}\nsd: 1\nr: 0.5\n",
         "means: no value for the condition"),
        ("kind: fitted\n", "kind: 'fitted' is not a kind of observer file"),
        ("kind: stated\nmean: 1\n", "mean: unknown key"),
        ("kind: stated\nmeans: {circle: {plain: 1}}\nr: 0.5\n", "sd: missing"),
        ("kind: stated\nquestion: nope\n" + "".join(f"{k}: {v}\n" for k, v in GOOD.items()),
         "question: the experiment asks no question 'nope'"),
    ]
    for text, words in cases:
        p.write_text(text, encoding="utf-8")
        r = cli("simulate", str(CVR), "--observer", str(p), "-n", "3", "-m", "2", "--quiet")
        assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
        lines = [x for x in r.stderr.splitlines() if x.strip()]
        assert len(lines) == 1 and str(p) in lines[0] and words in lines[0], r.stderr
    # an experiment whose ANOVAs read two questions needs the question named
    p.write_text("kind: stated\nmeans: {}\nsd: 1\nr: 0.5\n", encoding="utf-8")
    r = cli("simulate", str(ROOT / "experiments" / "whirlpool.yaml"), "--observer", str(p),
            "-m", "2", "--quiet")
    assert r.returncode == 2 and "question: " in r.stderr and "sensation, turns" in r.stderr
