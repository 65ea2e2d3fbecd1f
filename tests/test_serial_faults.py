"""Every fault of the serial line, on the serial backend against the emulator.

Dropped, corrupted and delayed bytes: detected, retried, counted, and the device
drives exactly the schedule (compared with the emulated firmware's own output
history). A pulled cable or a silent device: DeviceLost within one heartbeat
period, a message for people, and the device off by itself. A device of
another geometry: refused at the handshake.

The emulator runs in-process on a virtual clock (the same bytes on the line as on a
pty, in a fraction of the time), except where the subject is a real process: a host
killed, stopped or starved of the CPU, talking to the emulator over a real pty.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from vtexp.clock import VirtualClock
from vtexp.devices import open_device, wire
from vtexp.devices.emulator import Faults, LoopbackEmulator, PtyEmulator
from vtexp.devices.link import DeviceLost
from vtexp.devices.serial_device import SerialDevice, setting_of
from vtexp.devices.wire import Level, Onset, Status
from vtexp.errors import DeviceError
from vtexp.model import DeviceProfile, Pulse, PulseTrain, Schedule

ROOT = Path(__file__).resolve().parents[1]
VEST = DeviceProfile.load("vest_6x8")
PAD = DeviceProfile.load("pad_20x20")
SMA = DeviceProfile.load("sma_5x5")
HEARTBEAT_MS = 200
# Byte-fault tests use a long heartbeat: at these fault rates (about one frame in six
# damaged) a run of lost replies could otherwise pass for a pulled cable, which is
# what the cable tests below check, with the default period.
NOISY = {"heartbeat_ms": 600}


def sweep(n: int = 8, soa: float = 15, dur: float = 20) -> Schedule:
    """n pulses walking over the vest, levels alternating (each one a visible change)."""
    return Schedule(device="vest_6x8", pulses=[
        Pulse(row=i % 8, col=(i * 5) % 6, onset_ms=i * soa, duration_ms=dur, level=1 + i % 2)
        for i in range(n)])


def on_events(emu: PtyEmulator | LoopbackEmulator) -> list:
    return [(a.index, a.setting) for a in emu.actuations() if not a.setting.is_off]


def expected(s: Schedule, cols: int = 6) -> list:
    return sorted((p.row * cols + p.col, setting_of(p)) for p in s.pulses)


@pytest.fixture
def clock():
    return VirtualClock()


@pytest.fixture
def emu(clock):
    """The emulated vest in-process, on the test's virtual clock."""
    e = LoopbackEmulator.for_profile(VEST, clock=clock)
    e.start()
    yield e
    e.stop()


@pytest.fixture
def pty_emu():
    """The emulated vest on a real pty, for a host in another process."""
    e = PtyEmulator.for_profile(VEST)
    e.start()
    yield e
    e.stop()


# --------------------------------------------------------------------------- bytes

@pytest.mark.parametrize("timing", ["device", "host"])
@pytest.mark.parametrize("fault", [
    Faults(drop_rate=0.004, seed=11),
    Faults(corrupt_rate=0.004, seed=12),
    Faults(drop_rate=0.003, corrupt_rate=0.003, seed=13),
], ids=["dropped", "corrupted", "both"])
def test_damaged_bytes_are_detected_retried_counted_and_never_actuate_wrongly(fault, timing):
    s = sweep()
    plays = 10
    dev = open_device("emulator", VEST, faults=fault, timing=timing, clock=VirtualClock(),
                      **NOISY)
    with dev:
        for _ in range(plays):
            rep = dev.play(s)
            assert [p.scheduled_onset_ms for p in rep.pulses] == [p.onset_ms for p in s.sorted()]
        stats = dev.link_stats()
    emu = dev.emulator
    injected = sum(c.dropped + c.corrupted for c in emu.fault_counts.values())
    assert injected > 0
    # Detected and counted on both ends, retried by the host...
    assert stats["rx_bad_total"] + emu.firmware.counters.rx_bad > 0
    assert stats["retries"] + stats["device_frames_lost"] > 0
    # ... and the device drove exactly the schedule, every time, nothing else.
    assert sorted(on_events(emu)) == sorted(expected(s) * plays)
    assert emu.all_outputs_off()


def test_a_late_reply_is_retried_and_the_retry_does_not_actuate_twice():
    # Replies arrive 70 ms late; the host's reply timeout is 30 ms: every request is
    # sent again, and the device answers the repeat from its cache without acting.
    s = sweep(4)
    dev = open_device("emulator", VEST, faults=Faults(delay_ms=70), reply_timeout_ms=30,
                      timing="host", clock=VirtualClock())
    with dev:
        dev.play(s)
        stats = dev.link_stats()
    assert stats["timeouts"] > 0 and stats["stale_replies"] > 0
    assert dev.emulator.firmware.counters.duplicates > 0
    assert sorted(on_events(dev.emulator)) == expected(s)


def test_the_clock_mapping_holds_its_bound_when_replies_are_late():
    # Every reply 40 ms late, the reply wait 30 ms: each heartbeat is sent again, and the
    # reply that comes is the first sending's, its device clock read before the repeat
    # left. Measured from the repeat, the exchange looked 10 ms long and mapped the
    # device's clock 35 ms wrong, claiming 5 ms (on a busy computer: a marker stamped
    # 14 ms off, claiming 0.1 ms).
    clock = VirtualClock()
    dev = open_device("emulator", VEST, faults=Faults(delay_ms=40), reply_timeout_ms=30,
                      clock=clock)
    with dev:
        report = dev.play(sweep(4))
        assert dev.link_stats()["timeouts"] > 0
        offset, error = dev.clock_map.offset_ms()
        truth = -dev.emulator._origin * 1000.0          # device ms − host ms
        assert abs(offset - truth) <= error + 1e-6, (offset, truth, error)
        host_ms = report.started_at_host_ms
        started = dev.emulator._origin * 1000.0 + report.started_at_ms   # host ms
        assert abs(host_ms - started) <= report.host_clock_error_ms + 1e-6


def test_lost_onset_events_are_fetched_again_not_guessed():
    # Drop only what the device sends: ONSET/PLAY_DONE events get lost and the host
    # must ask for the onsets (GET_ONSETS) and the status; every onset it reports must
    # be one the device stamped and sent.
    sent: list[Onset] = []

    def tap(direction, msg):            # what the device put on the line, before the fault
        if direction == "to_host" and isinstance(msg, Onset):
            sent.append(msg)
    s = sweep(12, soa=5, dur=5)
    dev = open_device("emulator", VEST, faults=Faults(drop_rate=0.005, direction="to_host",
                                                        seed=5), emulator_options={"trace": tap},
                      clock=VirtualClock(), **NOISY)
    with dev:
        reports = [dev.play(s) for _ in range(8)]
        stats = dev.link_stats()
    assert stats["device_frames_lost"] > 0 and stats["onsets_fetched"] > 0
    stamped = sorted(m.t_us for m in sent for _ in range(m.count))
    got = sorted(round((rep.started_at_ms + p.onset_ms) * 1000) for rep in reports
                 for p in rep.pulses)
    assert got == stamped


# --------------------------------------------------------------------------- the cable

def long_vest_schedule() -> Schedule:
    return Schedule(device="vest_6x8", pulses=[
        Pulse(row=r, col=1, onset_ms=300 * r, duration_ms=1500, level=2) for r in range(4)])


@pytest.mark.parametrize("timing", ["device", "host"])
def test_cable_pulled_mid_trial(emu, clock, timing):
    dev = SerialDevice(VEST, emu.port, timing=timing, heartbeat_ms=HEARTBEAT_MS, clock=clock)
    with dev:
        pulled = []

        def pull():
            pulled.append(clock.now())
            emu.unplug()
        clock.call_later(0.4, pull)
        with pytest.raises(DeviceLost) as exc:
            dev.play(long_vest_schedule())
        noticed = clock.now() - pulled[0]
    msg = str(exc.value)
    assert f"lost contact with the tactile device on {emu.port}" in msg
    assert "cable may have been pulled" in msg and "turns every actuator off by itself" in msg
    assert noticed < HEARTBEAT_MS / 1000
    # The device, still powered, heard nothing more and turned everything off by itself.
    clock.sleep(1.0)
    assert emu.all_outputs_off()
    assert emu.firmware.counters.watchdog_trips == 1
    assert emu.actuations()[-1].cause == "watchdog"


def test_device_gone_silent_is_noticed_within_one_heartbeat(emu, clock):
    dev = SerialDevice(VEST, emu.port, heartbeat_ms=HEARTBEAT_MS, clock=clock)
    with dev:
        muted = []

        def mute():
            muted.append(clock.now())
            emu.mute()
        clock.call_later(0.3, mute)
        with pytest.raises(DeviceLost,
                           match=r"nothing valid came back .* \(heartbeat period 200 ms\)"):
            dev.play(long_vest_schedule())
        assert clock.now() - muted[0] < HEARTBEAT_MS / 1000
    clock.sleep(0.3)
    assert emu.all_outputs_off()        # it heard nothing either: its watchdog fired


def test_after_a_pulled_cable_the_session_can_resume_on_the_replugged_device(emu, clock):
    dev = SerialDevice(VEST, emu.port, heartbeat_ms=HEARTBEAT_MS, clock=clock)
    dev.open()
    emu.unplug()
    with pytest.raises(DeviceLost):
        dev.play(sweep(3))
    dev.all_off()           # a session's cleanup: no second error, the loss was reported
    dev.close()
    dev.port = emu.replug()
    with dev:
        rep = dev.play(sweep(3))
    assert len(rep.pulses) == 3


def test_closing_says_goodbye_and_the_device_raises_no_alarm(emu, clock):
    with SerialDevice(VEST, emu.port, heartbeat_ms=HEARTBEAT_MS, clock=clock) as dev:
        dev.play(sweep(2))
    clock.sleep(2 * HEARTBEAT_MS / 1000)       # longer than its watchdog
    assert emu.all_outputs_off() and not emu.firmware.session
    assert emu.firmware.counters.watchdog_trips == 0 and emu.firmware.alarms == []
    assert emu.actuations()[-1].cause in ("play", "bye")


def test_a_lost_device_is_reported_even_if_the_first_call_is_all_off(emu, clock):
    dev = SerialDevice(VEST, emu.port, heartbeat_ms=HEARTBEAT_MS, clock=clock)
    dev.open()
    emu.unplug()
    clock.sleep(0.05)
    with pytest.raises(DeviceLost):
        dev.all_off()
    dev.close()


@pytest.mark.realtime          # a real process and a real pty
def test_host_killed_mid_trial_device_turns_off_by_itself(pty_emu):
    """The host process dies (SIGKILL: no all-off, no goodbye) during a play."""
    emu = pty_emu
    code = ("import sys; from vtexp.devices import open_device; "
            "from vtexp.model import DeviceProfile, Schedule, Pulse; "
            "p = DeviceProfile.load('vest_6x8'); "
            f"d = open_device('serial:{emu.port}', p, heartbeat_ms={HEARTBEAT_MS}); d.open(); "
            "print('open', flush=True); "
            "d.play(Schedule(device='vest_6x8', pulses=[Pulse(row=0, col=0, onset_ms=0, "
            "duration_ms=1900, level=2)]))")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                            env=dict(os.environ, PYTHONPATH=str(ROOT)))
    try:
        assert proc.stdout.readline().strip() == "open"
        deadline = time.monotonic() + 5
        while emu.outputs()[0].is_off and time.monotonic() < deadline:
            time.sleep(0.005)
        assert not emu.outputs()[0].is_off, "the play never started"
        os.kill(proc.pid, signal.SIGKILL)
        killed = time.monotonic()
        proc.wait(5)
        while not emu.all_outputs_off() and time.monotonic() - killed < 1.0:
            time.sleep(0.005)
        off_after = time.monotonic() - killed
    finally:
        if proc.poll() is None:
            proc.kill()
    assert emu.all_outputs_off()
    assert off_after < 2 * HEARTBEAT_MS / 1000      # watchdog (200 ms) + loop slack
    assert emu.actuations()[-1].cause == "watchdog"



@pytest.mark.realtime          # a real process and a real pty
def test_a_host_starved_of_the_cpu_is_no_pulled_cable(pty_emu):
    """The host process stopped for 400 ms (SIGSTOP: a loaded lab PC, a swapping disk):
    more than the heartbeat period, less than the watchdog it asked for. Nothing was sent
    meanwhile, so no answer was missed: the play goes on and the session with it."""
    emu = pty_emu
    code = ("from vtexp.devices import open_device; "
            "from vtexp.model import DeviceProfile, Schedule, Pulse; "
            "p = DeviceProfile.load('vest_6x8'); "
            f"d = open_device('serial:{emu.port},heartbeat_ms={HEARTBEAT_MS},watchdog_ms=1000', p); "
            "d.open(); print('open', flush=True); "
            "r = d.play(Schedule(device='vest_6x8', pulses=[Pulse(row=0, col=c, onset_ms=300 * c, "
            "duration_ms=200, level=2) for c in range(6)])); "
            "d.play(Schedule(device='vest_6x8', pulses=[Pulse(row=1, col=0, onset_ms=0, "
            "duration_ms=50, level=1)])); d.close(); print('played', len(r.pulses), flush=True)")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, PYTHONPATH=str(ROOT)))
    try:
        assert proc.stdout.readline().strip() == "open"
        deadline = time.monotonic() + 5
        while emu.outputs()[0].is_off and time.monotonic() < deadline:
            time.sleep(0.005)
        os.kill(proc.pid, signal.SIGSTOP)
        time.sleep(0.4)
        os.kill(proc.pid, signal.SIGCONT)
        out, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert out.strip() == "played 6"
    assert emu.firmware.counters.watchdog_trips == 0


STALL_HOST = """
import json, sys, time
from vtexp.devices import open_device
from vtexp.errors import DeviceError
from vtexp.model import DeviceProfile, Schedule, Pulse
p = DeviceProfile.load('vest_6x8')
d = open_device(sys.argv[1], p)
d.open()
one = Schedule(device='vest_6x8', pulses=[Pulse(row=0, col=0, onset_ms=0, duration_ms=int(sys.argv[2]), level=2)])
d.play(one)
print('stop me', flush=True)
time.sleep(1.0)                      # stopped (SIGSTOP) in here, by the test
try:                                 # ... or once this play's pulse has started
    d.play(one, on_started=lambda device_ms, host_ms: print('playing', flush=True))
    print(json.dumps({'played': True, **d.link_stats()}), flush=True)
except DeviceError as e:
    print(json.dumps({'played': False, 'error': str(e), **d.link_stats()}), flush=True)
d.close()
"""


def stalled_host(emu, spec: str, duration_ms: int, stop_after_s: float,
                 after: str = "stop me") -> dict:
    """The host process stopped (SIGSTOP) for 0.5 s, ``stop_after_s`` after it said
    ``after``: "stop me" (idle, between its two plays) or "playing" (its second play's
    pulse has started on the device: timed from there, a busy computer's slow start of
    the play cannot move the stop before the pulse)."""
    import json
    proc = subprocess.Popen([sys.executable, "-c", STALL_HOST, spec, str(duration_ms)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, PYTHONPATH=str(ROOT)))
    try:
        said = []
        for line in proc.stdout:
            said.append(line.strip())
            if said[-1] == after:
                break
        if not said or said[-1] != after:
            proc.wait(timeout=20)
            raise AssertionError(f"the host said {said}, not {after!r}: {proc.stderr.read()}")
        time.sleep(stop_after_s)
        os.kill(proc.pid, signal.SIGSTOP)
        time.sleep(0.5)
        os.kill(proc.pid, signal.SIGCONT)
        out, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    return json.loads(out.strip().splitlines()[-1])


@pytest.mark.realtime          # a real process and a real pty
def test_a_session_the_watchdog_ended_between_plays_is_started_again(pty_emu):
    """The host stopped 500 ms while idle, longer than its 200 ms watchdog: the device
    turned everything off (it was off) and ended the session; the next play says HELLO
    again and plays, counted."""
    emu = pty_emu
    got = stalled_host(emu, f"serial:{emu.port}", 50, 0.1)
    assert got["played"] is True and got["sessions_renewed"] == 1
    assert emu.firmware.counters.watchdog_trips == 1
    assert sum(1 for a in emu.actuations() if not a.setting.is_off) == 2   # both plays, once


@pytest.mark.realtime          # a real process and a real pty
def test_a_play_the_watchdog_cut_short_says_why(pty_emu):
    """Stopped 500 ms in the middle of a 1 s pulse: the device switched it off after its
    200 ms watchdog; the play fails with what happened and what to change."""
    emu = pty_emu
    got = stalled_host(emu, f"serial:{emu.port}", 1000, 0.3, after="playing")
    assert got["played"] is False
    assert "turned every actuator off: its watchdog heard nothing from this computer for " \
        "200 ms" in got["error"]
    assert f"serial:{emu.port},watchdog_ms=1000" in got["error"]
    assert emu.actuations()[-1].cause == "watchdog"

# --------------------------------------------------------------------------- handshake

def test_device_of_another_geometry_is_refused_at_handshake(clock):
    emu = LoopbackEmulator.for_profile(PAD, rows=16, cols=16, clock=clock)
    with emu:
        dev = SerialDevice(PAD, emu.port, clock=clock)
        with pytest.raises(DeviceError) as exc:
            dev.open()
    msg = str(exc.value)
    assert "reports 16x16 erm_motor actuators" in msg
    assert "profile 'pad_20x20' describes 20x20 erm_motor" in msg and "Nothing was played" in msg
    assert emu.actuations() == []


def test_device_of_another_kind_is_refused_at_handshake(clock):
    # an 8x6 SMA panel is no vest
    emu = LoopbackEmulator.for_profile(SMA, rows=8, cols=6, clock=clock)
    with emu, pytest.raises(DeviceError, match=r"8x6 sma_pin actuators driven by pulse_train, "
                                               r"but profile 'vest_6x8'"):
        SerialDevice(VEST, emu.port, clock=clock).open()


def test_device_with_fewer_levels_than_the_profile_allows_is_refused(clock):
    emu = LoopbackEmulator.for_profile(VEST, max_level=1, clock=clock)
    with emu, pytest.raises(DeviceError, match="allows level 2, but the device .* up to 1 only"):
        SerialDevice(VEST, emu.port, clock=clock).open()


def test_sma_panel_weaker_than_its_profile_is_refused(clock):
    emu = LoopbackEmulator.for_profile(SMA, max_width_us=1000, clock=clock)
    with emu, pytest.raises(DeviceError, match=r"pulse width of 1.5 ms, but the device .* 1 ms"):
        SerialDevice(SMA, emu.port, clock=clock).open()


def test_a_port_with_no_vtexp_device_says_so():
    # loop:// echoes what we send: a port that answers, but not as a vtexp device does.
    dev = SerialDevice(VEST, "loop://", handshake_timeout_s=0.3)
    with pytest.raises(DeviceError, match=r"no answer to the vtexp handshake from loop:// "
                                          r"within 0.3 s"):
        dev.open()


def test_a_missing_port_says_where_to_look():
    with pytest.raises(DeviceError, match=r"cannot open the serial port '/dev/does-not-exist'.*"
                                          r"vtexp device list"):
        open_device("serial:/dev/does-not-exist", VEST).open()


@pytest.mark.parametrize("where", ["pty", "loopback"])
def test_a_port_in_use_by_another_program_is_refused(emu, pty_emu, clock, where):
    port, clock = (pty_emu.port, None) if where == "pty" else (emu.port, clock)
    kw = {"clock": clock} if clock else {}
    with SerialDevice(VEST, port, **kw), \
            pytest.raises(DeviceError, match="another program .* has it open"):
        SerialDevice(VEST, port, **kw).open()


def test_sma_trains_survive_a_noisy_line():
    tr = PulseTrain(amplitude_v=2.0, frequency_hz=25, pulse_width_ms=1.5)
    s = Schedule(device="sma_5x5", pulses=[
        Pulse(row=i % 5, col=(2 * i) % 5, onset_ms=20 * i, duration_ms=20, train=tr)
        for i in range(5)])
    dev = open_device("emulator", SMA, faults=Faults(corrupt_rate=0.004, seed=2),
                      clock=VirtualClock(), **NOISY)
    with dev:
        for _ in range(4):
            dev.play(s)
    assert sorted(on_events(dev.emulator)) == sorted(expected(s, 5) * 4)


# --------------------------------------------------------------------------- link settings

def test_link_settings_after_the_port_reach_the_device(emu, clock):
    dev = open_device(f"serial:{emu.port},heartbeat_ms=400,watchdog_ms=900,baud=115200,"
                      "reply_ms=80", VEST, clock=clock)
    assert dev.reply_timeout_s == 0.08
    with dev:
        info = dev.info()
        assert (info.details["heartbeat_ms"], info.details["watchdog_ms"]) == (400, 900)
        assert info.details["baudrate"] == 115200
    assert (emu.firmware.heartbeat_ms, emu.firmware.watchdog_ms) == (400, 900)


@pytest.mark.parametrize("spec, says", [
    ("serial:/dev/ttyACM0,heartbeat=500", "unknown link option 'heartbeat=500'"),
    ("emulator:fast", "unknown emulator option 'fast'"),
    ("emulator:virtual,lockstep=/tmp/clock", "unknown link option 'lockstep=/tmp/clock'"),
    ("emulator:watchdog_ms=0", "watchdog_ms must be a whole number above 0"),
    ("serial:/dev/ttyACM0,watchdog_ms=0", "watchdog_ms must be a whole number above 0"),
    ("serial:/dev/ttyACM0,baud=fast", "baud must be a whole number above 0"),
    ("serial:/dev/ttyACM0,timing=soon", "timing must be device or host"),
    ("serial:/dev/ttyACM0,reply_ms=-5", "reply_ms must be a whole number above 0"),
])
def test_a_wrong_link_setting_is_named(spec, says):
    from vtexp.errors import InputError
    with pytest.raises(InputError, match=says):
        open_device(spec, VEST)


def test_the_emulator_takes_the_link_settings_and_suggests_itself():
    """``emulator:watchdog_ms=1000`` (and ``emulator:virtual,...``) set the link as a
    port's settings do; a longer watchdog is suggested as an emulator spec, which works
    as printed (the pty an emulator serves is gone when the program ends)."""
    dev = open_device("emulator:watchdog_ms=1000", VEST)
    assert (dev.heartbeat_ms, dev.watchdog_ms, dev.clock.virtual) == (200, 1000, False)
    assert dev._spec_with_watchdog(2000) == "emulator:watchdog_ms=2000"
    dev = open_device("emulator:virtual,heartbeat_ms=100", VEST)
    assert (dev.heartbeat_ms, dev.watchdog_ms, dev.clock.virtual) == (100, 100, True)
    assert dev._spec_with_watchdog(400) == "emulator:virtual,heartbeat_ms=100,watchdog_ms=400"
    again = open_device(dev._spec_with_watchdog(400), VEST)
    assert (again.heartbeat_ms, again.watchdog_ms, again.clock.virtual) == (100, 400, True)
    with open_device("emulator:virtual,watchdog_ms=700", VEST) as dev:
        assert dev.info().details["watchdog_ms"] == 700
        assert dev.emulator.firmware.watchdog_ms == 700


def test_a_play_the_watchdog_stopped_keeps_the_onsets_it_played(emu, clock):
    """The host fell silent in the middle of a play (its heartbeats held back): the
    device's watchdog stopped the play and ended the session. The onsets of the pulses
    it played are not lost: the host asks for them with GET_ONSETS (served without a
    session) before its next HELLO forgets them, and the error carries them."""
    from vtexp.errors import PlayInterrupted

    s = Schedule(device="vest_6x8", pulses=[
        Pulse(row=0, col=0, onset_ms=0, duration_ms=100, level=1),
        Pulse(row=1, col=1, onset_ms=50, duration_ms=900, level=2),
        Pulse(row=2, col=2, onset_ms=800, duration_ms=100, level=1)])
    dev = SerialDevice(VEST, emu.port, clock=clock)
    with dev:
        dev.open()
        dev._link.may_heartbeat = lambda now: False
        with pytest.raises(PlayInterrupted) as exc:
            dev.play(s)
        played = exc.value.report
        assert played.completed is False
        assert [(p.row, p.col) for p in played.pulses] == [(0, 0), (1, 1)]
        assert played.pulses[1].onset_ms - played.pulses[0].onset_ms == pytest.approx(50, abs=1)
        # the second pulse was cut short by the trip: it lasted until the device stopped
        assert played.pulses[0].duration_ms == 100
        assert played.pulses[1].duration_ms == pytest.approx(played.duration_ms - 50, abs=1)
        assert played.duration_ms < 800
        assert "the play stopped after 2 of 3 onsets" in str(exc.value)
        assert emu.firmware.counters.watchdog_trips == 1
        dev._link.may_heartbeat = dev._may_heartbeat
        dev.play(sweep(2))                   # a new session: the next play plays


@pytest.mark.parametrize("heartbeat_ms, reply_ms, survives", [
    (200, 25, True),                 # the defaults
    (1000, 120, True),               # the simulated chip's, as 'device emulate' suggests
    (1000, 250, False),              # its earlier suggestion: three attempts fit
], ids=["defaults", "avr-suggested", "avr-before"])
def test_four_replies_lost_in_a_row_do_not_lose_the_device(clock, heartbeat_ms, reply_ms,
                                                           survives):
    """Every reply of a request lost four times in a row (a noisy line): the fifth attempt
    is answered within the silence limit with the defaults and with the settings suggested
    for the simulated chip, which 'vtexp device emulate --firmware avr' prints."""
    from vtexp.devices.link import suggested_reply_ms

    if survives and heartbeat_ms != 200:
        assert suggested_reply_ms(heartbeat_ms) == reply_ms
    emu = LoopbackEmulator.for_profile(VEST, clock=clock)
    with emu:
        dev = SerialDevice(VEST, emu.port, heartbeat_ms=heartbeat_ms, reply_timeout_ms=reply_ms,
                           clock=clock)
        with dev:
            dev.open()
            link = dev._link
            wait_s = link.reply_timeout_for(len(wire.encode(Status(), 0)))
            emu.faults = Faults(drop_rate=1.0, direction="to_host")
            clock.call_later(3.5 * wait_s, lambda: setattr(emu, "faults", Faults()))
            if survives:
                dev.status()
                assert link.stats.timeouts == 4
            else:
                with pytest.raises(DeviceLost):
                    dev.status()


def test_a_host_timed_play_the_watchdog_stopped_is_not_played_again(emu, clock):
    """Host-streamed timing: the host stalls between two instants (no frame, no heartbeat)
    and the device's watchdog ends the session. The next frame is refused NO_SESSION;
    the play is not started again from its beginning (a pulse felt twice), and the error
    carries the onset the device acknowledged, as the emulated device's record says."""
    from vtexp.errors import PlayInterrupted

    s = Schedule(device="vest_6x8", pulses=[
        Pulse(row=0, col=0, onset_ms=0, duration_ms=50, level=1),
        Pulse(row=1, col=1, onset_ms=400, duration_ms=50, level=2)])
    dev = SerialDevice(VEST, emu.port, timing="host", clock=clock)
    with dev:
        dev.open()
        dev._link.may_heartbeat = lambda now: False
        with pytest.raises(PlayInterrupted, match="stopped after 1 of 2 onsets") as exc:
            dev.play(s)
        dev._link.may_heartbeat = dev._may_heartbeat
        rose = [a for a in emu.actuations() if not a.setting.is_off]
        assert [(a.index, a.setting) for a in rose] == [(0, Level(1))]    # once
        [p] = exc.value.report.pulses
        assert (p.row, p.col) == (0, 0) and not exc.value.report.completed
        assert exc.value.report.started_at_ms + p.onset_ms == rose[0].t_us / 1000
        dev.play(sweep(2))                   # a new session: the next play plays


def test_a_device_with_frames_over_4096_bytes_is_heard(clock):
    """A device that takes payloads of 8,000 bytes sends frames as long (docs/protocol.md,
    "The largest frame a host must accept"): its ONSETS_REPLY to a request for 622 lost
    onsets is 4,988 bytes, over the reader's 4,096 before the handshake, and is heard."""
    emu = LoopbackEmulator.for_profile(VEST, clock=clock, max_payload=8000)
    s = Schedule(device="vest_6x8", pulses=[
        Pulse(row=(i % 48) // 6, col=i % 6, onset_ms=2 * i, duration_ms=1, level=1)
        for i in range(700)])
    with emu:
        dev = SerialDevice(VEST, emu.port, clock=clock)
        with dev:
            dev.open()
            hear = dev._link.on_event
            dev._link.on_event = lambda m: None if isinstance(m, Onset) else hear(m)
            rep = dev.play(s)
            assert dev.recovered["onsets_fetched"] == 700
            assert dev._link.stats.rx_bad == {}
    played = [a.t_us for a in emu.actuations() if not a.setting.is_off]
    assert [round(rep.started_at_ms + p.onset_ms, 3) for p in rep.pulses] == \
        [round(t / 1000, 3) for t in played]
