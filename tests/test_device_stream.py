"""DeviceBase.stream: a live stream of output frames on the sim and on the emulated
firmware (its bytes on a loopback line), held to the profile's limits (safety.StreamGuard),
on a virtual clock: seconds of streaming take a fraction of one."""

from __future__ import annotations

import pytest

from vtexp.clock import VirtualClock
from vtexp.devices import open_device
from vtexp.model import DeviceProfile, PulseTrain
from vtexp.safety import check_schedule, outputs_schedule

SMA = DeviceProfile.load("sma_5x5")
PAD = DeviceProfile.load("pad_20x20")
TRAIN = PulseTrain(amplitude_v=2.0, frequency_hz=40.0, pulse_width_ms=1.0)

def sim_changes(dev):
    return [(e.t_ms, key, drive) for e in dev.history if e.kind == "frame"
            for key, drive in e.detail.items()] + \
        [(e.t_ms, key, None) for e in dev.history if e.kind == "all_off"
         for key in [(r, c) for r in range(dev.profile.rows) for c in range(dev.profile.cols)]]


def emulator_changes(dev, profile):
    from vtexp.devices.wire import Level

    out = []
    for a in dev.emulator.actuations():
        key = divmod(a.index, profile.cols)
        s = a.setting
        if s.is_off:
            drive = None
        elif isinstance(s, Level):
            drive = s.level
        else:
            drive = PulseTrain(amplitude_v=s.amplitude_mv / 1000, frequency_hz=s.frequency_chz / 100,
                               pulse_width_ms=s.width_us / 1000)
        out.append((a.t_us / 1000.0, key, drive))
    return out


@pytest.mark.parametrize("spec", ["sim", "emulator"])
def test_a_pin_held_on_by_a_stream_is_cut_and_rests_on_the_device(spec):
    """1.5 s of frames every 10 ms asking the same four pins to stay on: the device's own
    record of what it drove never breaks a limit, and the degradations are reported."""
    kinds = set()
    clock = VirtualClock()
    with open_device(spec, SMA, clock=clock) as dev:
        margin = dev._stream_margin()
        t_end = clock.now() + 1.5
        while clock.now() < t_end:
            rep = dev.stream({(1, 1): TRAIN, (1, 2): TRAIN, (2, 1): TRAIN, (2, 2): TRAIN})
            kinds |= {d.kind for d in rep.degradations}
            wait = min(0.01, dev.stream_deadline_s() or 0.01)
            clock.sleep(wait)
        dev.all_off()
        changes = sim_changes(dev) if spec == "sim" else emulator_changes(dev, SMA)
        if spec == "emulator":
            assert dev.emulator.all_outputs_off()
    assert {"max_on", "rest"} <= kinds
    sched = outputs_schedule(changes, SMA)
    check_schedule(sched, SMA)
    on = [p for p in sched.pulses if (p.row, p.col) == (1, 1)]
    # held on until the guard cut it (max_on_ms less the margin its watchdog needs);
    # check_schedule above holds it to max_on_ms
    assert on[0].duration_ms > 1000 - margin - 50


def test_a_stalled_host_is_switched_off_by_the_devices_watchdog_before_any_limit():
    """The loop stops checking in while a pin is on: no heartbeat keeps the emulated
    device's session alive, its watchdog switches everything off, well before the pin's
    max on-time; the next frame says what happened."""
    from vtexp.errors import StreamCut

    clock = VirtualClock()
    with open_device("emulator", SMA, clock=clock) as dev:
        dev.stream({(2, 2): TRAIN})
        clock.sleep(0.6)                                 # stalled: no frame, no check-in
        assert dev.emulator.all_outputs_off()
        with pytest.raises(StreamCut) as cut:
            dev.stream({(2, 2): TRAIN})
        history = emulator_changes(dev, SMA)
    on = [t for t, k, d in history if d is not None]
    off = [t for t, k, d in history if d is None]
    assert off[0] - on[0] <= dev.stream_watchdog_ms() + dev.stream_checkin_ms + 20
    # the error says when the device switched off, on its clock (a live record's all-off)
    assert cut.value.off_at_ms == pytest.approx(off[0], abs=0.001)
    clock = VirtualClock()
    with open_device("sim", SMA, clock=clock) as sim:
        sim.stream({(2, 2): TRAIN})
        clock.sleep(0.3)
        with pytest.raises(StreamCut, match="watchdog") as cut:
            sim.stream({(2, 2): TRAIN})
        wd = [e for e in sim.history if e.kind == "watchdog"]
        assert len(wd) == 1 and sim.state.max() == 0
        assert cut.value.off_at_ms == wd[0].t_ms


def test_a_play_after_a_stream_waits_for_the_pins_to_cool():
    from vtexp.model import Pulse, Schedule

    with open_device("sim", SMA) as dev:
        dev.stream({(0, 0): TRAIN})
        dev.stream({(0, 0): TRAIN})
        t_off = dev._now_ms()
        report = dev.play(Schedule(device="sma_5x5", pulses=[
            Pulse(row=0, col=0, onset_ms=0, duration_ms=100, train=TRAIN)]))
        assert report.started_at_ms - t_off >= SMA.limits.min_off_ms - 1e-6
        kinds = [e.kind for e in dev.history]
        assert kinds.index("all_off") < kinds.index("play")


def test_a_serial_stream_sends_only_the_changes_and_reports_the_device_time():
    sent = []
    with open_device("emulator", PAD, trace=lambda d, m: sent.append((d, m)),
                     clock=VirtualClock()) as dev:
        dev.stream({(r, 0): 3 for r in range(20)})
        sent.clear()
        rep = dev.stream({(r, 0): 3 for r in range(19)} | {(5, 5): 2})
        assert rep.changed == 2
        frames = [m for d, m in sent if d == "to_device" and type(m).__name__ == "SetFrame"]
        assert len(frames) == 1 and len(frames[0].changes) == 2
        assert rep.host_before_ms <= rep.host_after_ms
        now_dev = dev.emulator.clock_us() / 1000.0
        assert 0 <= now_dev - rep.t_device_ms < 1000
        assert dev.emulator.outputs()[5 * 20 + 5].level == 2
