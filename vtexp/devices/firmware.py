"""The device side of wire protocol v1, as a state machine with an injected clock.

This is what the firmware of a vtexp array does, written in Python so that
the emulator (:mod:`vtexp.devices.emulator`) can run it behind a real
pseudo-terminal and tests can run it against a fake clock, byte for byte.
It does no I/O: :meth:`Firmware.receive` takes the bytes that arrived and
returns the frames to send; :meth:`Firmware.tick` applies whatever is due
(schedule events, the watchdog) and returns the frames that produced;
:meth:`Firmware.next_deadline_us` says when ``tick`` must run next.

Behaviour that the host relies on (``docs/protocol.md``):

- every request is answered by exactly one reply frame; a repeated request
  (same sequence number and bytes) is not executed again, its cached reply is
  re-sent, so a retry never actuates twice;
- a frame that fails COBS, CRC or parsing changes nothing and is answered
  with ``NAK BAD_FRAME``; a request is validated completely before any output
  changes (a refused frame changes nothing);
- schedules play from the device's own clock; each onset is stamped with the
  clock read after the outputs changed and reported in an ``ONSET`` event;
- ``ALL_OFF`` works at any time, with or without a session; ``BYE`` turns
  everything off and ends the session without an alarm;
- the watchdog: when no valid frame has arrived for ``watchdog_ms`` during a
  session, every output goes off, any play stops, the session ends (the host
  must say ``HELLO`` again) and an ``ALARM`` is sent.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from .. import __version__
from ..model import DeviceProfile, LevelDrive
from . import wire
from .wire import (
    Ack,
    Alarm,
    AlarmCode,
    AllOff,
    Bye,
    DeviceState,
    DoneReason,
    GetOnsets,
    Heartbeat,
    Hello,
    HelloReply,
    Level,
    Message,
    Nak,
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


@dataclass(frozen=True)
class FirmwareConfig:
    """What a device is and can hold; reported in ``HELLO_REPLY``."""

    rows: int
    cols: int
    actuator: int
    drive: int
    max_level: int = 0
    max_amplitude_mv: int = 0
    max_frequency_chz: int = 0
    max_width_us: int = 0
    max_pulses: int = 4096
    max_payload: int = 1024
    firmware: str = f"vtexp-emulator {__version__}"
    device_id: str = "emulator"
    min_watchdog_ms: int = 20
    max_watchdog_ms: int = 10_000

    @classmethod
    def for_profile(cls, profile: DeviceProfile, **overrides) -> FirmwareConfig:
        """A device built to ``profile``: its geometry, drive and hardware ceilings.

        The hardware ceilings are the profile's drive (every declared level;
        the highest amplitude, frequency and pulse width); the profile's safety
        limits are the host's business (``vtexp.safety``).
        """
        kw: dict = {"rows": profile.rows, "cols": profile.cols,
                    "actuator": wire.ACTUATOR_KINDS[profile.actuator],
                    "drive": wire.DRIVE_KINDS[profile.drive.kind],
                    "device_id": f"emulated {profile.name}"}
        d = profile.drive
        if isinstance(d, LevelDrive):
            kw["max_level"] = len(d.levels) - 1
        else:
            lim = profile.limits
            kw["max_amplitude_mv"] = round(1000 * max(d.amplitude_v, lim.max_amplitude_v or 0))
            kw["max_frequency_chz"] = round(100 * max([*d.frequencies_hz,
                                                        lim.max_frequency_hz or 0]))
            kw["max_width_us"] = round(1000 * max([*d.pulse_width_ms,
                                                    lim.max_pulse_width_ms or 0]))
        kw.update(overrides)
        return cls(**kw)


@dataclass(frozen=True)
class Actuation:
    """One output change, as the device made it (what the emulator 'drove')."""

    t_us: int
    index: int
    setting: Setting
    cause: str                   # frame | play | all_off | watchdog | hello
    play_id: int | None = None


@dataclass
class Playback:
    play_id: int
    pulses: list[WirePulse]
    start_us: int
    # (time from start, 0 = off / 1 = on, pulse number): offsets sort before onsets
    events: list[tuple[int, int, int]]
    pos: int = 0
    onsets: list[int] = field(default_factory=list)
    active: dict[int, list[int]] = field(default_factory=dict)   # actuator -> pulses on it
    started: bool = False

    @classmethod
    def of(cls, play_id: int, pulses: list[WirePulse], start_us: int) -> Playback:
        ev = [(p.onset_us, 1, i) for i, p in enumerate(pulses)]
        ev += [(p.onset_us + p.duration_us, 0, i) for i, p in enumerate(pulses)]
        ev.sort()
        return cls(play_id, pulses, start_us, ev, onsets=[wire.NOT_PLAYED] * len(pulses))

    @property
    def n_onsets(self) -> int:
        return sum(1 for t in self.onsets if t != wire.NOT_PLAYED)

    def next_due_us(self) -> int | None:
        if self.pos < len(self.events):
            return self.start_us + self.events[self.pos][0]
        # A schedule of no pulses is due once, at its start, to finish.
        return self.start_us if not self.events else None


@dataclass
class Counters:
    rx_frames: int = 0
    rx_bad: int = 0
    duplicates: int = 0
    naks: int = 0
    watchdog_trips: int = 0


class Firmware:
    """Wire protocol v1, device side. Not thread-safe: the emulator holds a lock."""

    def __init__(self, config: FirmwareConfig, clock_us: Callable[[], int]):
        self.cfg = config
        self.clock_us = clock_us
        self.n = config.rows * config.cols
        self.off: Setting = wire.OFF[config.drive]
        self.outputs: list[Setting] = [self.off] * self.n
        self.history: list[Actuation] = []
        self.alarms: list[Alarm] = []
        self.counters = Counters()
        self.session = False
        self.heartbeat_ms = 0
        self.watchdog_ms = 0
        self.last_rx_us = 0
        self._tx_seq = 0
        self._last_request: bytes | None = None     # decoded frame of the last executed request
        self._last_reply: bytes = b""
        self._reader = wire.FrameReader(max_frame=config.max_payload + wire.MIN_FRAME)
        self._upload: list[WirePulse] | None = None
        self._upload_id = 0
        self._upload_n = 0
        self._upload_drive = config.drive
        self._uploaded: tuple[int, list[WirePulse]] | None = None   # complete, ready to trigger
        self.play: Playback | None = None
        self.last_play: Playback | None = None

    # -- I/O boundary -----------------------------------------------------------------------
    def receive(self, data: bytes) -> list[bytes]:
        """Bytes from the host in; frames to send out (replies, then any events)."""
        # The watchdog first: a frame that arrives after the deadline is too late to
        # save the session (on a microcontroller the timer interrupt would have fired).
        out: list[bytes] = self._watchdog()
        for item in self._reader.feed(data):
            if isinstance(item, wire.WireError):
                self.counters.rx_bad += 1
                out.append(self._nak_for(item))
                continue
            seq, msg = item
            if not msg.REQUEST:            # a reply or an event sent to the device
                self.counters.rx_bad += 1
                out.append(self._send(self._nak(seq, NakReason.UNKNOWN_TYPE, msg.TYPE)))
                continue
            self.counters.rx_frames += 1
            if self.session:
                self.last_rx_us = self.clock_us()      # any valid request feeds the watchdog
            out.extend(self._request(seq, msg))
        out.extend(self.tick())
        return out

    def tick(self) -> list[bytes]:
        """Apply what is due now: schedule events, then the watchdog."""
        out = self._watchdog()
        if out:
            return out
        now = self.clock_us()
        pb = self.play
        if pb is not None and (due := pb.next_due_us()) is not None and due <= now:
            out.extend(self._advance(pb, now))
        return out

    def _watchdog(self) -> list[bytes]:
        if self.session and self.clock_us() - self.last_rx_us > self.watchdog_ms * 1000:
            return self._trip_watchdog()
        return []

    def next_deadline_us(self) -> int | None:
        cands = []
        if self.play is not None and (due := self.play.next_due_us()) is not None:
            cands.append(due)
        if self.session:
            cands.append(self.last_rx_us + self.watchdog_ms * 1000 + 1)
        return min(cands) if cands else None

    @property
    def state(self) -> int:
        if not self.session:
            return DeviceState.NO_SESSION
        if self.play is not None:
            return DeviceState.PLAYING if self.play.started else DeviceState.ARMED
        if self._upload is not None:
            return DeviceState.UPLOADING
        return DeviceState.IDLE

    # -- frames out -------------------------------------------------------------------------
    def _send(self, msg: Message) -> bytes:
        b = wire.encode(msg, self._tx_seq)
        self._tx_seq = (self._tx_seq + 1) & 0xFF
        return b

    def _nak(self, seq: int, reason: int, detail: int = 0) -> Nak:
        self.counters.naks += 1
        return Nak(seq, reason, detail & 0xFFFF)

    def _nak_for(self, err: wire.WireError) -> bytes:
        seq = getattr(err, "seq", 0)
        if isinstance(err, wire.VersionError):
            return self._send(self._nak(0, NakReason.BAD_VERSION, wire.PROTOCOL_VERSION))
        if isinstance(err, wire.UnknownTypeError):
            return self._send(self._nak(seq, NakReason.UNKNOWN_TYPE, getattr(err, "mtype", 0)))
        if isinstance(err, wire.PayloadError):
            return self._send(self._nak(seq, NakReason.BAD_PAYLOAD))
        return self._send(self._nak(0, NakReason.BAD_FRAME))

    # -- requests ---------------------------------------------------------------------------
    def _request(self, seq: int, msg: Message) -> list[bytes]:
        key = wire.frame_body(msg, seq)
        if key == self._last_request and not isinstance(msg, Hello):
            # A retry of what was already done: answer again, do not act again.
            self.counters.duplicates += 1
            return [self._last_reply]
        events: list[Message] = []
        reply = self._execute(seq, msg, events)
        frame = self._send(reply)
        self._last_request, self._last_reply = key, frame
        return [frame] + [self._send(e) for e in events]

    def _execute(self, seq: int, msg: Message, events: list[Message]) -> Message:
        now = self.clock_us()
        if isinstance(msg, Hello):
            return self._hello(seq, msg, events)
        if isinstance(msg, AllOff):                    # always allowed: abort means off
            t = self._all_off("all_off", DoneReason.ALL_OFF, events)
            return Ack(seq, t)
        if isinstance(msg, Bye):                       # a clean goodbye: off, session over
            t = self._all_off("bye", DoneReason.ALL_OFF, events)
            self.session = False
            return Ack(seq, t)
        if isinstance(msg, Status):
            pb = self.play or self.last_play
            c = self.counters
            return StatusReply(seq, self.state, pb.play_id if pb else 0,
                               pb.n_onsets if pb else 0, now, c.rx_frames, c.rx_bad,
                               c.duplicates, c.watchdog_trips)
        if isinstance(msg, GetOnsets):
            # Read-only, so served without a session too: after a watchdog trip the host
            # recovers the interrupted play's onsets before its HELLO forgets them.
            return self._get_onsets(seq, msg)
        if not self.session:
            return self._nak(seq, NakReason.NO_SESSION)
        if isinstance(msg, Heartbeat):
            return Ack(seq, now)
        if isinstance(msg, (SetFrame, SetFrameFull)):
            return self._set_frame(seq, msg)
        if isinstance(msg, UploadBegin):
            return self._upload_begin(seq, msg)
        if isinstance(msg, UploadChunk):
            return self._upload_chunk(seq, msg)
        if isinstance(msg, Trigger):
            return self._trigger(seq, msg)
        return self._nak(seq, NakReason.UNKNOWN_TYPE, msg.TYPE)   # pragma: no cover

    def _hello(self, seq: int, msg: Hello, events: list[Message]) -> Message:
        if msg.protocol < 1:
            return self._nak(seq, NakReason.UNSUPPORTED_PROTOCOL, wire.PROTOCOL_VERSION)
        self._all_off("hello", DoneReason.ALL_OFF, events)
        clamp = lambda v: max(self.cfg.min_watchdog_ms, min(self.cfg.max_watchdog_ms, v))
        self.heartbeat_ms = clamp(msg.heartbeat_ms)
        self.watchdog_ms = clamp(msg.watchdog_ms)
        self.session = True
        self.last_rx_us = self.clock_us()
        self._upload = self._uploaded = None
        self.last_play = None                  # its onsets are forgotten with the session
        c = self.cfg
        return HelloReply(seq, min(msg.protocol, wire.PROTOCOL_VERSION), self.heartbeat_ms,
                          self.watchdog_ms, c.rows, c.cols, c.actuator, c.drive, c.max_level,
                          c.max_amplitude_mv, c.max_frequency_chz, c.max_width_us, c.max_pulses,
                          c.max_payload, self.clock_us(), c.firmware, c.device_id)

    def _check_setting(self, s: Setting) -> bool:
        """Within what the hardware can do (not the profile's limits: that is the host's)."""
        c = self.cfg
        if isinstance(s, Level):
            return s.level <= c.max_level
        if isinstance(s, Train):
            if s.is_off:
                return True
            return (s.amplitude_mv <= c.max_amplitude_mv and 0 < s.frequency_chz
                    <= c.max_frequency_chz and 0 < s.width_us <= c.max_width_us
                    # a pulse as long as the period would hold the pin on
                    and s.width_us * s.frequency_chz < 100_000_000)
        return False

    def _set_frame(self, seq: int, msg: SetFrame | SetFrameFull) -> Message:
        if self.play is not None:
            return self._nak(seq, NakReason.BUSY, self.play.play_id)
        if msg.drive != self.cfg.drive:
            return self._nak(seq, NakReason.WRONG_DRIVE, self.cfg.drive)
        if isinstance(msg, SetFrameFull):
            if len(msg.settings) != self.n:
                return self._nak(seq, NakReason.BAD_PAYLOAD, self.n)
            changes = list(enumerate(msg.settings))
        else:
            changes = list(msg.changes)
        for index, s in changes:           # validate everything before touching an output
            if index >= self.n or not self._check_setting(s):
                return self._nak(seq, NakReason.OUT_OF_RANGE, index)
        for index, s in changes:
            self._set(index, s, "frame")
        return Ack(seq, self.clock_us())

    def _upload_begin(self, seq: int, msg: UploadBegin) -> Message:
        if self.play is not None:
            return self._nak(seq, NakReason.BUSY, self.play.play_id)
        if msg.drive != self.cfg.drive:
            return self._nak(seq, NakReason.WRONG_DRIVE, self.cfg.drive)
        if msg.n_pulses > self.cfg.max_pulses:
            return self._nak(seq, NakReason.TOO_LARGE, self.cfg.max_pulses)
        self._upload, self._upload_id, self._upload_n = [], msg.play_id, msg.n_pulses
        self._uploaded = None
        if msg.n_pulses == 0:
            self._uploaded, self._upload = (msg.play_id, []), None
        return Ack(seq, self.clock_us())

    def _upload_chunk(self, seq: int, msg: UploadChunk) -> Message:
        up = self._upload
        if up is None or msg.play_id != self._upload_id:
            return self._nak(seq, NakReason.NO_SCHEDULE, msg.play_id)
        if msg.drive != self.cfg.drive:
            return self._nak(seq, NakReason.WRONG_DRIVE, self.cfg.drive)
        if msg.first != len(up):
            return self._nak(seq, NakReason.OUT_OF_ORDER, len(up))
        if len(up) + len(msg.pulses) > self._upload_n:
            return self._nak(seq, NakReason.TOO_LARGE, self._upload_n)
        prev = up[-1].onset_us if up else 0
        for k, p in enumerate(msg.pulses):
            if (p.index >= self.n or not self._check_setting(p.setting) or p.duration_us == 0
                    or p.onset_us + p.duration_us > 0xFFFF_FFFF):
                return self._nak(seq, NakReason.OUT_OF_RANGE, p.index)
            if p.onset_us < prev:
                return self._nak(seq, NakReason.OUT_OF_ORDER, msg.first + k)
            prev = p.onset_us
        up.extend(msg.pulses)
        if len(up) == self._upload_n:
            self._uploaded, self._upload = (self._upload_id, up), None
        return Ack(seq, self.clock_us())

    def _trigger(self, seq: int, msg: Trigger) -> Message:
        if self.play is not None:
            return self._nak(seq, NakReason.BUSY, self.play.play_id)
        if self._uploaded is None or self._uploaded[0] != msg.play_id:
            return self._nak(seq, NakReason.NO_SCHEDULE, msg.play_id)
        # The schedule stays loaded: triggering the same play_id again replays it.
        pb = Playback.of(msg.play_id, self._uploaded[1], 0)
        # The clock is read after the playback is prepared, so that preparing it does
        # not make the first onset late.
        now = self.clock_us()
        pb.start_us = max(now, msg.at_us) if msg.at_us else now
        self.play, self.last_play = pb, None    # one play's onsets are kept: this one's
        return Ack(seq, pb.start_us)

    def _get_onsets(self, seq: int, msg: GetOnsets) -> Message:
        pb = next((p for p in (self.play, self.last_play)
                   if p is not None and p.play_id == msg.play_id), None)
        if pb is None:
            return self._nak(seq, NakReason.NO_SCHEDULE, msg.play_id)
        fit = (self.cfg.max_payload - 5) // 8
        times = pb.onsets[msg.first:msg.first + min(msg.count, fit)]
        return OnsetsReply(seq, msg.play_id, msg.first, tuple(times))

    # -- outputs ----------------------------------------------------------------------------
    def _set(self, index: int, s: Setting, cause: str, play_id: int | None = None) -> None:
        if self.outputs[index] != s:
            self.outputs[index] = s
            self.history.append(Actuation(self.clock_us(), index, s, cause, play_id))

    def _all_off(self, cause: str, reason: int, events: list[Message]) -> int:
        for i, s in enumerate(self.outputs):
            if s != self.off:
                self._set(i, self.off, cause)
        t = self.clock_us()
        pb = self.play
        if pb is not None:
            self.play, self.last_play = None, pb
            events.append(PlayDone(pb.play_id, reason, pb.n_onsets, t))
        return t

    def _advance(self, pb: Playback, now: int) -> list[bytes]:
        pb.started = True
        first_on, n_on = None, 0
        while pb.pos < len(pb.events) and pb.start_us + pb.events[pb.pos][0] <= now:
            _, on, i = pb.events[pb.pos]
            pb.pos += 1
            p = pb.pulses[i]
            stack = pb.active.setdefault(p.index, [])
            if on:
                stack.append(i)
                first_on = i if first_on is None else first_on
                n_on += 1
            else:
                stack.remove(i)
            # Overlapping pulses on one actuator: the latest started one drives it.
            self._set(p.index, pb.pulses[stack[-1]].setting if stack else self.off, "play",
                      pb.play_id)
        t = self.clock_us()                   # stamped after the outputs changed
        out: list[bytes] = []
        if n_on:
            for i in range(first_on, first_on + n_on):
                pb.onsets[i] = t
            out.append(self._send(Onset(pb.play_id, first_on, n_on, t)))
        if pb.pos == len(pb.events):
            self.play, self.last_play = None, pb
            out.append(self._send(PlayDone(pb.play_id, DoneReason.FINISHED, pb.n_onsets, t)))
        return out

    def _trip_watchdog(self) -> list[bytes]:
        events: list[Message] = []
        t = self._all_off("watchdog", DoneReason.WATCHDOG, events)
        self.session = False
        self._last_request = None          # a late retry must hear NO_SESSION, not an old ACK
        self.counters.watchdog_trips += 1
        alarm = Alarm(AlarmCode.WATCHDOG, t)
        self.alarms.append(alarm)
        events.append(alarm)
        return [self._send(e) for e in events]
