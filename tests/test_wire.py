"""Wire protocol v1 codec: the shipped vectors, independent references, and properties."""

from __future__ import annotations

import json
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vtexp.devices import wire
from vtexp.devices.wire import (
    Ack,
    Alarm,
    AllOff,
    FrameReader,
    GetOnsets,
    Heartbeat,
    Hello,
    HelloReply,
    Level,
    Nak,
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

ROOT = Path(__file__).resolve().parents[1]
VECTORS_PATH = ROOT / "protocols" / "wire" / "v1_vectors.json"
VECTORS = json.loads(VECTORS_PATH.read_text(encoding="utf-8"))


# --------------------------------------------------------------------------- references

def test_crc_is_crc32_iso_hdlc():
    check = VECTORS["crc32_check"]
    assert wire.crc32(check["ascii"].encode()) == int(check["crc32"], 16) == 0xCBF43926


@pytest.mark.parametrize("case", VECTORS["cobs"], ids=lambda c: c["decoded"][:12])
def test_cobs_matches_the_published_examples(case):
    dec, enc = bytes.fromhex(case["decoded"]), bytes.fromhex(case["encoded"])
    assert wire.cobs_encode(dec) == enc
    assert wire.cobs_decode(enc) == dec


def test_a_frame_built_by_hand_decodes():
    # HELLO, seq 9, protocol 1, heartbeat 300 ms, watchdog 301 ms: built without the codec.
    body = bytes([1, 0x01, 9]) + struct.pack("<BHH", 1, 300, 301)
    body += struct.pack("<I", zlib.crc32(body))
    assert 0 not in body            # so COBS is one block: length + 1, then the bytes
    on_wire = b"\x00" + bytes([len(body) + 1]) + body + b"\x00"
    assert wire.encode(Hello(1, 300, 301), 9) == on_wire
    assert FrameReader().feed(on_wire) == [(9, Hello(1, 300, 301))]


# --------------------------------------------------------------------------- shipped vectors

@pytest.mark.parametrize("case", VECTORS["frames"], ids=lambda c: c["name"])
def test_frame_vectors(case):
    msg = wire.message_from_dict(case["message"])
    assert wire.frame_body(msg, case["seq"]).hex() == case["raw"]
    assert wire.encode(msg, case["seq"]).hex() == case["wire"]
    assert FrameReader().feed(bytes.fromhex(case["wire"])) == [(case["seq"], msg)]


def test_every_message_type_has_a_vector():
    names = {c["message"]["type"] for c in VECTORS["frames"]}
    assert names == set(wire.MESSAGES_BY_NAME)


@pytest.mark.parametrize("case", VECTORS["bad_frames"], ids=lambda c: c["name"])
def test_bad_frame_vectors_are_rejected_with_their_reason(case):
    r = FrameReader()
    out = r.feed(bytes.fromhex(case["wire"]))
    assert len(out) == 1 and isinstance(out[0], wire.WireError)
    assert out[0].kind == case["error"]
    assert r.stats.errors == {case["error"]: 1}


@pytest.mark.parametrize("case", VECTORS["streams"], ids=lambda c: c["name"])
def test_stream_vectors_resynchronise(case):
    r = FrameReader()
    data = bytes.fromhex(case["wire"])
    # Byte by byte, as a slow UART would deliver it: the result must not depend on chunking.
    out = [x for b in data for x in r.feed(bytes([b]))]
    good = [{"seq": x[0], "message": x[1].to_dict()} for x in out if isinstance(x, tuple)]
    assert good == case["messages"]
    assert sum(isinstance(x, wire.WireError) for x in out) == case["n_errors"] == r.stats.bad
    assert len(r._buf) == case["pending_bytes"]


# v1's vectors as first published (SHA-256 of each, JSON with sorted keys, first 16 hex
# digits): they never change; clarifications of the document only add vectors.
FROZEN = {
    ("conversations", "handshake_play_and_onsets"): "ba4e60b50d2a8ed6",
    ("conversations", "retry_is_not_executed_twice"): "3a7faffb5de515dc",
    ("conversations", "garbage_and_corruption_change_nothing"): "3814254ddb6ba99e",
    ("conversations", "refusals"): "a3b8fdbb39c77a35",
    ("conversations", "watchdog"): "1070923445ff9f61",
    ("conversations", "bye"): "15b18ddaad645fe0",
    ("cobs", None): "d6c7f8ce19da9135",
    ("frames", None): "46ff611cb4a38fe2",
    ("bad_frames", None): "0649bfa2b23b9f99",
    ("streams", None): "2e14625d3c047e0e",
}


@pytest.mark.parametrize("where", FROZEN, ids=lambda w: w[1] or w[0])
def test_published_vectors_never_change(where):
    import hashlib
    section, name = where
    item = VECTORS[section] if name is None else next(
        c for c in VECTORS[section] if c["name"] == name)
    digest = hashlib.sha256(json.dumps(item, sort_keys=True).encode()).hexdigest()[:16]
    assert digest == FROZEN[where]


def test_the_vectors_file_is_what_the_generator_writes(tmp_path):
    out = tmp_path / "v.json"
    subprocess.run([sys.executable, str(ROOT / "protocols" / "wire" / "make_vectors.py"),
                    str(out)], check=True, capture_output=True)
    assert json.loads(out.read_text()) == VECTORS


# --------------------------------------------------------------------------- properties

u8 = st.integers(0, 0xFF)
u16 = st.integers(0, 0xFFFF)
u32 = st.integers(0, 0xFFFF_FFFF)
u64 = st.integers(0, 0xFFFF_FFFF_FFFF_FFFF)
text = st.text(max_size=40).filter(lambda s: len(s.encode()) <= 255)
levels = st.builds(Level, u8)
trains = st.builds(Train, u16, u16, u16)


def _frames(drive, settings_, n):
    return st.lists(st.tuples(u16, settings_), max_size=n).map(
        lambda ch: SetFrame(drive, tuple(ch)))


def _chunks(drive, settings_):
    pulses = st.lists(st.builds(WirePulse, u16, u32, u32, settings_), max_size=20)
    return st.builds(lambda pid, first, ps: UploadChunk(pid, first, drive, tuple(ps)),
                     u16, u16, pulses)


messages = st.one_of(
    st.builds(Hello, u8, u16, u16), st.just(Heartbeat()), st.just(AllOff()), st.just(Status()),
    _frames(wire.DRIVE_LEVEL, levels, 50), _frames(wire.DRIVE_TRAIN, trains, 50),
    st.lists(levels, max_size=400).map(lambda s: SetFrameFull(wire.DRIVE_LEVEL, tuple(s))),
    st.lists(trains, max_size=100).map(lambda s: SetFrameFull(wire.DRIVE_TRAIN, tuple(s))),
    st.builds(UploadBegin, u16, u16, st.sampled_from([1, 2])),
    _chunks(wire.DRIVE_LEVEL, levels), _chunks(wire.DRIVE_TRAIN, trains),
    st.builds(Trigger, u16, u64), st.builds(GetOnsets, u16, u16, u16),
    st.builds(HelloReply, u8, u8, u16, u16, u16, u16, u8, u8, u8, u16, u16, u16, u16, u16, u64,
              text, text),
    st.builds(Ack, u8, u64), st.builds(Nak, u8, u8, u16),
    st.builds(StatusReply, u8, u8, u16, u16, u64, u32, u32, u32, u16),
    st.builds(OnsetsReply, u8, u16, u16, st.lists(u64, max_size=60).map(tuple)),
    st.builds(Onset, u16, u16, u16, u64), st.builds(PlayDone, u16, u8, u16, u64),
    st.builds(Alarm, u8, u64),
)


@given(st.binary(max_size=1200))
def test_cobs_round_trip_and_no_zero(data):
    enc = wire.cobs_encode(data)
    assert 0 not in enc
    assert len(enc) <= len(data) + 1 + len(data) // 254
    assert wire.cobs_decode(enc) == data


@given(messages, u8)
def test_every_message_round_trips(msg, seq):
    frame = wire.encode(msg, seq)
    assert frame[0] == 0 and frame[-1] == 0 and 0 not in frame[1:-1]
    assert wire.decode_frame(frame[1:-1]) == (seq, msg)
    assert wire.message_from_dict(json.loads(json.dumps(msg.to_dict()))) == msg


@given(st.lists(st.tuples(messages, u8), min_size=1, max_size=6),
       st.lists(st.binary(max_size=40), min_size=7, max_size=7),
       st.integers(1, 64))
@settings(max_examples=150)
def test_reader_recovers_every_frame_between_garbage(msgs, garbage, chunk):
    """Garbage before, between and after frames: every frame still decodes, in order."""
    stream = b"".join(g + wire.encode(m, s) for (m, s), g in zip(msgs, garbage)) + garbage[-1]
    r = FrameReader()
    out = [x for i in range(0, len(stream), chunk) for x in r.feed(stream[i:i + chunk])]
    good = [x for x in out if isinstance(x, tuple)]
    assert good == [(s, m) for m, s in msgs]


@given(messages, u8, st.data())
@settings(max_examples=300)
def test_damaged_frames_never_decode_to_another_message(msg, seq, data):
    """Dropped, altered or inserted bytes: the frame is rejected or (if the damage
    missed it) comes out as sent; never as a different message. The next frame
    after the damage always decodes."""
    frame = bytearray(wire.encode(msg, seq))
    n = data.draw(st.integers(1, 4))
    for _ in range(n):
        op = data.draw(st.sampled_from(["drop", "flip", "insert"]))
        i = data.draw(st.integers(1, len(frame) - 1))
        if op == "drop":
            del frame[i]
        elif op == "flip":
            frame[i] ^= data.draw(st.integers(1, 255))
        else:
            frame.insert(i, data.draw(u8))
    nxt = wire.encode(Heartbeat(), 77)
    out = FrameReader().feed(bytes(frame) + nxt)
    good = [x for x in out if isinstance(x, tuple)]
    assert good[-1] == (77, Heartbeat())
    assert all(g == (seq, msg) for g in good[:-1])


def test_a_run_without_delimiter_is_dropped_and_counted():
    r = FrameReader(max_frame=64)
    out = r.feed(b"\x01" * 500 + wire.encode(AllOff(), 3))
    assert out[-1] == (3, AllOff())
    assert [e.kind for e in out[:-1]] == ["bad_frame"]


@pytest.mark.parametrize("msg, what", [
    (SetFrame(wire.DRIVE_LEVEL, ((0, Level(256)),)), "level=256"),
    (SetFrame(wire.DRIVE_LEVEL, ((70000, Level(1)),)), "actuator index=70000"),
    (SetFrame(wire.DRIVE_LEVEL, ((0, Train(1, 1, 1)),)), "Train setting in a message of drive"),
    (SetFrame(3, ()), "unknown drive kind 3"),
    (SetFrame(wire.DRIVE_LEVEL, ((0, Level(1)),) * 65536), "number of changes=65536"),
    (Trigger(1, -5), "at_us=-5"),
    (Hello(256), "protocol=256"),
    (UploadChunk(1, 0, wire.DRIVE_TRAIN, (WirePulse(2, 0, 10, Train(1, 2, 1.5)),)),
     r"pulses\[0\] width_us=1.5"),
    (OnsetsReply(1, 1, 0, (5, 2**64)), r"times_us\[1\]=18446744073709551616"),
    (HelloReply(0, 1, 200, 200, 8, 6, 2, 1, 2, 0, 0, 0, 4096, 1024, 0, "x" * 256, ""),
     "firmware: text of 256 bytes; at most 255 fit"),
])
def test_values_that_do_not_fit_are_refused_when_encoding(msg, what):
    with pytest.raises(wire.PayloadError, match=what):
        wire.encode(msg, 0)


def test_status_counters_wrap_at_their_width():
    big = StatusReply(1, 0, 0, 0, 0, 2**32 + 5, 2**32, 7, 2**16 + 3)
    wrapped = StatusReply(1, 0, 0, 0, 0, 5, 0, 7, 3)
    assert wire.decode_frame(wire.encode(big, 0)[1:-1]) == (0, wrapped)


@pytest.mark.parametrize("mtype, payload, what", [
    (Hello.TYPE, "01c8", "HELLO: payload too short (2 bytes)"),
    (Heartbeat.TYPE, "00", "HEARTBEAT: 1 unexpected trailing bytes"),
    (SetFrame.TYPE, "0301000000", "SET_FRAME: unknown drive kind 3"),
    (SetFrame.TYPE, "01", "SET_FRAME: payload too short (1 bytes)"),
    (SetFrame.TYPE, "0102000001", "SET_FRAME: payload too short (5 bytes)"),
    (SetFrame.TYPE, "01010000000101", "SET_FRAME: 1 unexpected trailing bytes"),
    (SetFrameFull.TYPE, "020102", "SET_FRAME_FULL: payload is not a whole number of settings"),
    (UploadChunk.TYPE, "0100000001" + "00" * 10, "UPLOAD_CHUNK: payload is not a whole number "
     "of pulses"),
    (UploadChunk.TYPE, "0100000009", "UPLOAD_CHUNK: unknown drive kind 9"),
    (OnsetsReply.TYPE, "0001000000" + "00" * 7, "ONSETS_REPLY: payload is not a whole number "
     "of times"),
    (HelloReply.TYPE, "00" * 31 + "01ff00", "HELLO_REPLY: text is not UTF-8"),
    (HelloReply.TYPE, "00" * 31 + "05414243", "HELLO_REPLY: payload too short (35 bytes)"),
])
def test_malformed_payloads_say_what_is_wrong(mtype, payload, what):
    body = bytes([wire.PROTOCOL_VERSION, mtype, 9]) + bytes.fromhex(payload)
    with pytest.raises(wire.PayloadError) as e:
        wire.decode_frame(wire.cobs_encode(body + wire.CRC.pack(wire.crc32(body))))
    assert str(e.value) == what and e.value.seq == 9


def test_sizes_are_the_bytes_on_the_wire():
    assert (Level.SIZE, Train.SIZE) == (1, 6)
    for drive, setting in ((wire.DRIVE_LEVEL, Level(1)), (wire.DRIVE_TRAIN, Train(1, 2, 3))):
        chunk = UploadChunk(1, 0, drive, (WirePulse(0, 0, 1, setting),) * 3)
        assert len(chunk.pack()) == 5 + 3 * UploadChunk.pulse_size(drive)
        assert UploadChunk.pulse_size(drive) == 10 + setting.SIZE


def test_requests_and_replies_are_the_messages_docs_protocol_lists_as_such():
    requests = {n for n, cls in wire.MESSAGES_BY_NAME.items() if cls.REQUEST}
    replies = {n for n, cls in wire.MESSAGES_BY_NAME.items() if cls.REPLY}
    assert requests == {"Hello", "Heartbeat", "AllOff", "SetFrame", "SetFrameFull", "UploadBegin",
                        "UploadChunk", "Trigger", "Status", "GetOnsets", "Bye"}
    assert replies == {"HelloReply", "Ack", "Nak", "StatusReply", "OnsetsReply"}


def test_describe_is_one_readable_line():
    line = wire.describe(SetFrame(1, ((3, Level(2)), (4, Level(0)))))
    assert line == "SetFrame #3=L2, #4=L0"
    assert "BAD_FRAME" in wire.describe(Nak(0, wire.NakReason.BAD_FRAME))
