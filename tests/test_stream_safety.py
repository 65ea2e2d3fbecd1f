"""Limits across frames of outputs (live drive): safety.StreamGuard and outputs_schedule."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vtexp.errors import UnsafeStimulus
from vtexp.model import DeviceProfile, PulseTrain
from vtexp.safety import StreamGuard, check_schedule, outputs_schedule

VEST = DeviceProfile.load("vest_6x8")
SMA = DeviceProfile.load("sma_5x5")
TRAIN = PulseTrain(amplitude_v=2.0, frequency_hz=40.0, pulse_width_ms=1.0)


def step(guard, desired, t, log):
    """One frame at time t (sent and confirmed at once), its changes appended to log."""
    allowed, notes = guard.admit(desired, t)
    before = dict(log["state"])
    for key in before.keys() | allowed.keys():
        if before.get(key) != allowed.get(key):
            log["changes"].append((t, key, allowed.get(key)))
    log["state"] = allowed
    guard.commit(allowed, t, t)
    return allowed, notes


def new_log():
    return {"state": {}, "changes": []}


def test_a_train_held_on_is_cut_before_max_on_and_rests():
    g = StreamGuard(SMA, margin_ms=50)
    log = new_log()
    step(g, {(2, 2): TRAIN}, 0.0, log)
    assert g.next_deadline_ms() == pytest.approx(950.0)
    allowed, notes = step(g, {(2, 2): TRAIN}, 949.0, log)
    assert allowed == {(2, 2): TRAIN} and not notes
    allowed, notes = step(g, {(2, 2): TRAIN}, 950.0, log)
    assert allowed == {} and [n.kind for n in notes] == ["max_on"]
    assert "cut short at 950 ms (limit 1000 ms), resting 20 ms" in notes[0].text
    assert g.next_deadline_ms() == pytest.approx(970.0, abs=0.01)  # the rest: min_off_ms
    allowed, notes = step(g, {(2, 2): TRAIN}, 969.0, log)
    assert allowed == {} and [n.kind for n in notes] == ["rest"]
    allowed, notes = step(g, {(2, 2): TRAIN}, 970.01, log)
    assert allowed == {(2, 2): TRAIN} and not notes
    check_schedule(outputs_schedule(log["changes"], SMA, end_ms=1100.0), SMA)


def test_a_profile_without_cooling_still_rests_a_tenth_of_max_on():
    """The vest's motors have no min_off_ms: a train cut at its maximum on-time rests a
    tenth of max_on_ms (200 ms), so a held pattern is never on more than 91 % of the time."""
    g = StreamGuard(VEST, margin_ms=50)
    log = new_log()
    step(g, {(0, 0): 1}, 0.0, log)
    allowed, notes = step(g, {(0, 0): 1}, 1950.0, log)
    assert allowed == {} and "resting 200 ms" in notes[0].text
    assert step(g, {(0, 0): 1}, 2149.0, log)[0] == {}
    assert step(g, {(0, 0): 1}, 2150.01, log)[0] == {(0, 0): 1}


def test_an_sma_pin_stays_off_until_it_has_cooled():
    g = StreamGuard(SMA)
    log = new_log()
    step(g, {(0, 0): TRAIN}, 0.0, log)
    step(g, {}, 100.0, log)
    allowed, notes = step(g, {(0, 0): TRAIN, (0, 1): TRAIN}, 110.0, log)
    assert allowed == {(0, 1): TRAIN}
    assert notes[0].kind == "cooling" and notes[0].actuators == ((0, 0),)
    assert "cooling: 1 held off (min_off_ms 20)" == notes[0].text
    assert g.next_deadline_ms() == pytest.approx(120.0, abs=0.01)
    allowed, _ = step(g, {(0, 0): TRAIN, (0, 1): TRAIN}, 120.01, log)
    assert set(allowed) == {(0, 0), (0, 1)}


def test_cooling_counts_from_when_the_device_confirmed_the_off():
    g = StreamGuard(SMA)
    g.commit({(0, 0): TRAIN}, 0.0, 1.0)
    g.admit({}, 100.0)
    g.commit({}, 100.0, 108.0)            # the off took 8 ms to be confirmed
    assert g.admit({(0, 0): TRAIN}, 127.0)[0] == {}
    assert g.admit({(0, 0): TRAIN}, 128.01)[0] == {(0, 0): TRAIN}


def test_the_power_budget_keeps_the_strongest_then_what_the_newest_frame_asks_for():
    g = StreamGuard(VEST)
    first = {(0, c): 1 for c in range(6)} | {(1, c): 1 for c in range(6)}
    step(g, first, 0.0, new_log())
    more = dict(first) | {(7, 0): 2, (7, 1): 1}
    allowed, notes = g.admit(more, 10.0)
    assert (7, 0) in allowed and (7, 1) in allowed        # level 2; then new before old
    assert notes[0].kind == "budget" and set(notes[0].actuators) == {(1, 4), (1, 5)}
    assert notes[0].text == "power budget: 2 of 14 skipped (max_simultaneous 12)"
    g.commit(allowed, 10.0, 10.0)
    allowed, _ = g.admit(more, 20.0)                      # the same frame again: no churn
    assert (7, 1) in allowed and (1, 5) not in allowed


def test_a_setting_beyond_one_pulse_limit_is_never_driven():
    g = StreamGuard(VEST)
    allowed, notes = g.admit({(0, 0): 3, (0, 1): 1, (9, 0): 1}, 0.0)
    assert allowed == {(0, 1): 1}
    assert notes[0].kind == "refused" and set(notes[0].actuators) == {(0, 0), (9, 0)}
    assert "level 3 exceeds max_level 2" in notes[0].text
    allowed, notes = StreamGuard(SMA).admit(
        {(0, 0): TRAIN.model_copy(update={"amplitude_v": 2.5})}, 0.0)
    assert allowed == {} and "max_amplitude_v" in notes[0].text


def test_outputs_schedule_turns_a_history_into_an_auditable_schedule():
    changes = [(10.0, (0, 0), 1), (20.0, (0, 0), 2), (2100.0, (0, 0), None)]
    s = outputs_schedule(changes, VEST)
    assert [(p.onset_ms, p.duration_ms, p.level) for p in s.pulses] == [(0, 10, 1), (10, 2080, 2)]
    with pytest.raises(UnsafeStimulus, match="on for 2090.0 ms"):
        check_schedule(s, VEST)                # touching pulses are one activation


frames = st.lists(st.tuples(st.floats(1, 400),
                            st.sets(st.tuples(st.integers(0, 4), st.integers(0, 4)),
                                    max_size=14)),
                  min_size=1, max_size=60)


@settings(max_examples=150, deadline=None)
@given(frames=frames, margin=st.floats(0, 60))
def test_whatever_is_asked_frame_after_frame_what_is_applied_is_safe(frames, margin):
    """Any sequence of frames on the SMA panel, each at most by the guard's deadline,
    gives an output history that check_schedule (the one place limits live) accepts."""
    g = StreamGuard(SMA, margin_ms=margin)
    log = new_log()
    t = 0.0
    for dt, pins in frames:
        deadline = g.next_deadline_ms()
        t = min(t + dt, deadline) if deadline is not None else t + dt
        step(g, {pin: TRAIN for pin in pins}, t, log)
    check_schedule(outputs_schedule(log["changes"], SMA, end_ms=t), SMA)


def test_an_off_that_came_after_the_deadline_is_reported_as_an_overrun():
    g = StreamGuard(SMA)
    g.commit({(0, 0): TRAIN}, 0.0, 0.5)
    allowed, notes = g.admit({(0, 0): TRAIN}, 1100.0)      # the host woke up 150 ms late
    assert allowed == {} and notes[0].kind == "max_on"
    g.commit(allowed, 1100.0, 1101.0)
    assert g.overruns == [((0, 0), 1101.0)]
