"""Onset timing on the emulated device over a real pty: device-side vs host-streamed
timing vs a naive host loop, and the bytes a frame costs on the wire.

The emulator runs in its own process (``vtexp device emulate``), as firmware
runs on its own microcontroller; the host talks to it through pyserial over
a pseudo-terminal. A schedule of N pulses at a fixed SOA is played three ways:

- device-side: uploaded once, triggered; the device plays it from its clock;
- host-streamed: the host sends a sparse frame at each change time (sleep,
  then spin to the deadline) and the device applies it on arrival;
- baseline: the naive host loop — write a frame, ``time.sleep(soa)``, repeat.

Each onset is the time the device reports (its own clock, stamped after the
outputs changed). Error of pulse i = (onset_i - onset_0) - (scheduled_i -
scheduled_0); drift = slope of the error over the run (least squares),
reported per minute and over the whole run. No claim here is about a real
microcontroller: the emulator is Python on a general-purpose OS, so these
figures bound what the protocol allows on this machine.

Prints a table, writes ``bench/results/timing.json``.
Usage: python bench/timing.py [--n 300] [--soa-ms 200] [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vtexp.devices import wire
from vtexp.devices.serial_device import SerialDevice
from vtexp.devices.wire import (
    Ack,
    Level,
    SetFrame,
    SetFrameFull,
    UploadChunk,
    WirePulse,
)
from vtexp.model import DeviceProfile, Pulse, Schedule
from vtexp.safety import check_schedule

PROFILE = "pad_20x20"


def start_emulator() -> tuple[subprocess.Popen, str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    p = subprocess.Popen([sys.executable, "-m", "vtexp", "device", "emulate", "--profile",
                          PROFILE], stdout=subprocess.PIPE, text=True, env=env)
    first = p.stdout.readline()
    if " on " not in first:
        p.kill()
        raise SystemExit(f"the emulator did not start: {first!r}")
    return p, first.rsplit(" on ", 1)[1].strip()


def schedule(n: int, soa_ms: float) -> Schedule:
    """n pulses of level 5 at a fixed SOA, walking along the pad's top row."""
    dur = min(100.0, soa_ms / 2)
    return Schedule(device=PROFILE, pulses=[
        Pulse(row=0, col=i % 20, onset_ms=i * soa_ms, duration_ms=dur, level=5)
        for i in range(n)])


def errors_ms(onsets_us: list[float], sched_ms: list[float]) -> list[float]:
    return [(t - onsets_us[0]) / 1000.0 - (s - sched_ms[0]) for t, s in zip(onsets_us, sched_ms)]


def summary(err: list[float], sched_ms: list[float]) -> dict:
    a = sorted(abs(e) for e in err)

    def pct(q: float) -> float:
        k = (len(a) - 1) * q
        lo = int(k)
        hi = min(lo + 1, len(a) - 1)
        return a[lo] + (a[hi] - a[lo]) * (k - lo)
    xs = [s / 60000.0 for s in sched_ms]              # minutes
    mx, my = statistics.fmean(xs), statistics.fmean(err)
    sxx = sum((x - mx) ** 2 for x in xs)
    slope = sum((x - mx) * (y - my) for x, y in zip(xs, err)) / sxx if sxx else 0.0
    run_min = (sched_ms[-1] - sched_ms[0]) / 60000.0
    return {"n": len(err), "mean_ms": my, "p50_ms": pct(0.5), "p95_ms": pct(0.95),
            "p99_ms": pct(0.99), "max_ms": a[-1], "drift_ms_per_min": slope,
            "drift_over_run_ms": slope * run_min, "last_minus_first_ms": err[-1] - err[0]}


def run_device_side(port: str, s: Schedule) -> tuple[list[float], dict]:
    with SerialDevice(DeviceProfile.load(PROFILE), port, timing="device") as dev:
        rep = dev.play(s)
        stats = dev.link_stats()
    return [(rep.started_at_ms + p.onset_ms) * 1000 for p in rep.pulses], stats


def run_host_streamed(port: str, s: Schedule) -> tuple[list[float], dict]:
    with SerialDevice(DeviceProfile.load(PROFILE), port, timing="host") as dev:
        rep = dev.play(s)
        stats = dev.link_stats()
    return [(rep.started_at_ms + p.onset_ms) * 1000 for p in rep.pulses], stats


def run_naive(port: str, s: Schedule, soa_ms: float) -> tuple[list[float], dict]:
    """What most lab scripts do: write the next frame, sleep one SOA, repeat.

    The frames are written and not waited for (as open firmwares are driven);
    the device's ACKs, read off the line, give the onsets. A long heartbeat
    period keeps the link's own heartbeats out of the way: the loop's frames
    feed the watchdog.
    """
    profile = DeviceProfile.load(PROFILE)
    check_schedule(s, profile)              # the same pulses, checked as play() would
    acks: list[int] = []

    def tap(direction: str, msg: object) -> None:
        if direction == "to_host" and isinstance(msg, Ack):
            acks.append(msg.t_us)
    with SerialDevice(profile, port, heartbeat_ms=2000, trace=tap) as dev:
        link = dev._link                    # the bare link: the naive loop has no scheduler
        acks.clear()
        prev = None
        for i, p in enumerate(s.sorted()):
            idx = p.row * profile.cols + p.col
            changes = ((idx, Level(p.level)),) if prev is None or prev == idx else \
                ((prev, Level(0)), (idx, Level(p.level)))
            msg = SetFrame(wire.DRIVE_LEVEL, changes)
            link._write(wire.encode(msg, (100 + i) % 256), msg)
            prev = idx
            time.sleep(soa_ms / 1000.0)
        stats = dev.link_stats()
    return acks[:len(s.pulses)], stats


def wire_costs() -> list[dict]:
    full = SetFrameFull(wire.DRIVE_LEVEL, tuple(Level(5 if i % 4 == 0 else 0) for i in range(400)))
    full_on = SetFrameFull(wire.DRIVE_LEVEL, tuple(Level(5) for _ in range(400)))
    sparse2 = SetFrame(wire.DRIVE_LEVEL, ((0, Level(0)), (1, Level(5))))
    sparse10 = SetFrame(wire.DRIVE_LEVEL, tuple((i, Level(3)) for i in range(10)))
    chunk = UploadChunk(1, 0, wire.DRIVE_LEVEL, tuple(WirePulse(i, i * 200_000, 100_000, Level(5))
                                                       for i in range(50)))
    ack = wire.encode(Ack(0, 0), 0)
    rows = []
    for name, msg in [("full 20x20 frame, 100 of 400 on", full),
                      ("full 20x20 frame, all 400 on", full_on),
                      ("sparse update, 2 actuators", sparse2),
                      ("sparse update, 10 actuators", sparse10),
                      ("schedule upload, 50 pulses (one chunk)", chunk)]:
        n = len(wire.encode(msg, 0))
        rows.append({"what": name, "bytes": n, "ack_bytes": len(ack),
                     "ms_115200": n * 10 / 115200 * 1000, "ms_1M": n * 10 / 1_000_000 * 1000})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=300, help="pulses per run (default 300)")
    ap.add_argument("--soa-ms", type=float, default=200.0, help="SOA (default 200 ms)")
    ap.add_argument("--quick", action="store_true", help="50 pulses at 100 ms")
    args = ap.parse_args()
    n, soa = (50, 100.0) if args.quick else (args.n, args.soa_ms)
    s = schedule(n, soa)
    sched = [p.onset_ms for p in s.sorted()]
    proc, port = start_emulator()
    results: dict = {"n": n, "soa_ms": soa, "run_s": (n - 1) * soa / 1000, "port": port,
                     "machine": {"python": platform.python_version(),
                                 "platform": platform.platform(), "cpus": os.cpu_count()},
                     "modes": {}}
    try:
        for name, fn in [("device-side", lambda: run_device_side(port, s)),
                         ("host-streamed", lambda: run_host_streamed(port, s)),
                         ("baseline: write + sleep(soa)", lambda: run_naive(port, s, soa))]:
            print(f"running {name}: {n} pulses at {soa:g} ms SOA "
                  f"({(n - 1) * soa / 1000:.0f} s)...", file=sys.stderr, flush=True)
            onsets, stats = fn()
            err = errors_ms(onsets, sched)
            results["modes"][name] = {**summary(err, sched), "link": stats,
                                      "errors_ms": [round(e, 4) for e in err]}
    finally:
        proc.terminate()
        proc.wait(10)
    base = results["modes"]["baseline: write + sleep(soa)"]
    print(f"\nOnset error on the emulated {PROFILE} over a pty: {n} pulses at {soa:g} ms SOA, "
          f"run of {(n - 1) * soa / 1000:.0f} s (error vs pulse 0; |error| percentiles)\n")
    hdr = (f"| {'mode':<28} | p50 ms | p95 ms | p99 ms | max ms | mean ms | drift ms/min "
           f"| drift over run ms | p99 vs baseline |")
    print(hdr)
    print("|" + "|".join("-" * (len(c)) for c in hdr.split("|")[1:-1]) + "|")
    for name, m in results["modes"].items():
        ratio = base["p99_ms"] / m["p99_ms"] if m["p99_ms"] > 0 else float("inf")
        m["p99_ratio_baseline_over_mode"] = ratio
        print(f"| {name:<28} | {m['p50_ms']:6.3f} | {m['p95_ms']:6.3f} | {m['p99_ms']:6.3f} "
              f"| {m['max_ms']:6.3f} | {m['mean_ms']:7.3f} | {m['drift_ms_per_min']:12.3f} "
              f"| {m['drift_over_run_ms']:17.3f} | {ratio:14.1f}x |")
    costs = wire_costs()
    results["wire"] = costs
    print("\nWire cost of one frame (COBS, CRC-32, both delimiters; 8N1 = 10 bits per byte)\n")
    print("| frame                                   | bytes | ms at 115200 | ms at 1 Mbaud |")
    print("|-----------------------------------------|-------|--------------|---------------|")
    for c in costs:
        print(f"| {c['what']:<39} | {c['bytes']:5d} | {c['ms_115200']:12.2f} "
              f"| {c['ms_1M']:13.3f} |")
    print(f"\n(every request is answered by an ACK of {costs[0]['ack_bytes']} bytes)")
    out = ROOT / "bench" / "results" / "timing.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=1) + "\n", encoding="utf-8")
    print(f"\nwrote {out.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
