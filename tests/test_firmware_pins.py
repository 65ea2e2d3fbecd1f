"""What the ATmega2560 firmware does at its pins, from vtexp-simavr's cycle-stamped trace.

The very .elf a lab flashes runs in simavr; vtexp talks to it through serial:PORT.
The trace is the chip's pins (SPI bytes at each latch edge, output enable, sync out,
the SMA gate ports) with CPU cycles, so these are statements about the chip, not
about what the firmware or the host believe:

- every device-reported onset is the latch edge of that instant (within 1 us), and
  the sync output rises with it, once per instant;
- the outputs equal the schedule tick for tick (so durations equal the schedule to
  one 1 ms PWM tick, and each level has its Table 1 duty);
- everything is off within the watchdog time after the host goes silent, and at
  once after ALL_OFF and BYE; output enable stays off through a reset;
- a retried request acts once; damaged, dropped and inserted bytes never actuate
  anything the host did not ask for.
"""

from __future__ import annotations

import os
import random
import signal
import time

import numpy as np
import pytest
import serial

from vtexp.devices import fwtrace, open_device, wire
from vtexp.devices.cfirmware import AvrSimulator
from vtexp.devices.link import suggested_reply_ms
from vtexp.errors import DeviceError
from vtexp.model import DeviceProfile, Pulse, PulseTrain, Schedule

VEST = DeviceProfile.load("vest_6x8")
PAD = DeviceProfile.load("pad_20x20")
SMA = DeviceProfile.load("sma_5x5")
TICK = 16_000                 # cycles per 1 ms PWM tick

# The .elf in simavr paced to the wall clock, as the chip on a bench: real time is its
# subject (the study runs in lockstep instead: tests/test_firmware_study.py).
pytestmark = pytest.mark.realtime


def link(sim: AvrSimulator, heartbeat_ms: int = 1000) -> str:
    """The simulator's port as ``vtexp device emulate --firmware avr`` suggests it: on a
    loaded 2-core machine the simulated chip can fall a tenth of a second behind the wall
    clock, which a 200 ms heartbeat would take for a pulled cable (the watchdog tests use
    their own); the reply wait fits five attempts of a request in the silence limit."""
    reply_ms = suggested_reply_ms(heartbeat_ms)
    return f"serial:{sim.port},heartbeat_ms={heartbeat_ms},reply_ms={reply_ms}"


def trace_of(sim: AvrSimulator) -> fwtrace.Trace:
    sim.command("flush")
    return fwtrace.Trace.load(sim.trace_path)


def expected_bits(pulses: list[Pulse], profile: DeviceProfile, start_tick: int,
                  n_ticks: int) -> np.ndarray:
    """The chain's outputs tick by tick for a play starting at ``start_tick``: each onset
    instant restarts the 10-slot carrier; an actuator is on while a pulse covers the
    tick (the latest started drives it) and its slot is under the level's duty."""
    slots = fwtrace.level_slots(profile)
    ps = sorted(pulses, key=lambda p: p.onset_ms)
    instants = sorted({round(p.onset_ms) for p in ps})
    bits = np.zeros((n_ticks, profile.rows * profile.cols), dtype=bool)
    for k in range(n_ticks):
        t = k
        last = max((i for i in instants if i <= t), default=None)
        if last is None:
            continue
        slot = (t - last) % 10
        for j, p in reversed(list(enumerate(ps))):
            idx = p.row * profile.cols + p.col
            if round(p.onset_ms) <= t < round(p.onset_ms + p.duration_ms):
                if not any(q.row * profile.cols + q.col == idx and round(q.onset_ms) <= t <
                           round(q.onset_ms + q.duration_ms) for q in ps[j + 1:]):
                    bits[k, idx] = slot < slots[p.level]
    return bits


def bits_from(trace: fwtrace.Trace, profile: DeviceProfile, start_tick: int,
              n_ticks: int) -> np.ndarray:
    """The chain's outputs at ticks start_tick .. start_tick + n_ticks - 1, from the pins."""
    out = fwtrace.chain_outputs(trace, profile.rows * profile.cols)
    ticks = np.rint((out.cycles - trace.clock_start) / TICK).astype(np.int64)
    rows = []
    for k in range(start_tick, start_tick + n_ticks):
        at = np.flatnonzero(ticks == k)
        assert len(at), f"no latch at tick {k}"
        rows.append(out.bits[at[-1]])
    return np.array(rows)


def sweep(profile: DeviceProfile, n: int = 12, soa: int = 50, dur: int = 70) -> Schedule:
    top = len(profile.drive.levels) - 1
    return Schedule(device=profile.name, pulses=[
        Pulse(row=i % profile.rows, col=(i * 5) % profile.cols, onset_ms=(i // 2) * soa,
              duration_ms=dur + 10 * (i % 3), level=1 + i % top) for i in range(n)])


# --------------------------------------------------------------------------- timing

@pytest.mark.parametrize("profile", [VEST, PAD], ids=lambda p: p.name)
def test_reported_onsets_are_the_latch_edges_and_sync_marks_each_instant(profile):
    s = sweep(profile)
    with AvrSimulator(profile.name) as sim:
        with open_device(link(sim), profile) as dev:
            reports = [dev.play(s), dev.play(s)]
        tr = trace_of(sim)
    rises = tr.sync_rises
    instants = []
    for rep in reports:
        instants += sorted({rep.started_at_ms * 1000 + p.onset_ms * 1000 for p in rep.pulses})
    assert len(rises) == len(instants)          # one sync edge per onset instant, no more
    latch = np.array([c for c, _ in tr.latches])
    for t_us, rise in zip(instants, rises):
        edge = latch[np.argmin(np.abs(latch - rise))]
        assert edge == pytest.approx(rise, abs=2)     # sync rises with the latch
        # the device's own onset time is the latch edge, on its clock, within 1 us
        assert abs(tr.device_us(edge) - t_us) <= 1.0


@pytest.mark.parametrize("profile", [VEST, PAD], ids=lambda p: p.name)
def test_outputs_equal_the_schedule_tick_for_tick(profile):
    s = sweep(profile)
    n_ticks = round(s.duration_ms) + 1          # to the tick after the last pulse ends
    with AvrSimulator(profile.name) as sim:
        with open_device(link(sim), profile) as dev:
            reps = [dev.play(s), dev.play(s)]
        tr = trace_of(sim)
    want = expected_bits(s.pulses, profile, 0, n_ticks)
    for rep in reps:
        start = round(rep.started_at_ms)
        got = bits_from(tr, profile, start, n_ticks)
        wrong = np.argwhere(got != want)
        assert len(wrong) == 0, f"first difference at tick {wrong[0][0]}, actuator {wrong[0][1]}"


def test_each_level_has_its_table_1_duty():
    s = Schedule(device="pad_20x20", pulses=[
        Pulse(row=level, col=2 * level % 20, onset_ms=0, duration_ms=60, level=level)
        for level in range(1, 11)])
    with AvrSimulator("pad_20x20") as sim:
        with open_device(link(sim), PAD) as dev:
            dev.play(s)
        tr = trace_of(sim)
    seen = fwtrace.duty_per_level(tr, 400)
    for p in s.pulses:
        duty = PAD.drive.levels[p.level].duty           # seed 000 Table 1
        assert seen[p.row * 20 + p.col] == {round(duty * 10)}


def test_sma_trains_on_the_pins():
    tr_40 = PulseTrain(amplitude_v=2.0, frequency_hz=40, pulse_width_ms=1.0)
    tr_25 = PulseTrain(amplitude_v=1.41, frequency_hz=25, pulse_width_ms=1.5)
    s = Schedule(device="sma_5x5", pulses=[
        Pulse(row=0, col=0, onset_ms=0, duration_ms=200, train=tr_40),
        Pulse(row=2, col=3, onset_ms=50, duration_ms=200, train=tr_25)])
    with AvrSimulator("sma_5x5") as sim:
        with open_device(link(sim), SMA) as dev:
            rep = dev.play(s)
        tr = trace_of(sim)
    trains = fwtrace.trains(tr)
    assert [t.index for t in trains] == [0, 13]
    a, b = trains
    # Edges on the 100 us tick, each about 6.4 us after it (the interrupt's entry), up to
    # about 8 us later when a UART interrupt is being served: within one tick, by far.
    assert len(a.pulses) == 8 and len(b.pulses) == 5
    assert a.widths_us == pytest.approx([1000.0] * 8, abs=20)
    assert a.periods_us == pytest.approx([25_000.0] * 7, abs=20)
    assert b.widths_us == pytest.approx([1500.0] * 5, abs=20)
    assert b.periods_us == pytest.approx([40_000.0] * 4, abs=20)
    assert fwtrace.code_to_mv(a.code, 2000) == 2000 and fwtrace.code_to_mv(b.code, 2000) == 1410
    for train, pulse in zip(trains, rep.pulses):
        onset_us = rep.started_at_ms * 1000 + pulse.onset_ms * 1000
        assert abs(tr.device_us(train.start) - onset_us) <= 1.0


def test_a_full_20x20_frame_and_a_256_pulse_schedule_on_the_pad():
    # one whole 10 ms carrier period each, so that every level shows its duty
    big = Schedule(device="pad_20x20", pulses=[
        Pulse(row=i // 20 % 20, col=i % 20, onset_ms=i * 12, duration_ms=10, level=1 + i % 10)
        for i in range(256)])
    sim = AvrSimulator("pad_20x20")
    with sim:
        with open_device(link(sim), PAD) as dev:
            full = wire.SetFrameFull(1, tuple(wire.Level(1) for _ in range(400)))
            assert isinstance(dev._link.expect(full, wire.Ack), wire.Ack)
            time.sleep(0.05)
            dev._link.expect(wire.AllOff(), wire.Ack)
            rep = dev.play(big)
    tr = fwtrace.Trace.load(sim.trace_path)
    assert fwtrace.chain_outputs(tr, 400).bits.all(axis=1).any()     # all 400 at once
    assert len(rep.pulses) == 256
    start = tr.cycle_of(rep.started_at_ms * 1000)
    got = [p for p in fwtrace.level_pulses(tr, 400) if p.start >= start]     # not the frame
    assert [(p.index, p.on_slots) for p in got] == \
        [(q.row * 20 + q.col, q.level) for q in big.pulses]
    # 512-byte chunks at 1 Mbaud, back to back: the receive ring never dropped a byte
    assert sim.peeked(tr) == {"vt_uart_overruns": 0}



@pytest.mark.parametrize("profile, pulse, says", [
    (PAD, Pulse(row=3, col=7, onset_ms=40, duration_ms=50, level=11),
     "pulse 2 (actuator row 3, col 7, at 40 ms): level 11 is above the device's highest, 10"),
    (SMA, Pulse(row=4, col=1, onset_ms=40, duration_ms=50,
                train=PulseTrain(amplitude_v=2.5, frequency_hz=40, pulse_width_ms=1.0)),
     "pulse 2 (actuator row 4, col 1, at 40 ms): amplitude 2.5 V is above the device's 2 V"),
])
def test_a_schedule_past_the_chips_limits_is_refused_at_upload(profile, pulse, says):
    """What the host's safety check stops never gets this far; a schedule that does (another
    program's, or one played past the check) is refused by the chip, named, and not played."""
    ok = Pulse(row=0, col=0, onset_ms=0, duration_ms=50,
               level=5 if profile is PAD else None,
               train=None if profile is PAD else PulseTrain(amplitude_v=1.0, frequency_hz=40,
                                                            pulse_width_ms=1.0))
    s = Schedule(device=profile.name, pulses=[ok, pulse])
    with AvrSimulator(profile.name) as sim:
        with open_device(link(sim), profile) as dev:
            with pytest.raises(DeviceError) as e:
                dev._call(lambda ln: dev._play_device(ln, s, s.sorted()))     # past the check
            assert dev.play(Schedule(device=profile.name, pulses=[ok])).pulses  # still usable
        tr = trace_of(sim)
    assert says in str(e.value) and "nothing of it was played" in str(e.value)
    if profile is PAD:
        on = fwtrace.chain_outputs(tr, 400).bits
        assert not on[:, 3 * 20 + 7].any()
    else:
        assert [t.index for t in fwtrace.trains(tr)] == [0]


def test_a_starved_chip_loses_the_time_and_never_runs_faster_than_the_wall():
    """The simulator's process stopped for half a second, as a busy computer starves it:
    the chip's clock stands still, then goes on at the wall's pace. Caught up, it would
    run faster than any crystal, and every interval the host times on the wall (a train
    it cuts at its maximum on-time, a heartbeat) would be longer on the chip's clock."""
    with AvrSimulator(SMA.name) as sim:
        time.sleep(0.3)
        os.kill(sim.proc.pid, signal.SIGSTOP)
        try:
            time.sleep(0.5)
        finally:
            os.kill(sim.proc.pid, signal.SIGCONT)
        time.sleep(0.8)
    tr = fwtrace.Trace.load(sim.trace_path)
    steps = [(fwtrace.us(c1 - c0) / 1000.0, (w1 - w0) / 1e6)
             for (c0, w0), (c1, w1) in zip(tr.wall, tr.wall[1:])]   # (chip ms, wall ms)
    # the stop is seen: one 100 ms step of the chip's took the wall 0.5 s, and the chip
    # went on after it (on a busy computer more slowly than the wall: 100 ms in 145)
    stop = max(range(len(steps)), key=lambda i: steps[i][1] - steps[i][0])
    assert steps[stop][1] - steps[stop][0] > 400 and len(steps) - stop > 2, steps
    assert tr.end["lost_ns"] > 400e6
    # and no step of the chip's clock is shorter on the wall than on the chip, beyond the
    # 2 ms of lag it may catch up
    assert all(c <= w + 2.5 for c, w in steps), steps


# --------------------------------------------------------------------------- off

class Raw:
    """Frames to the firmware by hand (no heartbeat thread: silence is silence)."""

    def __init__(self, port: str):
        self.port = serial.serial_for_url(port, baudrate=1_000_000, timeout=0.05)
        self.reader = wire.FrameReader()
        self.seen: list[wire.Message] = []

    def send(self, msg: wire.Message, seq: int, wait_s: float = 2.0) -> wire.Message:
        """Send and return the reply; sent again every 0.2 s without one (the first frames
        may arrive before the firmware's UART is up, as on a board just reset)."""
        frame = wire.encode(msg, seq)
        end = time.monotonic() + wait_s
        while time.monotonic() < end:
            self.port.write(frame)
            again = time.monotonic() + 0.2
            while time.monotonic() < again:
                for item in self.reader.feed(self.port.read(256)):
                    if isinstance(item, tuple):
                        self.seen.append(item[1])
                        if item[1].REPLY and item[1].ack_seq == seq:
                            return item[1]
        raise AssertionError(f"no reply to {msg}")

    def drain(self) -> list[wire.Message]:
        """What the firmware sent since (events)."""
        for item in self.reader.feed(self.port.read(4096)):
            if isinstance(item, tuple):
                self.seen.append(item[1])
        return self.seen


def off_for_good(tr: fwtrace.Trace, n: int) -> int:
    """The cycle from which every output stays off to the end of the trace (a PWM output is
    off between its slots too, so only 'off from then on' says the pulse ended)."""
    out = fwtrace.chain_outputs(tr, n)
    on = np.flatnonzero(out.bits.any(axis=1))
    assert len(on), "nothing was ever on"
    assert on[-1] + 1 < len(out.cycles), "still on at the end"
    return int(out.cycles[on[-1] + 1])


@pytest.mark.parametrize("how", ["silence", "all_off", "bye"])
def test_everything_off_after_silence_all_off_and_bye(how):
    with AvrSimulator("vest_6x8") as sim:
        link = Raw(sim.port)
        assert isinstance(link.send(wire.Hello(1, 200, 200), 0), wire.HelloReply)
        link.send(wire.SetFrame(1, tuple((i, wire.Level(2)) for i in range(0, 48, 5))), 1)
        if how == "silence":
            time.sleep(0.5)                     # the host says nothing: the watchdog acts
            events = link.drain()
        else:
            msg = wire.AllOff() if how == "all_off" else wire.Bye()
            assert isinstance(link.send(msg, 2), wire.Ack)
            time.sleep(0.1)
        tr = trace_of(sim)
    on = fwtrace.chain_outputs(tr, 48)
    assert on.bits.any()                        # the frame did drive them
    last_rx = tr.rx0[-1]                        # the last frame's final byte into the UART
    # everything off = output enable high (drains off at once), and nothing on after it
    off = next(c for c, v in tr.oe if c > last_rx and v == 1)
    assert off_for_good(tr, 48) <= off
    dt_ms = fwtrace.us(off - last_rx) / 1000
    if how == "silence":
        assert 200 <= dt_ms <= 200 + 2          # watchdog + one tick + the frame's handling
        assert any(isinstance(m, wire.Alarm) for m in events)
    else:
        assert dt_ms <= 1.0                     # at once
    assert fwtrace.all_off_at_end(tr, 48)


def test_sma_pins_off_when_the_host_goes_silent():
    with AvrSimulator("sma_5x5") as sim:
        link = Raw(sim.port)
        link.send(wire.Hello(1, 100, 100), 0)
        link.send(wire.SetFrame(2, ((6, wire.Train(2000, 5000, 1500)),)), 1)
        time.sleep(0.4)
        tr = trace_of(sim)
    edges = fwtrace.gate_edges(tr)[6]
    assert edges and edges[-1][1] == 0
    rises = [c for c, s in edges if s]
    assert fwtrace.us(rises[-1] - tr.rx0[-1]) / 1000 < 100 + 1    # no pulse after the watchdog


def test_no_sma_pulse_outlasts_its_width_when_trains_change_mid_pulse():
    """Trains on all 25 pins, changed again and again at random moments to another
    width, amplitude or frequency. A change that comes during a pulse lets that pulse end
    when it was to (its rest is the new train's first pulse), never joined to a new one;
    with 25 pins on, ticks come while the one before is still preparing (vt_late_ticks),
    and their falls still come on time (the fall ring). From the pins: no pulse is longer
    than the widest train, 1500 us."""
    settings = [wire.Train(2000, 4000, 1500), wire.Train(1410, 4000, 1000),
                wire.Train(2000, 2500, 1500), wire.Train(1000, 5000, 500)]
    rng = random.Random(12)
    with AvrSimulator("sma_5x5") as sim:
        link = Raw(sim.port)
        link.send(wire.Hello(1, 1000, 1000), 0)
        link.send(wire.SetFrame(2, tuple((i, settings[0]) for i in range(25))), 1)
        for seq in range(2, 160):
            time.sleep(rng.uniform(0.002, 0.02))
            pins = rng.sample(range(25), rng.randint(3, 25))
            link.send(wire.SetFrame(2, tuple((i, rng.choice(settings)) for i in pins)), seq)
        link.send(wire.AllOff(), 160)
    tr = fwtrace.Trace.load(sim.trace_path)         # with the counters read at the end
    late = sim.peeked(tr)
    pulses = fwtrace.pin_pulses(tr, 25)
    widths = [fwtrace.us(f - r) for ps in pulses.values() for r, f in ps]
    assert len(widths) > 1000
    assert max(widths) <= 1500 + 20, max(widths)        # an edge's jitter: a few us
    syncs = tr.sync_rises
    during = sum(int(np.count_nonzero((syncs > r + 320) & (syncs < f - 320)))
                 for ps in pulses.values() for r, f in ps)
    # Changes that came mid-pulse, on some pin: the sends are timed by the wall clock, so
    # how many land inside a pulse varies (33 and 53 in two runs on an idle machine, 26 in
    # a run under the suite's load).
    assert during > 10, during
    assert late["vt_late_ticks"] > 0 and late["vt_uart_overruns"] == 0, late
    assert fwtrace.all_off_at_end(tr, 25)


def test_new_amplitudes_on_running_sma_pins_change_together_just_after_the_tick():
    """Eight running trains on the eight channels of one LTC2656 get a new amplitude in
    one frame: their channels' input registers are written before the commit, and one
    transfer after the commit's tick updates all eight (written one transfer a channel
    at the tick, the last changed 269 us into the new trains' first pulses)."""
    a2000, a1000 = wire.Train(2000, 5000, 1500), wire.Train(1000, 5000, 1500)
    with AvrSimulator("sma_5x5") as sim:
        link = Raw(sim.port)
        link.send(wire.Hello(1, 1000, 1000), 0)
        link.send(wire.SetFrame(2, tuple((i, a2000) for i in range(8))), 1)
        time.sleep(0.05)
        link.send(wire.SetFrame(2, tuple((i, a1000) for i in range(8))), 2)
        time.sleep(0.05)
        link.send(wire.AllOff(), 3)
    tr = fwtrace.Trace.load(sim.trace_path)
    changes = [(c, pin) for c, pin, code in fwtrace.dac_codes(tr)
               if pin < 8 and fwtrace.code_to_mv(code, 2000) == 1000]
    assert sorted(pin for _, pin in changes) == list(range(8))
    cycles = {c for c, _ in changes}
    assert len(cycles) == 1, sorted(cycles)                   # one transfer
    commit = [r for r in tr.sync_rises if r < min(cycles)][-1]  # the second frame's tick
    assert 0 < fwtrace.us(min(cycles) - commit) <= 40


def test_output_enable_stays_off_through_a_reset():
    with AvrSimulator("vest_6x8") as sim:
        link = Raw(sim.port)
        link.send(wire.Hello(1, 1000, 1000), 0)
        link.send(wire.SetFrame(1, ((3, wire.Level(2)),)), 1)
        time.sleep(0.05)
        sim.command("reset")
        time.sleep(0.1)
        tr = trace_of(sim)
    reset = tr.resets[-1]
    assert tr.oe_off_at(reset)
    # after the reset, output enable comes back only once zeros are latched
    back = next(c for c, v in tr.oe if c > reset and v == 0)
    latched = [d for c, d in tr.latches if reset < c < back]
    assert latched and not any(any(d) for d in latched)
    assert fwtrace.all_off_at_end(tr, 48)


# --------------------------------------------------------------------------- faults

def test_a_retried_trigger_plays_once():
    with AvrSimulator("vest_6x8") as sim:
        link = Raw(sim.port)
        link.send(wire.Hello(1, 1000, 1000), 0)
        link.send(wire.UploadBegin(4, 1, 1), 1)
        link.send(wire.UploadChunk(4, 0, 1, (wire.WirePulse(7, 0, 30_000, wire.Level(2)),)), 2)
        first = link.send(wire.Trigger(4, 0), 3)
        again = link.send(wire.Trigger(4, 0), 3)      # the same bytes: a retry
        time.sleep(0.1)
        status = link.send(wire.Status(), 4)
        tr = trace_of(sim)
    assert again == first                             # the cached reply, byte for byte
    assert status.duplicates == 1
    assert len(tr.sync_rises) == 1                    # one onset instant, one sync edge
    assert [p.index for p in fwtrace.level_pulses(tr, 48)] == [7]


@pytest.mark.slow
@pytest.mark.parametrize("rate", [1e-4, 1e-3, 1e-2])
def test_damaged_bytes_never_actuate_wrongly(rate):
    """Bytes dropped, altered and inserted, each at ``rate`` per byte in both directions,
    from the handshake on: plays go through or fail with a message, and the pins never
    show a pulse the host did not ask for. At 1e-2 a 75-byte reply arrives whole one time
    in ten, so plays may fail; none may actuate wrongly."""
    s = sweep(VEST, n=6, soa=30, dur=40)
    wanted = {(p.row * 6 + p.col, p.level) for p in s.pulses}
    plays = failed = 0
    with AvrSimulator("vest_6x8", seed=int(1 / rate)) as sim:
        with open_device(link(sim, 1000), VEST) as dev:
            sim.command(f"faults {rate} {rate} {rate}")
            for _ in range(8):
                plays += 1
                try:
                    dev.play(s)
                except DeviceError:
                    failed += 1
            sim.command("faults 0 0 0")
        tr = trace_of(sim)
    got = fwtrace.level_pulses(tr, 48)
    slots = fwtrace.level_slots(VEST)
    for p in got:                                   # nothing the host did not ask for
        assert (p.index, slots.index(p.on_slots)) in wanted
    assert len(got) <= plays * len(s.pulses)
    if rate <= 1e-3:
        assert failed == 0
        assert len(got) == plays * len(s.pulses)
