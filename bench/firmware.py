"""The reference firmware on its chip: onset error from the pins, against the Python
emulator and a naive host loop in the same run; latency; capacity; RAM; heartbeats.

The ATmega2560 build (the .elf a lab flashes) runs in simavr through vtexp-simavr,
whose trace stamps every latch edge with the CPU cycle: onset error here is the real
output change against the schedule, on the chip's own clock, to the cycle.

1. Onset error of N pulses (default 300) at a fixed SOA (default 200 ms, a 60 s run)
   on the vest (1 Mbaud):
   - firmware: two uploaded schedules of N/2 pulses on one device timeline (the second
     triggered for the device time of the first's timeline's next SOA at least 400 ms
     after its last pulse, time to upload it: the device holds one schedule of up to
     256 pulses); error = latch edge - (start + scheduled onset);
   - the Python emulator (vtexp device emulate, its own process): the device-reported
     onsets of one schedule of N pulses (it has no pins);
   - baseline: a naive host loop against the same firmware: write a SET_FRAME,
     time.sleep(soa), repeat; error = latch edge - (first edge + i x soa).
   p50/p99/max of |error|, mean, drift (least-squares slope per minute, and the last
   10 s against the first 10 s), and p99 ratios to the baseline.
2. Latency from the host's last byte (the frame's final byte into the simulated UART) to
   the first output change: sparse SET_FRAMEs, and TRIGGERs (whose start the firmware
   sets 3 ms ahead to prepare the first instant).
3. Capacity on the pad: a full 20x20 frame (SET_FRAME_FULL) and a 256-pulse schedule,
   counted on the pins.
4. RAM and flash of each build (avr-size), and the deepest stack measured (the harness
   paints RAM and looks at the end of each run): RAM used = static + stack.
5. Heartbeats with one CPU core kept busy by another process: heartbeats sent, replies
   late, and whether the link was declared lost, over an idle minute, at heartbeat
   periods of 200 and 1000 ms, against the firmware in simavr and the Python emulator.
   On this machine the simulated device shares the CPU, so a loss here may be the
   device's starvation, which a real chip does not have.
6. A host starved of the CPU: a session of short plays against the firmware while the
   host process is stopped (SIGSTOP) for 300 ms every 2 s, with the device's watchdog at
   200 ms (the session ends: the device turned everything off, as it must) and at
   1000 ms (the session goes on: the host, having sent nothing, missed no answer).

Prints a table, writes bench/results/firmware.json.
Usage: python bench/firmware.py [--n 300] [--soa-ms 200] [--quick]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vtexp.devices import cfirmware, fwtrace, open_device, wire  # noqa: E402
from vtexp.devices.cfirmware import AvrSimulator  # noqa: E402
from vtexp.devices.serial_device import setting_of  # noqa: E402
from vtexp.errors import DeviceError  # noqa: E402
from vtexp.model import DeviceProfile, Pulse, Schedule  # noqa: E402

VEST = DeviceProfile.load("vest_6x8")
PAD = DeviceProfile.load("pad_20x20")
CYC_US = fwtrace.HZ / 1e6
#: Link settings of parts 1-4, as vtexp device emulate suggests them for a simulated chip:
#: on a loaded machine the simulator (or the emulator's process) can fall a tenth of a
#: second behind, which the default 200 ms heartbeat takes for a pulled cable. Onsets are
#: played from the device's clock, so this changes nothing that is measured; part 5
#: measures the heartbeat itself.
SIM_LINK = ",heartbeat_ms=1000,reply_ms=120"


def sweep(n: int, soa_ms: float, first: int = 0) -> list[Pulse]:
    """n pulses of level 2 for 100 ms at a fixed SOA, walking over the vest."""
    return [Pulse(row=(first + i) % 8, col=(first + i) * 5 % 6, onset_ms=i * soa_ms,
                  duration_ms=min(100.0, soa_ms / 2), level=2) for i in range(n)]


def stats(err_us: list[float], t_s: list[float]) -> dict:
    a = np.abs(np.array(err_us))
    e = np.array(err_us)
    t = np.array(t_s)
    slope = float(np.polyfit(t, e, 1)[0]) * 60 if len(t) > 2 else float("nan")
    first, last = e[t <= t[0] + 10], e[t >= t[-1] - 10]
    return {"n": len(e), "p50_us": float(np.percentile(a, 50)),
            "p99_us": float(np.percentile(a, 99)), "max_us": float(a.max()),
            "mean_us": float(e.mean()), "drift_us_per_min": slope,
            "last10s_minus_first10s_us": float(last.mean() - first.mean()),
            "span_s": float(t[-1] - t[0])}


def latch_edges(tr: fwtrace.Trace, n: int) -> np.ndarray:
    """Cycles of the latches at which some actuator turned on (0 -> 1)."""
    out = fwtrace.chain_outputs(tr, n)
    b = out.bits
    up = np.zeros(len(b), dtype=bool)
    up[1:] = (b[1:] & ~b[:-1]).any(axis=1)
    return out.cycles[up]


# --------------------------------------------------------------------------- 1. onsets

def firmware_onsets(n: int, soa_ms: float) -> tuple[dict, dict]:
    half = n // 2
    parts = [sweep(half, soa_ms), sweep(n - half, soa_ms, first=half)]
    second_step = half + max(1, math.ceil(400 / soa_ms))
    with AvrSimulator("vest_6x8") as sim:
        with open_device(f"serial:{sim.port}{SIM_LINK}", VEST) as dev:
            link = dev._link
            starts, planned = [], []
            for k, pulses in enumerate(parts):
                wp = dev._wire_pulses(pulses)
                pid = 100 + k
                link.expect(wire.UploadBegin(pid, len(wp), 1), wire.Ack)
                per = (dev._payload_budget() - 5) // wire.UploadChunk.pulse_size(1)
                for j in range(0, len(wp), per):
                    link.expect(wire.UploadChunk(pid, j, 1, tuple(wp[j:j + per])), wire.Ack)
                # the second part continues the first's timeline on the device clock, at
                # the first SOA step at least 400 ms after its last pulse (the upload's time)
                at = 0 if k == 0 else starts[0] + round(second_step * soa_ms * 1000)
                ack = link.expect(wire.Trigger(pid, at), wire.Ack)
                starts.append(ack.t_us)
                planned += [ack.t_us + round(p.onset_ms * 1000) for p in pulses]
                time.sleep((pulses[-1].onset_ms + pulses[-1].duration_ms) / 1000 + 0.05)
                while link.expect(wire.Status(), wire.StatusReply).state in (2, 3):
                    time.sleep(0.01)
    tr = fwtrace.Trace.load(sim.trace_path)
    edges = latch_edges(tr, 48)
    sync = tr.sync_rises
    err, t_s, report_vs_edge = [], [], []
    for t_plan in planned:
        c_plan = tr.cycle_of(t_plan)
        k = np.argmin(np.abs(edges - c_plan))
        err.append((edges[k] - c_plan) / CYC_US)
        t_s.append(t_plan / 1e6)
    for c in sync:                   # each instant: sync edge vs the latch edge beside it
        k = np.argmin(np.abs(edges - c))
        report_vs_edge.append(abs(edges[k] - c) / CYC_US)
    s = stats(err, t_s)
    s["second_start_exact"] = starts[1] - starts[0] == round(second_step * soa_ms * 1000)
    s["sync_vs_latch_max_us"] = max(report_vs_edge)
    return s, {"stack_used": tr.stack_used, "max_lag_ms": tr.end.get("max_lag_ns", 0) / 1e6}


def emulator_onsets(n: int, soa_ms: float) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    p = subprocess.Popen([sys.executable, "-m", "vtexp", "device", "emulate", "--profile",
                          "vest_6x8"], stdout=subprocess.PIPE, text=True, env=env)
    port = p.stdout.readline().rsplit(" on ", 1)[1].strip()
    try:
        s = Schedule(device="vest_6x8", pulses=sweep(n, soa_ms))
        with open_device(f"serial:{port}{SIM_LINK}", VEST) as dev:
            rep = dev.play(s)
    finally:
        p.terminate()
        p.wait()
    err = [(q.onset_ms - q.scheduled_onset_ms) * 1000 for q in rep.pulses]
    return stats(err, [q.scheduled_onset_ms / 1000 for q in rep.pulses])


def naive_onsets(n: int, soa_ms: float) -> tuple[dict, list[float]]:
    """write a frame, time.sleep(soa), repeat: against the firmware, on its pins."""
    with AvrSimulator("vest_6x8") as sim:
        with open_device(f"serial:{sim.port}{SIM_LINK}", VEST, timing="host") as dev:
            link = dev._link
            prev = None
            sizes = set()
            for i, p in enumerate(sweep(n, soa_ms)):
                idx = p.row * 6 + p.col
                changes = [(idx, setting_of(p))]
                if prev is not None and prev != idx:
                    changes.append((prev, wire.Level(0)))
                msg = wire.SetFrame(1, tuple(changes))
                sizes.add(len(wire.encode(msg, 0)) - 2)     # as the trace counts: no delimiters
                link.expect(msg, wire.Ack)
                prev = idx
                time.sleep(soa_ms / 1000)
    tr = fwtrace.Trace.load(sim.trace_path)
    others = {len(wire.encode(m, 0)) - 2 for m in (wire.Hello(), wire.Heartbeat(),
                                                   wire.AllOff(), wire.Bye(), wire.Status())}
    assert not sizes & others, "SET_FRAMEs must be told apart from the rest by their size"
    edges = latch_edges(tr, 48)
    # the SET_FRAMEs, by their size; each one's first output change is the first rise
    # after its last byte
    frames = np.array([c for c, size in tr.rx_frames if size in sizes])
    assert len(frames) == n, (len(frames), n)
    firsts, lat = [], []
    for c in frames:
        after = edges[edges >= c]
        if len(after):
            firsts.append(after[0])
            lat.append((after[0] - c) / CYC_US)
    firsts = np.array(firsts)
    err = [(c - firsts[0]) / CYC_US - i * soa_ms * 1000 for i, c in enumerate(firsts)]
    return stats(err, [i * soa_ms / 1000 for i in range(len(err))]), lat


# --------------------------------------------------------------------------- 2-3. latency, capacity

def trigger_latency(plays: int = 30) -> list[float]:
    p = Pulse(row=0, col=0, onset_ms=0, duration_ms=5, level=1)
    with AvrSimulator("vest_6x8") as sim:
        with open_device(f"serial:{sim.port}{SIM_LINK}", VEST) as dev:
            for _ in range(plays):
                dev.play(Schedule(device="vest_6x8", pulses=[p]))
                time.sleep(0.01)
    tr = fwtrace.Trace.load(sim.trace_path)
    sync = tr.sync_rises
    # each onset's TRIGGER: the last frame of its size before it (a size no other frame of
    # this conversation has)
    size = len(wire.encode(wire.Trigger(1, 0), 0)) - 2
    others = {len(wire.encode(m, 0)) - 2 for m in (
        wire.Hello(), wire.Heartbeat(), wire.AllOff(), wire.Bye(), wire.Status(),
        wire.UploadBegin(1, 1, 1), wire.GetOnsets(1, 0, 1),
        wire.UploadChunk(1, 0, 1, tuple(dev._wire_pulses([p]))))}
    assert size not in others, "TRIGGERs must be told apart from the rest by their size"
    triggers = np.array([c for c, n in tr.rx_frames if n == size])
    out = []
    for c in sync:
        before = triggers[triggers < c]
        if len(before):
            out.append((c - before[-1]) / CYC_US)
    return out


def capacity() -> dict:
    with AvrSimulator("pad_20x20") as sim:
        with open_device(f"serial:{sim.port}{SIM_LINK}", PAD) as dev:
            ack = dev._link.expect(wire.SetFrameFull(1, tuple(wire.Level(1) for _ in range(400))),
                                   wire.Ack)
            time.sleep(0.05)
            dev._link.expect(wire.AllOff(), wire.Ack)
            big = Schedule(device="pad_20x20", pulses=[
                Pulse(row=i // 20 % 20, col=i % 20, onset_ms=i * 12, duration_ms=10,
                      level=1 + i % 10) for i in range(256)])
            rep = dev.play(big)
    tr = fwtrace.Trace.load(sim.trace_path)       # the whole trace, with the stack at the end
    out = fwtrace.chain_outputs(tr, 400)
    all_on = bool(out.bits.all(axis=1).any())
    start = tr.cycle_of(rep.started_at_ms * 1000)
    pulses = [p for p in fwtrace.level_pulses(tr, 400) if p.start >= start]
    exact = [(p.index, p.on_slots) for p in pulses] == \
        [(q.row * 20 + q.col, q.level) for q in big.pulses]
    return {"full_frame_acked": isinstance(ack, wire.Ack), "full_frame_all_400_on": all_on,
            "schedule_256_reported": len(rep.pulses), "schedule_256_on_pins": len(pulses),
            "schedule_256_exact": exact, "stack_used": tr.stack_used}


# --------------------------------------------------------------------------- 4. RAM, flash

def sizes(stack: dict[str, int | None]) -> dict:
    built = cfirmware.build("avr-all")
    out = {}
    for prof in cfirmware.PROFILES:
        r = subprocess.run(["avr-size", "-A", str(built / "avr" / prof / "vtexp-fw.elf")],
                           capture_output=True, text=True, check=True)
        sz = {ln.split()[0]: int(ln.split()[1]) for ln in r.stdout.splitlines()
              if ln.startswith(".")}
        static = sz.get(".data", 0) + sz.get(".bss", 0) + sz.get(".noinit", 0)
        st = stack.get(prof)
        out[prof] = {"flash": sz.get(".text", 0) + sz.get(".data", 0), "ram_static": static,
                     "stack_measured": st, "ram_used": static + (st or 0)}
    return out


def stack_of(profile: str, schedule: Schedule, device_profile: DeviceProfile) -> int | None:
    with AvrSimulator(profile) as sim:
        with open_device(f"serial:{sim.port}{SIM_LINK}", device_profile) as dev:
            dev.play(schedule)
    return fwtrace.Trace.load(sim.trace_path).stack_used


# --------------------------------------------------------------------------- 5. heartbeats

def heartbeats(kind: str, heartbeat_ms: int, seconds: float) -> dict:
    busy = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        if kind == "firmware":
            sim = AvrSimulator("vest_6x8")
            port = sim.start()
        else:
            env = dict(os.environ, PYTHONPATH=str(ROOT))
            sim = subprocess.Popen([sys.executable, "-m", "vtexp", "device", "emulate",
                                    "--profile", "vest_6x8"], stdout=subprocess.PIPE, text=True,
                                   env=env)
            port = sim.stdout.readline().rsplit(" on ", 1)[1].strip()
        try:
            dev = open_device(f"serial:{port},heartbeat_ms={heartbeat_ms}", VEST)
            lost = None
            dev.open()
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                time.sleep(0.2)
                if dev._link.lost:
                    lost = dev._link.lost
                    break
            st = dev.link_stats()
            try:
                dev.close()
            except DeviceError:         # lost: closed all the same
                pass
        finally:
            if kind == "firmware":
                sim.stop()
            else:
                sim.terminate()
                sim.wait()
    finally:
        busy.kill()
        busy.wait()
    sent = st["heartbeats"] + st["timeouts"]
    return {"heartbeats": st["heartbeats"], "late_replies": st["timeouts"],
            "loss_rate": st["timeouts"] / sent if sent else float("nan"),
            "lost": lost is not None, "lost_reason": lost}


HOST_LOOP = """
import json, sys, time
from vtexp.devices import open_device
from vtexp.model import DeviceProfile, Pulse, Schedule
from vtexp.errors import DeviceError
dev = open_device(sys.argv[1], DeviceProfile.load("vest_6x8"))
dev.open()
print("open", flush=True)
end = time.monotonic() + float(sys.argv[2])
plays = lost = 0
try:
    while time.monotonic() < end:
        dev.play(Schedule(device="vest_6x8", pulses=[Pulse(row=0, col=0, onset_ms=0,
                                                           duration_ms=100, level=1)]))
        plays += 1
        time.sleep(0.1)
except DeviceError as e:
    lost = str(e)
st = dev.link_stats()
try:
    dev.close()
except DeviceError:
    pass
print(json.dumps({"plays": plays, "lost": lost, "heartbeats": st.get("heartbeats", 0)}))
"""


def host_stalls(heartbeat_ms: int, watchdog_ms: int, seconds: float,
                stop_ms: int = 300, every_s: float = 2.0) -> dict:
    """A session against the firmware while the host process is stopped (SIGSTOP) for
    stop_ms every every_s: a host starved of the CPU, the case of a loaded lab PC."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    with AvrSimulator("vest_6x8") as sim:
        spec = f"serial:{sim.port},heartbeat_ms={heartbeat_ms},watchdog_ms={watchdog_ms}"
        host = subprocess.Popen([sys.executable, "-c", HOST_LOOP, spec, str(seconds)],
                                stdout=subprocess.PIPE, text=True, env=env)
        assert host.stdout.readline().strip() == "open"
        stops = 0
        t_end = time.monotonic() + seconds
        while host.poll() is None and time.monotonic() < t_end - every_s:
            time.sleep(every_s)
            if host.poll() is not None:
                break
            os.kill(host.pid, signal.SIGSTOP)
            time.sleep(stop_ms / 1000)
            os.kill(host.pid, signal.SIGCONT)
            stops += 1
        out = json.loads(host.communicate(timeout=60)[0].strip().splitlines()[-1])
    return {**out, "stops": stops, "stop_ms": stop_ms}


# --------------------------------------------------------------------------- main

def pct(x: list[float], q: float) -> float:
    return float(np.percentile(np.array(x), q)) if x else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=300)
    ap.add_argument("--soa-ms", type=float, default=200.0)
    ap.add_argument("--quick", action="store_true", help="n = 40, heartbeats for 10 s")
    args = ap.parse_args()
    n = 40 if args.quick else args.n
    hb_s = 10 if args.quick else 60
    t0 = time.time()
    res: dict = {"machine": {"python": platform.python_version(), "cpus": os.cpu_count()},
                 "n": n, "soa_ms": args.soa_ms}
    print(f"onsets: {n} pulses at {args.soa_ms:g} ms SOA, three ways ...", file=sys.stderr)
    res["firmware"], extra = firmware_onsets(n, args.soa_ms)
    res["emulator"] = emulator_onsets(n, args.soa_ms)
    res["naive"], set_frame_lat = naive_onsets(n, args.soa_ms)
    print("latency, capacity, RAM ...", file=sys.stderr)
    trig = trigger_latency()
    res["latency_us"] = {
        "set_frame": {"p50": pct(set_frame_lat, 50), "p95": pct(set_frame_lat, 95),
                      "max": max(set_frame_lat)},
        "trigger": {"p50": pct(trig, 50), "p95": pct(trig, 95), "max": max(trig)}}
    res["capacity"] = capacity()
    sma = Schedule(device="sma_5x5", pulses=[
        Pulse(row=i % 5, col=i // 5 % 5, onset_ms=i * 20, duration_ms=60,
              train={"amplitude_v": 1.0 + (i % 3) * 0.5, "frequency_hz": 40,
                     "pulse_width_ms": 1.0}) for i in range(60)])
    res["sizes"] = sizes({"vest_6x8": extra["stack_used"], "pad_20x20":
                          res["capacity"]["stack_used"],
                          "sma_5x5": stack_of("sma_5x5", sma, DeviceProfile.load("sma_5x5"))})
    print("heartbeats with one core busy ...", file=sys.stderr)
    res["heartbeats"] = {f"{kind} {hb} ms": heartbeats(kind, hb, hb_s)
                         for kind in ("firmware", "emulator") for hb in (200, 1000)}
    print("host stopped 300 ms every 2 s ...", file=sys.stderr)
    res["host_stalls"] = {f"heartbeat {hb} ms, watchdog {wd} ms": host_stalls(hb, wd, hb_s)
                          for hb, wd in ((200, 200), (200, 1000))}
    res["seconds"] = round(time.time() - t0, 1)

    f, e, b = res["firmware"], res["emulator"], res["naive"]
    print(f"\nOnset error, {n} pulses at {args.soa_ms:g} ms SOA ({f['span_s']:.0f} s), "
          "1 Mbaud")
    print(f"{'':34} {'p50 us':>8} {'p99 us':>8} {'max us':>9} {'mean us':>9} "
          f"{'drift us/min':>13} {'last-first 10 s':>16} {'p99 / naive':>11}")
    for name, s in (("firmware (pins, cycle-exact)", f), ("Python emulator (reported)", e),
                    ("naive host loop (pins)", b)):
        print(f"{name:34} {s['p50_us']:8.1f} {s['p99_us']:8.1f} {s['max_us']:9.1f} "
              f"{s['mean_us']:9.1f} {s['drift_us_per_min']:13.3f} "
              f"{s['last10s_minus_first10s_us']:16.2f} {s['p99_us'] / b['p99_us']:11.4f}")
    print(f"second schedule started exactly on the first one's timeline: "
          f"{f['second_start_exact']}; sync vs latch edge, max {f['sync_vs_latch_max_us']:.2f} "
          f"us; simulator's largest lag behind the wall clock {extra['max_lag_ms']:.1f} ms")
    lat = res["latency_us"]
    print(f"\nHost's last byte -> first output change (us): SET_FRAME p50 "
          f"{lat['set_frame']['p50']:.0f}, p95 {lat['set_frame']['p95']:.0f}, max "
          f"{lat['set_frame']['max']:.0f}; TRIGGER p50 {lat['trigger']['p50']:.0f}, p95 "
          f"{lat['trigger']['p95']:.0f}, max {lat['trigger']['max']:.0f}")
    c = res["capacity"]
    print(f"Pad: full 20x20 frame acked {c['full_frame_acked']}, all 400 on the pins "
          f"{c['full_frame_all_400_on']}; 256-pulse schedule: {c['schedule_256_reported']} "
          f"onsets reported, {c['schedule_256_on_pins']} pulses on the pins, each on its "
          f"actuator at its level's duty: {c['schedule_256_exact']}")
    print(f"\n{'build':10} {'flash':>7} {'RAM static':>11} {'stack':>6} {'RAM used':>9}  "
          "(of 8192; goal <= 7680)")
    for prof, s in res["sizes"].items():
        print(f"{prof:10} {s['flash']:7d} {s['ram_static']:11d} {s['stack_measured'] or 0:6d} "
              f"{s['ram_used']:9d}")
    print(f"\nHeartbeats over {hb_s} s idle, one core busy:")
    for k, h in res["heartbeats"].items():
        print(f"  {k:22} {h['heartbeats']:5d} answered, {h['late_replies']:3d} late "
              f"({h['loss_rate']:.3%}), link lost: {h['lost']}")
    print(f"\nA session ({hb_s} s of 100 ms plays) with the host stopped (SIGSTOP) 300 ms every "
          "2 s, against the firmware:")
    for k, h in res["host_stalls"].items():
        print(f"  {k:28} {h['stops']:3d} stops, {h['plays']:4d} plays, session lost: "
              f"{bool(h['lost'])}" + (f" ({h['lost'][:90]}...)" if h["lost"] else ""))
    out = ROOT / "bench" / "results"
    out.mkdir(parents=True, exist_ok=True)
    (out / "firmware.json").write_text(json.dumps(res, indent=2, default=str) + "\n")
    print(f"\nwrote bench/results/firmware.json ({res['seconds']} s)")


if __name__ == "__main__":
    main()
