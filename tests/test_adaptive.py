"""Adaptive procedures: the rules against hand-worked sequences and PsychoPy's
StairHandler, QUEST+ against a plain loop over the grid, the device's range checked
before the first trial, resume replaying the log, and both shipped adaptive studies
run, resumed and analysed through the CLI."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from conftest import ROOT
from vtexp.adaptive import (Quest, QuestPlus, QuestPlusRule, QuestRule, Staircase,
                            StaircaseRule, fit_psychometric, psi, target_probability)

STAIR = ROOT / "experiments" / "shape_soa_staircase.yaml"
QPLUS = ROOT / "experiments" / "apparent_motion_questplus.yaml"


def _run(rule, answers):
    s = Staircase(rule)
    levels = []
    for yes in answers:
        levels.append(s.propose())
        s.update(s.propose(), yes)
    return levels, s


# --------------------------------------------------------------------------- staircases

def test_one_up_two_down_by_hand():
    # start 10, down after two yes, up after one no; steps 4 then 2 after the first reversal
    rule = StaircaseRule(start=10, steps_down=(4, 2), steps_up=(4, 2), n_up=1, n_down=2)
    answers = [1, 1, 1, 1, 0, 1, 1, 0, 0, 1, 1]
    levels, s = _run(rule, [bool(a) for a in answers])
    #   10 y, 10 y -> 6; 6 y, 6 y -> 2; 2 n -> up (reversal at 2, step 2) 4;
    #   4 y, 4 y -> down (reversal at 4, step 2) 2; 2 n -> up (reversal at 2) 4; 4 n -> 6;
    #   6 y, 6 y -> down (reversal at 6) 4
    assert levels == [10, 10, 6, 6, 2, 4, 4, 2, 4, 6, 6]
    assert s.reversal_levels == [2, 4, 2, 6]
    assert s.level == 4
    assert s.estimate() == pytest.approx((2 + 6) / 2)   # all but the first, to an even count


def test_weighted_up_down_by_hand():
    # Kaernbach 1991: target 75 % -> up steps 3 x the down step
    from vtexp.adaptive import weighted_up_steps
    up = weighted_up_steps((1.0,), 0.75)
    assert up == (3.0,)
    rule = StaircaseRule(start=10, steps_down=(1.0,), steps_up=up)
    levels, s = _run(rule, [True, True, False, True, False, False])
    assert levels == [10, 9, 8, 11, 10, 13]
    assert s.level == 16 and s.reversal_levels == [8, 11, 10]
    assert rule.target == pytest.approx(0.75)


def test_stop_rules_and_limits():
    rule = StaircaseRule(start=3, steps_down=(2,), steps_up=(2,), minimum=0, maximum=6,
                         max_reversals=3)
    levels, s = _run(rule, [True, True, True, False, False, False, False, True, False])
    assert min(levels) == 0 and max(levels) <= 6        # clamped at the limits
    assert s.finished and len(s.reversal_levels) >= 3
    assert Staircase(StaircaseRule(start=1, steps_down=(1,), steps_up=(1,), max_trials=2)) \
        .finished is False
    assert target_probability(1, 2) == pytest.approx(0.5 ** 0.5)
    assert target_probability(1, 3) == pytest.approx(0.5 ** (1 / 3))
    assert target_probability(2, 1) == pytest.approx(1 - 0.5 ** 0.5)
    assert target_probability(1, 1) == pytest.approx(0.5)


@pytest.mark.parametrize("n_up,n_down,steps,initial", [
    (1, 1, [1.0], False), (1, 2, [4.0, 2.0, 1.0], False), (1, 3, [2.0, 1.0], True),
    (2, 1, [3.0], True), (1, 2, [8.0, 4.0, 2.0, 1.0], True)])
def test_staircase_matches_psychopy(n_up, n_down, steps, initial):
    """The same answers give PsychoPy's StairHandler's levels and reversals (linear steps)."""
    data = pytest.importorskip("psychopy.data")
    rng = np.random.default_rng(n_up * 10 + n_down)
    answers = (rng.random(80) < 0.7).tolist()
    ps = data.StairHandler(startVal=20.0, nReversals=1000, stepSizes=steps, nTrials=1000,
                           nUp=n_up, nDown=n_down, stepType="lin", minVal=0.0, maxVal=40.0,
                           applyInitialRule=initial)
    theirs = []
    for yes in answers:
        theirs.append(next(ps))
        ps.addResponse(int(yes))
    rule = StaircaseRule(start=20.0, steps_down=tuple(steps), steps_up=tuple(steps), n_up=n_up,
                         n_down=n_down, minimum=0.0, maximum=40.0, initial_one_down=initial)
    mine, s = _run(rule, answers)
    assert mine == pytest.approx(theirs)
    assert s.reversal_levels == pytest.approx(ps.reversalIntensities)


# --------------------------------------------------------------------------- QUEST / QUEST+

def _plain_questplus(levels, thresholds, slopes, lapses, guess, history):
    """Posterior and expected entropies by plain loops over the grid, as Watson 2017 writes
    them (no algebra, no numpy vectorisation)."""
    thetas = [(a, b, l) for a in thresholds for b in slopes for l in lapses]

    def p_yes(x, th):
        a, b, l = th
        return guess + (1 - guess - l) * (1 - math.exp(-((x / a) ** b)))

    post = [1.0 / len(thetas)] * len(thetas)
    for x, yes in history:
        post = [p * (p_yes(x, th) if yes else 1 - p_yes(x, th)) for p, th in zip(post, thetas)]
        z = sum(post)
        post = [p / z for p in post]
    eh = []
    for x in levels:
        total = 0.0
        for r in (1, 0):
            joint = [p * (p_yes(x, th) if r else 1 - p_yes(x, th)) for p, th in zip(post, thetas)]
            pr = sum(joint)
            h = -sum((j / pr) * math.log(j / pr) for j in joint if j > 0)
            total += pr * h
        eh.append(total)
    return post, eh


def test_questplus_equals_a_plain_grid_computation():
    levels = list(np.linspace(10, 300, 12))
    th, sl, la = list(np.linspace(20, 280, 7)), [1.0, 2.5, 4.0], [0.0, 0.03]
    q = QuestPlus(QuestPlusRule(levels=tuple(levels), thresholds=tuple(th), slopes=tuple(sl),
                                lapses=tuple(la), guess=0.0))
    rng = np.random.default_rng(5)
    history = []
    for k in range(25):
        x = q.propose()
        yes = bool(rng.random() < psi(x, 120, 3, 0, 0.02))
        history.append((x, yes))
        q.update(x, yes)
        if k in (0, 7, 24):
            post, eh = _plain_questplus(levels, th, sl, la, 0.0, history)
            np.testing.assert_allclose(q.posterior, post, rtol=0, atol=1e-9)
            np.testing.assert_allclose(q.expected_entropy(), eh, rtol=0, atol=1e-9)
    assert q.propose() == levels[int(np.argmin(eh))]


def test_questplus_draws_among_the_best_with_the_keyed_stream():
    from vtexp.design import HashRandom
    rule = QuestPlusRule(levels=tuple(range(10, 301, 10)), thresholds=(50, 100, 150, 200),
                         slopes=(2, 4), select_among=4)
    a, b = QuestPlus(rule), QuestPlus(rule)
    picks = [a.propose(HashRandom(7)) for _ in range(3)]
    assert picks == [b.propose(HashRandom(7)) for _ in range(3)]
    best = np.argsort(a.expected_entropy(), kind="stable")[:4]
    assert all(p in [rule.levels[i] for i in best] for p in picks)


def test_quest_posterior_by_hand():
    th = tuple(np.linspace(10, 200, 40))
    q = Quest(QuestRule(thresholds=th, slope=3, lapse=0.01, prior_mean=100, prior_sd=50))
    history = [(100, True), (60, False), (80, True)]
    for x, yes in history:
        q.update(x, yes)
    post = []
    for a in th:
        p = math.exp(-0.5 * ((a - 100) / 50) ** 2)
        for x, yes in history:
            py = 0.99 * (1 - math.exp(-((x / a) ** 3)))
            p *= py if yes else 1 - py
        post.append(p)
    z = sum(post)
    np.testing.assert_allclose(q.posterior(), [p / z for p in post], atol=1e-12)
    assert q.propose() == pytest.approx(sum(a * p / z for a, p in zip(th, post)))


@pytest.mark.parametrize("function", ["weibull", "logistic", "normal", "gumbel"])
def test_the_likelihood_gradient_equals_finite_differences(function):
    from scipy.optimize import approx_fprime

    from vtexp.adaptive.fit import _nll
    rng = np.random.default_rng(1)
    checked = 0
    while checked < 60:
        levels = np.sort(rng.uniform(10 if function == "weibull" else -50, 300, 6))
        n = rng.integers(1, 20, 6).astype(float)
        k = np.floor(rng.uniform(0, 1, 6) * (n + 1)).clip(0, n)
        guess = float(rng.choice([0.0, 0.5, 1 / 3]))
        slope = rng.uniform(0.5, 10) if function == "weibull" else rng.uniform(0.01, 5)
        for lapse in (None, 0.02):
            theta = np.array([rng.uniform(50, 250), np.log(slope)]
                             + ([rng.uniform(0, 0.1)] if lapse is None else []))
            p = psi(levels, theta[0], slope, guess, theta[2] if lapse is None else lapse,
                    function)
            if p.min() < 1e-6 or p.max() > 1 - 1e-6:
                continue                    # where psi's own rounding hides its slope
            _, grad = _nll(theta, levels, k, n, guess, function, lapse)
            num = approx_fprime(theta, lambda t: _nll(t, levels, k, n, guess, function,
                                                      lapse)[0], 1e-7)
            np.testing.assert_allclose(grad, num, rtol=2e-3, atol=2e-3)
            checked += 1


def test_fit_recovers_a_known_function():
    rng = np.random.default_rng(3)
    x = np.repeat(np.linspace(20, 300, 15), 40)
    yes = rng.random(x.size) < psi(x, 150, 3, 0.25, 0.02)
    f = fit_psychometric(x, yes, guess=0.25, bootstrap=50, name="p")
    assert abs(f.threshold - 150) < 12 and f.threshold_ci[0] < 150 < f.threshold_ci[1]
    again = fit_psychometric(x, yes, guess=0.25, bootstrap=50, name="p")
    assert again.threshold_ci == f.threshold_ci                # keyed: the same every run


# --------------------------------------------------------------------------- bad input

def _variant(tmp_path, src, old, new, name="bad.yaml"):
    text = src.read_text(encoding="utf-8")
    assert old in text
    p = tmp_path / name
    p.write_text(text.replace(old, new), encoding="utf-8")
    return p


@pytest.mark.parametrize("old,new,words", [
    ("    start: 400\n    n_up", "    start: 410\n    n_up", "start 410 is not one of the levels"),
    ("steps: [80, 40, 20]", "steps: [80, 30, 20]", "a step of 30"),
    ("values: {min: 20, max: 500, step: 20}", "values: {min: 20, max: 500, step: 12.5}",
     "whole milliseconds"),
    ("slow: {start: 400}", "slow: {start: 600}", "start 600 is not one of the levels"),
])
def test_a_staircase_off_the_device_is_refused_before_the_first_trial(cli, tmp_path, old, new,
                                                                       words):
    bad = _variant(tmp_path, STAIR, old, new)
    data = tmp_path / "data"
    r = cli("run", str(bad), "-p", "01", "--responder", "scripted:correct", "--data", str(data),
            "--quiet")
    assert r.returncode == 2
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and words in lines[0] and "bad.yaml:" in lines[0], r.stderr
    assert "Traceback" not in r.stderr and not data.exists()


def test_levels_beyond_the_device_are_refused(tmp_path):
    from vtexp.errors import InputError
    from vtexp.experiment import load_experiment
    bad = _variant(tmp_path, QPLUS, "  variable: soa_ms\n  values: {min: 10, max: 300, step: 5}",
                   "  variable: level\n  values: {min: 1, max: 4, step: 1}")
    with pytest.raises(InputError, match="vest_6x8 plays whole levels from 0 to 2; 3 is not"):
        load_experiment(bad)


# --------------------------------------------------------------------------- sessions

PSY = "scripted:psychometric:threshold=150,slope=3,lapse=0.02"


def _beh(data, exp, pid):
    f = next((data / exp / f"sub-{pid}" / "ses-1" / "beh").glob("*_beh.tsv"))
    return f, pd.read_csv(f, sep="\t", dtype=str)


def test_resume_gives_the_same_proposals_and_refuses_a_tampered_log(cli, tmp_path):
    data = tmp_path / "data"
    args = ["--responder", PSY, "--data", str(data), "--quiet"]
    assert cli("run", str(QPLUS), "-p", "A", *args).returncode == 0
    assert cli("run", str(QPLUS), "-p", "B", "--max-trials", "17", *args).returncode == 0
    r = cli("run", str(QPLUS), "-p", "B", "--session", "1", "--resume", *args)
    assert r.returncode == 0, r.stderr
    # Same seed (design.seed absent: derived from participant), so compare B with a fresh
    # uninterrupted run of B in another folder.
    other = tmp_path / "other"
    assert cli("run", str(QPLUS), "-p", "B", "--responder", PSY, "--data", str(other),
               "--quiet").returncode == 0
    _, resumed = _beh(data, "apparent_motion_questplus", "B")
    _, whole = _beh(other, "apparent_motion_questplus", "B")
    cols = ["trial", "proposed", "presented", "answer"]
    pd.testing.assert_frame_equal(resumed[cols], whole[cols])
    assert resumed["proposed"].nunique() > 5

    # a changed answer: the next proposal no longer follows
    assert cli("run", str(QPLUS), "-p", "C", "--max-trials", "12", *args).returncode == 0
    f, beh = _beh(data, "apparent_motion_questplus", "C")
    lines = f.read_text(encoding="utf-8").splitlines(keepends=True)
    cells = lines[5].split("\t")
    i = beh.columns.get_loc("answer")
    cells[i] = "moving" if cells[i] == "separate" else "separate"
    lines[5] = "\t".join(cells)
    f.write_text("".join(lines), encoding="utf-8")
    r = cli("run", str(QPLUS), "-p", "C", "--session", "1", "--resume", *args)
    assert r.returncode != 0
    assert "does not follow from the answers" in r.stderr and "trial 6" in r.stderr
    assert "Traceback" not in r.stderr and "--resume" not in r.stderr    # no hint to retry


def test_both_adaptive_studies_run_resume_and_analyse(cli, tmp_path):
    data = tmp_path / "data"
    for exp, pid in ((STAIR, "01"), (QPLUS, "01"), (QPLUS, "02")):
        base = ["--responder", PSY, "--data", str(data), "--quiet"]
        r = cli("run", str(exp), "-p", pid, "--max-trials", "20", *base)
        assert r.returncode == 0, r.stderr
        r = cli("run", str(exp), "-p", pid, "--session", "1", "--resume", *base)
        assert r.returncode == 0, r.stderr
    _, stair = _beh(data, "shape_soa_staircase", "01")
    ok = stair[stair["status"] == "ok"]
    assert (ok["proposed"] == ok["presented"]).all()          # a staircase stays on the levels
    assert set(stair["status"]) <= {"ok", "stopped"}
    for name, n in (("shape_soa_staircase", 1), ("apparent_motion_questplus", 2)):
        out = tmp_path / f"out-{name}"
        r = cli("analyze", str(data / name), "--out", str(out))
        assert r.returncode == 0, r.stderr
        fit = pd.read_csv(out / name / "psychometric_fit.csv")
        assert len(fit) == n and fit["converged"].all()
        assert ((fit["threshold_ci_low"] <= fit["threshold"])
                & (fit["threshold"] <= fit["threshold_ci_high"])).all()
        assert (fit["threshold"] - 150).abs().max() < 60
        assert (out / name / "figure_psychometric.png").stat().st_size > 5000
        assert "threshold of soa_ms" in (out / name / "report.md").read_text(encoding="utf-8")
