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

Payloads are declared, not written out: each message is a dataclass whose
fields carry their wire type in wire order (``ack_seq: u8``, ``firmware: text``,
a run of settings or pulses), as the table of messages in ``docs/protocol.md``
lists them, and one table-driven codec packs and unpacks them all.
"""

from __future__ import annotations

import operator
import re
import struct
import zlib
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field, fields
from itertools import starmap
from operator import attrgetter, itemgetter
from typing import Annotated, Any, ClassVar, get_type_hints

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


# --------------------------------------------------------------------------- wire types
#
# Every setting and message below is a frozen dataclass whose fields are annotated
# with their wire type, in the order they stand on the wire (``ack_seq: u8``): the
# classes are the table of docs/protocol.md's "Messages" section, declared once.
# _Layout reads each class's row when the module loads and compiles it into
# struct.Struct objects; one pack and one unpack serve every message.

class UInt:
    """An unsigned little-endian integer field: ``u8``, ``u16``, ``u32`` or ``u64``.

    Parameters
    ----------
    code : str
        Its :mod:`struct` format character: ``B``, ``H``, ``I`` or ``Q``.
    wraps : bool
        A counter, sent modulo its width rather than refused when it outgrows it
        (``STATUS_REPLY``'s counters, "each wrapping at its width").
    """

    def __init__(self, code: str, wraps: bool = False):
        self.struct = struct.Struct("<" + code)
        self.code, self.wraps = code, wraps
        self.name = f"u{8 * self.struct.size}"
        self.max = (1 << 8 * self.struct.size) - 1

    def __repr__(self) -> str:
        return self.name + (" (wrapping)" if self.wraps else "")


class Text:
    """``len:u8`` and then that many bytes of UTF-8 (the protocol's ``str``)."""


class DriveSetting:
    """One setting, encoded as the message's ``drive`` field says (:data:`SETTINGS`)."""


@dataclass(frozen=True)
class Repeated:
    """Items one after the other: ``count`` of them after a count field, or to the end.

    Parameters
    ----------
    item : UInt, DriveSetting, tuple of (str, wire type), or a dataclass
        One item: a bare value, a plain tuple (its parts named for error messages),
        or a dataclass annotated like the messages; integers first, then the setting
        if it holds one.
    what : str
        The items in the plural, for error messages.
    count : UInt or None
        The count written before the items; None: they run to the end of the payload.
    """

    item: Any
    what: str
    count: UInt | None = None


U8, U16, U32, U64 = UInt("B"), UInt("H"), UInt("I"), UInt("Q")
DRIVE_SETTING = DriveSetting()

# The annotations the table is written in.
u8 = Annotated[int, U8]
u16 = Annotated[int, U16]
u32 = Annotated[int, U32]
u64 = Annotated[int, U64]
wrapping_u16 = Annotated[int, UInt("H", wraps=True)]
wrapping_u32 = Annotated[int, UInt("I", wraps=True)]
text = Annotated[str, Text()]


class _Wire:
    """What every class with a row in the table has: its compiled layout."""

    _LAYOUT: ClassVar[_Layout]

    def pack(self) -> bytes:
        """The bytes of this value on the wire (a message: its payload)."""
        return self._LAYOUT.pack(self)

    @classmethod
    def unpack(cls, payload: bytes) -> Any:
        """Inverse of :meth:`pack`; raises :class:`PayloadError` on malformed bytes."""
        return cls._LAYOUT.unpack(payload)


# --------------------------------------------------------------------------- settings

@dataclass(frozen=True)
class Level(_Wire):
    """A vibration motor at an intensity level (0 = off); seed 000 Table 1, seed 001 §3.3."""

    level: u8

    KIND: ClassVar[int] = DRIVE_LEVEL
    SIZE: ClassVar[int]                 # bytes on the wire, from the layout

    @property
    def is_off(self) -> bool:
        return self.level == 0


@dataclass(frozen=True)
class Train(_Wire):
    """An SMA pin driven by a pulse train (seed 002 §3.3): 0 mV = off.

    Units are integers so that both ends agree bit for bit: millivolts,
    centi-hertz (0.01 Hz) and microseconds.
    """

    amplitude_mv: u16
    frequency_chz: u16
    width_us: u16

    KIND: ClassVar[int] = DRIVE_TRAIN
    SIZE: ClassVar[int]

    @property
    def is_off(self) -> bool:
        return self.amplitude_mv == 0


Setting = Level | Train
SETTINGS: dict[int, type[Level | Train]] = {DRIVE_LEVEL: Level, DRIVE_TRAIN: Train}
OFF: dict[int, Setting] = {DRIVE_LEVEL: Level(0), DRIVE_TRAIN: Train(0, 0, 0)}
drive_setting = Annotated[Setting, DRIVE_SETTING]


@dataclass(frozen=True)
class WirePulse:
    """One pulse of an uploaded schedule, in device units (µs from the trigger)."""

    index: u16
    onset_us: u32
    duration_us: u32
    setting: drive_setting


# --------------------------------------------------------------------------- messages

class Message(_Wire):
    """Base of all v1 messages: ``TYPE`` on the wire, then the payload's fields.

    A message's fields are annotated with their wire types in wire order; ``pack`` and
    ``unpack`` follow them. ``REQUEST`` and ``REPLY`` follow from the type's range.
    """

    TYPE: ClassVar[int]
    NAME: ClassVar[str]                 # as docs/protocol.md names it: SetFrame -> SET_FRAME
    REQUEST: ClassVar[bool] = False     # host -> device, answered by exactly one reply
    REPLY: ClassVar[bool] = False       # device -> host, carries ack_seq

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        cls.NAME = re.sub(r"(?<!^)(?=[A-Z])", "_", cls.__name__).upper()
        # docs/protocol.md: types 0x01-0x3F are requests, 0x41-0x5F replies, 0x61-0x7F events
        cls.REQUEST = 0x01 <= cls.TYPE <= 0x3F
        cls.REPLY = 0x41 <= cls.TYPE <= 0x5F

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
    protocol: u8 = PROTOCOL_VERSION
    heartbeat_ms: u16 = 200
    watchdog_ms: u16 = 200


@dataclass(frozen=True)
class Heartbeat(Message):
    """Keep the device's watchdog fed; the ACK's time also measures round trips."""

    TYPE = 0x02


@dataclass(frozen=True)
class AllOff(Message):
    """Every actuator off at once; any play in progress is abandoned."""

    TYPE = 0x03


@dataclass(frozen=True)
class SetFrame(Message):
    """Sparse update: only the listed actuators change, all in the same instant."""

    TYPE = 0x04
    drive: u8
    changes: Annotated[tuple[tuple[int, Setting], ...],
                       Repeated((("actuator index", U16), ("setting", DRIVE_SETTING)),
                                "changes", count=U16)]


@dataclass(frozen=True)
class SetFrameFull(Message):
    """Dense update: a setting for every actuator, row-major (index = row * cols + col)."""

    TYPE = 0x05
    drive: u8
    settings: Annotated[tuple[Setting, ...], Repeated(DRIVE_SETTING, "settings")]


@dataclass(frozen=True)
class UploadBegin(Message):
    """Announce a schedule of ``n_pulses`` pulses (sorted by onset) under ``play_id``."""

    TYPE = 0x06
    play_id: u16
    n_pulses: u16
    drive: u8


@dataclass(frozen=True)
class UploadChunk(Message):
    """Pulses ``first .. first + len(pulses) - 1`` of the schedule being uploaded."""

    TYPE = 0x07
    play_id: u16
    first: u16
    drive: u8
    pulses: Annotated[tuple[WirePulse, ...], Repeated(WirePulse, "pulses")]

    @staticmethod
    def pulse_size(drive: int) -> int:
        """Bytes of one pulse with settings of ``drive`` (a :data:`DRIVE_KINDS` value)."""
        return UploadChunk._LAYOUT.item_size("pulses", drive)


@dataclass(frozen=True)
class Trigger(Message):
    """Start the uploaded schedule at device time ``at_us`` (0: as soon as received)."""

    TYPE = 0x08
    play_id: u16
    at_us: u64 = 0


@dataclass(frozen=True)
class Status(Message):
    TYPE = 0x09


@dataclass(frozen=True)
class Bye(Message):
    """The host is leaving: everything off and the session ends, without a watchdog alarm."""

    TYPE = 0x0B


@dataclass(frozen=True)
class GetOnsets(Message):
    """Ask again for onsets the host missed (their ONSET events were lost)."""

    TYPE = 0x0A
    play_id: u16
    first: u16
    count: u16


# -- device -> host: replies -----------------------------------------------------------------

@dataclass(frozen=True)
class HelloReply(Message):
    """What the device is: protocol, firmware, geometry, drive and capacities."""

    TYPE = 0x41
    ack_seq: u8
    protocol: u8
    heartbeat_ms: u16
    watchdog_ms: u16
    rows: u16
    cols: u16
    actuator: u8
    drive: u8
    max_level: u8
    max_amplitude_mv: u16
    max_frequency_chz: u16
    max_width_us: u16
    max_pulses: u16
    max_payload: u16
    now_us: u64
    firmware: text
    device_id: text


@dataclass(frozen=True)
class Ack(Message):
    """Request ``ack_seq`` done; ``t_us`` is the device time at which it took effect."""

    TYPE = 0x42
    ack_seq: u8
    t_us: u64


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
    ack_seq: u8
    reason: u8
    detail: u16 = 0

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
    ack_seq: u8
    state: u8
    play_id: u16
    n_onsets: u16
    now_us: u64
    rx_frames: wrapping_u32
    rx_bad: wrapping_u32
    duplicates: wrapping_u32
    watchdog_trips: wrapping_u16


@dataclass(frozen=True)
class OnsetsReply(Message):
    """Device time of each pulse's onset from ``first`` on (:data:`NOT_PLAYED` if none)."""

    TYPE = 0x45
    ack_seq: u8
    play_id: u16
    first: u16
    times_us: Annotated[tuple[int, ...], Repeated(U64, "times")]


# -- device -> host: events ------------------------------------------------------------------

@dataclass(frozen=True)
class Onset(Message):
    """Pulses ``first .. first + count - 1`` of ``play_id`` started at device time ``t_us``."""

    TYPE = 0x61
    play_id: u16
    first: u16
    count: u16
    t_us: u64


class DoneReason:
    FINISHED = 0
    ALL_OFF = 1
    WATCHDOG = 2
    NAMES: ClassVar[dict[int, str]] = {0: "finished", 1: "stopped by ALL_OFF",
                                       2: "stopped by the watchdog"}


@dataclass(frozen=True)
class PlayDone(Message):
    TYPE = 0x62
    play_id: u16
    reason: u8
    n_onsets: u16
    t_us: u64


class AlarmCode:
    WATCHDOG = 1            # the host went silent: everything was turned off
    NAMES: ClassVar[dict[int, str]] = {1: "watchdog"}


@dataclass(frozen=True)
class Alarm(Message):
    TYPE = 0x63
    code: u8
    t_us: u64


MESSAGES: dict[int, type[Message]] = {
    cls.TYPE: cls for cls in (Hello, Heartbeat, AllOff, SetFrame, SetFrameFull, UploadBegin,
                              UploadChunk, Trigger, Status, GetOnsets, Bye, HelloReply, Ack, Nak,
                              StatusReply, OnsetsReply, Onset, PlayDone, Alarm)}
MESSAGES_BY_NAME: dict[str, type[Message]] = {c.__name__: c for c in MESSAGES.values()}
_PLAIN: dict[str, type] = {"Level": Level, "Train": Train, "WirePulse": WirePulse}


# --------------------------------------------------------------------------- layouts
#
# Speed matters: a live stream encodes a frame at every change and the emulated
# firmware decodes each one. So a layout packs a message's fixed fields with one
# Struct call and lets map, zip and starmap walk a run's items in C (_Items); only
# when struct refuses a value does it walk the fields to say which one.

def _wire_fields(cls: type) -> list[tuple[str, Any]]:
    """``(name, wire type)`` of each field of the dataclass ``cls``, in wire order."""
    hints = get_type_hints(cls, include_extras=True)
    out = []
    for f in fields(cls):
        wire_type = next((m for m in getattr(hints[f.name], "__metadata__", ())
                          if isinstance(m, (UInt, Text, DriveSetting, Repeated))), None)
        if wire_type is None:
            raise TypeError(f"{cls.__name__}.{f.name} is not annotated with a wire type")
        out.append((f.name, wire_type))
    return out


def _values(names: list[str]) -> Callable[[Any], tuple]:
    """The named attributes of an object, as a tuple (``attrgetter`` returns a bare one)."""
    if len(names) == 1:
        get = attrgetter(names[0])
        return lambda x: (get(x),)
    return attrgetter(*names) if names else lambda x: ()


def _item_parts(item: Any) -> list[tuple[str, Any]]:
    """``(label, wire type)`` of each part of a :attr:`Repeated.item` ("" for a bare one)."""
    if isinstance(item, type):
        return _wire_fields(item)
    return list(item) if isinstance(item, tuple) else [("", item)]


def _fits(t: UInt, v: Any) -> bool:
    try:
        return t.wraps or 0 <= operator.index(v) <= t.max
    except TypeError:
        return False


class _Items:
    """A run's :attr:`Repeated.item` compiled, with settings of the class ``setting``.

    Packing flattens each item into the values of its Struct; unpacking goes a column
    at a time (each integer of the items, each field of their settings) so that map
    and zip walk the items in C. Items of one integer each (onset times, levels) take
    one struct call for the whole run.
    """

    def __init__(self, item: Any, setting: type[Level | Train] | None):
        parts = _item_parts(item)
        ints = [(label, t) for label, t in parts if isinstance(t, UInt)]
        k, self.ints, self.setting = len(ints), ints, setting
        if parts[:k] != ints or len(parts) != k + (setting is not None) or not (
                setting or isinstance(item, UInt)):
            raise TypeError(f"{item!r}: v1's runs hold bare integers, or integers and then "
                            "one setting of the drive kind")
        s_names = [name for name, _ in setting._LAYOUT.head_fields] if setting else []
        self.codes = "".join(t.code for _, t in ints) + (setting._LAYOUT.head.format[1:]
                                                         if setting else "")
        self.struct = struct.Struct("<" + self.codes)
        self.size = self.struct.size
        # ints_of and setting_of take an item apart (setting_of None: the item is the
        # setting, or holds none); combine puts the columns back together into items.
        self.setting_of: Callable[[Any], Setting] | None = None
        if isinstance(item, type):                                # UploadChunk.pulses
            self.ints_of = _values([label for label, _ in ints])
            self.setting_of = attrgetter(parts[k][0])
            self.combine: Callable[..., Iterable[Any]] = lambda *cols: map(item, *cols)
        elif isinstance(item, tuple):                             # SetFrame.changes
            self.ints_of = itemgetter(slice(0, k))
            self.setting_of, self.combine = itemgetter(k), zip
        else:                                                     # OnsetsReply.times_us,
            self.ints_of = (lambda x: (x,)) if k else (lambda x: ())   # SetFrameFull.settings
            self.combine = lambda col: col
        # flat: an item -> the values of its Struct, with one Python call at most
        ints_of, setting_of = self.ints_of, self.setting_of
        if setting is None:
            self.flat = ints_of
        elif setting_of is None:
            self.flat = _values(s_names)
        elif len(s_names) == 1:
            get = attrgetter(s_names[0])
            self.flat = lambda x: (*ints_of(x), get(setting_of(x)))
        else:
            gets = attrgetter(*s_names)
            self.flat = lambda x: (*ints_of(x), *gets(setting_of(x)))
        self.single = len(self.codes) == 1
        self.single_get = attrgetter(s_names[0]) if self.single and setting else None

    def settings(self, items: Iterable[Any]) -> Iterable[Setting]:
        """The settings that ``items`` hold."""
        if self.setting is None:
            return ()
        return items if self.setting_of is None else map(self.setting_of, items)

    def pack(self, items: Sequence[Any], where: str) -> bytes:
        try:
            if self.single:
                values = map(self.single_get, items) if self.single_get else items
                return struct.pack(f"<{len(items)}{self.codes}", *values)
            return b"".join(starmap(self.struct.pack, map(self.flat, items)))
        except AttributeError:
            # A setting of another kind lacks the fields read (checking every item
            # first would cost more than the packing), so say which it was.
            for s in self.settings(items):
                if not isinstance(s, self.setting):         # type: ignore[arg-type]
                    raise PayloadError(f"{where}: a {type(s).__name__} setting in a message "
                                       f"of drive kind {self.setting.KIND}") from None
            raise

    def unpack(self, data: bytes) -> tuple:
        n = len(data) // self.size
        if self.single:
            cols: list[Iterable[Any]] = [struct.unpack(f"<{n}{self.codes}", data)]
        else:
            cols = list(zip(*self.struct.iter_unpack(data))) if n else [()] * len(self.codes)
        if self.setting:
            k = len(self.ints)
            cols[k:] = [map(self.setting, *cols[k:])]
        return tuple(self.combine(*cols))

    def leaves(self, x: Any, where: str) -> Iterator[tuple[str, UInt, Any]]:
        """``(name, type, value)`` of every integer of the item ``x``."""
        for (label, t), v in zip(self.ints, self.ints_of(x)):
            yield f"{where} {label}".rstrip(), t, v
        for s in self.settings((x,)):
            yield from s._LAYOUT.leaves(s, where + " ")


class _Text:
    """A :class:`Text` field compiled."""

    def __init__(self, layout: _Layout, name: str):
        self.layout, self.name, self.get = layout, name, attrgetter(name)

    def pack(self, obj: Any) -> bytes:
        b = self.get(obj).encode("utf-8")
        if len(b) > 255:
            raise PayloadError(f"{self.layout.cls.__name__}: {self.name}: text of {len(b)} "
                               "bytes; at most 255 fit")
        return bytes([len(b)]) + b

    def unpack(self, payload: bytes, i: int, values: list) -> int:
        end = i + 1 + (payload[i] if i < len(payload) else 0)
        if end > len(payload):
            raise self.layout.too_short(len(payload))
        try:
            values.append(str(payload[i + 1:end], "utf-8"))
        except UnicodeDecodeError:
            raise PayloadError(f"{self.layout.name}: text is not UTF-8") from None
        return end

    def leaves(self, obj: Any, where: str) -> Iterator[tuple[str, UInt, Any]]:
        return iter(())


class _Run:
    """A :class:`Repeated` field compiled: its count, its items for each drive kind."""

    def __init__(self, layout: _Layout, name: str, rep: Repeated):
        self.layout, self.name, self.get, self.rep = layout, name, attrgetter(name), rep
        self.where = layout.cls.__name__            # as encoding errors name the message
        self.count = rep.count.struct if rep.count else None
        self.drive_at: int | None = None
        self.by_drive: dict[int | None, _Items] = {}
        if not any(isinstance(t, DriveSetting) for _, t in _item_parts(rep.item)):
            self.by_drive[None] = _Items(rep.item, None)
        elif "drive" in layout.head_names:
            self.drive_at = layout.head_names.index("drive")
            self.by_drive = {kind: _Items(rep.item, s) for kind, s in SETTINGS.items()}
        else:
            raise TypeError(f"{layout.cls.__name__}.{name}: settings, but no drive field "
                            "before them says which")

    def items(self, drive: int | None, where: str) -> _Items:
        """The items for the drive kind ``drive`` (None: a run without settings)."""
        found = self.by_drive.get(drive)
        if found is None:
            raise PayloadError(f"{where}: unknown drive kind {drive}")
        return found

    def pack(self, obj: Any) -> bytes:
        v = self.get(obj)
        items = self.items(None if self.drive_at is None else obj.drive, self.where)
        return (self.count.pack(len(v)) if self.count else b"") + items.pack(v, self.where)

    def unpack(self, payload: bytes, i: int, values: list) -> int:
        n, count = len(payload), None
        if self.count:                  # read before the drive kind is looked at
            if i + self.count.size > n:
                raise self.layout.too_short(n)
            (count,) = self.count.unpack_from(payload, i)
            i += self.count.size
        items = self.items(None if self.drive_at is None else values[self.drive_at],
                           self.layout.name)
        if count is not None:
            end = i + count * items.size
            if end > n:
                raise self.layout.too_short(n)
        elif (n - i) % items.size:
            raise PayloadError(f"{self.layout.name}: payload is not a whole number of "
                               f"{self.rep.what}")
        else:
            end = n
        values.append(items.unpack(payload[i:end]))
        return end

    def leaves(self, obj: Any, where: str) -> Iterator[tuple[str, UInt, Any]]:
        v = self.get(obj)
        if self.rep.count:
            yield f"{where}number of {self.name}", self.rep.count, len(v)
        items = self.items(None if self.drive_at is None else obj.drive, self.where)
        for j, x in enumerate(v):
            yield from items.leaves(x, f"{where}{self.name}[{j}]")


class _Layout:
    """The row of ``cls`` compiled: fixed fields, then texts and runs of items."""

    def __init__(self, cls: type):
        self.cls, self.name = cls, getattr(cls, "NAME", cls.__name__)
        fields_ = _wire_fields(cls)
        k = next((i for i, (_, t) in enumerate(fields_) if not isinstance(t, UInt)),
                 len(fields_))
        self.head_fields = fields_[:k]
        self.head_names = [n for n, _ in self.head_fields]
        self.head = struct.Struct("<" + "".join(t.code for _, t in self.head_fields))
        self.values = _values(self.head_names)
        if any(t.wraps for _, t in self.head_fields):
            get, masks = self.values, [t.max if t.wraps else -1 for _, t in self.head_fields]
            self.values = lambda x: tuple(map(operator.and_, get(x), masks))
        self.tail: list[_Text | _Run] = []
        for j, (name, t) in enumerate(fields_[k:], k):
            if isinstance(t, Text):
                self.tail.append(_Text(self, name))
            elif isinstance(t, Repeated) and (t.count or j == len(fields_) - 1):
                self.tail.append(_Run(self, name, t))
            else:
                raise TypeError(f"{cls.__name__}.{name}: v1 has integers first, then texts "
                                "and runs of items, a run to the end of the payload last")

    def item_size(self, name: str, drive: int | None = None) -> int:
        """Bytes of one item of the run ``name``, with settings of ``drive``."""
        run = next(p for p in self.tail if isinstance(p, _Run) and p.name == name)
        return run.by_drive[drive].size

    def pack(self, obj: Any) -> bytes:
        try:
            out = self.head.pack(*self.values(obj))
            for part in self.tail:
                out += part.pack(obj)
            return out
        except struct.error as e:
            for name, t, v in self.leaves(obj, f"{self.cls.__name__}: "):
                if not _fits(t, v):
                    raise PayloadError(f"{name}={v!r} does not fit the wire field {t.name} "
                                       f"(a whole number from 0 to {t.max})") from None
            raise PayloadError(f"{self.cls.__name__}: {e}") from None

    def leaves(self, obj: Any, where: str) -> Iterator[tuple[str, UInt, Any]]:
        """``(name, type, value)`` of every integer of ``obj``, counts of runs included."""
        for name, t in self.head_fields:
            yield where + name, t, getattr(obj, name)
        for part in self.tail:
            yield from part.leaves(obj, where)

    def unpack(self, payload: bytes) -> Any:
        n, i = len(payload), self.head.size
        if not self.tail:
            if n != i:
                raise self.too_short(n) if n < i else self.trailing(n - i)
            return self.cls(*self.head.unpack(payload))
        if n < i:
            raise self.too_short(n)
        values = list(self.head.unpack_from(payload))
        for part in self.tail:
            i = part.unpack(payload, i, values)
        if i != n:
            raise self.trailing(n - i)
        return self.cls(*values)

    def too_short(self, n: int) -> PayloadError:
        return PayloadError(f"{self.name}: payload too short ({n} bytes)")

    def trailing(self, extra: int) -> PayloadError:
        return PayloadError(f"{self.name}: {extra} unexpected trailing bytes")


for _cls in (Level, Train, *MESSAGES.values()):
    _cls._LAYOUT = _Layout(_cls)
for _setting in SETTINGS.values():
    _setting.SIZE = _setting._LAYOUT.head.size
del _cls, _setting


# --------------------------------------------------------------------------- frames

def frame_body(msg: Message, seq: int) -> bytes:
    """Header + payload + CRC, before COBS (what the CRC and the vectors' ``raw`` cover)."""
    if not 0 <= seq <= 255:
        raise PayloadError(f"sequence number {seq} is not a byte")
    head = HEADER.pack(PROTOCOL_VERSION, msg.TYPE, seq) + msg._LAYOUT.pack(msg)
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
        return seq, cls._LAYOUT.unpack(body[HEADER.size:])
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
        self._buf = bytearray()
        self._overflow = False
        self.accept(max_frame)
        self.stats = ReaderStats()

    def accept(self, max_frame: int) -> None:
        """Take frames of up to ``max_frame`` decoded bytes from now on; a frame being
        read is kept."""
        self.max_frame = max_frame
        self.max_encoded = max_frame + max_frame // 254 + 2

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
