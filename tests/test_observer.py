"""The model participant on its own, in a session, and the simulator's power against theory."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest
from conftest import ROOT
from scipy import stats

from vtexp.compile import compile_conditions
from vtexp.devices.sim import SimDevice
from vtexp.experiment import load_experiment
from vtexp.observer import ModelObserver, ObserverModel
from vtexp.observer.params import load_params
from vtexp.observer.percept import Skin, features, noise_density
from vtexp.session import SessionOptions, run_session
from vtexp.simulate import Setup, run_power, simulate_participant, simulate_studies

GRID = ROOT / "experiments" / "duration_interval_grid.yaml"
STUDIES = ["six_mode_ball", "duration_interval_grid", "whirlpool", "circle_vs_rectangle",
           "letters"]


def _rate(setup: Setup, n: int, seed: int = 0) -> float:
    df = simulate_studies(setup, seed, [0], n)
    return float(df["correct"].mean())


def test_the_noise_is_calibrated_by_the_two_point_threshold():
    """Two one-tau pulses one TPT apart are told apart at d' = 1 (efficiency 1)."""
    from vtexp.model import DeviceProfile, PlayedPulse, PlayReport
    prof = DeviceProfile.load("vest_6x8")           # pitch 40 mm
    skin = Skin(two_point_threshold_mm=40.0, integration_ms=40.0, intensity_levels=8)
    reps = [PlayReport(device="vest_6x8", started_at_ms=0, duration_ms=40, pulses=[
        PlayedPulse(row=0, col=c, scheduled_onset_ms=0, onset_ms=0, duration_ms=40, level=2)])
        for c in (0, 1)]
    f = features(reps, prof, skin, np.array([0, 1]))
    d = float(np.linalg.norm((f[0] - f[1]).astype(float)) / math.sqrt(noise_density(skin)))
    assert d == pytest.approx(1.0, rel=0.02)


def test_a_clear_percept_beats_a_blurred_one():
    """The same shapes on the back, felt by a skin as sharp as a palm's (10 mm) and by one
    that blurs over four tactors (160 mm): the shapes are farther apart in d' and
    recognised more often with the clear percept. The low-speed prior is off: it moves
    what was played away from the told shapes by the same amount for both skins, which
    costs the sharp one more (its own test is below)."""
    sharp = Setup.load(GRID, overrides={"two_point_threshold_mm": {"lower_back": 10.0},
                                        "speed_prior_mm_s": 0.0})
    blurred = Setup.load(GRID, overrides={"two_point_threshold_mm": {"lower_back": 160.0},
                                          "speed_prior_mm_s": 0.0})
    q = sharp.lx.experiment.asked()[0]

    def mean_d(setup):
        who = setup.model.participant(0, "A", typical=True)
        ds = []
        for c, played in zip(setup.conditions, setup.played, strict=True):
            g = setup.model.geometry(q, c, played, who)
            d = np.sqrt(np.diag(g.gram)) * g.scale
            ds.extend(d[d > 0])
        return float(np.mean(ds))
    assert mean_d(sharp) > mean_d(blurred)
    assert _rate(sharp, 12) > _rate(blurred, 12) + 0.05


def test_a_lapse_rate_of_one_answers_at_chance():
    setup = Setup.load(GRID, overrides={"lapse": 1.0})
    df = simulate_studies(setup, 3, [0], 20)               # 20 x 96 = 1920 answers
    n = len(df)
    rate = df["correct"].mean()
    assert abs(rate - 0.25) < 4 * math.sqrt(0.25 * 0.75 / n)
    counts = df["answer"].value_counts()
    assert set(counts.index) == {"triangle", "circle", "square", "rectangle"}
    assert stats.chisquare(counts.to_numpy()).pvalue > 0.001


def test_the_same_seed_gives_the_same_answers_and_another_seed_others():
    setup = Setup.load(GRID)
    a = simulate_participant(setup, 7, "P1")
    b = simulate_participant(Setup.load(GRID), 7, "P1")
    c = simulate_participant(setup, 8, "P1")
    assert [r["answer"] for r in a] == [r["answer"] for r in b]
    assert [r["answer"] for r in a] != [r["answer"] for r in c]


def test_participants_differ_and_the_population_is_reproducible():
    m = Setup.load(GRID).model
    ps = [m.participant(0, f"P{i}") for i in range(40)]
    assert len({p.two_point_threshold_mm for p in ps}) > 1
    assert len({p.efficiency for p in ps}) == 40
    assert ps[3] == m.participant(0, "P3")
    typical = m.participant(0, "P1", typical=True)
    params = load_params()
    assert typical.two_point_threshold_mm == params.two_point_threshold_mm["lower_back"]
    assert typical.lapse == pytest.approx(params.lapse)


@pytest.mark.parametrize("name", STUDIES)
def test_a_session_with_the_model_observer_logs_what_the_simulator_predicts(tmp_path, name):
    """The Responder in a real session (sim device, BIDS log) and the fast simulator answer
    every trial and question alike."""
    path = ROOT / "experiments" / f"{name}.yaml"
    setup = Setup.load(path)
    lx = load_experiment(path)
    model = ObserverModel.for_experiment(lx)
    conditions = compile_conditions(lx, model.profile)
    res = run_session(lx, SimDevice(model.profile), ModelObserver(model, "sim1", 1, seed=5),
                      SessionOptions(participant="sim1", data_dir=tmp_path,
                                     conditions=conditions, max_trials=40))
    with open(res.paths.beh_tsv, encoding="utf-8") as f:
        logged = [(int(r["trial"]), r["question"], r["answer"])
                  for r in csv.DictReader(f, delimiter="\t") if r["practice"] == "0"]
    predicted = [(r["trial"], r["question"], r["answer"])
                 for r in simulate_participant(setup, 5, "sim1")]
    assert logged and logged == predicted[:len(logged)]


def test_every_study_declares_how_the_model_answers():
    for name in STUDIES:
        lx = load_experiment(ROOT / "experiments" / f"{name}.yaml")
        ObserverModel.for_experiment(lx)       # raises if an answer has no template


def test_an_answer_without_a_template_is_a_clear_error(tmp_path):
    from vtexp.errors import InputError
    text = (ROOT / "experiments" / "six_mode_ball.yaml").read_text(encoding="utf-8")
    head, _, _ = text.partition("\nobserver:")
    p = tmp_path / "six.yaml"
    p.write_text(head + "\n", encoding="utf-8")
    with pytest.raises(InputError) as e:
        ObserverModel.for_experiment(load_experiment(p))
    assert "plane circular" in str(e.value) and "observer.templates" in str(e.value)


PAIRED = """\
name: paired
title: Two durations of the same shapes (a paired design for the power check)
device: vest_6x8
stimuli:
  circle: {generator: shape, params: {shape: circle}}
  square: {generator: shape, params: {shape: square}}
encoding: {pipeline: edge-trace}
coding:
  protocol: sequential-trace
  params: {soa_ms: 200, loops: 1, level: 1, vertex_level: 2}
factors:
  shape: {sets: stimulus, levels: [circle, square]}
  duration:
    sets: coding
    levels:
      short: {duration_ms: 60}
      long: {duration_ms: 200}
design: {repetitions: 6, order: random}
question:
  kind: choice
  prompt: Which shape?
  options: [circle, square]
  correct: "{shape}"
analysis:
  anova:
    - {dv: rate, within: [duration]}
"""


def test_simulated_power_matches_the_paired_t_test_power(tmp_path):
    """For a one-factor, two-level design the rm-ANOVA is the paired t test, whose power is
    analytic (noncentral t) given the effect size d_z. d_z is measured on a large simulated
    sample; the simulator's power at N = 8 must agree with the formula within its interval."""
    p = tmp_path / "paired.yaml"
    p.write_text(PAIRED, encoding="utf-8")
    setup = Setup.load(p)
    pilot = simulate_studies(setup, 11, [99999], 600)
    per = pilot.groupby(["participant", "duration"], observed=True)["correct"].mean().unstack()
    diff = (per["long"] - per["short"]).to_numpy()
    dz = diff.mean() / diff.std(ddof=1)
    n, alpha = 8, 0.05
    t_crit = stats.t.ppf(1 - alpha / 2, n - 1)
    nc = dz * math.sqrt(n)
    analytic = (1 - stats.nct.cdf(t_crit, n - 1, nc)) + stats.nct.cdf(-t_crit, n - 1, nc)
    res = run_power(p, n, 600, alpha=alpha, seed=11, workers=1)
    row = res.table.iloc[0]
    assert 0.15 < analytic < 0.95, analytic          # the check must have room either way
    se = math.sqrt(analytic * (1 - analytic) / 600)
    assert abs(row["power"] - analytic) < 3 * se + 0.03, (row["power"], analytic, dz)
    assert row["ci_low"] <= row["power"] <= row["ci_high"]


def test_the_smallest_n_reaches_the_target_and_the_one_below_does_not(tmp_path):
    from vtexp.simulate import smallest_n
    p = tmp_path / "paired.yaml"
    p.write_text(PAIRED, encoding="utf-8")
    table, results = smallest_n(p, 0.8, 60, seed=2, n_max=64, workers=1)
    row = table.iloc[0]
    n = int(row["smallest_n"])
    assert n in results and row["power"] >= 0.8
    assert results[n].table["power"].iloc[0] >= 0.8
    if n > 4:
        assert n - 1 in results and results[n - 1].table["power"].iloc[0] < 0.8
    doubled = [m for m in (4, 8, 16, 32, 64) if m <= max(results)]
    assert set(doubled) <= set(results)           # doubling from 4, then bisection


def test_wrong_observer_parameters_are_one_clear_message(cli, tmp_path):
    text = (ROOT / "experiments" / "circle_vs_rectangle.yaml").read_text(encoding="utf-8")
    bad = tmp_path / "cvr.yaml"
    bad.write_text(text.replace("\nobserver:\n", "\nobserver:\n  params: {lapse: 3}\n"),
                   encoding="utf-8")
    r = cli("simulate", str(bad), "--studies", "4", "-n", "3", "--quiet")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert f"{bad}:" in r.stderr and "observer.params.lapse" in r.stderr
    r = cli("simulate", str(ROOT / "experiments" / "whirlpool.yaml"), "--observer",
            str(tmp_path / "missing.yaml"), "--quiet")
    assert r.returncode == 2 and "no such observer file" in r.stderr


def test_a_site_override_keeps_the_other_sites():
    p = load_params(None, {"two_point_threshold_mm": {"palm": 12.0}})
    assert p.two_point_threshold_mm["palm"] == 12.0
    assert p.two_point_threshold_mm["lower_back"] == load_params().two_point_threshold_mm[
        "lower_back"]


def test_the_integration_filter_is_the_recursion_of_p2_exactly():
    """(P2), u[n] = a u[n-1] + (1 - a) x[n], as a filter: equal to the recursion written
    out, bit for bit, on pulses of every kind of edge."""
    from vtexp.observer.percept import leaky
    rng = np.random.default_rng(3)
    x = rng.random((3, 7, 400))
    x[x < 0.6] = 0.0
    dt, tau = 12.5, 40.0
    a = math.exp(-dt / tau)
    expected = np.empty_like(x)
    acc = np.zeros(x.shape[:-1])
    for n in range(x.shape[-1]):
        acc = a * acc + (1.0 - a) * x[..., n]
        expected[..., n] = acc
    assert np.array_equal(leaky(x, dt, tau), expected)


def test_a_named_surface_is_its_true_heights_so_a_ball_and_a_bowl_differ():
    """Rendered through shape from shading a bowl is the ball (they shade alike under
    the paper's light); as the participant was told (intensity = height) the bowl is
    high at the rim and low in the middle, in every mode."""
    path = ROOT / "experiments" / "six_mode_ball.yaml"
    told = Setup.load(path)
    rendered = Setup.load(path, overrides={"answer_templates": "rendered"})
    for setup, apart in ((told, True), (rendered, False)):
        m = setup.model
        for c in setup.conditions:
            ball, bowl = m.template_report("ball", c), m.template_report("concave surface", c)
            same = sorted((p.row, p.col, p.onset_ms, p.level) for p in ball.pulses) == \
                sorted((p.row, p.col, p.onset_ms, p.level) for p in bowl.pulses)
            assert same is not apart, (c.label, apart)


def test_quick_successive_taps_are_felt_closer_as_goldreich_predicts():
    """Two taps l apart and dt apart are felt l / (1 + 2 (sigma_s / (sigma_v dt))^2)
    apart (Goldreich 2007); without a speed prior, where they were played."""
    from vtexp.model import DeviceProfile, PlayedPulse, PlayReport
    from vtexp.observer.percept import felt_positions
    prof = DeviceProfile.load("vest_6x8")           # pitch 40 mm
    for dt in (50.0, 100.0, 400.0):
        rep = PlayReport(device="vest_6x8", started_at_ms=0, duration_ms=dt + 50, pulses=[
            PlayedPulse(row=0, col=c, scheduled_onset_ms=t, onset_ms=t, duration_ms=50,
                        level=2) for c, t in ((0, 0.0), (2, dt))])
        skin = Skin(39.0, 40.0, 8, localisation_sd_mm=10.0, speed_sd_mm_s=100.0)
        f = felt_positions(rep, prof, skin)
        ratio = (10.0 / (100.0 * dt / 1000.0)) ** 2
        assert (f[1, 1] - f[0, 1]) * 40.0 == pytest.approx(80.0 / (1 + 2 * ratio))
        assert f[0, 1] + f[1, 1] == pytest.approx(2.0)                # about the middle
        assert np.array_equal(felt_positions(rep, prof, Skin(39.0, 40.0, 8)),
                              [[0, 0], [0, 2]])


def test_a_pin_that_cannot_cool_moves_less_per_pulse():
    """(P6): faster trains move an SMA pin less per pulse; a single widest pulse from
    cool is 1; a pin driven again before it has cooled moves less than a cool one."""
    from vtexp.model import PlayedPulse, PlayReport, PulseTrain
    from vtexp.observer.percept import pin_strokes

    def train(f, w=1.0, at=0.0, col=0, dur=200.0):
        return PlayedPulse(row=0, col=col, scheduled_onset_ms=at, onset_ms=at, duration_ms=dur,
                           train=PulseTrain(amplitude_v=2.0, frequency_hz=f, pulse_width_ms=w))

    rep = PlayReport(device="sma_5x5", started_at_ms=0, duration_ms=200,
                     pulses=[train(25, col=0), train(40, col=1), train(50, col=2),
                             train(25, w=1.5, col=3, dur=40)])
    s = pin_strokes(rep, 2.0, 1.5, 5.0, 400.0)
    assert s[0] > s[1] > s[2] and s[3] == pytest.approx(1.0)
    again = PlayReport(device="sma_5x5", started_at_ms=0, duration_ms=400,
                       pulses=[train(40), train(40, at=200.0)])
    a = pin_strokes(again, 2.0, 1.5, 5.0, 400.0)
    assert a[1] < a[0] == pytest.approx(s[1])


def test_integration_time_per_site_or_one_for_all():
    p = load_params()
    assert p.integration_of("lower_back") > 0 and p.integration_of("palm") > 0
    assert load_params(None, {"integration_ms": 90.0}).integration_of("lower_back") == 90.0
    q = load_params(None, {"integration_ms": {"lower_back": 120.0}})
    assert q.integration_of("lower_back") == 120.0
    assert q.integration_of("palm") == p.integration_of("palm")
