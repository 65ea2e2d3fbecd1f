"""Pulse trains, phantom points and apparent movement on the SMA panel (seed 002 §2.2, §4),
and the whirlpool (Fig. 10) as a path on pins and phantom points."""

from __future__ import annotations

import itertools
import math
from collections import defaultdict

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vtexp.coding import CODINGS
from vtexp.coding.pulses import (
    PulseTrainParams,
    phantom_weights,
    pulse_trains,
    tactile_brush_soa_ms,
)
from vtexp.encoding import PIPELINES
from vtexp.encoding.phantom_grid import fit_to_array
from vtexp.encoding.snake import snake_corners
from vtexp.encoding.spiral_path import spiral_path
from vtexp.errors import InputError, UnsafeStimulus
from vtexp.model import DeviceProfile, Pattern, PatternPoint
from vtexp.safety import check_schedule
from vtexp.stimuli import GENERATORS, render_shape
from vtexp.stimuli.spiral import WhirlpoolParams, render_whirlpool, spiral_points

SMA = DeviceProfile.load("sma_5x5")


def path(points, corners=()) -> Pattern:
    return Pattern(rows=5, cols=5, points=[
        PatternPoint(row=r, col=c, order=k, corner=k in corners) for k, (r, c) in enumerate(points)])


def by_pin(schedule):
    pins = defaultdict(list)
    for p in schedule.pulses:
        pins[(p.row, p.col)].append(p)
    return pins


# --------------------------------------------------------------------------- phantom weights

fraction = st.sampled_from([0.0, 0.25, 0.5, 0.75]) | st.floats(0, 0.999)


@given(r=st.integers(0, 3), c=st.integers(0, 3), br=fraction, bc=fraction)
def test_phantom_weights_sum_rules(r, c, br, bc):
    lin = phantom_weights(r + br, c + bc, "linear")
    en = phantom_weights(r + br, c + bc, "energy")
    assert math.isclose(sum(w for _, w in lin), 1.0, rel_tol=1e-9)             # linear: sum 1
    assert math.isclose(sum(w * w for _, w in en), 1.0, rel_tol=1e-9)          # energy: squares
    pins = {p for p, _ in lin}
    assert pins == {p for p, _ in en}
    assert pins <= {(r, c), (r, c + 1), (r + 1, c), (r + 1, c + 1)}
    # the felt position is the intensity-weighted (linear) or energy-weighted centre
    assert math.isclose(sum(p[0] * w for p, w in lin), r + br, abs_tol=1e-9)
    assert math.isclose(sum(p[1] * w * w for p, w in en), c + bc, abs_tol=1e-9)


def test_phantom_points_of_the_9x9_grid():
    assert phantom_weights(2, 3, "energy") == [((2, 3), 1.0)]                    # a pin
    assert phantom_weights(2, 3.5, "linear") == [((2, 3), 0.5), ((2, 4), 0.5)]  # edge midpoint
    mid = phantom_weights(2, 3.5, "energy")
    assert [p for p, _ in mid] == [(2, 3), (2, 4)]
    assert all(math.isclose(w, math.sqrt(0.5)) for _, w in mid)
    centre = phantom_weights(1.5, 1.5, "linear")                                  # cell centre
    assert [p for p, _ in centre] == [(1, 1), (1, 2), (2, 1), (2, 2)]
    assert all(math.isclose(w, 0.25) for _, w in centre)
    with pytest.raises(InputError):
        phantom_weights(0, 0.5, "cubic")


# --------------------------------------------------------------------------- timing

def test_tactile_brush_soa():
    assert tactile_brush_soa_ms(200) == pytest.approx(111.3)
    assert tactile_brush_soa_ms(400) == pytest.approx(175.3)
    assert tactile_brush_soa_ms(0) == pytest.approx(47.3)


def test_points_follow_the_path_onset_to_onset():
    pts = [(0, 0), (0, 1), (0, 2), (0, 3)]
    s = pulse_trains(path(pts), SMA)                           # Tactile Brush SOA
    onsets = sorted(p.onset_ms for p in s.pulses)
    assert onsets == pytest.approx([0, 111.3, 222.6, 333.9], abs=1 / 64)
    assert all(p.duration_ms == 200 for p in s.pulses)
    s = pulse_trains(path(pts), SMA, soa_ms=150, loops=2)
    assert [p.onset_ms for p in s.sorted()] == [150.0 * k for k in range(8)]
    assert s.duration_ms == 150 * 7 + 200


def test_soa_after_a_corner_follows_its_longer_duration():
    s = pulse_trains(path([(0, 0), (0, 1), (0, 2)], corners={1}), SMA)
    on = {p.col: p.onset_ms for p in s.pulses}
    assert on[2] - on[1] == pytest.approx(0.32 * 400 + 47.3, abs=1 / 64)
    assert on[1] - on[0] == pytest.approx(0.32 * 200 + 47.3, abs=1 / 64)


# --------------------------------------------------------------------------- drive

def test_tables_2_to_4_and_corner_emphasis():
    pat = path([(0, 0), (0, 1), (0, 2)], corners={1})
    s = pulse_trains(pat, SMA, frequency_hz=25)                          # Table 2
    plain = [p for p in s.pulses if p.col != 1]
    corner = [p for p in s.pulses if p.col == 1]
    assert all(p.train.amplitude_v == 2.0 and p.train.frequency_hz == 25
               and p.train.pulse_width_ms == 1.0 and p.duration_ms == 200 for p in plain)
    assert len(corner) == 1                                               # Table 4
    c = corner[0].train
    assert (c.amplitude_v, c.frequency_hz, c.pulse_width_ms) == (2.0, 40.0, 1.5)
    assert corner[0].duration_ms == 400
    off = pulse_trains(pat, SMA, corner_emphasis=False)
    assert all(p.train.pulse_width_ms == 1.0 and p.duration_ms == 200 for p in off.pulses)


@pytest.mark.parametrize("model, volts", [("linear", 1.0), ("energy", 2 * math.sqrt(0.5))])
def test_phantom_point_drives_two_pins_together(model, volts):
    s = pulse_trains(path([(1, 1.5)]), SMA, phantom_model=model)
    assert sorted((p.row, p.col) for p in s.pulses) == [(1, 1), (1, 2)]
    assert {p.onset_ms for p in s.pulses} == {0.0}
    assert all(p.train.amplitude_v == pytest.approx(volts, abs=1e-4) for p in s.pulses)
    four = pulse_trains(path([(1.5, 1.5)]), SMA, phantom_model=model)
    assert len(four.pulses) == 4
    assert all(p.train.amplitude_v == pytest.approx(2 * (0.25 if model == "linear" else 0.5),
                                                    abs=1e-4) for p in four.pulses)


def test_a_pin_plays_the_strongest_request_and_never_two_at_once():
    # (0,0) pin, then the phantom (0,0.5) 50 ms later: pin (0,0) is asked twice at once.
    s = pulse_trains(path([(0, 0), (0, 0.5)]), SMA, soa_ms=50, phantom_model="linear")
    pin = sorted(by_pin(s)[(0, 0)], key=lambda p: p.onset_ms)
    assert [(p.onset_ms, p.offset_ms, p.train.amplitude_v) for p in pin] == \
        [(0.0, 200.0, 2.0), (200.0, 250.0, 1.0)]


point = st.tuples(st.integers(0, 8), st.integers(0, 8)).map(lambda rc: (rc[0] / 2, rc[1] / 2))


@settings(max_examples=60, deadline=None)
@given(pts=st.lists(point, min_size=1, max_size=30), corners=st.sets(st.integers(0, 29)),
       model=st.sampled_from(["linear", "energy"]),
       soa=st.none() | st.floats(20, 400), amp=st.floats(0.5, 2.0))
def test_schedule_invariants(pts, corners, model, soa, amp):
    s = pulse_trains(path(pts, corners), SMA, phantom_model=model, soa_ms=soa,
                     amplitude_v=amp, corner_amplitude_v=amp)
    assert s.device == "sma_5x5" and s.coding == "pulse-trains"
    for p in s.pulses:
        assert 0 < p.train.amplitude_v <= amp <= SMA.limits.max_amplitude_v
        assert p.onset_ms * 64 == int(p.onset_ms * 64)                 # 1/64 ms ticks
    for pulses in by_pin(s).values():                                  # one train at a time
        pulses.sort(key=lambda p: p.onset_ms)
        assert all(a.offset_ms <= b.onset_ms for a, b in itertools.pairwise(pulses))
    # every pin a point asks for is on at that point's onset
    on = [(p.row, p.col, p.onset_ms, p.offset_ms) for p in s.pulses]
    t = 0.0
    for k, (r, c) in enumerate(pts):
        t0 = round(t * 64) / 64
        for (pr, pc), _ in phantom_weights(r, c, model):
            assert any(a == pr and b == pc and o <= t0 < e for a, b, o, e in on)
        dur = 400 if k in corners else 200
        t += soa if soa is not None else tactile_brush_soa_ms(dur)


def test_mistakes_are_reported_for_people():
    pat = path([(0, 0)])
    with pytest.raises(InputError, match="amplitude_v: 2.5 V is above max_amplitude_v 2.0"):
        pulse_trains(pat, SMA, amplitude_v=2.5)
    with pytest.raises(InputError, match="driven by levels"):
        pulse_trains(Pattern(rows=8, cols=6, points=[PatternPoint(row=0, col=0)]),
                     DeviceProfile.load("vest_6x8"))
    with pytest.raises(InputError, match="encoded for a 8x6 array"):
        pulse_trains(Pattern(rows=8, cols=6, points=[PatternPoint(row=0, col=0)]), SMA)
    with pytest.warns(UserWarning, match="characterised"):
        pulse_trains(pat, SMA, frequency_hz=30)
    with pytest.raises(ValueError):
        PulseTrainParams(frequency=40)                                  # unknown key
    fn, model = CODINGS["pulse-trains"]
    assert fn is pulse_trains and model is PulseTrainParams


# --------------------------------------------------------------------------- safety

def longest_shared_run(pattern: Pattern, model: str = "energy") -> int:
    """Most consecutive points of the path that share one pin."""
    runs: dict[tuple[int, int], int] = defaultdict(int)
    best = 0
    for p in pattern.ordered():
        pins = {pin for pin, _ in phantom_weights(p.row, p.col, model)}
        runs = {pin: runs.get(pin, 0) + 1 for pin in pins}
        best = max(best, *runs.values())
    return best


@pytest.mark.parametrize("shape", ["circle", "square", "rectangle", "triangle"])
def test_study_shapes_pass_safety_on_the_panel(shape):
    # Pins alone (seed 002 Fig. 8) and with phantom points (Fig. 9), Table 4's corners,
    # Tactile Brush's SOA: the paper's stimuli are within sma_5x5's limits.
    pat = snake_corners(render_shape(shape=shape), 5, 5, subdivisions=1)
    assert longest_shared_run(pat) == 1
    check_schedule(pulse_trains(pat, SMA), SMA)
    pat = snake_corners(render_shape(shape=shape), 5, 5)
    m = longest_shared_run(pat)
    assert m >= 3
    # With phantom points m consecutive points share a pin, which is then on for
    # (m - 1) SOA + 200 ms without a pause; the profile's max_on_ms allows it.
    assert (m - 1) * tactile_brush_soa_ms(200) + 200 <= SMA.limits.max_on_ms
    check_schedule(pulse_trains(pat, SMA), SMA)


def unbound(profile: DeviceProfile) -> DeviceProfile:
    """``profile`` with limits of time and budget that nothing reaches: what a coding plays
    when it has nothing to fit."""
    lim = profile.limits.model_copy(update={"max_on_ms": 1e9, "min_off_ms": 0.0,
                                            "max_simultaneous": 10_000})
    return profile.model_copy(update={"limits": lim})


def assert_only_shortened(fitted, free):
    """Every pulse of ``fitted`` lies where its pin is on in ``free``, with a train that pin
    plays there: fitting to the limits took time away and added none. (Where a point
    stops early for the budget, a weaker train of the next point on the same pin may play
    where the stopped one was the strongest.)"""
    pins = by_pin(free)
    for q in fitted.pulses:
        mine = sorted(pins[(q.row, q.col)], key=lambda f: f.onset_ms)
        assert q.train in [f.train for f in mine], q
        t = q.onset_ms
        for f in mine:
            if f.onset_ms <= t < f.offset_ms:
                t = f.offset_ms
        assert t >= q.offset_ms, q


def test_a_pin_on_too_long_rests_before_a_point_begins():
    """A pin shared by three consecutive points is on for 2 SOA + L without a pause: with
    L = 700 ms at Tactile Brush's SOA, past max_on_ms. The pin rests min_off_ms just before
    the onset of the last point that leaves at most max_on_ms before the rest (issue 20):
    the schedule passes the safety check, every point's onset is kept, nothing is longer.
    A panel rated for less than the paper's 2 V still refuses it."""
    pat = snake_corners(render_shape(shape="circle"), 5, 5)
    assert longest_shared_run(pat) == 3
    expected = 2 * tactile_brush_soa_ms(700) + 700
    assert expected > SMA.limits.max_on_ms
    free = pulse_trains(pat, unbound(SMA), corner_emphasis=False, vibration_ms=700)
    with pytest.raises(UnsafeStimulus, match=f"on for {expected:.1f} ms.*max_on_ms"):
        check_schedule(free.model_copy(update={"device": "sma_5x5"}), SMA)
    fitted = pulse_trains(pat, SMA, corner_emphasis=False, vibration_ms=700)
    check_schedule(fitted, SMA)
    assert_only_shortened(fitted, free)
    on = [(p.row, p.col, p.onset_ms, p.offset_ms) for p in fitted.pulses]
    soa = tactile_brush_soa_ms(700)
    for k, pt in enumerate(pat.ordered()):
        t0 = round(k * soa * 64) / 64
        for (r, c), _ in phantom_weights(pt.row, pt.col):
            assert any((a, b) == (r, c) and o <= t0 < e for a, b, o, e in on)
    rests = [b.onset_ms - a.offset_ms for pulses in by_pin(fitted).values()
             for a, b in itertools.pairwise(sorted(pulses, key=lambda q: q.onset_ms))
             if b.onset_ms > a.offset_ms]
    assert rests and min(rests) >= SMA.limits.min_off_ms
    weak = SMA.model_copy(update={"limits": SMA.limits.model_copy(update={"max_amplitude_v": 1.0})})
    with pytest.raises(UnsafeStimulus, match="max_amplitude_v"):
        check_schedule(pulse_trains(pat, SMA, corner_emphasis=False), weak)


@pytest.mark.filterwarnings("ignore:pulse-trains:UserWarning")
def test_what_cannot_be_split_is_refused_naming_the_parameter():
    """Two points on one pin 15 ms apart, each 995 ms long: on for 1010 ms, and no onset
    leaves room for a 20 ms rest. The coding says which parameter to change, and to what;
    the value it names works."""
    pat = path([(2, 2), (2, 2)])
    with pytest.raises(UnsafeStimulus, match=r"pulse-trains on sma_5x5: actuator \(row 2, "
                       r"col 2\) at 0.0 ms would be on for 1010.0 ms.*set vibration_ms to at "
                       r"most 979") as e:
        pulse_trains(pat, SMA, vibration_ms=995, soa_ms=15, corner_emphasis=False)
    assert e.value.schedule is not None and e.value.schedule.pulses    # for the live loop
    check_schedule(pulse_trains(pat, SMA, vibration_ms=979, soa_ms=15,
                                corner_emphasis=False), SMA)
    with pytest.raises(UnsafeStimulus, match="set frequency_hz to at most 50"):
        pulse_trains(pat, SMA, frequency_hz=60)
    with pytest.raises(UnsafeStimulus, match="set corner_pulse_width_ms to at most 1.5"):
        pulse_trains(path([(2, 2)], corners=[0]), SMA, corner_pulse_width_ms=2)
    pulse_trains(pat, SMA, corner_pulse_width_ms=2)          # no corner: not used


# --------------------------------------------------------------------------- whirlpool

def test_whirlpool_image():
    img = render_whirlpool(turns=3, line_width_px=3)
    assert img.shape == (240, 320) and img.dtype == np.uint8
    xy = spiral_points(turns=3)
    on_line = img[np.round(xy[:, 1]).astype(int), np.round(xy[:, 0]).astype(int)]
    assert np.median(on_line) >= 200 and img[0, 0] == 40
    # outer end at rotation_deg, clockwise outward by default
    end = spiral_points(turns=2, rotation_deg=90)[-1]
    assert end[0] == pytest.approx(160, abs=1e-6) and end[1] == pytest.approx(120 + 96)
    a = spiral_points(turns=1)
    ang = np.unwrap(np.arctan2(a[:, 1] - 120, a[:, 0] - 160))
    assert ang[-1] - ang[0] == pytest.approx(2 * np.pi, rel=1e-3)        # clockwise as seen
    b = spiral_points(turns=1, clockwise=False)
    assert np.unwrap(np.arctan2(b[:, 1] - 120, b[:, 0] - 160))[-1] < 0
    noisy = render_whirlpool(noise_sd=10, seed=3)
    assert noisy.std() > img.std() * 0.5
    fn, model = GENERATORS["whirlpool"]
    assert fn is render_whirlpool and model is WhirlpoolParams
    with pytest.raises(ValueError):
        WhirlpoolParams(turn=3)


def winding(pts: np.ndarray, centre) -> float:
    a = np.unwrap(np.arctan2(pts[:, 0] - centre[0], pts[:, 1] - centre[1]))
    return float(a[-1] - a[0]) / (2 * np.pi)


def _mapped_truth(params):
    xy = spiral_points(**params)
    rc = xy[:, ::-1]
    p = WhirlpoolParams(**params)
    centre = np.array([p.center_y * p.height, p.center_x * p.width])
    both = fit_to_array(np.vstack([rc, centre]), 5, 5)     # same box: centre inside it
    return both[:-1], both[-1]


@pytest.mark.parametrize("turns", [1, 1.5, 2, 3, 4])
def test_whirlpool_path_keeps_its_turns_with_phantom_points(turns):
    """Inward from the outer end, along the drawn line (every grid point within the grid's
    rounding, 0.36 pin, of the true curve), winding as many turns as drawn (±0.2)."""
    params = {"turns": turns, "inner": 0.3}
    pat = spiral_path(render_whirlpool(**params), 5, 5)
    assert pat.pipeline == "spiral-path" and pat.closed == []
    pts = np.array([(p.row, p.col) for p in pat.ordered()])
    assert np.abs(np.diff(pts, axis=0)).max() == 0.5                  # 8-neighbour steps
    truth, centre = _mapped_truth(params)
    dev = np.hypot(*(pts[:, None, :] - truth[None, :, :]).transpose(2, 0, 1)).min(axis=1)
    assert dev.max() <= 0.36
    inward_truth = -winding(truth, centre)       # drawn outward; played inward
    assert winding(pts, centre) == pytest.approx(inward_truth, abs=0.2)
    d = np.hypot(*(pts - centre).T)
    assert d[0] > d[-1]                                               # outside to centre


def test_whirlpool_without_phantom_points_loses_its_turns():
    """Seed 002 Figs. 12-13: on the pins alone nobody could count the turns; with phantom
    points everyone felt more than three. On 5x5 pins a 4-turn whirlpool keeps about one
    turn; on the 9x9 grid all four."""
    params = {"turns": 4, "inner": 0.3}
    _, centre = _mapped_truth(params)
    with_ps = spiral_path(render_whirlpool(**params), 5, 5)
    without = spiral_path(render_whirlpool(**params), 5, 5, subdivisions=1)
    w_with = abs(winding(np.array([(p.row, p.col) for p in with_ps.ordered()]), centre))
    w_without = abs(winding(np.array([(p.row, p.col) for p in without.ordered()]), centre))
    assert w_with > 3.5 and w_without < 3.5
    assert len(without.points) < len(with_ps.points)


def test_whirlpool_direction_and_bad_input():
    params = {"turns": 2, "inner": 0.3}
    _, centre = _mapped_truth(params)
    inward = np.array([(p.row, p.col)
                       for p in spiral_path(render_whirlpool(**params), 5, 5).ordered()])
    outward = np.array([(p.row, p.col) for p in spiral_path(
        render_whirlpool(**params), 5, 5, direction="outward").ordered()])
    assert tuple(outward[0]) == tuple(inward[-1]) and tuple(outward[-1]) == tuple(inward[0])
    assert winding(outward, centre) == pytest.approx(-winding(inward, centre), abs=0.2)
    with pytest.warns(UserWarning, match="no line found"):
        assert spiral_path(np.full((240, 320), 90, np.uint8), 5, 5).points == []
    assert PIPELINES["spiral-path"][0] is spiral_path


def test_whirlpool_schedule_on_the_panel():
    """The whirlpool as seed 002 §4 plays it, by apparent movement along the path, with
    Table 3 and Tactile Brush's SOA: on the pins alone and with phantom points, 2 to 4
    turns, within sma_5x5's limits. With phantom points the centre pins take part in
    several consecutive points; the longest train on one pin and the shortest rest
    between two are what the profile's max_on_ms and min_off_ms were set from."""
    for turns in (2, 3, 4):
        img = render_whirlpool(turns=turns, inner=0.3)
        check_schedule(pulse_trains(spiral_path(img, 5, 5, subdivisions=1), SMA), SMA)
        check_schedule(pulse_trains(spiral_path(img, 5, 5), SMA), SMA)
    # Played much faster, a pin would come back before it has rested (SOA 30 ms), or too
    # many pins would overlap for the power budget (SOA 20 ms). The coding ends the
    # earlier train min_off_ms before the pin begins again, and the oldest point still
    # vibrating when a new one would take more pins than the budget (issue 20).
    four = spiral_path(render_whirlpool(turns=4, inner=0.3), 5, 5)
    for soa, refusal in ((30, "below min_off_ms 20"), (20, "above max_simultaneous 8")):
        free = pulse_trains(four, unbound(SMA), soa_ms=soa)
        with pytest.raises(UnsafeStimulus, match=refusal):
            check_schedule(free.model_copy(update={"device": "sma_5x5"}), SMA)
        fitted = pulse_trains(four, SMA, soa_ms=soa)
        check_schedule(fitted, SMA)
        assert_only_shortened(fitted, free)
