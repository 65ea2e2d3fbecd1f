"""Write ``v1_vectors.json``: the byte-exact test vectors of wire protocol v1.

The file is the protocol's reference, shared by the codec tests
(``tests/test_wire.py``), the firmware/emulator tests
(``tests/test_emulator.py``) and anyone writing firmware in another language.
v1 is frozen: running this must reproduce the committed file exactly
(``tests/test_wire.py`` checks it). A change of bytes is a new protocol
version, with a new file.

- ``crc32_check`` and ``cobs``: independent references (the CRC-32 check value;
  the COBS examples of the Wikipedia article and Cheshire & Baker 1999).
- ``frames``: one message of each type: its fields, the bytes before COBS
  (``raw``) and on the wire (``wire``, both delimiters included).
- ``bad_frames``: bytes that must be rejected, and why.
- ``streams``: a byte stream with garbage, lost and corrupted bytes, and the
  messages a receiver must still recover from it, in order.
- ``conversations``: a device built to a shipped profile, fed host bytes at
  given device times; the bytes it must answer, exactly.

Usage: python protocols/wire/make_vectors.py [OUT.json]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))

from vtexp.devices import wire
from vtexp.devices.firmware import Firmware, FirmwareConfig
from vtexp.devices.wire import (
    Ack,
    Alarm,
    AllOff,
    Bye,
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
from vtexp.model import DeviceProfile

# Wikipedia, "Consistent Overhead Byte Stuffing", examples 1-11 (hex, decoded -> encoded).
COBS = [
    ("00", "0101"),
    ("0000", "010101"),
    ("001100", "01021101"),
    ("11220033", "03112202 33".replace(" ", "")),
    ("11223344", "0511223344"),
    ("11000000", "02110101 01".replace(" ", "")),
    ("".join(f"{i:02x}" for i in range(1, 255)), "ff" + "".join(f"{i:02x}" for i in range(1, 255))),
    ("".join(f"{i:02x}" for i in range(255)),
     "01ff" + "".join(f"{i:02x}" for i in range(1, 255))),
    ("".join(f"{i:02x}" for i in range(1, 256)),
     "ff" + "".join(f"{i:02x}" for i in range(1, 255)) + "02ff"),
    ("".join(f"{i:02x}" for i in range(2, 256)) + "00",
     "ff" + "".join(f"{i:02x}" for i in range(2, 256)) + "0101"),
    ("".join(f"{i:02x}" for i in range(3, 256)) + "0001",
     "fe" + "".join(f"{i:02x}" for i in range(3, 256)) + "0201"),
]

FRAMES = [
    ("hello", 0, Hello(1, 200, 200)),
    ("heartbeat", 1, Heartbeat()),
    ("all_off", 2, AllOff()),
    ("set_frame_levels", 3, SetFrame(1, ((0, Level(2)), (5, Level(0)), (399, Level(10))))),
    ("set_frame_train", 4, SetFrame(2, ((12, Train(2000, 4000, 1000)),))),
    ("set_frame_full_vest", 5, SetFrameFull(1, tuple(Level(i % 3) for i in range(48)))),
    ("upload_begin", 6, UploadBegin(7, 2, 1)),
    ("upload_chunk", 7, UploadChunk(7, 0, 1, (WirePulse(0, 0, 300_000, Level(2)),
                                             WirePulse(1, 200_000, 300_000, Level(1))))),
    ("trigger_now", 8, Trigger(7, 0)),
    ("trigger_at", 9, Trigger(7, 1_234_567_890)),
    ("status", 10, Status()),
    ("get_onsets", 11, GetOnsets(7, 0, 2)),
    ("bye", 12, Bye()),
    ("hello_reply", 0, HelloReply(0, 1, 200, 200, 8, 6, 2, 1, 2, 0, 0, 0, 4096, 1024, 1000,
                                  "vtexp-emulator 0.1.0", "emulated vest_6x8")),
    ("ack", 1, Ack(1, 5000)),
    ("nak_bad_frame", 2, Nak(0, 1, 0)),
    ("nak_out_of_range", 3, Nak(3, 7, 399)),
    ("status_reply", 4, StatusReply(10, 0, 7, 2, 9_000_000, 12, 1, 0, 0)),
    ("onsets_reply", 5, OnsetsReply(11, 7, 0, (1_000_000, 1_200_000))),
    ("onset", 6, Onset(7, 0, 1, 1_000_000)),
    ("play_done", 7, PlayDone(7, 0, 2, 1_500_000)),
    ("alarm_watchdog", 8, Alarm(1, 2_000_000)),
    ("max_seq", 255, Heartbeat()),
]


def frames() -> list[dict]:
    return [{"name": n, "seq": seq, "message": m.to_dict(),
             "raw": wire.frame_body(m, seq).hex(), "wire": wire.encode(m, seq).hex()}
            for n, seq, m in FRAMES]


def bad_frames() -> list[dict]:
    good = wire.encode(Heartbeat(), 1)[1:-1]
    raw = wire.frame_body(Heartbeat(), 1)
    flipped = bytearray(good)
    flipped[2] ^= 0x40
    v2 = bytes([2]) + raw[1:-4]
    v2 = v2 + wire.CRC.pack(wire.crc32(v2))
    unknown = bytes([1, 0x7E, 3])
    unknown = unknown + wire.CRC.pack(wire.crc32(unknown))
    short = bytes([1, 2, 3])
    trunc_payload = bytes([1, Hello.TYPE, 4, 1, 200])        # HELLO needs 5 payload bytes
    trunc_payload += wire.CRC.pack(wire.crc32(trunc_payload))
    return [
        {"name": "bit_flip", "wire": "00" + bytes(flipped).hex() + "00", "error": "bad_crc"},
        # A lost byte usually breaks the COBS block structure before the CRC is reached.
        {"name": "byte_lost", "wire": "00" + (good[:3] + good[4:]).hex() + "00",
         "error": "bad_cobs"},
        {"name": "cobs_runs_past_end", "wire": "00" + "05aabb" + "00", "error": "bad_cobs"},
        {"name": "too_short", "wire": "00" + wire.cobs_encode(short).hex() + "00",
         "error": "bad_frame"},
        {"name": "version_2", "wire": "00" + wire.cobs_encode(v2).hex() + "00",
         "error": "bad_version"},
        {"name": "unknown_type", "wire": "00" + wire.cobs_encode(unknown).hex() + "00",
         "error": "unknown_type"},
        {"name": "payload_too_short", "wire": "00" + wire.cobs_encode(trunc_payload).hex() + "00",
         "error": "bad_payload"},
    ]


def streams() -> list[dict]:
    a = wire.encode(Hello(1, 200, 200), 0)
    b = wire.encode(SetFrame(1, ((3, Level(1)),)), 1)
    c = wire.encode(AllOff(), 2)
    lost = b[:5] + b[6:]
    bad = bytearray(b)
    bad[6] ^= 0x01          # 0x01 -> 0x00: the corruption adds a delimiter, splitting the frame
    stream = b"\xff\xfe noise \x13\x11" + a + lost + bytes(bad) + b"\x01\x02" + c + b[:4]
    return [{"name": "garbage_lost_and_corrupted_bytes", "wire": stream.hex(),
             "messages": [{"seq": 0, "message": Hello(1, 200, 200).to_dict()},
                          {"seq": 2, "message": AllOff().to_dict()}],
             # the garbage, the frame with a lost byte, both halves of the split frame,
             # and the two garbage bytes before the last frame; the cut-off copy of b at
             # the end is not a frame yet (3 bytes pending)
             "n_errors": 5,
             "pending_bytes": 3}]


def conversations() -> list[dict]:
    out = []
    vest = FirmwareConfig.for_profile(DeviceProfile.load("vest_6x8"))

    def run(name: str, cfg: FirmwareConfig, steps: list[tuple[int, bytes | None]],
            note: str) -> None:
        now = [0]
        fw = Firmware(cfg, lambda: now[0])
        rec = []
        for t, host in steps:
            now[0] = t
            dev = fw.receive(host) if host is not None else fw.tick()
            rec.append({"t_us": t, "host": None if host is None else host.hex(),
                        "device": b"".join(dev).hex()})
        out.append({"name": name, "note": note, "config": cfg.__dict__, "steps": rec})

    e = wire.encode
    run("handshake_play_and_onsets", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        (2000, e(UploadBegin(1, 2, 1), 1)),
        (3000, e(UploadChunk(1, 0, 1, (WirePulse(0, 0, 300_000, Level(2)),
                                       WirePulse(1, 100_000, 300_000, Level(1)))), 2)),
        (4000, e(Trigger(1, 0), 3)),             # starts now: pulse 0 at 4000
        (50_000, e(Heartbeat(), 4)),
        (104_000, None),                          # pulse 1 due at 104000
        (150_000, e(Heartbeat(), 5)),
        (250_000, e(Heartbeat(), 6)),
        (304_000, None),                          # pulse 0 off
        (350_000, e(Heartbeat(), 7)),
        (404_000, None),                          # pulse 1 off: PLAY_DONE
        (405_000, e(GetOnsets(1, 0, 2), 8)),
    ], "upload two pulses, trigger, heartbeats keep the watchdog fed, onsets and done")
    run("retry_is_not_executed_twice", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        (2000, e(SetFrame(1, ((4, Level(2)),)), 1)),
        (3000, e(SetFrame(1, ((4, Level(2)),)), 1)),     # same seq and bytes: a retry
        (4000, e(SetFrame(1, ((4, Level(0)),)), 2)),
    ], "the second frame repeats seq 1: the cached ACK is sent again, nothing is driven")
    run("garbage_and_corruption_change_nothing", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        (2000, b"\x00\x13\x37\xaa\x00"),
        (3000, e(SetFrame(1, ((0, Level(2)),)), 1)[:-3] + b"\x55\x00"),
        (4000, e(SetFrame(1, ((0, Level(2)),)), 1)),
    ], "garbage and a corrupted frame are answered NAK BAD_FRAME; the clean resend acts")
    run("refusals", vest, [
        (1000, e(SetFrame(1, ((0, Level(1)),)), 0)),     # before HELLO
        (2000, e(Hello(1, 200, 200), 1)),
        (3000, e(SetFrame(1, ((48, Level(1)),)), 2)),    # index beyond 8x6
        (4000, e(SetFrame(1, ((0, Level(3)),)), 3)),     # level beyond the hardware's 2
        (5000, e(SetFrame(2, ((0, Train(2000, 4000, 1000)),)), 4)),   # wrong drive
        (6000, e(Trigger(9, 0), 5)),                    # nothing uploaded
        (7000, e(UploadBegin(2, 2, 1), 6)),
        (8000, e(UploadChunk(2, 1, 1, (WirePulse(0, 0, 1000, Level(1)),)), 7)),  # gap
        (9000, e(UploadChunk(2, 0, 1, (WirePulse(0, 5000, 1000, Level(1)),
                                      WirePulse(1, 0, 1000, Level(1)))), 8)),  # unsorted
    ], "each refusal names its reason; none changes an output")
    run("watchdog", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        (2000, e(SetFrame(1, ((0, Level(2)), (7, Level(1)))), 1)),
        (150_000, e(Heartbeat(), 2)),
        (350_000, None),                          # 200 ms after the last frame: not yet
        (350_001, None),                          # now: everything off, ALARM
        (360_000, e(Heartbeat(), 3)),             # late host: NO_SESSION
        (370_000, e(AllOff(), 4)),                # ALL_OFF works without a session
    ], "silence longer than watchdog_ms turns everything off and ends the session")
    run("bye", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        (2000, e(SetFrame(1, ((9, Level(1)),)), 1)),
        (3000, e(Bye(), 2)),                      # everything off, session over
        (500_000, None),                          # long silence: no watchdog alarm
        (501_000, e(Heartbeat(), 3)),             # NO_SESSION until the next HELLO
    ], "a host that says BYE leaves the device off and idle, without a watchdog alarm")

    # -- Added with the normative edition of docs/protocol.md: one conversation per point a
    # firmware author had to guess. The conversations above are unchanged.
    def raw_frame(version: int, mtype: int, seq: int, payload: bytes = b"") -> bytes:
        body = bytes([version, mtype, seq]) + payload
        return b"\x00" + wire.cobs_encode(body + wire.CRC.pack(wire.crc32(body))) + b"\x00"

    def upload(pid: int, pulses: list[WirePulse], seq: int, drive: int = 1,
               per: int = 64) -> list[bytes]:
        frames = [e(UploadBegin(pid, len(pulses), drive), seq)]
        for k in range(0, len(pulses), per):
            seq += 1
            frames.append(e(UploadChunk(pid, k, drive, tuple(pulses[k:k + per])), seq))
        return frames

    run("unreadable_frames_are_naked_and_feed_no_watchdog", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        (50_000, raw_frame(2, Heartbeat.TYPE, 1)),                 # another version
        (100_000, raw_frame(1, 0x7E, 5)),                          # unknown type
        (150_000, raw_frame(1, Hello.TYPE, 6, bytes([1, 200]))),   # payload too short
        (180_000, raw_frame(1, Ack.TYPE, 7, bytes(9))),            # a reply sent to the device
        (201_000, None),                                           # 200 ms after HELLO: not yet
        (201_001, None),                                           # the watchdog fires
        (202_000, e(Status(), 8)),
    ], "a frame the device cannot act on (other version: ack_seq 0; unknown or reply type; "
       "malformed payload: ack_seq = its seq) is counted in rx_bad and NAKed, never executed, "
       "and does not feed the watchdog")
    small = FirmwareConfig.for_profile(DeviceProfile.load("vest_6x8"), max_payload=63)
    run("longest_frame", small, [
        (1000, e(Hello(1, 200, 200), 0)),
        (2000, e(SetFrame(1, tuple((i, Level(1)) for i in range(20))), 1)),   # payload 63
        (3000, e(SetFrame(1, tuple((i, Level(0)) for i in range(21))), 2)),   # payload 66
        (4000, e(Status(), 3)),
    ], "a frame whose payload exceeds max_payload is unreadable: NAK BAD_FRAME, ack_seq 0")
    run("device_sequence_runs_on_across_sessions", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        (2000, e(Heartbeat(), 1)),
        (3000, e(Hello(1, 200, 200), 0)),
        (4000, e(Heartbeat(), 1)),
    ], "the device numbers its frames from 0 at power-on and never restarts: a new HELLO "
       "does not reset its sequence")
    long_pulse = [WirePulse(2, 0, 1_000_000, Level(2))]
    run("hello_bye_and_all_off_during_a_play", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        *[(2000 + k, f) for k, f in enumerate(upload(1, long_pulse, 1))],
        (3000, e(Trigger(1, 0), 3)),
        (100_000, e(Hello(1, 200, 200), 4)),                       # reply, then PLAY_DONE 1
        *[(101_000 + k, f) for k, f in enumerate(upload(2, long_pulse, 5))],
        (102_000, e(Trigger(2, 0), 7)),
        (150_000, e(AllOff(), 8)),                                 # ACK, then PLAY_DONE 1
        (151_000, e(Trigger(2, 0), 9)),                            # the schedule stays loaded
        (200_000, e(Bye(), 10)),                                   # ACK, then PLAY_DONE 1
        (201_000, e(Heartbeat(), 11)),
    ], "HELLO, ALL_OFF and BYE each stop a play: their reply first, then PLAY_DONE reason 1")
    two = [WirePulse(0, 0, 200_000, Level(1)), WirePulse(1, 100_000, 200_000, Level(2))]
    run("busy_during_a_play", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        *[(2000 + k, f) for k, f in enumerate(upload(3, two, 1))],
        (3000, e(Trigger(3, 0), 3)),
        (10_000, e(SetFrame(1, ((5, Level(1)),)), 4)),
        (20_000, e(SetFrameFull(1, tuple(Level(0) for _ in range(48))), 5)),
        (30_000, e(UploadBegin(4, 1, 1), 6)),
        (40_000, e(UploadChunk(3, 0, 1, (WirePulse(0, 0, 1000, Level(1)),)), 7)),
        (50_000, e(Trigger(3, 0), 8)),
        (60_000, e(Heartbeat(), 9)),
        (70_000, e(Status(), 10)),
        (80_000, e(GetOnsets(3, 0, 2), 11)),
        (103_000, None),
        (150_000, e(Status(), 12)),
        (303_000, None),
        (304_000, e(Status(), 13)),
    ], "while a play is in progress (armed or playing) SET_FRAME, SET_FRAME_FULL, "
       "UPLOAD_BEGIN and TRIGGER are refused BUSY (detail = the play); UPLOAD_CHUNK finds no "
       "upload; HEARTBEAT, STATUS, GET_ONSETS, ALL_OFF, HELLO and BYE are served")
    one = [WirePulse(4, 0, 50_000, Level(2))]
    run("one_schedule_slot", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        *[(2000 + k, f) for k, f in enumerate(upload(1, one, 1))],
        (3000, e(UploadBegin(2, 1, 1), 3)),                        # forgets schedule 1
        (4000, e(Trigger(1, 0), 4)),
        (5000, e(Trigger(2, 0), 5)),                               # not complete yet
        (6000, e(UploadChunk(2, 0, 1, tuple(one)), 6)),
        (7000, e(Trigger(2, 0), 7)),
    ], "the device holds one schedule: UPLOAD_BEGIN forgets the previous one, complete or "
       "not; only a complete upload can be triggered")
    run("upload_refusals", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        (2000, e(UploadBegin(3, 3, 1), 1)),
        (3000, e(UploadChunk(4, 0, 1, (WirePulse(0, 0, 1000, Level(1)),)), 2)),
        (4000, e(UploadChunk(3, 0, 2, (WirePulse(0, 0, 1000, Train(1000, 4000, 1000)),)), 3)),
        (5000, e(UploadChunk(3, 0, 1, tuple(WirePulse(i, 0, 1000, Level(1))
                                             for i in range(4))), 4)),
        (6000, e(UploadChunk(3, 0, 1, (WirePulse(7, 0, 0, Level(1)),)), 5)),
        (7000, e(UploadChunk(3, 0, 1, (WirePulse(9, 0xFFFF_0000, 0x10000, Level(1)),)), 6)),
        (8000, e(UploadChunk(3, 0, 1, (WirePulse(0, 5000, 1000, Level(1)),)), 7)),
        (9000, e(UploadChunk(3, 2, 1, (WirePulse(1, 6000, 1000, Level(1)),)), 8)),
        (10_000, e(UploadChunk(3, 1, 1, (WirePulse(1, 1000, 1000, Level(1)),)), 9)),
        (11_000, e(UploadChunk(3, 1, 1, (WirePulse(1, 5000, 1000, Level(1)),
                                         WirePulse(2, 9000, 1000, Level(2)))), 10)),
        (12_000, e(UploadChunk(3, 3, 1, (WirePulse(1, 9000, 1000, Level(1)),)), 11)),
        (13_000, e(UploadBegin(5, 4097, 1), 12)),
    ], "refusals of an upload, checked in this order: NO_SCHEDULE (other play_id), "
       "WRONG_DRIVE, OUT_OF_ORDER (first is not the count received; detail = expected), "
       "TOO_LARGE (more than announced), then per pulse OUT_OF_RANGE (actuator, setting, "
       "duration 0, or an end past 2^32-1 us; detail = actuator) and OUT_OF_ORDER (onset "
       "before the previous one, across chunks; detail = pulse number). A refused chunk "
       "leaves the upload as it was; a complete upload takes no more chunks")
    late = [WirePulse(0, 0, 10_000, Level(1))]
    run("trigger_times", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        *[(2000 + k, f) for k, f in enumerate(upload(6, late, 1))],
        (5000, e(Trigger(6, 4000), 3)),                            # in the past: at once
        (15_000, None),
        (20_000, e(Trigger(6, 50_000), 4)),                        # in the future: armed
        (30_000, e(Status(), 5)),
        (50_000, None),
        (60_000, None),
    ], "TRIGGER at a time already past starts at once; at a future time the play is armed "
       "until then; the ACK carries the start")
    overlap = [WirePulse(0, 0, 100_000, Level(1)), WirePulse(0, 50_000, 100_000, Level(2)),
               WirePulse(5, 60_000, 10_000, Level(1))]
    run("overlap_and_a_late_tick", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        *[(2000 + k, f) for k, f in enumerate(upload(7, overlap, 1))],
        (3000, e(Trigger(7, 0), 3)),
        (73_000, e(Heartbeat(), 4)),          # late: the onsets due at 53000 and 63000 and
                                              # the offset at 73000 are applied together
        (103_000, None),                      # pulse 0 ends: actuator 0 stays on (pulse 1)
        (153_000, None),
        (154_000, e(GetOnsets(7, 0, 3), 5)),
    ], "where pulses overlap on an actuator the latest started drives it; instants found "
       "due together are applied together and reported in one ONSET with the time the "
       "outputs changed")
    run("an_empty_schedule_finishes", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        (2000, e(UploadBegin(8, 0, 1), 1)),
        (3000, e(Trigger(8, 0), 2)),                               # ACK, then PLAY_DONE
        (4000, e(SetFrame(1, ((1, Level(1)),)), 3)),
        (5000, e(Trigger(8, 20_000), 4)),
        (10_000, e(Status(), 5)),
        (20_000, None),
        (21_000, e(Status(), 6)),
    ], "a schedule of no pulses finishes at its start: PLAY_DONE with 0 onsets, and the "
       "device is idle again")
    run("watchdog_limits", vest, [
        (1000, e(Hello(1, 0, 0), 0)),                              # clamped up to 20 ms
        (21_000, None),
        (21_001, None),
        (30_000, e(Hello(1, 60_000, 60_000), 1)),                  # clamped down to 10 s
    ], "heartbeat and watchdog periods are clamped to the device's limits (20-10000 ms "
       "here): 0 never disables the watchdog")
    once = [WirePulse(3, 0, 5_000, Level(1))]
    run("a_resend_after_another_request_is_a_new_request", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        *[(2000 + k, f) for k, f in enumerate(upload(9, once, 1))],
        (3000, e(Trigger(9, 0), 3)),
        (8000, None),
        (9000, e(GetOnsets(9, 0, 1), 4)),
        (10_000, e(GetOnsets(9, 0, 1), 4)),                        # retry: the cached reply
        (11_000, e(Heartbeat(), 5)),
        (12_000, e(Trigger(9, 0), 3)),                             # old bytes: played again
        (17_000, None),
    ], "the reply cache holds the last request only: a resend is recognised only before "
       "any other request, so a host MUST resend its request in flight before anything "
       "else; the same bytes sent later are a new request and are executed")
    tiny = FirmwareConfig.for_profile(DeviceProfile.load("vest_6x8"), max_payload=45)
    eight = [WirePulse(i, i * 1000, 500, Level(1)) for i in range(8)]
    run("get_onsets_limits", tiny, [
        (1000, e(Hello(1, 200, 200), 0)),
        *[(2000 + k, f) for k, f in enumerate(upload(10, eight, 1, per=3))],
        (3000, e(Trigger(10, 0), 5)),
        *[(3000 + i * 1000, None) for i in range(1, 8)],
        (10_500, None),
        (11_000, e(GetOnsets(10, 0, 8), 6)),                       # (45 - 5) // 8 = 5 times
        (12_000, e(GetOnsets(10, 5, 8), 7)),                       # the other 3
        (13_000, e(GetOnsets(10, 8, 1), 8)),                       # past the end: none
        (14_000, e(GetOnsets(11, 0, 1), 9)),                       # another play
        (15_000, e(Hello(1, 200, 200), 10)),
        (16_000, e(GetOnsets(10, 0, 1), 11)),                      # forgotten with the session
    ], "GET_ONSETS answers at most (max_payload - 5) / 8 times, from the first asked, and "
       "none past the end; onsets are kept for the play in progress or the last one, until "
       "the next TRIGGER or HELLO")
    run("frame_details", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        (2000, e(SetFrame(1, ((2, Level(1)), (2, Level(2)))), 1)),   # the last one counts
        (3000, e(SetFrame(1, ()), 2)),                                # nothing to change
        (4000, e(SetFrameFull(1, tuple(Level(0) for _ in range(47))), 3)),
        (5000, raw_frame(1, SetFrame.TYPE, 4, bytes([3, 1, 0, 0, 0, 1]))),  # drive kind 3
    ], "a frame's changes apply in order (a repeated actuator takes its last setting); an "
       "empty SET_FRAME is acknowledged; SET_FRAME_FULL needs exactly one setting per "
       "actuator (BAD_PAYLOAD, detail = actuators); an unknown drive kind is a malformed "
       "payload")
    sma = FirmwareConfig.for_profile(DeviceProfile.load("sma_5x5"))
    run("pulse_train_limits", sma, [
        (1000, e(Hello(1, 200, 200), 0)),
        (2000, e(SetFrame(2, ((0, Train(2000, 5000, 1500)),)), 1)),   # 1.5 ms at 50 Hz
        (3000, e(SetFrame(2, ((1, Train(2000, 0, 1000)),)), 2)),      # no frequency
        (4000, e(SetFrame(2, ((2, Train(2000, 4000, 0)),)), 3)),      # no width
        (5000, e(SetFrame(2, ((3, Train(2001, 4000, 1000)),)), 4)),   # beyond the amplitude
        (6000, e(SetFrame(2, ((0, Train(0, 0, 0)), (4, Train(0, 9999, 9999)))), 5)),  # off
    ], "a train is within the hardware if amplitude, frequency and width are within the "
       "ceilings, frequency and width are not 0, and a pulse is shorter than its period "
       "(width_us * frequency_chz < 10^8); amplitude 0 is off, whatever the rest")

    # -- Added with the edition that settles the 13 points a second author still had to
    # guess (docs/protocol.md, "Changes in this edition"). Nothing above changes.
    v2_bad_crc = bytearray(raw_frame(2, Heartbeat.TYPE, 3))
    v2_bad_crc[-2] ^= 0x01 if v2_bad_crc[-2] != 0x01 else 0x03
    run("checks_of_a_frame_in_order", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        (2000, bytes(v2_bad_crc)),                                  # CRC before version
        (3000, raw_frame(2, 0x7E, 4)),                              # version before type
        (4000, raw_frame(1, 0x7E, 5, bytes([1]))),                  # type before payload
        (5000, raw_frame(1, SetFrame.TYPE, 6, bytes([3, 1, 0, 0, 0, 1]))),  # unknown drive
        (6000, e(Status(), 7)),
    ], "a frame's checks run in this order, the first failure answering: COBS and length, "
       "CRC, version, type, payload form. A version-2 frame with a bad CRC is BAD_FRAME; "
       "with a good CRC, BAD_VERSION")
    run("a_refused_request_is_answered_from_the_cache", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        (2000, e(SetFrame(1, ((48, Level(1)),)), 1)),               # OUT_OF_RANGE
        (3000, b"\x00\x13\x37\xaa\x00"),                           # an unreadable frame
        (4000, e(SetFrame(1, ((48, Level(1)),)), 1)),               # retry: the same NAK
        (5000, e(Status(), 2)),
    ], "a refused valid request's NAK is its reply: it enters the reply cache, and a retry "
       "hears it again from the cache (counted in duplicates). A NAK to an unreadable frame "
       "is not a reply and leaves the cache as it was")
    busy_one = [WirePulse(0, 0, 50_000, Level(1))]
    run("checks_of_set_frame_and_upload_begin_in_order", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        *[(2000 + k, f) for k, f in enumerate(upload(1, busy_one, 1))],
        (3000, e(Trigger(1, 0), 3)),
        (4000, e(SetFrame(2, ((99, Train(9999, 1, 1)),)), 4)),     # BUSY before all else
        (5000, e(UploadBegin(2, 5000, 2), 5)),                      # BUSY before all else
        (53_000, None),
        (54_000, e(SetFrame(2, ((99, Train(9999, 1, 1)),)), 6)),   # WRONG_DRIVE before range
        (55_000, e(SetFrameFull(2, tuple(Train(0, 0, 0) for _ in range(47))), 7)),
        (56_000, e(SetFrameFull(1, tuple(Level(3) for _ in range(47))), 8)),  # count, range
        (57_000, e(UploadBegin(2, 5000, 2), 9)),                    # WRONG_DRIVE before size
        (58_000, e(UploadBegin(2, 1, 3), 10)),                      # drive kind 3
        (59_000, e(UploadBegin(2, 1, 0), 11)),                      # drive kind 0
        (60_000, e(Status(), 12)),
    ], "SET_FRAME and SET_FRAME_FULL are checked BUSY, WRONG_DRIVE, the count of a full "
       "frame (BAD_PAYLOAD, detail = actuators), then each change (OUT_OF_RANGE); "
       "UPLOAD_BEGIN is checked BUSY, WRONG_DRIVE, TOO_LARGE. UPLOAD_BEGIN's payload has one "
       "length whatever its drive, so an unknown drive kind there (0, 3) is WRONG_DRIVE, a "
       "refused valid request")
    run("a_request_at_exactly_watchdog_ms_is_in_time", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        (201_000, e(Heartbeat(), 1)),                               # exactly 200 ms: in time
        (401_000, None),                                            # exactly 200 ms: no trip
        (401_001, None),                                            # more than 200 ms: trips
    ], "the watchdog trips when more than watchdog_ms has passed since the last valid "
       "request; a request after exactly watchdog_ms of silence is in time")
    run("a_full_frame_of_the_wrong_count_is_a_valid_request", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        (150_000, e(SetFrameFull(1, tuple(Level(0) for _ in range(47))), 1)),
        (350_000, None),                                            # fed at 150000: no trip
        (350_001, None),
        (351_000, e(Status(), 2)),
    ], "a SET_FRAME_FULL whose settings are whole but not one per actuator is a refused "
       "valid request (BAD_PAYLOAD, detail = actuators): counted in rx_frames, it feeds the "
       "watchdog and its NAK is cached")
    run("a_refused_hello_changes_nothing", vest, [
        (1000, e(Hello(0, 200, 200), 0)),                           # no session opened
        (2000, e(Heartbeat(), 1)),
        (3000, e(Hello(1, 200, 200), 2)),
        *[(4000 + k, f) for k, f in enumerate(upload(1, busy_one, 3))],
        (5000, e(Trigger(1, 0), 5)),
        (6000, e(Hello(0, 500, 500), 6)),                           # the play goes on
        (7000, e(Status(), 7)),
        (55_000, None),                                             # and finishes
        (56_000, e(Heartbeat(), 8)),
    ], "a HELLO refused UNSUPPORTED_PROTOCOL (protocol 0) changes nothing: no session is "
       "opened or ended, no play stops, no output changes, the periods stay; as a valid "
       "request it feeds the watchdog of a session in progress")
    two_more = [WirePulse(1, 0, 1000, Level(1)), WirePulse(2, 1000, 1000, Level(1))]
    run("a_refused_upload_begin_keeps_the_schedule", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        *[(2000 + k, f) for k, f in enumerate(upload(1, busy_one, 1))],
        (3000, e(UploadBegin(2, 5000, 1), 3)),                      # TOO_LARGE
        (4000, e(UploadBegin(2, 1, 2), 4)),                         # WRONG_DRIVE
        (5000, e(Trigger(1, 0), 5)),                                # schedule 1 is still there
        (55_000, None),
        (56_000, e(UploadBegin(3, 2, 1), 6)),
        (57_000, e(UploadChunk(3, 0, 1, (two_more[0],)), 7)),
        (58_000, e(UploadBegin(4, 5000, 1), 8)),                    # refused mid-upload
        (59_000, e(UploadChunk(3, 1, 1, (two_more[1],)), 9)),       # the upload goes on
        (60_000, e(Trigger(3, 0), 10)),
    ], "a refused UPLOAD_BEGIN changes nothing: the loaded schedule stays loaded and an "
       "upload in progress goes on")
    run("get_onsets_from_far_past_the_end", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        *[(2000 + k, f) for k, f in enumerate(upload(1, busy_one, 1))],
        (3000, e(Trigger(1, 0), 3)),
        (53_000, None),
        (54_000, e(GetOnsets(1, 1, 5), 4)),                         # first = pulses
        (55_000, e(GetOnsets(1, 0xFFFF, 0xFFFF), 5)),               # far past
        (56_000, e(GetOnsets(1, 0, 0), 6)),                         # count 0
    ], "k = max(0, min(count, pulses - first, (max_payload - 5) / 8)): from first at or "
       "past the last pulse, and for count 0, an ONSETS_REPLY with no times")
    mid = [WirePulse(0, 0, 20_000, Level(1)), WirePulse(1, 10_000, 20_000, Level(2))]
    run("a_frame_and_a_due_instant_in_one_step", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        *[(2000 + k, f) for k, f in enumerate(upload(1, mid, 1))],
        (3000, e(Trigger(1, 0), 3)),                                # pulse 0 on at 3000
        (13_000, e(Status(), 4)),                                   # pulse 1 due now: after
        (14_000, e(GetOnsets(1, 0, 2), 5)),
        (23_000, e(Trigger(1, 0), 6)),                              # pulse 0 ends now: BUSY
        (33_000, e(AllOff(), 7)),                                   # pulse 1 ends now: stopped
        (34_000, e(Status(), 8)),
    ], "where a frame arrives at the instant something is due, the watchdog is judged "
       "first, then the frame is handled, then what is due is applied: the reply says the "
       "state before the instant, the instant's events follow it, and a play the frame "
       "stops applies nothing more")
    run("the_watchdog_before_a_frame_and_a_due_instant", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        *[(2000 + k, f) for k, f in enumerate(upload(1, [WirePulse(0, 0, 150_000, Level(1)),
                                                        WirePulse(1, 150_000, 10_000,
                                                                  Level(1))], 1))],
        (4000, e(Trigger(1, 0), 3)),
        (210_000, e(Heartbeat(), 4)),        # too late: the deadline passed at 204000,
                                             # before the end and onset due at 154000
        (211_000, e(Status(), 5)),
    ], "the watchdog is judged before anything else in a step: a frame that arrives after "
       "the deadline is too late, and instants due before it but not yet applied are not "
       "applied: PLAY_DONE reason 2 and ALARM, then the frame's NAK NO_SESSION")
    run("onsets_after_a_watchdog_trip", vest, [
        (1000, e(Hello(1, 200, 200), 0)),
        *[(2000 + k, f) for k, f in enumerate(upload(1, [WirePulse(0, 0, 100_000, Level(1)),
                                                        WirePulse(1, 300_000, 10_000,
                                                                  Level(1))], 1))],
        (4000, e(Trigger(1, 0), 3)),
        (104_000, None),
        (204_001, None),                                            # the watchdog trips
        (210_000, e(Status(), 4)),                                  # no session; play kept
        (211_000, e(GetOnsets(1, 0, 2), 5)),                        # served without a session
        (212_000, e(Heartbeat(), 6)),
        (213_000, e(Hello(1, 200, 200), 7)),
        (214_000, e(GetOnsets(1, 0, 2), 8)),                        # forgotten with HELLO
    ], "GET_ONSETS is served without a session, like STATUS: after a watchdog trip the "
       "host recovers the interrupted play's onsets (never guessed) before its HELLO "
       "forgets them")
    return out


def build() -> dict:
    return {
        "protocol": wire.PROTOCOL_VERSION,
        "about": "vtexp wire protocol v1 test vectors; see docs/protocol.md. Bytes in hex.",
        "crc32_check": {"ascii": "123456789", "crc32": "cbf43926"},
        "cobs": [{"decoded": d, "encoded": e} for d, e in COBS],
        "frames": frames(),
        "bad_frames": bad_frames(),
        "streams": streams(),
        "conversations": conversations(),
    }


def main() -> None:
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else HERE / "v1_vectors.json"
    out.write_text(json.dumps(build(), indent=1) + "\n", encoding="utf-8")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
