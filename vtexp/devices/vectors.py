"""Replay ``protocols/wire/v1_vectors.json`` against a firmware's vector runner.

The reference firmware has a vector runner (``firmware/runner/``): its core with a
fake clock behind a line protocol. It runs on this computer (``vtexp-fw-vectors``,
on stdin and stdout) and on the ATmega2560 (``vtexp-fw-vectors.elf``, on its UART:
in simavr, or flashed on a board). :func:`replay` feeds it every vector and
returns what differs, byte for byte; a firmware ported to another chip passes the
same way (docs/firmware.md, "Porting the core").
"""

from __future__ import annotations

import json
import subprocess
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from ..errors import DeviceError
from ..resources import protocols_dir
from . import wire

CONFIG_FIELDS = ("rows", "cols", "actuator", "drive", "max_level", "max_amplitude_mv",
                 "max_frequency_chz", "max_width_us", "max_pulses", "max_payload",
                 "min_watchdog_ms", "max_watchdog_ms")


def load_vectors(path: Path | None = None) -> dict:
    p = path or protocols_dir() / "wire" / "v1_vectors.json"
    return json.loads(p.read_text(encoding="utf-8"))


def config_line(cfg: dict) -> str:
    texts = [cfg[k].encode("utf-8").hex() or "-" for k in ("firmware", "device_id")]
    return "config " + " ".join(str(cfg[k]) for k in CONFIG_FIELDS) + " " + " ".join(texts)


@dataclass(frozen=True)
class Mismatch:
    section: str
    name: str
    detail: str


def _decoded(hex_bytes: str) -> str:
    r = wire.FrameReader()
    items = r.feed(bytes.fromhex(hex_bytes)) if hex_bytes and hex_bytes[0] != "!" else []
    return "; ".join(wire.describe(x[1]) if isinstance(x, tuple) else f"bad frame ({x.kind})"
                     for x in items) or "(nothing)"


@dataclass(frozen=True)
class VectorResult:
    """One vector (or one group of them: the CRC check, the COBS examples, the frames)
    replayed against a runner: how many checks it made, and what differed (None if
    nothing)."""

    section: str
    name: str
    checks: int
    mismatch: str | None = None


def check_each(cmd: Callable[[str], str], vectors: dict | None = None
               ) -> Iterator[VectorResult]:
    """Feed every vector to a runner (``cmd`` sends one command line and returns the answer
    line), yielding one result per conversation, bad frame and stream, and one each for
    the CRC check, the COBS examples and the frames."""
    v = vectors or load_vectors()

    def answer(line: str) -> str:
        a = cmd(line)
        return a[2:] if a.startswith("= ") else a

    # CRC and COBS: the core's own functions
    got = answer("crc " + v["crc32_check"]["ascii"].encode().hex())
    yield VectorResult("crc32_check", "123456789", 1,
                       None if got == v["crc32_check"]["crc32"] else f"got {got}")
    bad: list[str] = []
    for k, c in enumerate(v["cobs"]):
        if answer(f"cobs {c['decoded'] or '-'}") != c["encoded"]:
            bad.append(f"example {k + 1}: encoding differs")
        if answer(f"uncobs {c['encoded']}") != c["decoded"]:
            bad.append(f"example {k + 1}: decoding differs")
    yield VectorResult("cobs", "examples", 2 * len(v["cobs"]), "; ".join(bad) or None)
    # every message type through the core's encoder
    bad = []
    for f in v["frames"]:
        raw = bytes.fromhex(f["raw"])
        got = answer(f"frame {raw[1]} {raw[2]} {raw[3:-4].hex() or '-'}")
        if got != f["wire"]:
            bad.append(f"{f['name']}: wire {got}, expected {f['wire']}")
    yield VectorResult("frames", "one of each type", len(v["frames"]), "; ".join(bad) or None)
    # the device's conversations, byte for byte, at the vectors' device times
    for conv in v["conversations"]:
        if cmd(config_line(conv["config"])) != "ok":
            yield VectorResult("conversations", conv["name"], 1, "config refused")
            continue
        n, why = 0, None
        for step in conv["steps"]:
            n += 1
            line = (f"at {step['t_us']} {step['host']}" if step["host"] else
                    f"tick {step['t_us']}")
            got = answer(line)
            if got != step["device"]:
                why = (f"at t={step['t_us']} us: answered {_decoded(got)}; "
                       f"expected {_decoded(step['device'])}")
                break
        yield VectorResult("conversations", conv["name"], n, why)
    # unreadable frames and resynchronisation, through a device with no session
    vest = v["conversations"][0]["config"]
    for bf in v["bad_frames"]:
        cmd(config_line(vest))
        reply = wire.FrameReader().feed(bytes.fromhex(answer(f"at 1000 {bf['wire']}")))
        naks = [m for _, m in (x for x in reply if isinstance(x, tuple))
                if isinstance(m, wire.Nak)]
        want = {"bad_crc": wire.NakReason.BAD_FRAME, "bad_cobs": wire.NakReason.BAD_FRAME,
                "bad_frame": wire.NakReason.BAD_FRAME, "bad_version": wire.NakReason.BAD_VERSION,
                "unknown_type": wire.NakReason.UNKNOWN_TYPE,
                "bad_payload": wire.NakReason.BAD_PAYLOAD}[bf["error"]]
        yield VectorResult("bad_frames", bf["name"], 1,
                           None if [x.reason for x in naks] == [want] else f"answered {naks}")
    for s in v["streams"]:
        cmd(config_line(vest))
        out = [m for x in wire.FrameReader().feed(bytes.fromhex(answer(f"at 1000 {s['wire']}")))
               if isinstance(x, tuple) for m in [x[1]]]
        naks = [m for m in out if isinstance(m, wire.Nak)]
        replies = [(type(m).__name__, m.ack_seq) for m in out if not isinstance(m, wire.Nak)]
        wanted = [("HelloReply", 0), ("Ack", 2)]
        ok = len(naks) == s["n_errors"] and replies == wanted
        yield VectorResult("streams", s["name"], 1,
                           None if ok else f"{len(naks)} NAKs and replies {replies}")


def replay(cmd: Callable[[str], str], vectors: dict | None = None) -> tuple[int, list[Mismatch]]:
    """Feed every vector to a runner (``cmd`` sends one command line and returns the answer
    line); return the number of checks made and the mismatches."""
    n, bad = 0, []
    for r in check_each(cmd, vectors):
        n += r.checks
        if r.mismatch is not None:
            bad.append(Mismatch(r.section, r.name, r.mismatch))
    return n, bad


class PythonRunner:
    """The vector runner's line protocol answered by vtexp's own model of the device
    (:class:`~vtexp.devices.firmware.Firmware`, the emulator's), on a fake clock."""

    def __init__(self, firmware_class: type | None = None):
        from .firmware import Firmware
        self.firmware_class = firmware_class or Firmware
        self.now = 0
        self.fw = None

    def __call__(self, line: str) -> str:
        from .firmware import FirmwareConfig
        cmd, _, rest = line.partition(" ")
        args = rest.split()
        if cmd == "config":
            vals = dict(zip(CONFIG_FIELDS, map(int, args[:len(CONFIG_FIELDS)])))
            texts = [bytes.fromhex(t).decode() if t != "-" else "" for t in args[-2:]]
            cfg = FirmwareConfig(**vals, firmware=texts[0], device_id=texts[1])
            self.now = 0
            self.fw = self.firmware_class(cfg, lambda: self.now)
            return "ok"
        if cmd in ("at", "tick"):
            assert self.fw is not None
            self.now = int(args[0])
            out = (self.fw.receive(bytes.fromhex(args[1])) if cmd == "at"
                   else self.fw.tick())
            return "= " + b"".join(out).hex()
        if cmd == "crc":
            return f"= {wire.crc32(bytes.fromhex(args[0])):08x}"
        if cmd == "cobs":
            return "= " + wire.cobs_encode(bytes.fromhex(args[0] if args[0] != "-" else ""
                                                         )).hex()
        if cmd == "uncobs":
            return "= " + wire.cobs_decode(bytes.fromhex(args[0])).hex()
        if cmd == "frame":
            body = bytes([wire.PROTOCOL_VERSION, int(args[0]), int(args[1])])
            body += bytes.fromhex(args[2]) if args[2] != "-" else b""
            return "= " + (b"\x00" + wire.cobs_encode(body + wire.CRC.pack(wire.crc32(body)))
                           + b"\x00").hex()
        return "! unknown command"

    def close(self) -> None:
        pass


class ProcessRunner:
    """The host build's vector runner, on its stdin and stdout."""

    def __init__(self, exe: Path):
        self.proc = subprocess.Popen([str(exe)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     text=True, bufsize=1)

    def __call__(self, line: str) -> str:
        assert self.proc.stdin and self.proc.stdout
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()
        return self.proc.stdout.readline().rstrip("\n")

    def close(self) -> None:
        if self.proc.stdin:
            self.proc.stdin.close()
        self.proc.wait(5)


class SerialRunner:
    """A vector runner on a serial port (the ATmega2560's, in simavr or on a board): one
    command line, one answer line. Opening waits until the runner answers (a board
    resets when its port opens, and bytes sent before its UART is up are lost)."""

    PROBE = ("crc 00", "= d202ef8d")

    def __init__(self, port: str, baudrate: int = 1_000_000, timeout_s: float = 10.0):
        import serial

        try:
            self.port = serial.serial_for_url(port, baudrate=baudrate, timeout=0.2)
        except (ValueError, OSError) as e:      # pyserial's SerialException is an OSError
            raise DeviceError(f"cannot open the vector runner's serial port {port!r}: {e}. "
                              "'vtexp device list' shows the ports found.") from None
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            self.port.write((self.PROBE[0] + "\n").encode())
            line = self.port.readline().strip().decode(errors="replace")
            while line and line != self.PROBE[1]:
                line = self.port.readline().strip().decode(errors="replace")
            if line == self.PROBE[1]:
                self.port.reset_input_buffer()
                self.port.timeout = timeout_s
                return
        self.port.close()
        raise DeviceError(f"no vector runner answered on {port} (flash it with 'vtexp firmware "
                          "flash --profile vectors')")

    def __call__(self, line: str) -> str:
        self.port.write((line + "\n").encode())
        answer = self.port.readline()
        if not answer.endswith(b"\n"):
            raise DeviceError(f"the vector runner did not answer {line[:40]!r} in time")
        return answer.decode().rstrip("\n")

    def close(self) -> None:
        self.port.close()


__all__ = ["Mismatch", "ProcessRunner", "PythonRunner", "SerialRunner", "VectorResult",
           "check_each", "load_vectors", "replay"]
