"""Safety limits: every limit refuses, and says which actuator, when and which limit."""

from __future__ import annotations

import pytest

from vtexp.errors import UnsafeStimulus
from vtexp.model import DeviceProfile, Pulse, PulseTrain, Schedule
from vtexp.safety import check_schedule

VEST = DeviceProfile.load("vest_6x8")
SMA = DeviceProfile.load("sma_5x5")


def sched(*pulses, device="vest_6x8"):
    return Schedule(device=device, pulses=list(pulses))


def lv(row=0, col=0, onset=0.0, dur=100.0, level=1):
    return Pulse(row=row, col=col, onset_ms=onset, duration_ms=dur, level=level)


def tr(row=0, col=0, onset=0.0, dur=200.0, amp=2.0, hz=40.0, width=1.0):
    return Pulse(row=row, col=col, onset_ms=onset, duration_ms=dur,
                 train=PulseTrain(amplitude_v=amp, frequency_hz=hz, pulse_width_ms=width))


def test_a_safe_schedule_passes():
    check_schedule(sched(lv(), lv(col=1, onset=100, level=2)), VEST)


@pytest.mark.parametrize("schedule, profile, message", [
    (sched(lv(level=3)), VEST, r"actuator \(row 0, col 0\) at 0.0 ms: level 3 exceeds max_level 2"),
    (sched(lv(row=8)), VEST, r"row 8, col 0.*outside the 8x6 array"),
    (sched(lv(dur=2500)), VEST, r"on for 2500.0 ms without a pause, above max_on_ms 2000"),
    # Two touching pulses of one actuator are one continuous activation.
    (sched(lv(dur=1500), lv(onset=1500, dur=1000)), VEST, r"on for 2500.0 ms"),
    (sched(*[lv(row=r, col=c) for r in range(3) for c in range(5)]), VEST,
     r"13 actuators on at once, above max_simultaneous 12"),
    (sched(tr(amp=3.0), device="sma_5x5"), SMA, r"amplitude 3.0 V exceeds max_amplitude_v 2.0"),
    (sched(tr(hz=80), device="sma_5x5"), SMA, r"frequency 80.0 Hz exceeds max_frequency_hz 50"),
    (sched(tr(width=2.0), device="sma_5x5"), SMA, r"pulse width 2.0 ms exceeds max_pulse_width"),
    (sched(tr(dur=1200), device="sma_5x5"), SMA, r"above max_on_ms 1000"),
    (sched(tr(dur=200), tr(onset=210, dur=100), device="sma_5x5"), SMA,
     r"at 210.0 ms: only 10.0 ms off.*min_off_ms 20"),
    (sched(lv(), device="sma_5x5"), SMA, r"driven by pulse trains, but the pulse has a level"),
    (sched(tr(), device="vest_6x8"), VEST, r"driven by levels, but the pulse has a pulse train"),
    (sched(lv(), device="pad_20x20"), VEST, r"coded for device 'pad_20x20'"),
])
def test_each_limit_refuses(schedule, profile, message):
    with pytest.raises(UnsafeStimulus, match=message):
        check_schedule(schedule, profile)


def test_offsets_before_onsets_at_the_same_time():
    # 12 on, then 12 others starting exactly as the first 12 stop: never 24 at once.
    first = [lv(row=r, col=c, dur=100) for r in range(2) for c in range(6)]
    second = [lv(row=r + 2, col=c, onset=100, dur=100) for r in range(2) for c in range(6)]
    check_schedule(sched(*first, *second), VEST)


# --------------------------------------------------------------------------- across plays

def test_cooling_wait_is_what_min_off_still_requires():
    from vtexp.safety import cooling_wait_ms

    rest = SMA.limits.min_off_ms                     # 20 ms
    s = sched(tr(row=0, col=0, onset=0), tr(row=1, col=1, onset=5), device="sma_5x5")
    # (0, 0) went off 8 ms ago: it needs rest - 8 ms more before its onset at 0 ms.
    assert cooling_wait_ms(s, SMA, {(0, 0): 992.0}, now_ms=1000.0) == pytest.approx(rest - 8)
    # (1, 1) went off 1 ms ago but starts 5 ms into the schedule: rest - 6 ms more.
    assert cooling_wait_ms(s, SMA, {(1, 1): 999.0}, now_ms=1000.0) == pytest.approx(rest - 6)
    # rested long enough, or never driven, or another actuator: no wait
    assert cooling_wait_ms(s, SMA, {(0, 0): 1000.0 - rest}, now_ms=1000.0) == 0.0
    assert cooling_wait_ms(s, SMA, {(4, 4): 999.0}, now_ms=1000.0) == 0.0
    # motors need no cooling (min_off_ms 0)
    assert cooling_wait_ms(sched(lv()), VEST, {(0, 0): 999.0}, now_ms=1000.0) == 0.0


def test_a_replay_on_the_sim_waits_for_the_wire_to_cool():
    from vtexp.devices import open_device

    s = sched(tr(dur=300), device="sma_5x5")
    with open_device("sim", SMA) as dev:
        a = dev.play(s)
        b = dev.play(s)
    assert b.started_at_ms == pytest.approx(a.started_at_ms + 300 + SMA.limits.min_off_ms)
    assert [e.kind for e in dev.history] == ["open", "play", "wait", "play", "all_off", "close"]


# --------------------------------------------------------------------------- profiles

@pytest.mark.parametrize("name", ["pad_20x20", "vest_6x8", "sma_5x5"])
def test_shipped_profiles_state_geometry_and_every_limit(name):
    p = DeviceProfile.load(name)
    g = p.geometry
    assert g.pitch_mm > 0 and g.body_site
    assert g.orientation.row_0 and g.orientation.col_0 and g.orientation.source
    lim = p.limits
    assert lim.max_on_ms > 0 and lim.min_off_ms >= 0 and lim.max_simultaneous >= 1
    if p.drive.kind == "levels":
        assert lim.max_level is not None
    else:
        assert None not in (lim.max_amplitude_v, lim.max_frequency_hz, lim.max_pulse_width_ms)
    assert g.index(g.rows - 1, g.cols - 1) == g.rows * g.cols - 1


def test_a_profile_without_explicit_orientation_is_refused(tmp_path):
    import yaml

    from vtexp.errors import InputError

    vest = DeviceProfile.load("vest_6x8").model_dump()
    vest["geometry"]["orientation"] = "row 0 at the top"        # the old free-text form
    f = tmp_path / "vest.yaml"
    f.write_text(yaml.safe_dump(vest), encoding="utf-8")
    with pytest.raises(InputError, match=r"geometry\.orientation"):
        DeviceProfile.load(f)
