"""One contract, every backend: what the session engine relies on from a Device.

The sim backend passes it in-process; the serial backend passes it against the
emulator in-process on a virtual clock (the ``emulator`` backend, with device-side
and host-streamed timing; on a real pty and the real clock where a test needs real
time), against the emulator over a real pseudo-terminal (as ``serial:PORT``), and against the
reference firmware in C: its host build on a pty, and its ATmega2560 build, the
very .elf, in simavr. "Driven" is what the device itself drove (the sim's record;
the emulated firmware's output history; the C firmware's record of its outputs;
for the ATmega2560, its pins in the simulator's trace), not what the host believes
it sent.
"""

from __future__ import annotations

import gc
import signal
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from vtexp.clock import REAL, VirtualClock
from vtexp.devices import Device, fwtrace, open_device
from vtexp.devices.cfirmware import AvrSimulator, HostFirmware
from vtexp.devices.emulator import PtyEmulator
from vtexp.devices.serial_device import setting_of
from vtexp.errors import UnsafeStimulus
from vtexp.model import DeviceProfile, Pulse, PulseTrain, Schedule

VEST = DeviceProfile.load("vest_6x8")
SMA = DeviceProfile.load("sma_5x5")


@dataclass
class Backend:
    name: str
    open: Callable[..., object]          # (profile, realtime=False) -> device (not open)
    driven: Callable[[object], list]     # device -> [(row, col, setting)] switched on
    all_off: Callable[[object], bool]
    cleanup: Callable[[], None] = lambda: None
    # The device keeps time on the computer's clock (a pty, a simulated chip), where a
    # busy computer makes it late; else on a virtual one, never late.
    realtime: bool = False


def _sim_driven(dev) -> list:
    return [(p.row, p.col, setting_of(Pulse(row=p.row, col=p.col, onset_ms=0, duration_ms=1,
                                            level=p.level, train=p.train)))
            for rep in dev.plays for p in rep.pulses]


def _emu_driven(emu: PtyEmulator, cols: int) -> list:
    return [(a.index // cols, a.index % cols, a.setting) for a in emu.actuations()
            if not a.setting.is_off]


def make_backend(name: str) -> Backend:
    if name == "sim":
        return Backend(name, lambda prof, realtime=False: open_device(
            "sim:realtime" if realtime else "sim", prof), _sim_driven,
            lambda dev: float(dev.state.max()) == 0.0)
    if name in ("emulator", "emulator-host-timing"):
        timing = "host" if name.endswith("host-timing") else "device"
        return Backend(name, lambda prof, realtime=False: open_device(
            "emulator", prof, timing=timing, clock=REAL if realtime else VirtualClock()),
            lambda dev: _emu_driven(dev.emulator, dev.profile.cols),
            lambda dev: dev.emulator.all_outputs_off())
    if name == "serial-pty":
        emus: list[PtyEmulator] = []

        def opener(prof, realtime=False):
            emu = PtyEmulator.for_profile(prof)
            emus.append(emu)
            dev = open_device(f"serial:{emu.start()}", prof)
            dev.test_emulator = emu
            return dev

        def cleanup():
            for e in emus:
                e.stop()
        return Backend(name, opener, lambda dev: _emu_driven(dev.test_emulator, dev.profile.cols),
                       lambda dev: dev.test_emulator.all_outputs_off(), cleanup, realtime=True)
    if name in ("c-host", "c-avr"):
        procs: list = []

        def c_opener(prof, realtime=False):
            if name == "c-host":
                proc = HostFirmware(prof, trace=Path(tempfile.mkstemp(suffix=".jsonl")[1]))
            else:
                proc = AvrSimulator(prof.name)
            procs.append(proc)
            # a second's heartbeat: the simulated chip may lag the wall clock under load
            dev = open_device(f"serial:{proc.start()},heartbeat_ms=1000,reply_ms=120", prof)
            dev.test_firmware = proc
            return dev

        def c_driven(dev):
            proc = dev.test_firmware
            proc.command("flush")
            got = (fwtrace.host_driven(proc.trace_path) if name == "c-host" else
                   fwtrace.driven(fwtrace.Trace.load(proc.trace_path), dev.profile))
            return [(i // dev.profile.cols, i % dev.profile.cols, s) for i, s in got]

        def c_all_off(dev):
            proc = dev.test_firmware
            proc.command("flush")
            n = dev.profile.rows * dev.profile.cols
            if name == "c-host":
                return fwtrace.host_all_off(proc.trace_path)
            return fwtrace.all_off_at_end(fwtrace.Trace.load(proc.trace_path), n)

        def c_cleanup():
            for proc in procs:
                proc.stop()
                if name == "c-host":
                    proc.trace_path.unlink(missing_ok=True)
        return Backend(name, c_opener, c_driven, c_all_off, c_cleanup, realtime=True)
    raise ValueError(name)


@pytest.fixture(params=["sim", "emulator", "emulator-host-timing", "serial-pty", "c-host",
                        "c-avr"])
def backend(request):
    b = make_backend(request.param)
    yield b
    b.cleanup()


def vest_schedule() -> Schedule:
    return Schedule(device="vest_6x8", pulses=[
        Pulse(row=0, col=0, onset_ms=0, duration_ms=60, level=2),
        Pulse(row=0, col=1, onset_ms=40, duration_ms=60, level=1),
        Pulse(row=3, col=5, onset_ms=80, duration_ms=40, level=2),
        Pulse(row=7, col=2, onset_ms=80, duration_ms=40, level=1)])


def expected(schedule: Schedule) -> list:
    return sorted((p.row, p.col, setting_of(p)) for p in schedule.pulses)


def test_satisfies_the_device_protocol(backend):
    dev = backend.open(VEST)
    assert isinstance(dev, Device)
    with dev:
        info = dev.info()
        assert (info.rows, info.cols, info.profile) == (8, 6, "vest_6x8")


def test_plays_exactly_the_schedule_and_reports_every_onset(backend):
    s = vest_schedule()
    with backend.open(VEST) as dev:
        reports = [dev.play(s) for _ in range(3)]
    assert sorted(backend.driven(dev)) == sorted(expected(s) * 3)
    for rep, after in zip(reports, [*reports[1:], None]):
        assert [(p.row, p.col, p.scheduled_onset_ms) for p in rep.pulses] == \
            [(p.row, p.col, p.onset_ms) for p in s.sorted()]
        assert rep.duration_ms == 120 and rep.completed
        # Not a timing test (bench/timing.py is): only units and order are checked, on the
        # device's own clock, so that a busy computer (a device late) cannot fail them.
        onsets = [p.onset_ms for p in rep.pulses]
        assert onsets == sorted(onsets)                          # in the schedule's order
        for p, q in zip(rep.pulses, rep.pulses[1:]):
            if p.scheduled_onset_ms == q.scheduled_onset_ms:     # one instant, one onset
                assert p.onset_ms == q.onset_ms
        for p in rep.pulses:
            # ms from the play's start: never early (a start may be aligned by up to 5 ms,
            # docs/protocol.md), and before the next play started on the device's clock
            assert p.onset_ms >= p.scheduled_onset_ms - 5
            if after is not None:
                assert rep.started_at_ms + p.onset_ms <= after.started_at_ms
            if not backend.realtime:        # a virtual clock is never late
                assert p.onset_ms - p.scheduled_onset_ms < 50
        if after is not None:
            assert after.started_at_ms >= rep.started_at_ms + 120
    assert backend.all_off(dev)


def test_unsafe_schedule_never_reaches_the_device(backend):
    too_strong = Schedule(device="vest_6x8", pulses=[
        Pulse(row=0, col=0, onset_ms=0, duration_ms=50, level=1),
        Pulse(row=1, col=0, onset_ms=10, duration_ms=50, level=3)])
    with backend.open(VEST) as dev, \
            pytest.raises(UnsafeStimulus, match=r"row 1, col 0.*level 3 exceeds max_level 2"):
        dev.play(too_strong)
    assert backend.driven(dev) == []


def test_pulse_trains_reach_the_sma_panel_as_trains(backend):
    tr = PulseTrain(amplitude_v=2.0, frequency_hz=40, pulse_width_ms=1.0)
    s = Schedule(device="sma_5x5", pulses=[
        Pulse(row=2, col=2, onset_ms=0, duration_ms=50, train=tr),
        Pulse(row=4, col=0, onset_ms=30, duration_ms=50, train=tr)])
    with backend.open(SMA) as dev:
        rep = dev.play(s)
    assert sorted(backend.driven(dev)) == expected(s)
    assert rep.pulses[0].train == tr


def test_replay_waits_for_the_sma_wire_to_cool(backend):
    tr = PulseTrain(amplitude_v=2.0, frequency_hz=50, pulse_width_ms=1.0)
    s = Schedule(device="sma_5x5", pulses=[Pulse(row=0, col=0, onset_ms=0, duration_ms=30,
                                                 train=tr)])
    with backend.open(SMA) as dev:
        a = dev.play(s)
        b = dev.play(s)                 # a replay asked for at once
    # seed 002: the wire must rest min_off_ms (100 ms) before it is driven again
    assert b.started_at_ms - (a.started_at_ms + 30) >= SMA.limits.min_off_ms - 1


def test_interrupt_during_a_play_turns_everything_off(backend):
    long = Schedule(device="vest_6x8", pulses=[
        Pulse(row=r, col=0, onset_ms=0, duration_ms=1500, level=2) for r in range(4)])
    dev = backend.open(VEST, realtime=True)
    # Ctrl-C as the terminal sends it: a real SIGINT, to the main thread. Without the
    # garbage collector's callbacks of this test process (Hypothesis times collections
    # with one): a KeyboardInterrupt raised inside a callback is printed and dropped
    # ("Exception ignored in gc callback"), and the play was never interrupted.
    main = threading.main_thread().ident
    timer = threading.Timer(0.2, signal.pthread_kill, (main, signal.SIGINT))
    callbacks, gc.callbacks[:] = gc.callbacks[:], []
    try:
        with dev:
            t = time.monotonic()
            timer.start()
            with pytest.raises(KeyboardInterrupt):
                dev.play(long)
            assert time.monotonic() - t < 1.0
            assert backend.all_off(dev)
    finally:
        gc.callbacks[:] = callbacks
        timer.cancel()


def test_close_turns_off_and_the_device_opens_again(backend):
    dev = backend.open(VEST)
    with dev:
        dev.play(vest_schedule())
    assert backend.all_off(dev)
    with dev:
        rep = dev.play(vest_schedule())
    assert len(rep.pulses) == 4
