"""The ``serial`` and ``emulator`` backends: a vtexp array on a serial port.

:class:`SerialDevice` opens any port pyserial opens (``/dev/ttyACM0``,
``COM3``, a pty path, a URL such as ``socket://host:port``), performs the
wire-protocol-v1 handshake, refuses a device whose geometry or drive differs
from the profile, and plays Schedules in one of two ways:

- ``timing="device"`` (default): the schedule is uploaded and triggered; the
  device plays it from its own clock and reports every onset (the host only
  triggers, so host jitter does not reach the skin);
- ``timing="host"``: the host sends a sparse frame at each change time and
  the device stamps when it applied it (for devices without schedule memory,
  and to measure what device-side timing buys, ``bench/timing.py``).

A live stream (``stream``, ``vtexp live``) sends each frame's changes as a
sparse ``SET_FRAME``, actuators switched off listed first; the ACK's time is the
device-reported onset.

Safety is :class:`~vtexp.devices.base.DeviceBase`'s: every Schedule passes
``vtexp.safety`` before a byte is written, and every error path ends in
ALL_OFF. While a schedule plays, ``play``'s ``should_stop`` is polled every few
ms (between frames, and while waiting for the device's onsets); a stop sends
ALL_OFF at once. When the device is lost, the host raises :class:`DeviceLost`
within one heartbeat period and the device's own watchdog turns everything off.

:class:`EmulatedDevice` (``emulator``) is a :class:`SerialDevice` talking to
an emulated device that it starts itself: a
:class:`~vtexp.devices.emulator.PtyEmulator` on a pseudo-terminal on the real clock,
a :class:`~vtexp.devices.emulator.LoopbackEmulator` in-process on a virtual one.

Time is the device's :class:`~vtexp.clock.Clock` (``clock=``): the link's timeouts
and heartbeats, the waits for a play's onsets and the host-streamed frames' times.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

from ..clock import REAL, Clock
from ..errors import DeviceError, InputError, PlayInterrupted, SessionAborted, StreamCut
from ..model import (
    DeviceInfo,
    DeviceProfile,
    LevelDrive,
    PlayedPulse,
    PlayReport,
    Pulse,
    PulseTrain,
    Schedule,
)
from . import wire
from .base import STOP_POLL_S, DeviceBase
from .clock import DeviceClock
from .link import DeviceLost, DeviceRefused, Link
from .wire import (
    Ack,
    AllOff,
    DoneReason,
    GetOnsets,
    Hello,
    HelloReply,
    Level,
    Message,
    NakReason,
    Onset,
    OnsetsReply,
    PlayDone,
    SetFrame,
    SetFrameFull,
    Setting,
    Status,
    StatusReply,
    Train,
    Trigger,
    UploadBegin,
    UploadChunk,
    WirePulse,
)

Timing = Literal["device", "host"]
ACTUATOR_NAMES = {v: k for k, v in wire.ACTUATOR_KINDS.items()}
DRIVE_NAMES = {v: k for k, v in wire.DRIVE_KINDS.items()}


def setting_of(p: Pulse) -> Setting:
    """A Schedule pulse's drive in wire units (mV, 0.01 Hz, µs)."""
    return drive_setting(p.level if p.level is not None else p.train)


def drive_setting(drive: int | PulseTrain) -> Setting:
    """A level or a pulse train in wire units (mV, 0.01 Hz, µs)."""
    if isinstance(drive, int):
        return Level(drive)
    return Train(round(drive.amplitude_v * 1000), round(drive.frequency_hz * 100),
                 round(drive.pulse_width_ms * 1000))


def change_groups(pulses: list[Pulse], cols: int, off: Setting
                  ) -> list[tuple[float, list[tuple[int, Setting]], list[int]]]:
    """The instants at which outputs change: ``(t_ms, [(index, setting)], [pulses starting])``.

    Offsets come before onsets at the same instant; where pulses of one
    actuator overlap, the latest started drives it (as the firmware does).
    """
    ev = sorted([(p.onset_ms, 1, i) for i, p in enumerate(pulses)]
                + [(p.offset_ms, 0, i) for i, p in enumerate(pulses)])
    active: dict[int, list[int]] = {}
    out: list[tuple[float, list[tuple[int, Setting]], list[int]]] = []
    k = 0
    while k < len(ev):
        t = ev[k][0]
        changed: dict[int, Setting] = {}
        starting: list[int] = []
        while k < len(ev) and ev[k][0] == t:
            _, on, i = ev[k]
            k += 1
            p = pulses[i]
            idx = p.row * cols + p.col
            stack = active.setdefault(idx, [])
            if on:
                stack.append(i)
                starting.append(i)
            else:
                stack.remove(i)
            changed[idx] = setting_of(pulses[stack[-1]]) if stack else off
        out.append((t, sorted(changed.items()), starting))
    return out


def wait_until(t: float, clock: Clock = REAL, link: Link | None = None, spin_s: float = 0.005,
               poll: Callable[[], None] | None = None) -> None:
    """Sleep until shortly before ``t`` (the clock's seconds), then spin to it.

    Sleeps in slices of at most 10 ms so that a lost ``link`` is raised at once,
    not at the next frame; with ``poll`` (which may raise), in slices of
    ``STOP_POLL_S``, calling it before each. The last ``spin_s`` are spent awake
    and poll nothing: a thread woken from sleep on a busy machine can start
    milliseconds late (``bench/timing.py``). A virtual clock is never late: it
    sleeps to the instant.
    """
    slice_s = 0.010 if poll is None else STOP_POLL_S
    spin_s = 0.0 if clock.virtual else spin_s
    while True:
        if link is not None:
            link.check()
        left = t - clock.now()
        if left <= 0:
            return
        if left > spin_s:
            if poll is not None:
                poll()
            clock.sleep(min(left - spin_s, slice_s))
        else:
            time.sleep(0)           # let the reader thread run while we spin


@dataclass
class _PlayState:
    play_id: int
    n: int
    onsets: list[int | None] = field(default_factory=list)
    done: PlayDone | None = None
    triggered: bool = False         # the device acknowledged the TRIGGER: it played
    alarm_us: int | None = None     # device time of a watchdog ALARM heard during the play


class SerialDevice(DeviceBase):
    """A vtexp array on a serial port (see the module docstring).

    Parameters
    ----------
    profile:
        What the array must be; the device's handshake is checked against it.
    port:
        Anything ``serial.serial_for_url`` opens.
    baudrate:
        Of the UART (ignored by USB CDC devices and ptys, used for timeouts). The
        reference firmware runs at 1,000,000 baud (docs/firmware.md).
    timing:
        ``"device"`` (upload and trigger) or ``"host"`` (stream frames).
    heartbeat_ms:
        Heartbeat period asked of the device; the device's watchdog and the
        host's silence limit follow it.
    watchdog_ms:
        Device watchdog; defaults to the heartbeat period.
    handshake_timeout_s:
        How long HELLO is tried: an Arduino resets when its port opens, and its
        bootloader waits about a second before the firmware starts.
    clock:
        What the device's link waits on (:class:`~vtexp.clock.Clock`; the real one
        unless another is given, a virtual one for an in-process emulator).
    """

    backend = "serial"

    def __init__(self, profile: DeviceProfile, port: str, *, baudrate: int = 1_000_000,
                 timing: Timing = "device", heartbeat_ms: int = 200,
                 watchdog_ms: int | None = None, reply_timeout_ms: float = 25,
                 retries: int = 8, handshake_timeout_s: float = 3.0,
                 trace: Callable[[str, object], None] | None = None, clock: Clock = REAL):
        super().__init__(profile, clock)
        if timing not in ("device", "host"):
            raise InputError(f"timing must be 'device' or 'host' (got {timing!r})")
        self.port = port
        self.baudrate = baudrate
        self.timing: Timing = timing
        self.heartbeat_ms = heartbeat_ms
        self.watchdog_ms = watchdog_ms or heartbeat_ms
        self.reply_timeout_s = reply_timeout_ms / 1000.0
        self.retries = retries
        self.handshake_timeout_s = handshake_timeout_s
        self.trace = trace
        self.hello: HelloReply | None = None
        self._link: Link | None = None
        self._current: _PlayState | None = None
        self._play_id = 0
        self._lost_reported = False
        self.alarms: list[wire.Alarm] = []
        # Set when the device's watchdog ended the session (ALARM, or NAK NO_SESSION):
        # this computer sent nothing for watchdog_ms, and the device turned everything off.
        self._session_ended: str | None = None
        #: When the device's watchdog switched everything off (its alarm's time, device ms).
        self._ended_at_ms: float | None = None
        # Recoveries above the link: onsets asked for again, PLAY_DONE replaced by STATUS,
        # sessions started again after the device's watchdog ended one between plays.
        self.recovered = {"onsets_fetched": 0, "status_polls": 0, "sessions_renewed": 0}
        self._drive = wire.DRIVE_KINDS[profile.drive.kind]
        self._off = wire.OFF[self._drive]
        self._outputs: list[Setting] = [self._off] * (profile.rows * profile.cols)
        # A host-streamed play's next frame (clock time): heartbeats keep clear of it.
        self._next_send_at: float | None = None
        #: The device's clock on this computer's, from every heartbeat's ACK.
        self.clock_map = DeviceClock(host=self.clock)

    # -- open / close -----------------------------------------------------------------------
    def _open(self) -> DeviceInfo:
        from .emulator import open_port

        self._lost_reported = False
        self._session_ended = None
        self._ended_at_ms = None
        try:
            port = open_port(self.port, baudrate=self.baudrate, clock=self.clock)
        except (ValueError, OSError) as e:      # pyserial's SerialException is an OSError
            hint = ("another program (another vtexp?) has it open"
                    if "lock" in str(e).lower() else
                    "'vtexp device list' shows the ports found")
            raise DeviceError(f"cannot open the serial port {self.port!r}: {e}. "
                              f"{hint}.") from None
        try:
            port.reset_input_buffer()
        except Exception:
            pass
        self.clock_map.reset()                  # a device opened again may have restarted its clock
        link = Link(port, name=self.port, reply_timeout_s=self.reply_timeout_s,
                    retries=self.retries, on_event=self._on_event,
                    on_clock_sample=self.clock_map.add, may_heartbeat=self._may_heartbeat,
                    trace=self.trace, clock=self.clock)
        self._link = link
        self._outputs = [self._off] * (self.profile.rows * self.profile.cols)
        link.start()
        try:
            self.hello = hello = self._handshake(link)
            self._check_against_profile(hello)
            link.accept_frames_up_to(hello.max_payload)
            link.start_heartbeat(hello.heartbeat_ms)
        except BaseException:
            link.close()
            self._link = None
            raise
        return DeviceInfo(
            backend=self.backend, profile=self.profile.name, rows=hello.rows, cols=hello.cols,
            firmware=hello.firmware, protocol=f"vtexp-wire/{hello.protocol}", port=self.port,
            details={"device_id": hello.device_id, "heartbeat_ms": hello.heartbeat_ms,
                     "watchdog_ms": hello.watchdog_ms, "max_pulses": hello.max_pulses,
                     "max_payload": hello.max_payload, "baudrate": self.baudrate,
                     "timing": self.timing})

    def _handshake(self, link: Link) -> HelloReply:
        attempt_s = 0.1
        tries = max(1, round(self.handshake_timeout_s / attempt_s))
        try:
            reply = link.request(Hello(wire.PROTOCOL_VERSION, self.heartbeat_ms,
                                       self.watchdog_ms),
                                 timeout_s=attempt_s, retries=tries - 1)
        except DeviceLost as e:
            raise DeviceError(f"the port {self.port} failed during the handshake: {e}") from None
        except DeviceError:
            raise DeviceError(
                f"no answer to the vtexp handshake from {self.port} within "
                f"{self.handshake_timeout_s:g} s. Is a device with {wire.PROTOCOL_NAME} "
                f"firmware on this port, at {self.baudrate} baud? ('vtexp device list' shows "
                "the ports; 'vtexp device emulate' starts an emulated one.)") from None
        if isinstance(reply, wire.Nak):
            if reply.reason == NakReason.UNSUPPORTED_PROTOCOL:
                raise DeviceError(f"the device on {self.port} speaks wire protocol up to "
                                  f"{reply.detail}, not {wire.PROTOCOL_VERSION}; update its "
                                  "firmware or vtexp")
            raise DeviceError(f"the device on {self.port} refused the handshake: "
                              f"{reply.reason_name}")
        if not isinstance(reply, HelloReply):
            raise DeviceError(f"the device on {self.port} answered the handshake with "
                              f"{type(reply).__name__}; it does not speak {wire.PROTOCOL_NAME}")
        if reply.protocol != wire.PROTOCOL_VERSION:
            raise DeviceError(f"the device on {self.port} chose wire protocol "
                              f"{reply.protocol}; this vtexp speaks {wire.PROTOCOL_VERSION}")
        return reply

    def _check_against_profile(self, h: HelloReply) -> None:
        """Refuse a device that is not the array the profile describes."""
        p = self.profile
        dev_kind = ACTUATOR_NAMES.get(h.actuator, f"actuator kind {h.actuator}")
        dev_drive = DRIVE_NAMES.get(h.drive, f"drive kind {h.drive}")
        if (h.rows, h.cols, dev_kind, dev_drive) != (p.rows, p.cols, p.actuator, p.drive.kind):
            raise DeviceError(
                f"the device on {self.port} ({h.firmware}, id {h.device_id!r}) reports "
                f"{h.rows}x{h.cols} {dev_kind} actuators driven by {dev_drive}, but profile "
                f"{p.name!r} describes {p.rows}x{p.cols} {p.actuator} actuators driven by "
                f"{p.drive.kind}. Nothing was played. Choose the profile of the device "
                "that is connected (--profile), or connect the right device.")
        lim = p.limits
        if isinstance(p.drive, LevelDrive):
            if (lim.max_level or 0) > h.max_level:
                raise DeviceError(f"profile {p.name!r} allows level {lim.max_level}, but the "
                                  f"device on {self.port} has levels up to {h.max_level} only")
        else:
            checks = [("amplitude", lim.max_amplitude_v or p.drive.amplitude_v, 1000,
                       h.max_amplitude_mv, "V"),
                      ("frequency", lim.max_frequency_hz or max(p.drive.frequencies_hz), 100,
                       h.max_frequency_chz, "Hz"),
                      ("pulse width", lim.max_pulse_width_ms or max(p.drive.pulse_width_ms),
                       1000, h.max_width_us, "ms")]
            for what, want, scale, has, unit in checks:
                if round(want * scale) > has:
                    raise DeviceError(f"profile {p.name!r} allows a {what} of {want:g} {unit}, "
                                      f"but the device on {self.port} goes up to "
                                      f"{has / scale:g} {unit} only")

    def _close(self) -> None:
        link = self._link
        if link is None:
            return
        try:
            if link.lost is None:
                # Say goodbye, so that the device ends the session now rather than
                # raising a watchdog alarm for a host that merely left.
                link.request(wire.Bye(), retries=2)
        except DeviceError:
            pass        # then its watchdog ends the session; everything is off already
        finally:
            link.close()
            self._link = None

    # -- loss -------------------------------------------------------------------------------
    def _lost(self, reason: str) -> DeviceLost:
        self._lost_reported = True
        wd = self.hello.watchdog_ms if self.hello else self.watchdog_ms
        return DeviceLost(
            f"lost contact with the tactile device on {self.port}: {reason}. The cable may "
            f"have been pulled or the device lost power. The device turns every actuator off "
            f"by itself after {wd} ms without hearing from this computer. Reconnect it, check "
            f"it with 'vtexp device check', then resume the session.")

    def _call(self, fn: Callable[[Link], Any]) -> Any:
        """Run ``fn(link)``, turning a lost link into a message for people.

        If the device's watchdog ended the session while nothing was playing (this
        computer was too busy to send a heartbeat for ``watchdog_ms``; the device turned
        everything off, which it was anyway), the session is started again with a new
        handshake, counted in ``recovered["sessions_renewed"]``, and ``fn`` runs on it.
        During a stream the outputs the host believes on are off: that is an error.
        """
        link = self._link
        if link is None:
            raise DeviceError(f"the device on {self.port} is not open")
        try:
            if self._session_ended is not None:
                self._renew_session(link)
            try:
                return fn(link)
            except DeviceRefused as e:
                st = self._current
                if e.nak.reason != NakReason.NO_SESSION or (st is not None and st.triggered):
                    raise                   # never play a schedule twice
                self._current = None
                self._session_ended = "NO_SESSION"
                self._renew_session(link)
                return fn(link)
        except DeviceLost:
            raise self._lost(link.lost or "the link was lost") from None

    def _spec_with_watchdog(self, watchdog_ms: int) -> str:
        """This device's ``--device`` spec (its options that are not the defaults) with
        that watchdog, and a heartbeat no longer than it."""
        opts = []
        if self.baudrate != 1_000_000:
            opts.append(f"baud={self.baudrate}")
        if self.heartbeat_ms > watchdog_ms:
            opts.append(f"heartbeat_ms={watchdog_ms}")
        elif self.heartbeat_ms != 200:
            opts.append(f"heartbeat_ms={self.heartbeat_ms}")
        opts.append(f"watchdog_ms={watchdog_ms}")
        if self.reply_timeout_s != 0.025:
            opts.append(f"reply_ms={self.reply_timeout_s * 1000:g}")
        if getattr(self.clock, "path", None) is not None:     # a chip's clock (lockstep)
            opts.append(f"lockstep={self.clock.path}")
        return ",".join([f"serial:{self.port}", *opts])

    def _watchdog_message(self) -> str:
        wd = self.hello.watchdog_ms if self.hello else self.watchdog_ms
        longer = max(1000, 2 * wd)
        if self._streaming:             # a stream holds max_on_ms only up to this watchdog
            longer = min(longer, self.stream_watchdog_limit_ms())
        return (f"the device on {self.port} turned every actuator off: its watchdog heard "
                f"nothing from this computer for {wd} ms (the program stalled, or the "
                f"computer was too busy). "
                + (f"A longer watchdog tolerates that: --device {self._spec_with_watchdog(longer)}"
                   if longer > wd else
                   f"{self.profile.name} cannot be streamed with a longer one: keep the "
                   "computer free of other work"))

    def _renew_session(self, link: Link) -> None:
        """A new session after the device's watchdog ended the last one."""
        if self._streaming:
            self._session_ended = None
            raise self._stream_cut()
        hello = self._handshake(link)
        self._check_against_profile(hello)
        self.hello = hello
        self._outputs = [self._off] * (self.profile.rows * self.profile.cols)
        self._session_ended = None
        self._ended_at_ms = None            # that trip's time is no stream's
        self.recovered["sessions_renewed"] += 1

    # -- events (reader thread) -------------------------------------------------------------
    def _on_event(self, msg: Message) -> None:
        st = self._current
        if isinstance(msg, Onset) and st is not None and msg.play_id == st.play_id:
            for i in range(msg.first, min(msg.first + msg.count, st.n)):
                st.onsets[i] = msg.t_us
        elif isinstance(msg, PlayDone) and st is not None and msg.play_id == st.play_id:
            st.done = msg
        elif isinstance(msg, wire.Alarm):
            self.alarms.append(msg)
            if msg.code == wire.AlarmCode.WATCHDOG:
                self._session_ended = "ALARM WATCHDOG"
                self._ended_at_ms = msg.t_us / 1000.0
                if st is not None:
                    st.alarm_us = msg.t_us

    # -- play -------------------------------------------------------------------------------
    def _play(self, schedule: Schedule) -> PlayReport:
        pulses = schedule.sorted()
        if self.timing == "host":
            return self._call(lambda link: self._play_host(link, schedule, pulses))
        return self._call(lambda link: self._play_device(link, schedule, pulses))

    def _wire_pulses(self, pulses: list[Pulse]) -> list[WirePulse]:
        c = self.profile.cols
        return [WirePulse(p.row * c + p.col, round(p.onset_ms * 1000),
                          max(1, round(p.duration_ms * 1000)), setting_of(p)) for p in pulses]

    def _play_device(self, link: Link, schedule: Schedule, pulses: list[Pulse]) -> PlayReport:
        assert self.hello is not None
        wp = self._wire_pulses(pulses)
        if len(wp) > self.hello.max_pulses:
            raise DeviceError(f"the schedule has {len(wp)} pulses; the device on {self.port} "
                              f"holds at most {self.hello.max_pulses}. Use timing='host' or "
                              "a shorter schedule.")
        self._play_id = (self._play_id + 1) & 0xFFFF
        pid = self._play_id
        per = max(1, (self._payload_budget() - 5) // UploadChunk.pulse_size(self._drive))
        k = 0
        try:
            link.expect(UploadBegin(pid, len(wp), self._drive), Ack)
            for k in range(0, len(wp), per):
                link.expect(UploadChunk(pid, k, self._drive, tuple(wp[k:k + per])), Ack)
        except DeviceRefused as e:
            if e.nak.reason == NakReason.NO_SESSION:
                raise                       # the watchdog ended the session: _call renews it
            raise DeviceError(self._refusal(e.nak, pulses, wp, k)) from None
        st = _PlayState(pid, len(wp), [None] * len(wp))
        self._current = st
        self._check_stop()                  # stopped during the upload: nothing is played
        if self.clock_map.age_ms() > self.clock_map.window_ms / 2:
            link.expect(wire.Heartbeat(), Ack)      # a fresh sample of the device's clock
        start_us = link.expect(Trigger(pid, 0), Ack).t_us
        st.triggered = True
        self._play_started(start_us / 1000.0, self.clock_map.to_host_ms(start_us / 1000.0))
        try:
            self._wait_done(link, st, schedule.duration_ms)
        except SessionAborted as e:         # stopped: the onsets the device reported so far
            e.played = self._report(start_us, schedule, [
                PlayedPulse(row=p.row, col=p.col, scheduled_onset_ms=p.onset_ms,
                            onset_ms=(t - start_us) / 1000.0, duration_ms=p.duration_ms,
                            level=p.level, train=p.train)
                for p, t in zip(pulses, st.onsets) if t is not None
            ]).model_copy(update={"completed": False})
            raise
        if st.done is not None and st.done.reason != DoneReason.FINISHED:
            self._current = None
            if st.done.reason == DoneReason.WATCHDOG:
                raise self._interrupted(link, st, pulses, start_us, schedule)
            raise DeviceError(f"the device on {self.port} stopped the play early "
                              f"({DoneReason.NAMES.get(st.done.reason, st.done.reason)}) "
                              f"after {st.done.n_onsets} of {len(wp)} onsets")
        self._fetch_missing(link, st)
        self._current = None
        report = [PlayedPulse(row=p.row, col=p.col, scheduled_onset_ms=p.onset_ms,
                              onset_ms=(t - start_us) / 1000.0, duration_ms=p.duration_ms,
                              level=p.level, train=p.train)
                  for p, t in zip(pulses, st.onsets)]
        return self._report(start_us, schedule, report)

    def _report(self, start_us: int, schedule: Schedule, pulses: list[PlayedPulse]
                ) -> PlayReport:
        """The report of a play, its start also on the host's clock (``devices.clock``)."""
        off = self.clock_map.offset_ms()
        return PlayReport(device=self.profile.name, started_at_ms=start_us / 1000.0,
                          duration_ms=schedule.duration_ms, pulses=pulses,
                          started_at_host_ms=None if off is None else start_us / 1000.0 - off[0],
                          host_clock_error_ms=None if off is None else off[1])

    def _refusal(self, nak: wire.Nak, pulses: list[Pulse], wp: list[WirePulse],
                 first: int) -> str:
        """What a NAK to a schedule's upload means, naming the pulse (actuator, time) and
        the device's limit it broke. Nothing of a refused schedule is played."""
        h = self.hello
        assert h is not None
        head = f"the device on {self.port} refused the schedule ({len(wp)} pulses)"
        tail = "; nothing of it was played."
        r = nak.reason
        if r == NakReason.TOO_LARGE:
            return f"{head}: it holds at most {nak.detail} pulses{tail}"
        if r == NakReason.BUSY:
            return f"{head}: it is still playing schedule {nak.detail}{tail}"
        if r == NakReason.WRONG_DRIVE:
            return (f"{head}: it is driven by {DRIVE_NAMES.get(nak.detail, nak.detail)}, "
                    f"not {self.profile.drive.kind}{tail}")
        if r == NakReason.OUT_OF_ORDER and nak.detail < len(pulses):
            q = pulses[nak.detail]
            return (f"{head}: pulse {nak.detail + 1} (actuator row {q.row}, col {q.col}, at "
                    f"{q.onset_ms:g} ms) starts before the pulse sent before it{tail}")
        if r == NakReason.OUT_OF_RANGE:
            for j in range(first, len(wp)):
                w, q = wp[j], pulses[j]
                if w.index != nak.detail:
                    continue
                where = (f"pulse {j + 1} (actuator row {q.row}, col {q.col}, at "
                         f"{q.onset_ms:g} ms)")
                s = w.setting
                if w.index >= h.rows * h.cols:
                    why = f"the device has {h.rows}x{h.cols} actuators"
                elif isinstance(s, wire.Level):
                    if s.level <= h.max_level:
                        continue
                    why = f"level {s.level} is above the device's highest, {h.max_level}"
                elif s.amplitude_mv > h.max_amplitude_mv:
                    why = (f"amplitude {s.amplitude_mv / 1000:g} V is above the device's "
                           f"{h.max_amplitude_mv / 1000:g} V")
                elif s.amplitude_mv and s.frequency_chz > h.max_frequency_chz:
                    why = (f"frequency {s.frequency_chz / 100:g} Hz is above the device's "
                           f"{h.max_frequency_chz / 100:g} Hz")
                elif s.amplitude_mv and s.width_us > h.max_width_us:
                    why = (f"pulse width {s.width_us / 1000:g} ms is above the device's "
                           f"{h.max_width_us / 1000:g} ms")
                elif s.amplitude_mv and s.width_us * s.frequency_chz >= 100_000_000:
                    why = (f"pulse width {s.width_us / 1000:g} ms fills the whole period of "
                           f"{s.frequency_chz / 100:g} Hz")
                elif w.duration_us + w.onset_us > 0xFFFFFFFF:
                    why = "it ends more than 71 minutes after the start"
                else:
                    continue
                return f"{head}: {where}: {why}{tail}"
        return (f"{head}: {NakReason.NAMES.get(r, r)} (detail {nak.detail}){tail}")

    def _wait_done(self, link: Link, st: _PlayState, duration_ms: float) -> None:
        """Wait for PLAY_DONE; if that event was lost, ask for the status instead.

        Polls ``should_stop`` every few ms while it waits (:meth:`_check_stop`).
        """
        hb = link.heartbeat_s or 0.2
        step = hb / 4 if self._should_stop is None else min(hb / 4, STOP_POLL_S)
        clock = self.clock
        deadline = clock.now() + duration_ms / 1000.0 + max(0.1, hb)
        while True:
            while st.done is None and link.lost is None:
                left = deadline - clock.now()
                if left <= 0:
                    break
                link.wait_for(lambda: st.done is not None or link.lost is not None,
                              min(left, step))
                self._check_stop()
            link.check()
            if st.done is not None:
                return
            self.recovered["status_polls"] += 1
            status = link.expect(Status(), StatusReply)
            if status.state in (wire.DeviceState.PLAYING, wire.DeviceState.ARMED) \
                    and status.play_id == st.play_id:
                deadline = clock.now() + hb       # still going (device clock slower?)
                continue
            if status.state == wire.DeviceState.NO_SESSION:
                st.done = PlayDone(st.play_id, DoneReason.WATCHDOG, status.n_onsets, 0)
                return                  # the watchdog stopped it; its PLAY_DONE was lost
            return                      # finished; the PLAY_DONE event was lost on the line

    def _interrupted(self, link: Link, st: _PlayState, pulses: list[Pulse], start_us: int,
                     schedule: Schedule) -> PlayInterrupted:
        """The error for a play the device's watchdog stopped, with the pulses it did play:
        their onsets asked for with GET_ONSETS, which the device serves without a session,
        before a HELLO would forget them (docs/protocol.md, "Session"). A device of the
        previous edition answers NO_SESSION: then only the onsets whose ONSET events were
        heard are kept."""
        then = ""
        try:
            self._fetch_missing(link, st, played_only=True)
        except DeviceLost:
            # Said here, so that the ALL_OFF after it does not replace this error (and its
            # report) with the loss; the next call on the device raises it again.
            self._lost_reported = True
            then = (f". Then contact with it was lost ({link.lost or 'the link failed'}): "
                    "reconnect it")
        except DeviceError:
            pass            # NO_SESSION (the previous edition): keep the onsets heard
        stop_us = st.done.t_us if st.done is not None and st.done.t_us else st.alarm_us
        n_played = st.done.n_onsets if st.done is not None else None
        return self._stopped(pulses, st.onsets, start_us, schedule, stop_us, n_played, then)

    def _stopped(self, pulses: list[Pulse], onsets: list[int | None], start_us: int,
                 schedule: Schedule, stop_us: int | None, n_played: int | None = None,
                 then: str = "") -> PlayInterrupted:
        """:class:`PlayInterrupted` for a play the watchdog stopped: the pulses with a
        device-reported onset (``onsets``, device µs), none guessed. A pulse the trip cut
        short lasts until the device's stop time (``stop_us``, from its PLAY_DONE or
        ALARM), when that was heard. ``n_played``: how many the device says it played."""
        played = []
        for p, t in zip(pulses, onsets):
            if t is None:
                continue
            dur = p.duration_ms
            if stop_us is not None and stop_us >= t:
                dur = min(dur, (stop_us - t) / 1000.0)
            played.append(PlayedPulse(row=p.row, col=p.col, scheduled_onset_ms=p.onset_ms,
                                      onset_ms=(t - start_us) / 1000.0, duration_ms=dur,
                                      level=p.level, train=p.train))
        update: dict[str, Any] = {"completed": False}
        if stop_us is not None and stop_us >= start_us:
            update["duration_ms"] = min(schedule.duration_ms, (stop_us - start_us) / 1000.0)
        report = self._report(start_us, schedule, played).model_copy(update=update)
        n_played = len(played) if n_played is None else n_played
        kept = ("their device-reported times are kept with the error"
                if n_played <= len(played) else
                f"the device-reported times of {len(played)} are kept with the error; those of "
                f"{n_played - len(played)} more are not known: the device does not serve "
                "GET_ONSETS without a session (firmware of the previous edition of the wire "
                "protocol; update it)")
        return PlayInterrupted(
            f"{self._watchdog_message()}; the play stopped after {n_played} of {len(pulses)} "
            f"onsets ({kept}){then}", report)

    def _fetch_missing(self, link: Link, st: _PlayState, *, played_only: bool = False) -> None:
        """Ask again for onsets whose ONSET events were lost (counted, never guessed).

        ``played_only``: the play was stopped early; a pulse the device did not play stays
        None (else that is an error)."""
        fit = (self._payload_budget() - 5) // 8
        first = 0
        while (missing := [i for i, t in enumerate(st.onsets) if t is None and i >= first]):
            first = missing[0]
            count = min(fit, missing[-1] - first + 1)
            rep = link.expect(GetOnsets(st.play_id, first, count), OnsetsReply,
                              reply_bytes=8 * count + 16)
            if not rep.times_us:
                raise DeviceError(f"the device on {self.port} has no onset for pulse {first}")
            for k, t in enumerate(rep.times_us):
                if st.onsets[first + k] is not None:
                    continue
                if t == wire.NOT_PLAYED:
                    if played_only:
                        continue            # not played before the play stopped
                    raise DeviceError(f"the device on {self.port} did not play pulse "
                                      f"{first + k} of the schedule")
                st.onsets[first + k] = t
                self.recovered["onsets_fetched"] += 1
            first += len(rep.times_us)

    def _payload_budget(self) -> int:
        """Largest payload to put in one frame: what the device takes, and no more than
        a quarter of a heartbeat period on the wire, so that a frame lost and sent
        again never looks like silence."""
        assert self.hello is not None
        period_s = self.hello.heartbeat_ms / 1000.0
        on_wire = int(self.baudrate / 10 * period_s / 4) - 16
        return max(64, min(self.hello.max_payload, on_wire))

    def _frames(self, state: list[Setting], changes: list[tuple[int, Setting]]
                ) -> list[Message]:
        """The smallest frame(s) that apply ``changes``: sparse, or dense if shorter."""
        size = wire.SETTINGS[self._drive].SIZE
        budget = self._payload_budget()
        room = budget - 3
        sparse = len(changes) * (2 + size)
        dense = len(state) * size
        if dense < sparse and dense + 1 <= budget:
            new = list(state)
            for i, s in changes:
                new[i] = s
            return [SetFrameFull(self._drive, tuple(new))]
        per = max(1, room // (2 + size))
        return [SetFrame(self._drive, tuple(changes[k:k + per]))
                for k in range(0, len(changes), per)]

    def _play_host(self, link: Link, schedule: Schedule, pulses: list[Pulse]) -> PlayReport:
        groups = change_groups(pulses, self.profile.cols, self._off)
        state = [self._off] * (self.profile.rows * self.profile.cols)
        onsets: list[int | None] = [None] * len(pulses)
        first_t_us: int | None = None
        poll = self._check_stop if self._should_stop is not None else None
        t0 = self.clock.now() + 0.002
        cols = self.profile.cols
        try:
            for t_ms, changes, starting in groups:
                target = t0 + t_ms / 1000.0
                self._next_send_at = target
                wait_until(target, self.clock, link, poll=poll)
                applied = None
                changed: set[int] = set()
                for msg in self._frames(state, changes):
                    try:
                        ack = link.expect(msg, Ack)
                    except DeviceRefused as e:
                        if e.nak.reason != NakReason.NO_SESSION or (
                                first_t_us is None and applied is None):
                            raise           # nothing played yet: it may be played anew
                        # The watchdog stopped the play between frames: never played twice.
                        self._session_ended = "NO_SESSION"
                        for i in starting:
                            if pulses[i].row * cols + pulses[i].col in changed:
                                onsets[i] = applied
                        start = first_t_us if first_t_us is not None else \
                            applied - round(t_ms * 1000)
                        alarm = next((a.t_us for a in reversed(self.alarms)
                                      if a.code == wire.AlarmCode.WATCHDOG and a.t_us >= start),
                                     None)
                        raise self._stopped(pulses, onsets, start, schedule,
                                            alarm) from None
                    applied = ack.t_us if applied is None else applied
                    changed.update(range(len(state)) if isinstance(msg, SetFrameFull)
                                   else (i for i, _ in msg.changes))
                for i, s in changes:
                    state[i] = s
                # The play's start on the device clock: the instant that came least late
                # says it best (each is sent at its time or later, never earlier)
                implied = applied - round(t_ms * 1000)
                if first_t_us is None:
                    self._play_started(implied / 1000.0,
                                       self.clock_map.to_host_ms(implied / 1000.0))
                first_t_us = implied if first_t_us is None else min(first_t_us, implied)
                for i in starting:
                    onsets[i] = applied
        finally:
            self._next_send_at = None
        start_us = first_t_us or 0
        report = [PlayedPulse(row=p.row, col=p.col, scheduled_onset_ms=p.onset_ms,
                              onset_ms=(t - start_us) / 1000.0, duration_ms=p.duration_ms,
                              level=p.level, train=p.train)
                  for p, t in zip(pulses, onsets)]
        return self._report(start_us, schedule, report)

    # -- live stream ------------------------------------------------------------------------
    def stream_watchdog_ms(self) -> float | None:
        return float(self.hello.watchdog_ms) if self.hello is not None else float(
            self.watchdog_ms)

    def _may_heartbeat(self, now: float) -> bool:
        """Whether the link may send a heartbeat now (its ``may_heartbeat``)."""
        nxt = self._next_send_at
        if nxt is not None and -0.001 < nxt - now < 0.005:
            return False            # a streamed frame is due in a moment; it feeds the watchdog
        if self._streaming and now - self._alive_at >= self.stream_checkin_ms / 1000.0:
            # Heartbeats only while the stream's loop checks in: a stalled host goes
            # silent, and the device's watchdog switches everything off.
            return False
        return True

    def _stream_checked_in(self) -> None:
        # A loop that stalled may find the session ended: say so at once.
        if self._link is not None and self._link.lost is not None:
            raise self._lost(self._link.lost)
        if self._session_ended is not None:
            self._session_ended = None
            raise self._stream_cut()

    def _stream_cut(self) -> StreamCut:
        """The stream's end by the device's watchdog, with when its alarm said it was."""
        off_at, self._ended_at_ms = self._ended_at_ms, None
        return StreamCut(self._watchdog_message(), off_at_ms=off_at)

    def _set_outputs(self, changes, *, full: bool = False) -> float:
        # Offsets first: a device that applies a frame's changes one after another (or a
        # frame split in two for its size) never has more actuators on than before or after.
        cols = self.profile.cols
        wire_changes = sorted(((r * cols + c, self._off if d is None else drive_setting(d))
                               for (r, c), d in changes.items()),
                              key=lambda ch: (not ch[1].is_off, ch[0]))
        if full:
            return self._call(lambda link: self._send_full(link, wire_changes))
        return self._call(lambda link: self._send_outputs(link, wire_changes))

    def _send_full(self, link: Link, changes: list[tuple[int, Setting]]) -> float:
        state = list(self._outputs)
        for i, s in changes:
            state[i] = s
        ack = link.expect(SetFrameFull(self._drive, tuple(state)), Ack)
        self._outputs = state
        return ack.t_us / 1000.0

    def _send_outputs(self, link: Link, changes: list[tuple[int, Setting]]) -> float:
        applied = None
        size = wire.SETTINGS[self._drive].SIZE
        per = max(1, (self._payload_budget() - 3) // (2 + size))
        for k in range(0, len(changes), per):
            msg = SetFrame(self._drive, tuple(changes[k:k + per]))
            ack = link.expect(msg, Ack)
            applied = ack.t_us if applied is None else applied
        for i, s in changes:
            self._outputs[i] = s
        return applied / 1000.0

    # -- all off ----------------------------------------------------------------------------
    def _all_off(self) -> None:
        link = self._link
        self._current = None
        self._outputs = [self._off] * (self.profile.rows * self.profile.cols)
        if link is None:
            return
        if link.lost is not None:
            if self._lost_reported:
                return      # already said; the device's watchdog has turned everything off
            raise self._lost(link.lost)
        self._call(lambda lk: lk.expect(AllOff(), Ack))

    # -- for tools --------------------------------------------------------------------------
    def ping(self) -> float:
        """Round-trip time of one heartbeat, ms."""
        self.open()
        return self._call(lambda link: link.ping())

    def status(self) -> StatusReply:
        self.open()
        return self._call(lambda link: link.expect(Status(), StatusReply))

    def link_stats(self) -> dict[str, Any]:
        """The link's counters (:class:`~vtexp.devices.link.LinkStats`) and recoveries."""
        d = self._link.stats.as_dict() if self._link is not None else {}
        return {**d, **self.recovered}


class EmulatedDevice(SerialDevice):
    """``emulator``: a :class:`SerialDevice` talking to an emulated device it starts: on a
    pty (:class:`~vtexp.devices.emulator.PtyEmulator`) on the real clock, in-process
    (:class:`~vtexp.devices.emulator.LoopbackEmulator`) on a virtual one."""

    backend = "emulator"

    def __init__(self, profile: DeviceProfile, *, faults: Any = None, emulator_options:
                 dict | None = None, **options: Any):
        super().__init__(profile, "", **options)
        self.emulator = None
        self._faults = faults
        self._emulator_options = emulator_options or {}

    def _spec_with_watchdog(self, watchdog_ms: int) -> str:
        """``emulator`` (``emulator:virtual``) with the link settings the serial device's
        spec would carry: the pty it serves is gone when the program ends."""
        settings = super()._spec_with_watchdog(watchdog_ms).split(",")[1:]
        return "emulator:" + ",".join((["virtual"] if self.clock.virtual else []) + settings)

    def _open(self) -> DeviceInfo:
        from .emulator import LoopbackEmulator, PtyEmulator

        if self.clock.virtual:
            self.emulator = LoopbackEmulator.for_profile(
                self.profile, clock=self.clock, faults=self._faults, **self._emulator_options)
        else:
            self.emulator = PtyEmulator.for_profile(self.profile, faults=self._faults,
                                                    **self._emulator_options)
        self.port = self.emulator.start()
        try:
            return super()._open()
        except BaseException:
            self.emulator.stop()
            raise

    def _close(self) -> None:
        try:
            super()._close()
        finally:
            if self.emulator is not None:
                self.emulator.stop()
