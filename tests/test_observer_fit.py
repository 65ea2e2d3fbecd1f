"""Fitting the model participant to answers: the likelihood, recovery of known parameters,
identifiability, and ``vtexp observer fit`` on logged sessions."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from conftest import ROOT

from vtexp.cli import main
from vtexp.compile import compile_conditions
from vtexp.devices.sim import SimDevice
from vtexp.experiment import load_experiment
from vtexp.observer import ModelObserver, ObserverModel
from vtexp.observer.fit import fit_participant, simulated_trials
from vtexp.observer.likelihood import Likelihood, Trial, _answer_options, decision_values
from vtexp.observer.model import question_columns
from vtexp.observer.params import load_params
from vtexp.session import SessionOptions, run_session
from vtexp.simulate import Setup, simulate_participant

GRID = ROOT / "experiments" / "duration_interval_grid.yaml"
#: Participants who differ only in their decision parameters (the fit holds the percept's).
SAME_SKIN = {"population": {"two_point_threshold_cv": 0.0, "integration_cv": 0.0,
                            "intensity_levels_sd": 0.0}}


@pytest.mark.parametrize("name", ["duration_interval_grid", "six_mode_ball", "whirlpool",
                                  "circle_vs_rectangle"])
def test_the_probabilities_are_the_frequencies_of_the_model_s_answers(name):
    """Choices with and without an abstain option, ratings and counts: what the likelihood
    says of each answer is how often the model participant gives it (6,000 draws a
    condition; at most 5 standard errors apart in the worst of every cell)."""
    setup = Setup.load(ROOT / "experiments" / f"{name}.yaml")
    m = setup.model
    who = m.participant(0, "x", typical=True)
    v = decision_values(m)
    v.update(efficiency=who.efficiency, decision_noise=who.decision_noise, lapse=0.05)
    who = dataclasses.replace(who, lapse=0.05, rating_bias=0.0)
    conditions = list(zip(setup.conditions, setup.played, strict=True))[:6]
    rng = np.random.default_rng(7)
    n = 6000
    for q in m.lx.experiment.asked():
        lik = Likelihood(m, who, [Trial(q.name, c, p, _answer_options(q)[0])
                                  for c, p in conditions])
        P = lik.probabilities(v)[0]
        opts = _answer_options(q)
        for gi, (c, p) in enumerate(conditions):
            got = m.answers(q, c, p, who, rng.random((n, question_columns(q))))
            freq = np.array([sum(a == o for a in got) for o in opts]) / n
            se = np.sqrt(np.maximum(P[gi] * (1 - P[gi]), 1e-4) / n)
            assert np.all(np.abs(freq - P[gi]) < 5 * se + 2e-3), (q.name, c.levels, freq, P[gi])
            assert P[gi].sum() == pytest.approx(1.0, abs=5e-3)


def test_the_likelihood_is_smooth_and_the_same_at_every_call():
    """Common random numbers: no Monte-Carlo jitter between neighbouring values."""
    setup = Setup.load(GRID)
    m = setup.model
    who = m.participant(0, "x", typical=True)
    lik = Likelihood(m, who, simulated_trials(setup, simulate_participant(setup, 1, "P1")))
    v = decision_values(m)
    x = np.linspace(np.log(0.05), np.log(0.2), 21)
    ll = np.array([lik({**v, "efficiency": float(np.exp(e))}) for e in x])
    assert lik({**v, "efficiency": float(np.exp(x[3]))}) == ll[3]
    second = np.abs(np.diff(ll, 2))
    assert second.max() < 0.05 * (ll.max() - ll.min()) + 0.05


@pytest.mark.parametrize("name", ["six_mode_ball", "letters", "whirlpool"])
def test_several_parameter_vectors_at_once_are_each_one_s_likelihood(name):
    """Likelihood.batch, which the fit's searches call with a point and its finite
    differences: each row is the likelihood of that vector alone, whatever else is in
    the batch (choices with and without abstaining, ratings, counts)."""
    from vtexp.observer.likelihood import batch_values
    setup = Setup.load(ROOT / "experiments" / f"{name}.yaml")
    m = setup.model
    lik = Likelihood(m, m.participant(0, "x", typical=True),
                     simulated_trials(setup, simulate_participant(setup, 3, "b1")))
    v = decision_values(m)
    vectors = [v, {**v, "efficiency": 0.3, "lapse": 0.1},
               {**v, "decision_noise": 2.5, "abstain_criterion": 0.2},
               {**v, "rating_step": 0.5, "rating_bias": -0.7, "turns_sd": 1.3}]
    together = lik.batch(batch_values(vectors))
    alone = [lik(x) for x in vectors]
    assert together == pytest.approx(alone, rel=1e-12, abs=1e-9)
    assert len(set(np.round(alone, 6))) > 1          # the vectors do differ in likelihood


def test_the_rating_step_and_the_turns_sd_are_recovered():
    """A whirlpool participant (three sessions, 54 ratings and 54 counts) whose rating
    criteria are 0.4 apart and whose counts of turns have an SD of 1.5, fitted from the
    observer file's 1.0 and 0.5: each truth inside its interval, each start outside."""
    path = ROOT / "experiments" / "whirlpool.yaml"
    truth = Setup.load(path, overrides={"rating_step": 0.4, "turns_sd": 1.5})
    rows = [r for ses in (1, 2, 3)
            for r in simulate_participant(truth, 4, "w1", session=ses, typical=True)]
    setup = Setup.load(path)
    m = setup.model
    lik = Likelihood(m, m.participant(0, "fit", typical=True), simulated_trials(setup, rows))
    f = fit_participant(lik, ["rating_step", "turns_sd"], decision_values(m))
    step, sd = f.params["rating_step"], f.params["turns_sd"]
    assert step.identified and step.low <= 0.4 <= step.high and step.high < 1.0
    assert sd.identified and sd.low <= 1.5 <= sd.high and sd.low > 0.5


def test_known_parameters_are_recovered_within_their_intervals():
    """Three model participants of the duration/interval study (96 trials each) with
    known efficiency and lapse, fitted back: both parameters identified, the truth
    inside at least 5 of the 6 intervals."""
    setup = Setup.load(GRID, overrides=SAME_SKIN)
    m = setup.model
    fixed = decision_values(m)
    skin = m.participant(0, "fit", typical=True)
    inside = 0
    for pid in ("r1", "r2", "r3"):
        who = m.participant(4, pid)
        lik = Likelihood(m, skin, simulated_trials(setup, simulate_participant(setup, 4, pid)))
        f = fit_participant(lik, ["efficiency", "lapse"], fixed, participant=pid)
        for name in ("efficiency", "lapse"):
            p = f.params[name]
            assert p.identified, (pid, name, p)
            inside += p.low <= getattr(who, name) <= p.high
    assert inside >= 5


def test_the_population_centre_s_interval_is_the_t_interval_for_a_normal_sample():
    """Participants whose log efficiencies are known to within 0.15 (a Gaussian profile)
    and spread well beyond that: the population is a normal sample, whose centre's exact
    95 % interval is the one-sample t interval. The small-sample cut gives it (within
    the grids' resolution); the chi-square cut is narrower, as for few participants it
    should not be (the reason for the cut)."""
    from scipy.stats import t as student

    from vtexp.observer.fit import (
        HALF_CHI2, ParameterFit, ParticipantFit, centre_cut, population, spec_of)
    assert centre_cut(4) == pytest.approx(2.952, abs=1e-3)
    assert centre_cut(3) == pytest.approx(3.492, abs=1e-3)
    assert centre_cut(10_000) == pytest.approx(HALF_CHI2, abs=1e-3)
    spec = spec_of("efficiency")
    u = np.linspace(*spec.bounds_u, 2001)
    logs = np.array([-3.4, -2.9, -2.1, -1.6, -2.6])
    for n in (4, 5):
        fits = [ParticipantFit(f"p{i}", 60, 0.0, {"efficiency": ParameterFit(
            "efficiency", float(np.exp(m)), 0.0, 0.0, True, grid=list(np.exp(u)),
            profile=list(-0.5 * ((u - m) / 0.15) ** 2))}, 1.0, 1)
            for i, m in enumerate(logs[:n])]
        pop = population(fits, ["efficiency"])
        x = logs[:n]
        half = student.ppf(0.975, n - 1) * x.std(ddof=1) / np.sqrt(n)
        lo, hi = np.log(pop.intervals["efficiency"])
        assert np.log(pop.values["efficiency"]) == pytest.approx(x.mean(), abs=0.01)
        assert lo == pytest.approx(x.mean() - half, abs=0.03)
        assert hi == pytest.approx(x.mean() + half, abs=0.03)
        clo, chi = np.log(pop.chi2_intervals["efficiency"])
        assert chi - clo < 0.8 * (hi - lo)


def test_the_integration_time_is_recovered_on_its_grid():
    """The back's integration time, the parameter seed 001's 0.1 s collapse asks about: a
    participant of the duration/interval study (two sessions) whose percept integrates
    over 150 ms is fitted back from the default's 40 ms, within a finite interval."""
    from vtexp.observer.fit import fit_percept_participant, percept_grid, with_percept
    setup = Setup.load(GRID, overrides={"integration_ms": 150.0})
    m = setup.model
    rows = [r for ses in (1, 2)
            for r in simulate_participant(setup, 5, "t1", session=ses, typical=True)]
    who = m.participant(0, "fit", typical=True)
    grid = percept_grid("integration_ms")
    liks = [Likelihood(m, with_percept(who, "integration_ms", v), simulated_trials(setup, rows))
            for v in grid]
    f = fit_percept_participant(liks, "integration_ms", grid, [], decision_values(m))
    p = f.params["integration_ms"]
    assert p.identified and p.low <= 150.0 <= p.high
    assert p.low > grid[0] and p.high < grid[-1] and p.high / p.low < 3


def test_a_parameter_the_answers_do_not_depend_on_is_not_identified(tmp_path):
    """Every answer of the duration/interval study rendered as the same circle: the
    percept cannot favour any answer, so efficiency changes nothing and is reported as
    not identified, with no estimate."""
    text = GRID.read_text(encoding="utf-8") + (
        "\nobserver:\n  templates:\n    triangle: circle\n    square: circle\n"
        "    rectangle: circle\n")
    path = tmp_path / "same_templates.yaml"
    path.write_text(text, encoding="utf-8")
    setup = Setup.load(path, overrides=SAME_SKIN)
    m = setup.model
    lik = Likelihood(m, m.participant(0, "fit", typical=True),
                     simulated_trials(setup, simulate_participant(setup, 2, "u1")))
    f = fit_participant(lik, ["efficiency"], decision_values(m), participant="u1")
    p = f.params["efficiency"]
    assert not p.identified and p.estimate is None
    assert p.text() == "not identified"
    assert max(p.profile) - min(p.profile) < 1e-6


# --------------------------------------------------------------------------- the command

@pytest.fixture(scope="module")
def logged(tmp_path_factory):
    """Sessions written as vtexp run writes them: two model participants of the
    duration/interval study (whole), and two trials of another study."""
    root = tmp_path_factory.mktemp("fitdata")
    lx = load_experiment(GRID)
    model = ObserverModel.for_experiment(lx)
    conditions = compile_conditions(lx, model.profile)
    for pid in ("sim1", "sim2"):
        run_session(lx, SimDevice(model.profile), ModelObserver(model, pid, 1, seed=9),
                    SessionOptions(participant=pid, data_dir=root / "grid",
                                   conditions=conditions))
    other = load_experiment(ROOT / "experiments" / "circle_vs_rectangle.yaml")
    om = ObserverModel.for_experiment(other)
    run_session(other, SimDevice(om.profile), ModelObserver(om, "sim1", 1, seed=9),
                SessionOptions(participant="sim1", data_dir=root / "other",
                               conditions=compile_conditions(other, om.profile),
                               max_trials=2))
    return root


def test_the_command_fits_logged_sessions_and_writes_an_observer_file(logged, tmp_path,
                                                                      capsys):
    data = logged / "grid" / "duration_interval_grid"
    out = tmp_path / "fitted.yaml"
    assert main(["observer", "fit", str(data), "--params", "efficiency,lapse",
                 "--out", str(out), "--json", str(tmp_path / "fit.json")]) == 0
    text = capsys.readouterr().out
    assert "sim1" in text and "sim2" in text and "efficiency [95% CI]" in text
    params = load_params(out)                       # what vtexp simulate --observer reads
    assert 1e-3 <= params.efficiency <= 1.0
    assert out.read_text(encoding="utf-8").startswith("# Fitted by vtexp observer fit")
    setup = Setup.load(GRID, params_file=out)
    assert setup.model.params.efficiency == params.efficiency
    # what was fitted, machine-readable: each identified centre in its 95 % interval
    fitted = params.fitted
    assert fitted is not None and fitted.participants == 2
    assert set(fitted.params) | set(fitted.not_identified) == {"efficiency", "lapse"}
    assert "efficiency" in fitted.params
    e = fitted.params["efficiency"]
    assert e.centre == pytest.approx(params.efficiency)
    assert e.low < e.centre < e.high
    for name, v in fitted.params.items():
        assert v.low <= v.centre <= v.high and v.centre == pytest.approx(getattr(params, name))
    doc = json.loads((tmp_path / "fit.json").read_text(encoding="utf-8"))
    assert doc["population"]["intervals"]["efficiency"] == pytest.approx([e.low, e.high],
                                                                         rel=1e-5)
    # vtexp simulate reports the power at the centre and its range over the intervals
    runs = sum((v.low != v.centre) + (v.high != v.centre) for v in fitted.params.values())
    assert main(["simulate", str(GRID), "--observer", str(out), "-n", "2", "-m", "2",
                 "--workers", "1", "-q", "--json", str(tmp_path / "sim.json")]) == 0
    cap = capsys.readouterr()
    assert f"{runs} more runs of 2 studies" in cap.err
    assert "over the fitted parameters' 95 % intervals" in cap.out
    sim = json.loads((tmp_path / "sim.json").read_text(encoding="utf-8"))
    rng = sim["power_range"]
    assert len(rng["runs"]) == runs and len(rng["effects"]) == len(sim["power"])
    for r in rng["effects"]:
        assert r["low"] <= r["centre"] <= r["high"]
        assert f"{r['centre']:6.3f}  {r['low']:.3f} .. {r['high']:.3f}" in cap.out


def test_the_percepts_come_from_the_device_events(logged, tmp_path):
    """A trial's percept is what its device events say was played, not the plan: the
    events as logged give the planned pulses; events moved 50 ms later give pulses 50 ms
    later."""
    import shutil

    import pandas as pd

    from vtexp.observer.fit import read_trials
    setup = Setup.load(GRID)
    plan = dict(enumerate(setup.played))
    data = logged / "grid" / "duration_interval_grid"

    def first_trial(folder):
        t = next(t for t in read_trials([folder]).trials["sim1"])
        return t, [(p.row, p.col, p.onset_ms, p.duration_ms) for p in t.played.pulses]

    t, played = first_trial(data)
    assert played == [(p.row, p.col, p.onset_ms, p.duration_ms)
                      for p in plan[t.condition.index].pulses]
    copy = tmp_path / "moved"
    shutil.copytree(data, copy)
    ev = next(copy.rglob("sub-sim1_*_events.tsv"))
    df = pd.read_csv(ev, sep="\t", dtype=str, keep_default_na=False)
    first = df["trial"] == "1"
    df.loc[first, "onset_ms"] = (df.loc[first, "onset_ms"].astype(float) + 50).astype(str)
    df.to_csv(ev, sep="\t", index=False)
    t2, moved = first_trial(copy)
    assert t2.condition.index == t.condition.index
    assert moved == [(r, c, o + 50, d) for r, c, o, d in played]


@pytest.mark.parametrize("case", ["unknown", "uninformed", "percept", "two-percepts", "mixed",
                                  "no-events"])
def test_bad_input_is_one_message(logged, tmp_path, capsys, case):
    grid = logged / "grid" / "duration_interval_grid"
    args = {"unknown": [str(grid), "--params", "efficiency,sharpness"],
            "uninformed": [str(grid), "--params", "rating_step"],
            "percept": [str(grid), "--params", "intensity_levels"],
            "two-percepts": [str(grid), "--params", "integration_ms,two_point_threshold_mm"],
            "mixed": [str(grid), str(logged / "other")],
            "no-events": None}[case]
    if case == "no-events":
        import shutil
        copy = tmp_path / "copy"
        shutil.copytree(grid, copy)
        for f in copy.rglob("*_events.tsv"):
            f.unlink()
        args = [str(copy)]
    code = main(["observer", "fit", *args, "--out", str(tmp_path / "o.yaml")])
    err = capsys.readouterr().err
    errors = [ln for ln in err.splitlines() if ln.startswith("vtexp: error:")]
    assert code == 2 and len(errors) == 1 and "Traceback" not in err
    expect = {"unknown": "no parameter 'sharpness'", "uninformed": "asks no rating question",
              "percept": "shapes the percept itself", "mixed": "different experiments",
              "two-percepts": "fit one of them at a time",
              "no-events": "no device events"}[case]
    assert expect in errors[0]
    assert not (tmp_path / "o.yaml").exists()
