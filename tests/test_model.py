"""The data model: shipped profiles, JSON round trips, validation."""

from __future__ import annotations

import json

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pydantic import ValidationError

from vtexp.errors import InputError
from vtexp.model import (DeviceProfile, Pattern, PatternPoint, PlayedPulse, PlayReport, Pulse,
                         PulseTrain, Schedule, TrialRecord, available_profiles)


def test_the_three_seed_devices_are_shipped_by_name():
    assert {"pad_20x20", "vest_6x8", "sma_5x5"} <= set(available_profiles())


def test_pad_carries_table_1_of_seed_000():
    pad = DeviceProfile.load("pad_20x20")
    assert (pad.rows, pad.cols) == (20, 20)
    assert pad.drive.kind == "levels" and pad.drive.carrier_hz == 100
    # seed 000, Table 1: level -> duty -> effective volts
    volts = [0, 1, 1.49, 1.94, 2.42, 2.86, 3.34, 3.80, 4.21, 4.55, 4.85]
    assert [lv.volts for lv in pad.drive.levels] == volts
    assert [lv.duty for lv in pad.drive.levels] == pytest.approx([i / 10 for i in range(11)])


def test_vest_is_six_wide_eight_tall_with_two_levels():
    vest = DeviceProfile.load("vest_6x8")
    assert (vest.cols, vest.rows) == (6, 8)            # seed 001: W = 6, H = 8
    assert [lv.volts for lv in vest.drive.levels] == [0, 1.0, 3.0]
    assert vest.limits.max_level == 2


def test_sma_panel_is_driven_by_pulse_trains():
    sma = DeviceProfile.load("sma_5x5")
    assert sma.drive.kind == "pulse_train" and sma.drive.amplitude_v == 2.0
    assert sma.drive.frequencies_hz == [25, 40, 50]
    assert sma.limits.max_pulse_width_ms == 1.5


@pytest.mark.parametrize("name", ["pad_20x20", "vest_6x8", "sma_5x5"])
def test_profile_json_round_trip(name):
    p = DeviceProfile.load(name)
    assert DeviceProfile.from_json(p.to_json()) == p


def test_unknown_profile_lists_the_known_ones():
    with pytest.raises(InputError, match="known profiles: .*vest_6x8"):
        DeviceProfile.load("vest_9x9")


def test_profile_with_level_limit_above_its_levels_is_refused(tmp_path):
    vest = DeviceProfile.load("vest_6x8").model_dump()
    vest["limits"]["max_level"] = 5
    f = tmp_path / "bad.yaml"
    import yaml
    f.write_text(yaml.safe_dump(vest))
    with pytest.raises(InputError, match="max_level 5 is above the highest declared level 2"):
        DeviceProfile.load(f)


points = st.builds(PatternPoint, row=st.floats(0, 4, allow_nan=False),
                   col=st.floats(0, 4, allow_nan=False), line=st.integers(0, 5),
                   order=st.none() | st.integers(0, 100), vertex=st.booleans(),
                   corner=st.booleans())


@given(st.lists(points, max_size=30))
def test_pattern_round_trip_with_fractional_phantom_points(pts):
    pat = Pattern(rows=5, cols=5, points=pts, closed=[0], pipeline="x", params={"a": 1})
    assert Pattern.from_json(pat.to_json()) == pat


def test_pattern_point_outside_the_array_is_refused():
    with pytest.raises(ValidationError, match="outside the 5x5 array"):
        Pattern(rows=5, cols=5, points=[PatternPoint(row=5.5, col=0)])


pulses = st.builds(Pulse, row=st.integers(0, 19), col=st.integers(0, 19),
                   onset_ms=st.floats(0, 1e5, allow_nan=False),
                   duration_ms=st.floats(0.001, 1e4, allow_nan=False),
                   level=st.integers(0, 10))
trains = st.builds(PulseTrain, amplitude_v=st.floats(0.1, 5), frequency_hz=st.floats(1, 100),
                   pulse_width_ms=st.floats(0.1, 2))


@given(st.lists(pulses, max_size=40))
def test_schedule_round_trip(ps):
    s = Schedule(device="pad_20x20", pulses=ps, coding="c", params={"soa_ms": 100})
    back = Schedule.from_json(s.to_json())
    assert back == s
    assert back.duration_ms == max((p.onset_ms + p.duration_ms for p in ps), default=0.0)


@given(trains)
def test_pulse_train_schedule_round_trip(tr):
    s = Schedule(device="sma_5x5", pulses=[Pulse(row=1, col=2, onset_ms=0, duration_ms=200,
                                                 train=tr)])
    assert Schedule.from_json(s.to_json()) == s


def test_pulse_needs_exactly_one_drive():
    with pytest.raises(ValidationError, match="either a level or a train"):
        Pulse(row=0, col=0, onset_ms=0, duration_ms=10)
    with pytest.raises(ValidationError, match="either a level or a train"):
        Pulse(row=0, col=0, onset_ms=0, duration_ms=10, level=1,
              train=PulseTrain(amplitude_v=2, frequency_hz=40, pulse_width_ms=1))


def test_play_report_and_trial_record_round_trip():
    rep = PlayReport(device="vest_6x8", started_at_ms=12.5, duration_ms=300,
                     pulses=[PlayedPulse(row=1, col=2, scheduled_onset_ms=0, onset_ms=0.2,
                                         duration_ms=300, level=2)])
    assert PlayReport.from_json(rep.to_json()) == rep
    rec = TrialRecord(trial=3, repetition=1, stimulus="circle",
                      condition={"shape": "circle", "timing": "300/200"}, answer="square",
                      correct_answer="circle", correct=False, rt_s=1.25, replays=2,
                      started_at="2026-11-22T08:00:00.000+00:00")
    assert TrialRecord.from_json(rec.to_json()) == rec
    assert json.loads(rec.to_json())["condition"]["timing"] == "300/200"


def test_unknown_keys_are_errors_in_every_model():
    with pytest.raises(ValidationError, match="Extra inputs are not permitted"):
        Pulse(row=0, col=0, onset_ms=0, duration_ms=1, level=1, colour="red")
