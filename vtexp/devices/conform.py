"""``vtexp device conform``: is a device's firmware wire protocol v1 as docs/protocol.md says?

Two kinds of check, one row each in the table it prints:

- **vectors**: every vector of ``protocols/wire/v1_vectors.json`` (the CRC check, the
  COBS examples, the frames, each conversation, each bad frame, the stream), byte for
  byte, through a *vector runner*: the firmware's core on a fake clock behind the line
  protocol of ``firmware/runner/`` (docs/firmware.md, "Porting the core"). The
  conversations need a clock the test controls, which a device playing in real time
  does not offer; a firmware ported to another chip builds its runner the same way;
- **rules**: the points the protocol's text decides (docs/protocol.md, "Changes in
  this edition") that can be seen on a device as flashed, in real time, over its
  serial port: each rule a short conversation in raw frames, judged on what comes back
  (never on how fast). Rules that need a fake clock (a request at exactly
  ``watchdog_ms``, late instants merged, a frame and an instant at one moment) are
  judged by their vectors; host-only rules (when a heartbeat is lost, the largest
  frame a host accepts) by vtexp's own tests.

Built-in devices bring their runner: ``emulator`` (vtexp's Python model of the
firmware), ``emulator:host`` (the C firmware built for this computer) and
``emulator:avr`` (the ATmega2560 build in simavr). For ``serial:PORT`` the runner is
given with ``--vectors`` (``serial:PORT`` of a board running the runner, or ``python``,
``host``, ``avr``); without it the vector rows say they were not run.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from typing import Any

from ..errors import DeviceError, InputError
from . import wire
from .wire import (
    Ack,
    Alarm,
    AllOff,
    Bye,
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
    Status,
    StatusReply,
    Train,
    Trigger,
    UploadBegin,
    UploadChunk,
    WirePulse,
)

R = NakReason
#: The longest HELLO_REPLY payload: 31 bytes of fields and two texts of 1 + 255 bytes.
LONGEST_HELLO_REPLY = 543


@dataclass(frozen=True)
class Row:
    """One line of the table: a vector or a rule, and how it went."""

    kind: str                # vector | rule
    name: str
    outcome: str             # pass | FAIL | not run
    detail: str = ""


class Failed(Exception):
    """A rule's check did not hold (its message says what came back)."""


# --------------------------------------------------------------------------- the client

class RawClient:
    """Frames to and from a device on a port, with no retries and no heartbeat: what a
    rule sends is exactly what goes out."""

    def __init__(self, port: Any, name: str):
        self.port = port
        self.name = name
        self.reader = wire.FrameReader()
        self.seq = 0
        self.inbox: list[tuple[int, Message] | wire.WireError] = []
        self.raw_lengths: list[tuple[str, int]] = []      # every device frame: type, raw bytes
        self.hello: HelloReply | None = None

    def next_seq(self) -> int:
        s = self.seq
        self.seq = (self.seq + 1) & 0xFF
        return s

    def send_bytes(self, data: bytes) -> None:
        self.port.write(data)

    def _pump(self, timeout_s: float) -> None:
        end = time.monotonic() + timeout_s
        while True:
            n = self.port.in_waiting
            data = self.port.read(n or 1)
            if data:
                self._take(data)
            if time.monotonic() >= end or (not data and self.inbox and timeout_s == 0):
                return

    def _take(self, data: bytes) -> None:
        # the raw length of each frame, for the rule on the largest frame
        for item in self.reader.feed(data):
            if isinstance(item, tuple):
                body = wire.frame_body(item[1], item[0])
                self.raw_lengths.append((type(item[1]).__name__, len(body)))
            self.inbox.append(item)

    def wait(self, pred: Callable[[Message], bool], timeout_s: float = 1.0
             ) -> Message | None:
        """The first frame received (or already received) for which ``pred`` holds; the
        frames before it stay in the inbox."""
        end = time.monotonic() + timeout_s
        while True:
            for k, item in enumerate(self.inbox):
                if isinstance(item, tuple) and pred(item[1]):
                    del self.inbox[k]
                    return item[1]
            left = end - time.monotonic()
            if left <= 0:
                return None
            self._pump(min(left, 0.02))

    def drain(self, settle_s: float = 0.05) -> list[Message]:
        """Everything that arrives within ``settle_s``, and what was waiting."""
        self._pump(settle_s)
        out = [x[1] for x in self.inbox if isinstance(x, tuple)]
        self.inbox.clear()
        return out

    def request(self, msg: Message | bytes, seq: int | None = None, timeout_s: float = 1.0
                ) -> Message:
        """Send ``msg`` (or a frame's bytes) and return the reply to it (a reply whose
        ack_seq is its seq; or a NAK with ack_seq 0 for an unreadable frame)."""
        if isinstance(msg, bytes):
            self.send_bytes(msg)
            want = seq
        else:
            want = self.next_seq() if seq is None else seq
            self.send_bytes(wire.encode(msg, want))
        reply = self.wait(lambda m: m.REPLY and (m.ack_seq == want or (
            isinstance(m, Nak) and m.ack_seq == 0 and m.reason in (R.BAD_FRAME,
                                                                     R.BAD_VERSION))),
                          timeout_s)
        if reply is None:
            raise Failed(f"no reply to {describe(msg)} within {timeout_s:g} s")
        return reply

    def open_session(self, heartbeat_ms: int = 1000, watchdog_ms: int = 1000) -> HelloReply:
        self.drain(0.0)
        r = self.request(Hello(1, heartbeat_ms, watchdog_ms))
        if not isinstance(r, HelloReply):
            raise Failed(f"HELLO answered {describe(r)}")
        self.hello = r
        self.drain(0.02)
        return r


def describe(m: Message | bytes | None) -> str:
    if m is None:
        return "nothing"
    if isinstance(m, bytes):
        return f"the bytes {m.hex()}"
    return wire.describe(m)


def expect_nak(got: Message, reason: int, detail: int | None = None, what: str = "") -> None:
    if not isinstance(got, Nak) or got.reason != reason or (
            detail is not None and got.detail != detail):
        want = f"NAK {R.NAMES.get(reason, reason)}" + (
            f" (detail {detail})" if detail is not None else "")
        raise Failed(f"{what}: answered {describe(got)}; expected {want}")


def expect(got: Message, cls: type, what: str) -> Any:
    if not isinstance(got, cls):
        raise Failed(f"{what}: answered {describe(got)}; expected {cls.__name__}")
    return got


def raw_frame(version: int, mtype: int, seq: int, payload: bytes = b"") -> bytes:
    body = bytes([version, mtype, seq]) + payload
    return b"\x00" + wire.cobs_encode(body + wire.CRC.pack(wire.crc32(body))) + b"\x00"


# --------------------------------------------------------------------------- the device

@dataclass
class Geometry:
    n: int
    drive: int
    other: int
    on: wire.Setting              # within the hardware, not off
    beyond: wire.Setting | None   # beyond the hardware, if the wire can say it

    @classmethod
    def of(cls, h: HelloReply) -> Geometry:
        n = h.rows * h.cols
        if h.drive == wire.DRIVE_LEVEL:
            on: wire.Setting = Level(min(1, h.max_level))
            beyond = Level(h.max_level + 1) if h.max_level < 255 else None
            return cls(n, h.drive, wire.DRIVE_TRAIN, on, beyond)
        f = min(h.max_frequency_chz, 1000) or 1
        w = max(1, min(h.max_width_us, 100_000_000 // f - 1))
        on = Train(max(1, min(h.max_amplitude_mv, 1000)), f, w)
        beyond = Train(h.max_amplitude_mv + 1, f, w) if h.max_amplitude_mv < 0xFFFF else None
        return cls(n, h.drive, wire.DRIVE_LEVEL, on, beyond)

    def other_setting(self) -> wire.Setting:
        return Train(0, 0, 0) if self.other == wire.DRIVE_TRAIN else Level(0)


def _play(c: RawClient, g: Geometry, pid: int, pulses: list[WirePulse]) -> int:
    """Upload and trigger a schedule; the start the device chose."""
    expect(c.request(UploadBegin(pid, len(pulses), g.drive)), Ack, "UPLOAD_BEGIN")
    if pulses:
        expect(c.request(UploadChunk(pid, 0, g.drive, tuple(pulses))), Ack, "UPLOAD_CHUNK")
    return expect(c.request(Trigger(pid, 0)), Ack, "TRIGGER").t_us


def _done(c: RawClient, pid: int, timeout_s: float = 2.0) -> PlayDone:
    d = c.wait(lambda m: isinstance(m, PlayDone) and m.play_id == pid, timeout_s)
    if d is None:
        raise Failed(f"no PLAY_DONE for play {pid} within {timeout_s:g} s")
    return d


# --------------------------------------------------------------------------- the rules

def rule_handshake(c: RawClient) -> str:
    h = c.open_session()
    if h.protocol != 1:
        raise Failed(f"HELLO_REPLY chose protocol {h.protocol}, not 1")
    if not 20 <= h.heartbeat_ms <= 10_000 or h.watchdog_ms == 0:
        raise Failed(f"periods in force {h.heartbeat_ms}/{h.watchdog_ms} ms")
    return f"{h.firmware!r}, {h.rows}x{h.cols}, drive {h.drive}, max_payload {h.max_payload}"


def rule_frame_checks_in_order(c: RawClient) -> str:
    c.open_session()
    v2 = bytearray(raw_frame(2, Heartbeat.TYPE, 3))
    v2[-2] ^= 0x01 if v2[-2] != 0x01 else 0x03                # a bad CRC (never a zero)
    expect_nak(c.request(bytes(v2), seq=0), R.BAD_FRAME, 0,
               "a version-2 frame with a bad CRC")
    expect_nak(c.request(raw_frame(2, 0x7E, 4), seq=0), R.BAD_VERSION, None,
               "a version-2 frame of an unknown type")
    s = c.next_seq()
    expect_nak(c.request(raw_frame(1, 0x7E, s, b"\x01"), seq=s), R.UNKNOWN_TYPE, 0x7E,
               "an unknown type with a payload")
    s = c.next_seq()
    expect_nak(c.request(raw_frame(1, SetFrame.TYPE, s, bytes([3, 1, 0, 0, 0, 1])), seq=s),
               R.BAD_PAYLOAD, 0, "SET_FRAME of drive kind 3")
    return "BAD_FRAME, BAD_VERSION, UNKNOWN_TYPE, BAD_PAYLOAD"


def rule_refused_request_cached(c: RawClient) -> str:
    h = c.open_session()
    g = Geometry.of(h)
    before = expect(c.request(Status()), StatusReply, "STATUS")
    s = c.next_seq()
    frame = wire.encode(SetFrame(g.drive, ((g.n, g.on),)), s)
    first = c.request(frame, seq=s)
    expect_nak(first, R.OUT_OF_RANGE, g.n, "SET_FRAME to an actuator beyond the array")
    c.send_bytes(b"\x00\x13\x37\xaa\x00")                      # an unreadable frame between
    if c.wait(lambda m: isinstance(m, Nak) and m.reason == R.BAD_FRAME, 1.0) is None:
        raise Failed("an unreadable frame was not answered NAK BAD_FRAME")
    again = c.request(frame, seq=s)
    if wire.encode(again, 0) != wire.encode(first, 0):
        raise Failed(f"the retry answered {describe(again)}, not the cached {describe(first)}")
    after = expect(c.request(Status()), StatusReply, "STATUS")
    if after.duplicates - before.duplicates != 1:
        raise Failed(f"duplicates went from {before.duplicates} to {after.duplicates}, not up "
                     "by one")
    return "the retry heard the cached NAK OUT_OF_RANGE"


def rule_check_order(c: RawClient) -> str:
    h = c.open_session()
    g = Geometry.of(h)
    bad_set = SetFrame(g.other, ((g.n, g.other_setting()),))
    too_many = min(0xFFFF, h.max_pulses + 1)
    _play(c, g, 1, [WirePulse(0, 0, 400_000, g.on)])
    expect_nak(c.request(bad_set), R.BUSY, 1, "SET_FRAME of the other drive during a play")
    expect_nak(c.request(UploadBegin(2, too_many, g.other)), R.BUSY, 1,
               "UPLOAD_BEGIN of the other drive, too large, during a play")
    expect(c.request(AllOff()), Ack, "ALL_OFF")
    _done(c, 1)
    expect_nak(c.request(bad_set), R.WRONG_DRIVE, g.drive,
               "SET_FRAME of the other drive to an actuator beyond the array")
    full = SetFrameFull(g.drive, tuple((g.beyond or g.on) for _ in range(g.n - 1)))
    if len(full.pack()) <= h.max_payload:
        expect_nak(c.request(full), R.BAD_PAYLOAD, g.n,
                   "SET_FRAME_FULL of one setting too few, beyond the hardware")
    if g.beyond is not None:
        expect_nak(c.request(SetFrame(g.drive, ((g.n, g.on), (0, g.beyond)))), R.OUT_OF_RANGE,
                   g.n, "SET_FRAME: the first change beyond the array, the second beyond "
                   "the hardware")
    if h.max_pulses < 0xFFFF:
        expect_nak(c.request(UploadBegin(2, too_many, g.other)), R.WRONG_DRIVE, g.drive,
                   "UPLOAD_BEGIN of the other drive, too large")
        expect_nak(c.request(UploadBegin(2, too_many, g.drive)), R.TOO_LARGE, h.max_pulses,
                   "UPLOAD_BEGIN too large")
    return "BUSY, WRONG_DRIVE, count, OUT_OF_RANGE; BUSY, WRONG_DRIVE, TOO_LARGE"


def rule_full_frame_wrong_count(c: RawClient) -> str:
    h = c.open_session()
    g = Geometry.of(h)
    before = expect(c.request(Status()), StatusReply, "STATUS")
    full = SetFrameFull(g.drive, tuple(g.on for _ in range(g.n + 1)))
    if len(full.pack()) > h.max_payload:
        full = SetFrameFull(g.drive, tuple(g.on for _ in range(g.n - 1)))
    expect_nak(c.request(full), R.BAD_PAYLOAD, g.n,
               f"SET_FRAME_FULL of {len(full.settings)} settings for {g.n} actuators")
    after = expect(c.request(Status()), StatusReply, "STATUS")
    if (after.rx_frames - before.rx_frames, after.rx_bad - before.rx_bad) != (2, 0):
        raise Failed(f"rx_frames rose by {after.rx_frames - before.rx_frames} and rx_bad by "
                     f"{after.rx_bad - before.rx_bad}; a refused valid request counts in "
                     "rx_frames (expected 2 and 0, with the STATUS)")
    return "BAD_PAYLOAD (detail = actuators), counted in rx_frames"


def rule_upload_begin_unknown_drive(c: RawClient) -> str:
    h = c.open_session()
    for kind in (3, 0):
        s = c.next_seq()
        got = c.request(raw_frame(1, UploadBegin.TYPE, s, bytes([9, 0, 1, 0, kind])), seq=s)
        expect_nak(got, R.WRONG_DRIVE, h.drive, f"UPLOAD_BEGIN of drive kind {kind}")
    return "WRONG_DRIVE for drive kinds 3 and 0"


def rule_refused_hello_changes_nothing(c: RawClient) -> str:
    h = c.open_session()
    g = Geometry.of(h)
    _play(c, g, 5, [WirePulse(0, 0, 300_000, g.on)])
    got = c.request(Hello(0, 500, 500))
    expect_nak(got, R.UNSUPPORTED_PROTOCOL, None, "HELLO for protocol 0 during a play")
    st = expect(c.request(Status()), StatusReply, "STATUS")
    if st.state not in (wire.DeviceState.PLAYING, wire.DeviceState.ARMED) or st.play_id != 5:
        raise Failed(f"after the refused HELLO the state is {st.state} (play {st.play_id}); "
                     "the play should go on")
    seen = [m for m in c.drain(0.0) if isinstance(m, PlayDone) and m.play_id == 5]
    d = seen[0] if seen else _done(c, 5)
    if d.reason != wire.DoneReason.FINISHED:
        raise Failed(f"the play ended {describe(d)}")
    expect(c.request(Bye()), Ack, "BYE")
    c.drain(0.02)
    expect_nak(c.request(Hello(0, 500, 500)), R.UNSUPPORTED_PROTOCOL, None,
               "HELLO for protocol 0 without a session")
    expect_nak(c.request(Heartbeat()), R.NO_SESSION, 0,
               "HEARTBEAT after a refused HELLO (no session may have opened)")
    return "the play went on; no session opened"


def rule_refused_upload_begin_keeps_schedule(c: RawClient) -> str:
    h = c.open_session()
    g = Geometry.of(h)
    expect(c.request(UploadBegin(7, 1, g.drive)), Ack, "UPLOAD_BEGIN")
    expect(c.request(UploadChunk(7, 0, g.drive, (WirePulse(0, 0, 20_000, g.on),))), Ack,
           "UPLOAD_CHUNK")
    if h.max_pulses < 0xFFFF:
        expect_nak(c.request(UploadBegin(8, h.max_pulses + 1, g.drive)), R.TOO_LARGE, None,
                   "UPLOAD_BEGIN too large")
    expect_nak(c.request(UploadBegin(8, 1, g.other)), R.WRONG_DRIVE, None,
               "UPLOAD_BEGIN of the other drive")
    got = c.request(Trigger(7, 0))
    expect(got, Ack, "TRIGGER of the schedule loaded before the refused UPLOAD_BEGINs")
    _done(c, 7)
    return "the loaded schedule played"


def rule_get_onsets_past_the_end(c: RawClient) -> str:
    h = c.open_session()
    g = Geometry.of(h)
    _play(c, g, 9, [WirePulse(0, 0, 10_000, g.on)])
    _done(c, 9)
    for first, count in ((1, 5), (0xFFFF, 0xFFFF), (0, 0)):
        r = expect(c.request(GetOnsets(9, first, count)), OnsetsReply,
                   f"GET_ONSETS from {first}, {count}")
        if r.times_us:
            raise Failed(f"GET_ONSETS from {first}, {count} of a 1-pulse play answered "
                         f"{len(r.times_us)} times; expected none")
    return "no times from 1, from 65535, or for count 0"


def rule_watchdog_trips(c: RawClient) -> str:
    h = c.open_session(heartbeat_ms=300, watchdog_ms=300)
    wd = h.watchdog_ms
    for _ in range(4):                     # fed well within the period: no trip
        time.sleep(wd / 6000)
        expect(c.request(Heartbeat()), Ack, "HEARTBEAT within the watchdog")
    alarm = c.wait(lambda m: isinstance(m, Alarm), 3 * wd / 1000 + 0.5)
    if alarm is None:
        raise Failed(f"no ALARM after {3 * wd} ms of silence (watchdog {wd} ms)")
    expect_nak(c.request(Heartbeat()), R.NO_SESSION, 0, "HEARTBEAT after the watchdog")
    return f"ALARM after silence; NO_SESSION after (watchdog {wd} ms)"


def rule_onsets_after_a_watchdog_trip(c: RawClient) -> str:
    h = c.open_session(heartbeat_ms=300, watchdog_ms=300)
    g = Geometry.of(h)
    _play(c, g, 11, [WirePulse(0, 0, 20_000, g.on), WirePulse(1 % g.n, 5_000_000, 10_000,
                                                                 g.on)])
    onset = c.wait(lambda m: isinstance(m, Onset) and m.play_id == 11, 1.0)
    if onset is None:
        raise Failed("no ONSET for the first pulse")
    d = _done(c, 11, 3 * h.watchdog_ms / 1000 + 0.5)       # silence: the watchdog stops it
    if d.reason != wire.DoneReason.WATCHDOG:
        raise Failed(f"the play ended {describe(d)}, not by the watchdog")
    r = c.request(GetOnsets(11, 0, 2))
    if isinstance(r, Nak):
        raise Failed(f"GET_ONSETS after the watchdog trip answered {describe(r)}: the "
                     "interrupted play's onsets cannot be recovered")
    r = expect(r, OnsetsReply, "GET_ONSETS after the watchdog trip")
    if list(r.times_us) != [onset.t_us, wire.NOT_PLAYED]:
        raise Failed(f"GET_ONSETS after the trip answered {list(r.times_us)}; expected "
                     f"[{onset.t_us}, not played]")
    c.open_session()
    expect_nak(c.request(GetOnsets(11, 0, 2)), R.NO_SCHEDULE, 11, "GET_ONSETS after HELLO")
    return "served without a session; forgotten with HELLO"


def rule_largest_frame(c: RawClient) -> str:
    h = c.hello
    if h is None:
        raise Failed("no handshake was made")
    limit = max(h.max_payload, LONGEST_HELLO_REPLY) + wire.MIN_FRAME
    worst = max(c.raw_lengths, key=lambda x: x[1], default=("", 0))
    over = [(t, n) for t, n in c.raw_lengths
            if n > (h.max_payload + wire.MIN_FRAME if t != "HelloReply" else limit)]
    if over:
        raise Failed(f"a {over[0][0]} of {over[0][1]} raw bytes; max_payload is "
                     f"{h.max_payload}")
    return f"longest frame received: {worst[0]}, {worst[1]} raw bytes"


#: (row name, check): in this order; the last one judges every frame the others received.
RULES: list[tuple[str, Callable[[RawClient], str]]] = [
    ("handshake", rule_handshake),
    ("checks_of_a_frame_in_order", rule_frame_checks_in_order),
    ("a_refused_request_is_answered_from_the_cache", rule_refused_request_cached),
    ("checks_of_set_frame_and_upload_begin_in_order", rule_check_order),
    ("a_full_frame_of_the_wrong_count_is_a_valid_request", rule_full_frame_wrong_count),
    ("upload_begin_of_an_unknown_drive_is_wrong_drive", rule_upload_begin_unknown_drive),
    ("a_refused_hello_changes_nothing", rule_refused_hello_changes_nothing),
    ("a_refused_upload_begin_keeps_the_schedule", rule_refused_upload_begin_keeps_schedule),
    ("get_onsets_from_far_past_the_end", rule_get_onsets_past_the_end),
    ("the_watchdog_trips_after_silence", rule_watchdog_trips),
    ("onsets_after_a_watchdog_trip", rule_onsets_after_a_watchdog_trip),
    ("no_frame_longer_than_max_payload", rule_largest_frame),
]


def check_rules(port: Any, name: str) -> Iterator[Row]:
    """Run every rule against the device on an open port, one row each. A device that
    answers no HELLO at all is one :class:`DeviceError`, before any row."""
    c = RawClient(port, name)
    deadline = time.monotonic() + 3.0
    try:
        while c.hello is None:
            try:
                c.open_session()
            except Failed as e:
                if time.monotonic() < deadline:
                    continue
                if not str(e).startswith("no reply"):
                    raise DeviceError(f"the device on {name} does not speak "
                                      f"{wire.PROTOCOL_NAME}: {e}") from None
                raise DeviceError(
                    f"no device answered the vtexp handshake (HELLO) on {name} within 3 s. "
                    f"Is a device with {wire.PROTOCOL_NAME} firmware on this port, at the "
                    "right baud rate (--baud)? 'vtexp device list' shows the ports.") from None
        for row_name, rule in RULES:
            c.drain(0.02)
            try:
                detail = rule(c)
                yield Row("rule", row_name, "pass", detail)
            except Failed as e:
                yield Row("rule", row_name, "FAIL", str(e))
            finally:
                try:                            # whatever happened, leave everything off
                    c.request(AllOff(), timeout_s=0.5)
                except Failed:
                    pass
    except OSError as e:                        # pyserial's SerialException: unplugged
        raise DeviceError(f"the port {name} failed during the conformance run: {e}") from None


def check_vectors(runner: Callable[[str], str]) -> Iterator[Row]:
    from .vectors import check_each
    for r in check_each(runner):
        yield Row("vector", f"{r.section}/{r.name}", "pass" if r.mismatch is None else "FAIL",
                  r.mismatch or f"{r.checks} checks")


# --------------------------------------------------------------------------- the targets

DEVICES = ("emulator", "emulator:host", "emulator:avr", "serial:PORT")
RUNNERS = ("python", "host", "avr", "serial:PORT")


@contextmanager
def vector_runner(spec: str | None, baud: int = 1_000_000) -> Iterator[Callable | None]:
    """A vector runner by name (:data:`RUNNERS`); None for none."""
    from . import cfirmware, vectors
    if spec is None:
        yield None
        return
    if spec == "python":
        yield vectors.PythonRunner()
        return
    if spec == "host":
        r = vectors.ProcessRunner(cfirmware.build("host") / "host" / "vtexp-fw-vectors")
        try:
            yield r
        finally:
            r.close()
        return
    if spec == "avr":
        built = cfirmware.build("avr-all", "sim")
        with cfirmware.AvrSimulator(None, elf=built / "avr" / "vectors"
                                    / "vtexp-fw-vectors.elf") as sim:
            r = vectors.SerialRunner(sim.port)
            try:
                yield r
            finally:
                r.close()
        return
    if spec.startswith("serial:") and spec[7:]:
        r = vectors.SerialRunner(spec[7:], baudrate=baud)
        try:
            yield r
        finally:
            r.close()
        return
    raise InputError(f"unknown vector runner {spec!r}; use one of {', '.join(RUNNERS)}",
                     key="--vectors")


@contextmanager
def device_port(spec: str, profile_name: str, baud: int = 1_000_000
                ) -> Iterator[tuple[str, str | None]]:
    """``(port, its built-in vector runner or None)`` for a device spec, serving the
    built-in devices on a pty while the block runs."""
    from ..model import DeviceProfile
    if spec.startswith("serial:"):
        port = spec[7:].split(",")[0]
        if not port:
            raise InputError("give the port after 'serial:', e.g. serial:/dev/ttyACM0",
                             key="--device")
        yield port, None
        return
    if spec not in DEVICES:
        raise InputError(f"unknown device {spec!r} for conform; use one of "
                         f"{', '.join(DEVICES)}", key="--device")
    profile = DeviceProfile.load(profile_name)
    with ExitStack() as stack:
        if spec == "emulator":
            from .emulator import PtyEmulator
            emu = stack.enter_context(PtyEmulator.for_profile(profile))
            yield emu.port, "python"
        elif spec == "emulator:host":
            from .cfirmware import HostFirmware
            fw = stack.enter_context(HostFirmware(profile))
            yield fw.port, "host"
        else:
            from .cfirmware import AvrSimulator
            sim = stack.enter_context(AvrSimulator(profile.name))
            yield sim.port, "avr"


def conform(device: str, *, profile: str = "vest_6x8", vectors: str | None = None,
            baud: int = 1_000_000) -> list[Row]:
    """Every rule against ``device`` and every vector through its runner: the rows."""
    import serial

    rows: list[Row] = []
    with device_port(device, profile, baud) as (port, builtin_runner):
        try:
            link = serial.serial_for_url(port, baudrate=baud, timeout=0.01)
        except (ValueError, OSError) as e:
            raise DeviceError(f"cannot open the serial port {port!r}: {e}. 'vtexp device "
                              "list' shows the ports found.") from None
        try:
            link.reset_input_buffer()
            rows += check_rules(link, port)
        finally:
            link.close()
    runner_spec = vectors or builtin_runner
    if runner_spec is None:
        rows.append(Row("vector", "(all)", "not run",
                        "no vector runner: give --vectors serial:PORT of the firmware's "
                        "vector runner (docs/firmware.md, \"Porting the core\")"))
        return rows
    with vector_runner(runner_spec, baud) as runner:
        rows += check_vectors(runner)
    return rows


def table(rows: list[Row]) -> str:
    """The rows as a table, and a summary line."""
    w = max(len(r.name) for r in rows)
    lines = [f"{'KIND':<6}  {'NAME':<{w}}  RESULT   DETAIL"]
    for r in rows:
        lines.append(f"{r.kind:<6}  {r.name:<{w}}  {r.outcome:<7}  {r.detail}")
    n_fail = sum(r.outcome == "FAIL" for r in rows)
    n_pass = sum(r.outcome == "pass" for r in rows)
    n_not = sum(r.outcome == "not run" for r in rows)
    by_kind = {k: (sum(r.outcome == "pass" for r in rows if r.kind == k),
                   sum(r.kind == k and r.outcome != "not run" for r in rows))
               for k in ("rule", "vector")}
    summary = (f"{n_pass} passed, {n_fail} failed" + (f", {n_not} not run" if n_not else "")
               + f" (rules {by_kind['rule'][0]}/{by_kind['rule'][1]}, vectors "
               f"{by_kind['vector'][0]}/{by_kind['vector'][1]})")
    if n_fail:
        summary += ": FAILED " + ", ".join(r.name for r in rows if r.outcome == "FAIL")
    else:
        summary += ": conforms" if not n_not else ": no failure in what was run"
    return "\n".join([*lines, "", summary])


__all__ = ["RULES", "Row", "check_rules", "check_vectors", "conform", "table"]
