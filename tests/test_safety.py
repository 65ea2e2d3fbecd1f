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
    (sched(tr(dur=500), device="sma_5x5"), SMA, r"above max_on_ms 400"),
    (sched(tr(dur=200), tr(onset=250, dur=100), device="sma_5x5"), SMA,
     r"at 250.0 ms: only 50.0 ms off.*min_off_ms 100"),
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
