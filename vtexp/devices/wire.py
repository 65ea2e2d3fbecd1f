"""Wire protocol v1: pure functions between bytes and messages.

The specification is ``docs/protocol.md``; this module is its executable form
and ``protocols/wire/v1_vectors.json`` pins it byte for byte. Nothing here
does I/O: :func:`encode` turns a message into the bytes of one frame,
:func:`decode_frame` turns the bytes between two delimiters back into a
message, and :class:`FrameReader` splits a byte stream into frames,
resynchronising on the next delimiter after any garbage.

Frame on the wire::

    00 | COBS( version:u8 | type:u8 | seq:u8 | payload | crc32:u32le ) | 00

COBS (Cheshire & Baker 1999) removes every zero byte from the frame, so a
zero always means "frame boundary" and a receiver that lost or gained bytes
finds the next frame at the next zero. CRC-32 is the IEEE 802.3 polynomial
(``zlib.crc32``; check value of ``b"123456789"`` is ``0xCBF43926``) over the
header and payload. All integers are little-endian.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterable
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar

PROTOCOL_VERSION = 1
PROTOCOL_NAME = f"vtexp-wire/{PROTOCOL_VERSION}"
DELIMITER = b"\x00"
HEADER = struct.Struct("<BBB")          # version, type, seq
CRC = struct.Struct("<I")
MIN_FRAME = HEADER.size + CRC.size       # decoded bytes of a frame with an empty payload
MAX_FRAME = 4096          # decoded bytes; a longer run without a delimiter is garbage
NOT_PLAYED = 0xFFFF_FFFF_FFFF_FFFF        # onset time of a pulse that has not been played

# Actuator kinds and drive kinds as numbered on the wire (HelloReply).
ACTUATOR_KINDS = {"erm_motor": 1, "coin_tactor": 2, "sma_pin": 3}
DRIVE_LEVEL = 1
DRIVE_TRAIN = 2
DRIVE_KINDS = {"levels": DRIVE_LEVEL, "pulse_train": DRIVE_TRAIN}


class WireError(ValueError):
    """Bytes that are not a valid v1 frame (the receiver drops and counts them)."""

    kind = "bad_frame"


class CobsError(WireError):
    kind = "bad_cobs"


class CrcError(WireError):
    kind = "bad_crc"


class TooLongError(WireError):
    kind = "too_long"


class VersionError(WireError):
    kind = "bad_version"


class UnknownTypeError(WireError):
    kind = "unknown_type"


class PayloadError(WireError):
    kind = "bad_payload"


# --------------------------------------------------------------------------- COBS and CRC

def crc32(data: bytes) -> int:
    """CRC-32/ISO-HDLC (IEEE 802.3), as zlib and most MCU CRC units compute it."""
    return zlib.crc32(data) & 0xFFFF_FFFF


def cobs_encode(data: bytes) -> bytes:
    """Consistent Overhead Byte Stuffing: the result holds no zero byte.

    Overhead is one byte per started block of 254 non-zero bytes
    (Cheshire & Baker, IEEE/ACM Trans. Networking 7(2), 1999).
    """
    out = bytearray()
    block = bytearray()
    full = False            # the last block written was a full one (code 0xFF)
    for b in data:
        full = False
        if b == 0:
            out.append(len(block) + 1)
            out += block
            block.clear()
        else:
            block.append(b)
            if len(block) == 254:
                out.append(255)
                out += block
                block.clear()
                full = True
    if not full:            # a full block at the very end needs no closing code
        out.append(len(block) + 1)
        out += block
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    """Inverse of :func:`cobs_encode`; raises :class:`CobsError` on malformed input."""
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        code = data[i]
        if code == 0:
            raise CobsError("zero byte inside a COBS block")
        end = i + code
        if end > n:
            raise CobsError(f"COBS block at byte {i} runs past the end of the frame")
        block = data[i + 1:end]
        if 0 in block:
            raise CobsError("zero byte inside a COBS block")
        out += block
        i = end
        if code != 255 and i < n:
            out.append(0)
    return bytes(out)


# --------------------------------------------------------------------------- settings

@dataclass(frozen=True)
class Level:
    """A vibration motor at an intensity level (0 = off); seed 000 Table 1, seed 001 §3.3."""

    level: int

    KIND: ClassVar[int] = DRIVE_LEVEL
    SIZE: ClassVar[int] = 1

    @property
    def is_off(self) -> bool:
        return self.level == 0

    def pack(self) -> bytes:
        return _pack("B", self.level, "level")

    @classmethod
    def unpack(cls, b: bytes) -> Level:
        return cls(b[0])


@dataclass(frozen=True)
class Train:
    """An SMA pin driven by a pulse train (seed 002 §3.3): 0 mV = off.

    Units are integers so that both ends agree bit for bit: millivolts,
    centi-hertz (0.01 Hz) and microseconds.
    """

    amplitude_mv: int
    frequency_chz: int
    width_us: int

    KIND: ClassVar[int] = DRIVE_TRAIN
    SIZE: ClassVar[int] = 6

    @property
    def is_off(self) -> bool:
        return self.amplitude_mv == 0

    def pack(self) -> bytes:
        return (_pack("<H", self.amplitude_mv, "amplitude_mv")
                + _pack("<H", self.frequency_chz, "frequency_chz")
                + _pack("<H", self.width_us, "width_us"))

    @classmethod
    def unpack(cls, b: bytes) -> Train:
        return cls(*struct.unpack("<HHH", b))


Setting = Level | Train
SETTINGS: dict[int, type[Level | Train]] = {DRIVE_LEVEL: Level, DRIVE_TRAIN: Train}
OFF: dict[int, Setting] = {DRIVE_LEVEL: Level(0), DRIVE_TRAIN: Train(0, 0, 0)}


def _pack(fmt: str, value: int, name: str) -> bytes:
    try:
        return struct.pack(fmt, value)
    except struct.error:
        raise PayloadError(f"{name}={value!r} does not fit the wire field {fmt!r}") from None


def _setting_kind(settings: Iterable[Setting], kind: int) -> None:
    cls = SETTINGS.get(kind)
    if cls is None:
        raise PayloadError(f"unknown drive kind {kind}")
    for s in settings:
        if not isinstance(s, cls):
            raise PayloadError(f"a {type(s).__name__} setting in a message of drive kind {kind}")


# --------------------------------------------------------------------------- messages

class _Reader:
    """Cursor over a payload that raises PayloadError instead of IndexError."""

    def __init__(self, data: bytes, name: str):
        self.data, self.i, self.name = data, 0, name

    def take(self, fmt: str) -> Any:
        s = struct.calcsize(fmt)
        if self.i + s > len(self.data):
            raise PayloadError(f"{self.name}: payload too short ({len(self.data)} bytes)")
        v = struct.unpack_from(fmt, self.data, self.i)
        self.i += s
        return v[0] if len(v) == 1 else v

    def raw(self, n: int) -> bytes:
        if self.i + n > len(self.data):
            raise PayloadError(f"{self.name}: payload too short ({len(self.data)} bytes)")
        b = self.data[self.i:self.i + n]
        self.i += n
        return b

    def text(self) -> str:
        n = self.take("<B")
        try:
            return self.raw(n).decode("utf-8")
        except UnicodeDecodeError:
            raise PayloadError(f"{self.name}: text is not UTF-8") from None

    def rest(self) -> int:
        return len(self.data) - self.i

    def end(self) -> None:
        if self.i != len(self.data):
            raise PayloadError(f"{self.name}: {len(self.data) - self.i} unexpected trailing bytes")


def _text(s: str) -> bytes:
    b = s.encode("utf-8")
    if len(b) > 255:
        raise PayloadError(f"text of {len(b)} bytes; at most 255 fit")
    return bytes([len(b)]) + b


class Message:
    """Base of all v1 messages: ``TYPE`` on the wire, ``pack``/``unpack`` of the payload."""

    TYPE: ClassVar[int]
    REQUEST: ClassVar[bool] = False     # host -> device, answered by exactly one reply
    REPLY: ClassVar[bool] = False       # device -> host, carries ack_seq

    def pack(self) -> bytes:
        raise NotImplementedError

    @classmethod
    def unpack(cls, payload: bytes) -> Message:
        raise NotImplementedError

    def to_dict(self) -> dict:
        d: dict[str, Any] = {"type": type(self).__name__}
        for f in fields(self):  # type: ignore[arg-type]
            d[f.name] = _jsonable(getattr(self, f.name))
        return d


def _jsonable(v: Any) -> Any:
    if isinstance(v, (Level, Train, WirePulse)):
        return {"kind": type(v).__name__,
                **{f.name: _jsonable(getattr(v, f.name)) for f in fields(v)}}
    if isinstance(v, tuple):
        return [_jsonable(x) for x in v]
    return v


def _from_jsonable(v: Any) -> Any:
    if isinstance(v, dict) and v.get("kind") in _PLAIN:
        cls = _PLAIN[v["kind"]]
        return cls(**{k: _from_jsonable(x) for k, x in v.items() if k != "kind"})
    if isinstance(v, list):
        return tuple(_from_jsonable(x) for x in v)
    return v


def message_from_dict(d: dict) -> Message:
    """Inverse of :meth:`Message.to_dict` (test vectors are stored this way)."""
    cls = MESSAGES_BY_NAME[d["type"]]
    return cls(**{k: _from_jsonable(v) for k, v in d.items() if k != "type"})


# -- host -> device ------------------------------------------------------------------------

@dataclass(frozen=True)
class Hello(Message):
    """Open a session: the highest protocol the host speaks and the link timing it wants."""

    TYPE = 0x01
    REQUEST = True
    protocol: int = PROTOCOL_VERSION
    heartbeat_ms: int = 200
    watchdog_ms: int = 200

    def pack(self) -> bytes:
        return struct.pack("<BHH", self.protocol, self.heartbeat_ms, self.watchdog_ms)

    @classmethod
    def unpack(cls, payload: bytes) -> Hello:
        r = _Reader(payload, "HELLO")
        m = cls(*r.take("<BHH"))
        r.end()
        return m


class _NoPayload(Message):
    """A message that is its type alone (an empty payload, checked to be empty)."""

    LABEL: ClassVar[str]

    def pack(self) -> bytes:
        return b""

    @classmethod
    def unpack(cls, payload: bytes) -> _NoPayload:
        _Reader(payload, cls.LABEL).end()
        return cls()


@dataclass(frozen=True)
class Heartbeat(_NoPayload):
    """Keep the device's watchdog fed; the ACK's time also measures round trips."""

    TYPE = 0x02
    REQUEST = True
    LABEL = "HEARTBEAT"


@dataclass(frozen=True)
class AllOff(_NoPayload):
    """Every actuator off at once; any play in progress is abandoned."""

    TYPE = 0x03
    REQUEST = True
    LABEL = "ALL_OFF"


@dataclass(frozen=True)
class SetFrame(Message):
    """Sparse update: only the listed actuators change, all in the same instant."""

    TYPE = 0x04
    REQUEST = True
    drive: int
    changes: tuple[tuple[int, Setting], ...]

    def pack(self) -> bytes:
        _setting_kind((s for _, s in self.changes), self.drive)
        out = bytearray(struct.pack("<BH", self.drive, len(self.changes)))
        for index, s in self.changes:
            out += _pack("<H", index, "actuator index") + s.pack()
        return bytes(out)

    @classmethod
    def unpack(cls, payload: bytes) -> SetFrame:
        r = _Reader(payload, "SET_FRAME")
        drive, n = r.take("<BH")
        scls = SETTINGS.get(drive)
        if scls is None:
            raise PayloadError(f"SET_FRAME: unknown drive kind {drive}")
        changes = tuple((r.take("<H"), scls.unpack(r.raw(scls.SIZE))) for _ in range(n))
        r.end()
        return cls(drive, changes)


@dataclass(frozen=True)
class SetFrameFull(Message):
    """Dense update: a setting for every actuator, row-major (index = row * cols + col)."""

    TYPE = 0x05
    REQUEST = True
    drive: int
    settings: tuple[Setting, ...]

    def pack(self) -> bytes:
        _setting_kind(self.settings, self.drive)
        return bytes([self.drive]) + b"".join(s.pack() for s in self.settings)

    @classmethod
    def unpack(cls, payload: bytes) -> SetFrameFull:
        r = _Reader(payload, "SET_FRAME_FULL")
        drive = r.take("<B")
        scls = SETTINGS.get(drive)
        if scls is None:
            raise PayloadError(f"SET_FRAME_FULL: unknown drive kind {drive}")
        if r.rest() % scls.SIZE:
            raise PayloadError("SET_FRAME_FULL: payload is not a whole number of settings")
        n = r.rest() // scls.SIZE
        return cls(drive, tuple(scls.unpack(r.raw(scls.SIZE)) for _ in range(n)))


@dataclass(frozen=True)
class WirePulse:
    """One pulse of an uploaded schedule, in device units (µs from the trigger)."""

    index: int
    onset_us: int
    duration_us: int
    setting: Setting


@dataclass(frozen=True)
class UploadBegin(Message):
    """Announce a schedule of ``n_pulses`` pulses (sorted by onset) under ``play_id``."""

    TYPE = 0x06
    REQUEST = True
    play_id: int
    n_pulses: int
    drive: int

    def pack(self) -> bytes:
        return (_pack("<H", self.play_id, "play_id") + _pack("<H", self.n_pulses, "n_pulses")
                + _pack("<B", self.drive, "drive"))

    @classmethod
    def unpack(cls, payload: bytes) -> UploadBegin:
        r = _Reader(payload, "UPLOAD_BEGIN")
        m = cls(*r.take("<HHB"))
        r.end()
        return m


@dataclass(frozen=True)
class UploadChunk(Message):
    """Pulses ``first .. first + len(pulses) - 1`` of the schedule being uploaded."""

    TYPE = 0x07
    REQUEST = True
    play_id: int
    first: int
    drive: int
    pulses: tuple[WirePulse, ...]

    def pack(self) -> bytes:
        _setting_kind((p.setting for p in self.pulses), self.drive)
        out = bytearray(struct.pack("<HHB", self.play_id, self.first, self.drive))
        for p in self.pulses:
            out += (_pack("<H", p.index, "actuator index") + _pack("<I", p.onset_us, "onset_us")
                    + _pack("<I", p.duration_us, "duration_us") + p.setting.pack())
        return bytes(out)

    @classmethod
    def unpack(cls, payload: bytes) -> UploadChunk:
        r = _Reader(payload, "UPLOAD_CHUNK")
        play_id, first, drive = r.take("<HHB")
        scls = SETTINGS.get(drive)
        if scls is None:
            raise PayloadError(f"UPLOAD_CHUNK: unknown drive kind {drive}")
        size = 10 + scls.SIZE
        if r.rest() % size:
            raise PayloadError("UPLOAD_CHUNK: payload is not a whole number of pulses")
        pulses = []
        for _ in range(r.rest() // size):
            index, onset, dur = r.take("<HII")
            pulses.append(WirePulse(index, onset, dur, scls.unpack(r.raw(scls.SIZE))))
        return cls(play_id, first, drive, tuple(pulses))

    @staticmethod
    def pulse_size(drive: int) -> int:
        return 10 + SETTINGS[drive].SIZE


@dataclass(frozen=True)
class Trigger(Message):
    """Start the uploaded schedule at device time ``at_us`` (0: as soon as received)."""

    TYPE = 0x08
    REQUEST = True
    play_id: int
    at_us: int = 0

    def pack(self) -> bytes:
        return _pack("<H", self.play_id, "play_id") + _pack("<Q", self.at_us, "at_us")

    @classmethod
    def unpack(cls, payload: bytes) -> Trigger:
        r = _Reader(payload, "TRIGGER")
        m = cls(*r.take("<HQ"))
        r.end()
        return m


@dataclass(frozen=True)
class Status(_NoPayload):
    TYPE = 0x09
    REQUEST = True
    LABEL = "STATUS"


@dataclass(frozen=True)
class Bye(_NoPayload):
    """The host is leaving: everything off and the session ends, without a watchdog alarm."""

    TYPE = 0x0B
    REQUEST = True
    LABEL = "BYE"


@dataclass(frozen=True)
class GetOnsets(Message):
    """Ask again for onsets the host missed (their ONSET events were lost)."""

    TYPE = 0x0A
    REQUEST = True
    play_id: int
    first: int
    count: int

    def pack(self) -> bytes:
        return struct.pack("<HHH", self.play_id, self.first, self.count)

    @classmethod
    def unpack(cls, payload: bytes) -> GetOnsets:
        r = _Reader(payload, "GET_ONSETS")
        m = cls(*r.take("<HHH"))
        r.end()
        return m


# -- device -> host: replies -----------------------------------------------------------------

@dataclass(frozen=True)
class HelloReply(Message):
    """What the device is: protocol, firmware, geometry, drive and capacities."""

    TYPE = 0x41
    REPLY = True
    ack_seq: int
    protocol: int
    heartbeat_ms: int
    watchdog_ms: int
    rows: int
    cols: int
    actuator: int
    drive: int
    max_level: int
    max_amplitude_mv: int
    max_frequency_chz: int
    max_width_us: int
    max_pulses: int
    max_payload: int
    now_us: int
    firmware: str
    device_id: str

    _FMT: ClassVar[str] = "<BBHHHHBBBHHHHHQ"

    def pack(self) -> bytes:
        return (struct.pack(self._FMT, self.ack_seq, self.protocol, self.heartbeat_ms,
                            self.watchdog_ms, self.rows, self.cols, self.actuator, self.drive,
                            self.max_level, self.max_amplitude_mv, self.max_frequency_chz,
                            self.max_width_us, self.max_pulses, self.max_payload, self.now_us)
                + _text(self.firmware) + _text(self.device_id))

    @classmethod
    def unpack(cls, payload: bytes) -> HelloReply:
        r = _Reader(payload, "HELLO_REPLY")
        head = r.take(cls._FMT)
        m = cls(*head, r.text(), r.text())
        r.end()
        return m


@dataclass(frozen=True)
class Ack(Message):
    """Request ``ack_seq`` done; ``t_us`` is the device time at which it took effect."""

    TYPE = 0x42
    REPLY = True
    ack_seq: int
    t_us: int

    def pack(self) -> bytes:
        return struct.pack("<BQ", self.ack_seq, self.t_us)

    @classmethod
    def unpack(cls, payload: bytes) -> Ack:
        r = _Reader(payload, "ACK")
        m = cls(*r.take("<BQ"))
        r.end()
        return m


class NakReason:
    """Why a request was refused (``Nak.reason``); ``detail`` qualifies it."""

    BAD_FRAME = 1            # COBS/CRC/length wrong: ack_seq unknown (0); resend the request
    BAD_VERSION = 2          # frame header version not spoken; detail = highest spoken
    UNKNOWN_TYPE = 3         # detail = the type byte
    BAD_PAYLOAD = 4
    NO_SESSION = 5           # no HELLO yet, or the watchdog ended the session
    UNSUPPORTED_PROTOCOL = 6  # HELLO asked for a protocol the device lacks; detail = highest
    OUT_OF_RANGE = 7         # actuator index or drive value beyond the hardware; detail = index
    WRONG_DRIVE = 8          # drive kind differs from the device's
    BUSY = 9                 # a play is in progress
    NO_SCHEDULE = 10         # trigger/chunk for a play_id not (completely) uploaded
    OUT_OF_ORDER = 11        # chunk not contiguous, or pulses not sorted by onset; detail = index
    TOO_LARGE = 12           # more pulses or a longer frame than the device holds; detail = max

    NAMES: ClassVar[dict[int, str]] = {}


NakReason.NAMES = {v: k for k, v in vars(NakReason).items() if isinstance(v, int)}


@dataclass(frozen=True)
class Nak(Message):
    TYPE = 0x43
    REPLY = True
    ack_seq: int
    reason: int
    detail: int = 0

    def pack(self) -> bytes:
        return struct.pack("<BBH", self.ack_seq, self.reason, self.detail)

    @classmethod
    def unpack(cls, payload: bytes) -> Nak:
        r = _Reader(payload, "NAK")
        m = cls(*r.take("<BBH"))
        r.end()
        return m

    @property
    def reason_name(self) -> str:
        return NakReason.NAMES.get(self.reason, f"reason {self.reason}")


class DeviceState:
    IDLE = 0
    UPLOADING = 1
    ARMED = 2         # schedule complete, waiting for (or at) its trigger time
    PLAYING = 3
    NO_SESSION = 4


@dataclass(frozen=True)
class StatusReply(Message):
    TYPE = 0x44
    REPLY = True
    ack_seq: int
    state: int
    play_id: int
    n_onsets: int
    now_us: int
    rx_frames: int
    rx_bad: int
    duplicates: int
    watchdog_trips: int

    _FMT: ClassVar[str] = "<BBHHQIIIH"

    def pack(self) -> bytes:
        return struct.pack(self._FMT, self.ack_seq, self.state, self.play_id, self.n_onsets,
                           self.now_us, self.rx_frames & 0xFFFFFFFF, self.rx_bad & 0xFFFFFFFF,
                           self.duplicates & 0xFFFFFFFF, self.watchdog_trips & 0xFFFF)

    @classmethod
    def unpack(cls, payload: bytes) -> StatusReply:
        r = _Reader(payload, "STATUS_REPLY")
        m = cls(*r.take(cls._FMT))
        r.end()
        return m


@dataclass(frozen=True)
class OnsetsReply(Message):
    """Device time of each pulse's onset from ``first`` on (:data:`NOT_PLAYED` if none)."""

    TYPE = 0x45
    REPLY = True
    ack_seq: int
    play_id: int
    first: int
    times_us: tuple[int, ...]

    def pack(self) -> bytes:
        return (struct.pack("<BHH", self.ack_seq, self.play_id, self.first)
                + b"".join(_pack("<Q", t, "onset time") for t in self.times_us))

    @classmethod
    def unpack(cls, payload: bytes) -> OnsetsReply:
        r = _Reader(payload, "ONSETS_REPLY")
        ack, play_id, first = r.take("<BHH")
        if r.rest() % 8:
            raise PayloadError("ONSETS_REPLY: payload is not a whole number of times")
        return cls(ack, play_id, first, tuple(r.take("<Q") for _ in range(r.rest() // 8)))


# -- device -> host: events ------------------------------------------------------------------

@dataclass(frozen=True)
class Onset(Message):
    """Pulses ``first .. first + count - 1`` of ``play_id`` started at device time ``t_us``."""

    TYPE = 0x61
    play_id: int
    first: int
    count: int
    t_us: int

    def pack(self) -> bytes:
        return struct.pack("<HHHQ", self.play_id, self.first, self.count, self.t_us)

    @classmethod
    def unpack(cls, payload: bytes) -> Onset:
        r = _Reader(payload, "ONSET")
        m = cls(*r.take("<HHHQ"))
        r.end()
        return m


class DoneReason:
    FINISHED = 0
    ALL_OFF = 1
    WATCHDOG = 2
    NAMES: ClassVar[dict[int, str]] = {0: "finished", 1: "stopped by ALL_OFF",
                                       2: "stopped by the watchdog"}


@dataclass(frozen=True)
class PlayDone(Message):
    TYPE = 0x62
    play_id: int
    reason: int
    n_onsets: int
    t_us: int

    def pack(self) -> bytes:
        return struct.pack("<HBHQ", self.play_id, self.reason, self.n_onsets, self.t_us)

    @classmethod
    def unpack(cls, payload: bytes) -> PlayDone:
        r = _Reader(payload, "PLAY_DONE")
        m = cls(*r.take("<HBHQ"))
        r.end()
        return m


class AlarmCode:
    WATCHDOG = 1            # the host went silent: everything was turned off
    NAMES: ClassVar[dict[int, str]] = {1: "watchdog"}


@dataclass(frozen=True)
class Alarm(Message):
    TYPE = 0x63
    code: int
    t_us: int

    def pack(self) -> bytes:
        return struct.pack("<BQ", self.code, self.t_us)

    @classmethod
    def unpack(cls, payload: bytes) -> Alarm:
        r = _Reader(payload, "ALARM")
        m = cls(*r.take("<BQ"))
        r.end()
        return m


MESSAGES: dict[int, type[Message]] = {
    cls.TYPE: cls for cls in (Hello, Heartbeat, AllOff, SetFrame, SetFrameFull, UploadBegin,
                              UploadChunk, Trigger, Status, GetOnsets, Bye, HelloReply, Ack, Nak,
                              StatusReply, OnsetsReply, Onset, PlayDone, Alarm)}
MESSAGES_BY_NAME: dict[str, type[Message]] = {c.__name__: c for c in MESSAGES.values()}
_PLAIN: dict[str, type] = {"Level": Level, "Train": Train, "WirePulse": WirePulse}


# --------------------------------------------------------------------------- frames

def frame_body(msg: Message, seq: int) -> bytes:
    """Header + payload + CRC, before COBS (what the CRC and the vectors' ``raw`` cover)."""
    if not 0 <= seq <= 255:
        raise PayloadError(f"sequence number {seq} is not a byte")
    head = HEADER.pack(PROTOCOL_VERSION, msg.TYPE, seq) + msg.pack()
    return head + CRC.pack(crc32(head))


def encode(msg: Message, seq: int) -> bytes:
    """The bytes of one frame on the wire, both delimiters included."""
    return DELIMITER + cobs_encode(frame_body(msg, seq)) + DELIMITER


def decode_frame(encoded: bytes, max_len: int = MAX_FRAME) -> tuple[int, Message]:
    """Decode the bytes between two delimiters into ``(seq, message)``.

    ``max_len`` is the longest decoded frame the receiver takes (header, payload and
    CRC: the maximum payload + 7). Raises a :class:`WireError` subclass that says
    what was wrong.
    """
    raw = cobs_decode(encoded)
    if len(raw) > max_len:
        raise TooLongError(f"frame of {len(raw)} bytes is longer than the {max_len}-byte "
                           "maximum (payload + 7)")
    if len(raw) < MIN_FRAME:
        raise WireError(f"frame of {len(raw)} bytes is shorter than the {MIN_FRAME}-byte minimum")
    body, (crc,) = raw[:-CRC.size], CRC.unpack(raw[-CRC.size:])
    if crc32(body) != crc:
        raise CrcError(f"CRC mismatch (frame says {crc:08x}, bytes give {crc32(body):08x})")
    version, mtype, seq = HEADER.unpack_from(body)
    if version != PROTOCOL_VERSION:
        raise VersionError(f"frame of protocol version {version}; this end speaks "
                           f"{PROTOCOL_VERSION}")
    cls = MESSAGES.get(mtype)
    if cls is None:
        err = UnknownTypeError(f"unknown message type 0x{mtype:02x}")
        err.seq = seq               # type: ignore[attr-defined]
        err.mtype = mtype           # type: ignore[attr-defined]
        raise err
    try:
        return seq, cls.unpack(body[HEADER.size:])
    except PayloadError as e:
        e.seq = seq                 # type: ignore[attr-defined]
        raise
    except (struct.error, ValueError) as e:
        err = PayloadError(f"{cls.__name__}: {e}")
        err.seq = seq               # type: ignore[attr-defined]
        raise err from None


@dataclass
class ReaderStats:
    frames: int = 0
    bytes: int = 0
    errors: dict[str, int] = field(default_factory=dict)

    @property
    def bad(self) -> int:
        return sum(self.errors.values())


class FrameReader:
    """Split a byte stream into frames; resynchronise on the next delimiter.

    Feed it whatever the port returned; it yields ``(seq, message)`` tuples
    for good frames and :class:`WireError` instances for bad ones (garbage,
    a CRC mismatch, a frame cut short by a lost byte). Empty frames (two
    delimiters in a row, as every frame starts with one) are skipped. A frame
    that decodes to more than ``max_frame`` bytes (header + payload + CRC) is
    refused, and a run of bytes without a delimiter longer than such a frame can
    be once encoded is dropped without being held.
    """

    def __init__(self, max_frame: int = MAX_FRAME):
        self.max_frame = max_frame
        self._buf = bytearray()
        self._overflow = False
        self.max_encoded = max_frame + max_frame // 254 + 2
        self.stats = ReaderStats()

    def feed(self, data: bytes) -> list[tuple[int, Message] | WireError]:
        out: list[tuple[int, Message] | WireError] = []
        self.stats.bytes += len(data)
        start = 0
        while True:
            z = data.find(0, start)
            chunk = data[start:] if z < 0 else data[start:z]
            if not self._overflow:
                self._buf += chunk
                if len(self._buf) > self.max_encoded:
                    self._overflow = True
                    self._buf.clear()
            if z < 0:
                break
            if self._overflow:
                out.append(self._error(WireError(f"more than {self.max_encoded} bytes without a "
                                                 "frame delimiter")))
                self._overflow = False
            elif self._buf:
                try:
                    out.append(decode_frame(bytes(self._buf), self.max_frame))
                    self.stats.frames += 1
                except WireError as e:
                    out.append(self._error(e))
                self._buf.clear()
            start = z + 1
        return out

    def _error(self, e: WireError) -> WireError:
        self.stats.errors[e.kind] = self.stats.errors.get(e.kind, 0) + 1
        return e


def describe(msg: Message) -> str:
    """One human-readable line (``vtexp device monitor``)."""
    name = type(msg).__name__
    if isinstance(msg, SetFrame):
        ch = ", ".join(f"#{i}={_show(s)}" for i, s in msg.changes[:8])
        more = f", ... ({len(msg.changes)} changes)" if len(msg.changes) > 8 else ""
        return f"{name} {ch}{more}"
    if isinstance(msg, SetFrameFull):
        on = sum(1 for s in msg.settings if not s.is_off)
        return f"{name} {len(msg.settings)} actuators, {on} on"
    if isinstance(msg, UploadChunk):
        return (f"{name} play {msg.play_id} pulses {msg.first}..{msg.first + len(msg.pulses) - 1}")
    if isinstance(msg, Nak):
        return f"{name} seq {msg.ack_seq}: {msg.reason_name} (detail {msg.detail})"
    if isinstance(msg, PlayDone):
        return (f"{name} play {msg.play_id} {DoneReason.NAMES.get(msg.reason, msg.reason)}, "
                f"{msg.n_onsets} onsets, t={msg.t_us} us")
    d = msg.to_dict()
    d.pop("type")
    return f"{name} " + " ".join(f"{k}={v}" for k, v in d.items())


def _show(s: Setting) -> str:
    if isinstance(s, Level):
        return f"L{s.level}"
    return f"{s.amplitude_mv}mV/{s.frequency_chz / 100:g}Hz/{s.width_us}us"
