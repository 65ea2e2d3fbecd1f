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
