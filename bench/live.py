"""Live vision-to-touch: frame rate, dropped frames, glass-to-skin latency and tracking error
of ``vtexp live`` against a naive loop and seed 001's 1 frame per second, in the same run.

For each pipeline a synthetic video is written with OpenCV's VideoWriter (640x480, 30 fps,
MJPG): an object crossing the frame and back while it bobs and turns
(``vtexp.live.synthetic``: a rectangle for the edge trace and the snake, seed 000's
shaded ball for the height contours). The video plays at its frame rate, as a camera
delivers frames, to each device named by ``--device`` (default: ``sim``, and
``emulator``: vtexp's model of the firmware in a process of its own, ``vtexp device
emulate``, over a pty with pyserial; ``avr``: the reference firmware's ATmega2560 build
in simavr the same way, ``vtexp device emulate --firmware avr``; ``host``: the reference
firmware built for this computer), in three ways:

- ``vtexp live``: the loop of ``vtexp.live`` — newest frame only (dropped, never queued),
  each frame's cycle played in time (``cycle``: the trace, apparent movement, a new
  frame's cycle going on from where it changed, ``vtexp live``'s default;
  ``cycle/place``: from the same place, ``--follow place``; the height contours are held
  by their static coding) or held (``hold``), only changed outputs sent, the profile's
  limits held across frames;
- ``naive``: capture -> encode -> the whole array in one full frame -> ``sleep(1/30)``,
  frames taken in order from a camera driver's queue of 4 buffers (new frames dropped
  when it is full, as V4L2 does when the program does not keep up);
- ``seed 001``: the same, one frame per second (the vest's camera, seed 001 §3.1).

Figures per row: frames processed per second; frames dropped (captured, never
processed); glass-to-skin latency p50/p95/p99 = capture of the frame that first showed a
change -> the device-reported onset of the first output it changed (the device's clock
put on the host's by the exchange with the shortest round trip); tracking error = at
every frame of the video, the distance (actuator pitches) between the centroid of the
points the array was playing then and the object's true centroid mapped onto the array,
mean and p95 (so a loop that lags is charged for it); bytes sent per second (serial
devices); how late the loop was for the safety guard's deadlines (max); the guard's
degradations, and the changes it left out (``out``: what they switch on is over the
power budget, so they have no onset to measure; not in the latencies). Ratios compare
``vtexp live`` with the naive loop in the same run.

Goals (issue 12): >= 30 fps sustained, p95 latency <= 40 ms for every pipeline on this
2-core machine, tracking error <= 0.5 pitch. A camera's 30 fps bounds the frame rate of
the rows above; the headroom table after them plays the same videos as fast as
``vtexp live`` takes them, for the frame rate the loop itself sustains.

Another device is one argument: ``--device avr``, or a board,
``--device serial:/dev/ttyACM0=vest_6x8`` (``=PROFILE``: run only the pipelines of that
profile). Prints a table, writes ``bench/results/live.json``.

Usage: python bench/live.py [--seconds 10] [--device SPEC[=PROFILE]]... [--quick]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import queue
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vtexp.devices import open_device  # noqa: E402
from vtexp.devices.base import stream_watchdog_limit_ms  # noqa: E402
from vtexp.model import DeviceProfile  # noqa: E402
from vtexp.errors import DeviceError  # noqa: E402
from vtexp.encoding.mapping import ImageToArray  # noqa: E402
from vtexp.live.encoder import LiveEncoder, LiveSetup  # noqa: E402
from vtexp.live.loop import ClockMap, LiveRun  # noqa: E402
from vtexp.live.program import held  # noqa: E402
from vtexp.live.sources import VideoSource  # noqa: E402
from vtexp.live.synthetic import write_video  # noqa: E402
from vtexp.encoding.figure import BackgroundModel  # noqa: E402

PIPELINES = [  # (pipeline, video object, object size, plays: "play" or "play/follow")
    ("edge-trace", "rectangle", 0.5, ("cycle", "cycle/place", "hold")),
    ("snake-corners", "rectangle", 0.5, ("cycle", "cycle/place", "hold")),
    ("height-contours", "ball", 0.6, ("cycle",)),
]
FIRMWARES = {"emulator": "python", "avr": "avr", "host": "host"}
FPS = 30.0


# --------------------------------------------------------------------------- devices


class EmulatorProcess:
    """``vtexp device emulate`` in its own process, as firmware on its own microcontroller:
    vtexp's model of the firmware (``python``), or the reference firmware in C, built for
    this computer (``host``) or for the ATmega2560 in simavr (``avr``). ``spec`` is the
    device spec it says to use (the C firmware's with its own timing options)."""

    def __init__(self, profile: str, firmware: str = "python"):
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        self.p = subprocess.Popen([sys.executable, "-m", "vtexp", "device", "emulate",
                                   "--profile", profile, "--firmware", firmware],
                                  stdout=subprocess.PIPE, text=True, env=env)
        first = self.p.stdout.readline()
        if " on " not in first:
            self.p.kill()
            raise SystemExit(f"the {firmware} emulator did not start: {first!r}")
        self.port = first.rsplit(" on ", 1)[1].strip()
        self.spec = f"serial:{self.port}"
        if firmware != "python":
            said = self.p.stdout.readline()
            if "--device " in said:
                self.spec = said.split("--device ", 1)[1].split()[0]
            if firmware == "avr" and stream_watchdog_limit_ms(DeviceProfile.load(profile)) < 1000:
                said = self.p.stdout.readline()     # the spec it gives for vtexp live
                assert said.startswith("with vtexp live: --device "), said
                self.spec = said.split("--device ", 1)[1].split()[0]

    def close(self) -> None:
        self.p.terminate()
        self.p.wait(10)


def make_device(spec: str, profile):
    """(device, cleanup) for a bench device spec."""
    if spec in FIRMWARES:
        emu = EmulatorProcess(profile.name, FIRMWARES[spec])
        return open_device(emu.spec, profile), emu.close
    return open_device(spec, profile), (lambda: None)


# --------------------------------------------------------------------------- loops


class Log:
    """What a loop did: (host time, centroid) of each frame's program as it took over,
    latencies, dropped frames, processing times."""

    def __init__(self):
        self.installs: list[tuple[float, float | None, float | None]] = []
        self.latencies: list[float] = []
        self.processed = 0
        self.captured = 0
        self.dropped = 0
        self.process_ms: list[float] = []
        self.late_ms: list[float] = []
        self.degradations: dict[str, int] = {}
        self.elapsed = 0.0
        self.reconnects = 0
        self.left_out = 0


def run_vtexp_live(video: Path, setup: LiveSetup, device, background=None) -> Log:
    log = Log()

    def sink(kind, e):
        if kind == "frame" and e["program"] != "same":
            log.installs.append((e["t_processed"], e["centroid_row"], e["centroid_col"]))

    model = None if background is None else BackgroundModel.from_reference(background)
    run = LiveRun(VideoSource(video), LiveEncoder(setup, model), device, sinks=[sink])
    st = run.run()
    log.latencies = list(st.latencies_ms)
    log.processed, log.captured, log.dropped = st.frames_processed, st.frames_captured, \
        st.frames_dropped
    log.process_ms = list(st.process_ms)
    log.late_ms = list(st.deadline_late_ms)
    log.degradations = dict(st.degradations)
    log.elapsed = st.elapsed_s
    log.reconnects = st.reconnects
    log.left_out = st.changes_left_out
    return log


def run_naive(video: Path, setup: LiveSetup, device, *, every_s: float | None = None) -> Log:
    """capture -> encode -> full frame -> sleep(1/30), from a driver queue of 4 buffers; or,
    with ``every_s``, the newest frame once every ``every_s`` seconds (seed 001: 1 s)."""
    log = Log()
    enc = LiveEncoder(setup)
    clock = ClockMap()
    src = VideoSource(video)
    src.open()
    q: queue.Queue = queue.Queue(maxsize=4)
    newest: list = [None]
    done = threading.Event()
    stop = threading.Event()

    def capture():
        for f in src.frames(stop):
            log.captured += 1
            if every_s is not None:
                if newest[0] is not None:
                    log.dropped += 1
                newest[0] = f
                continue
            try:
                q.put_nowait(f)
            except queue.Full:
                log.dropped += 1            # the driver has no free buffer: frame lost
        done.set()

    th = threading.Thread(target=capture, daemon=True)
    t0 = time.monotonic()
    th.start()
    device.open()
    state: dict | None = None

    def alive(fn) -> object:
        # A stall that let the device's watchdog end the session: open it again, as
        # vtexp live does, so that the baseline is measured to the end (counted).
        try:
            return fn()
        except DeviceError:
            log.reconnects += 1
            device.close()
            device.open()
            return None

    def sleep_alive(seconds: float) -> None:
        # The device layer needs a check-in at least every stream_checkin_ms (its
        # watchdog); a naive loop's sleep is cut into slices for that, nothing more.
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            time.sleep(min(left, device.stream_checkin_ms / 2000.0))
            if state is not None:
                d = device.stream_deadline_s()
                alive(lambda: device.stream(state) if d is not None and d <= 0
                      else device.stream_alive())

    try:
        while True:
            if every_s is not None:
                sleep_alive(every_s)
                f, newest[0] = newest[0], None
                if f is None:
                    if done.is_set():
                        break
                    continue
            else:
                try:
                    f = q.get(timeout=0.05)
                except queue.Empty:
                    if done.is_set():
                        break
                    if state is not None:
                        alive(device.stream_alive)
                    continue
            t = time.perf_counter()
            res = enc.process(f.image, frame=f.index, t_capture=f.t_capture)
            log.process_ms.append((time.perf_counter() - t) * 1000.0)
            log.processed += 1
            new = held(res.program.schedule) if res.program is not None else {}
            rep = alive(lambda: device.stream(new, full=True))
            if rep is None:
                state = None
                continue
            for dg in rep.degradations:
                log.degradations[dg.kind] = log.degradations.get(dg.kind, 0) + 1
            if rep.t_device_ms is not None:
                clock.add(rep.host_before_ms, rep.host_after_ms, rep.t_device_ms)
                if new != state:
                    log.latencies.append(clock.to_host_ms(rep.t_device_ms)
                                         - f.t_capture * 1000.0)
            if new != state:
                c = _centroid(res.program)
                log.installs.append((time.monotonic(), c[0], c[1]))
            state = new
            if every_s is None:
                sleep_alive(1.0 / FPS)
    finally:
        stop.set()
        device.all_off()
        th.join(timeout=5)
        src.close()
    log.elapsed = time.monotonic() - t0
    return log


def _centroid(program):
    if program is None or not program.pattern.points:
        return (None, None)
    pts = np.array(program.actuated, float)
    return (float(pts[:, 0].mean()), float(pts[:, 1].mean()))


# --------------------------------------------------------------------------- figures


def tracking(log: Log, truth: list[dict], t_start: float, to_array: ImageToArray) -> np.ndarray:
    """At every video frame's time, the played centroid against the true one (pitches)."""
    inst = sorted(log.installs)
    times = [t for t, _, _ in inst]
    out = []
    for tr in truth:
        t = t_start + tr["t_s"]
        k = int(np.searchsorted(times, t, side="right")) - 1
        if k < 0 or inst[k][1] is None:
            continue
        true = to_array.to_array([[tr["centroid_row"], tr["centroid_col"]]])[0]
        out.append(math.hypot(inst[k][1] - true[0], inst[k][2] - true[1]))
    return np.array(out)


def pct(xs, q):
    return float(np.percentile(xs, q)) if len(xs) else math.nan


def figures(log: Log, truth, t_start, to_array, tx_bytes=None) -> dict:
    err = tracking(log, truth, t_start, to_array)
    return {
        "fps": log.processed / max(log.elapsed, 1e-9),
        "captured": log.captured, "processed": log.processed, "dropped": log.dropped,
        "latency_n": len(log.latencies),
        "latency_p50_ms": pct(log.latencies, 50), "latency_p95_ms": pct(log.latencies, 95),
        "latency_p99_ms": pct(log.latencies, 99),
        "process_p50_ms": pct(log.process_ms, 50),
        "tracking_mean": float(err.mean()) if len(err) else math.nan,
        "tracking_p95": pct(err, 95),
        "bytes_per_s": None if tx_bytes is None else tx_bytes / max(log.elapsed, 1e-9),
        "deadline_late_max_ms": max(log.late_ms) if log.late_ms else None,
        "degradations": log.degradations,
        "reconnects": log.reconnects,
        "changes_left_out": log.left_out,
    }


def measure(kind: str, video: Path, truth, setup: LiveSetup, spec: str,
            backdrop=None) -> dict:
    device, cleanup = make_device(spec, setup.profile)
    try:
        t_start = time.monotonic()          # the video's frame 0 is due about now
        if kind == "vtexp live":
            log = run_vtexp_live(video, setup, device, backdrop)
        elif kind == "naive":
            log = run_naive(video, setup, device)
        else:
            log = run_naive(video, setup, device, every_s=1.0)
        tx = device.link_stats().get("tx_bytes") if hasattr(device, "link_stats") else None
    finally:
        device.close()
        cleanup()
    to_array = ImageToArray.from_params(_probe_params(setup, video))
    return figures(log, truth, t_start, to_array, tx)


def _probe_params(setup: LiveSetup, video: Path) -> dict:
    src = VideoSource(video)
    src.open()
    img = next(iter(src.frames(threading.Event()))).image
    src.close()
    return LiveEncoder(setup).process(img).pattern.params


# --------------------------------------------------------------------------- main


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="video length (default 10)")
    ap.add_argument("--device", action="append", metavar="SPEC[=PROFILE]",
                    help="device to bench on (repeatable; default: sim and emulator)")
    ap.add_argument("--quick", action="store_true", help="4 s videos")
    ap.add_argument("--textured", action="store_true",
                    help="the objects move over a photograph (scikit-image's brick wall, or "
                         "matplotlib's sample photograph) instead of a plain ground; vtexp "
                         "live is given the empty stage (--background FILE)")
    args = ap.parse_args()
    seconds = 4.0 if args.quick else args.seconds
    specs = args.device or ["sim", "emulator"]
    out_dir = ROOT / "bench" / "results"
    out_dir.mkdir(parents=True, exist_ok=True)
    videos = {}
    backdrop = _backdrop() if args.textured else None
    for pipeline, obj, size, _ in PIPELINES:
        path = out_dir / f"live-{obj}{'-textured' if backdrop is not None else ''}.avi"
        videos[obj] = (path, write_video(path, obj, seconds=seconds, size=size, fps=FPS,
                                         backdrop=backdrop))
    rows = []
    for spec_arg, spec, pipeline, obj, plays in cases(specs):
        path, truth = videos[obj]
        runs = [("vtexp live", play) for play in plays] + [("naive", "hold"),
                                                             ("seed 001 (1 fps)", "hold")]
        for kind, play in runs:
            how, _, follow = play.partition("/")
            setup = LiveSetup.make(pipeline, play=how, follow=follow or "change")
            f = measure(kind, path, truth, setup, spec, backdrop)
            row = {"device": spec_arg, "pipeline": pipeline, "profile": setup.profile.name,
                   "loop": kind, "play": play if kind == "vtexp live" else "full frame", **f}
            rows.append(row)
            print(f"  {spec_arg:10s} {pipeline:16s} {kind:17s} {row['play']:10s} "
                  f"{f['fps']:5.1f} fps  p95 {f['latency_p95_ms']:7.1f} ms  "
                  f"track {f['tracking_mean']:.2f}", flush=True)
    print_table(rows, seconds)
    # Headroom: the same videos delivered as fast as the loop takes them (no pacing, so
    # nothing is dropped and latency means nothing): the frame rate the loop sustains.
    capacity = []
    for spec_arg, spec, pipeline, obj, _ in cases(specs):
        setup = LiveSetup.make(pipeline)
        device, cleanup = make_device(spec, setup.profile)
        try:
            model = None if backdrop is None else BackgroundModel.from_reference(backdrop)
            st = LiveRun(VideoSource(videos[obj][0], pace=False), LiveEncoder(setup, model),
                         device).run()
        finally:
            device.close()
            cleanup()
        capacity.append({"device": spec_arg, "pipeline": pipeline,
                         "frames": st.frames_processed, "fps": st.fps,
                         "process_p95_ms": st.summary()["process_ms"]["p95"]})
    print("\nheadroom: the same videos as fast as vtexp live takes them (play cycle)")
    for c in capacity:
        print(f"  {c['device']:10s} {c['pipeline']:16s} {c['frames']:5d} frames  "
              f"{c['fps']:6.1f} fps  processing p95 {c['process_p95_ms']:.1f} ms  "
              f"(x{c['fps'] / FPS:.1f} the camera's {FPS:g} fps)")
    result = {"bench": "live", "seconds": seconds, "fps_in": FPS,
              "ground": "photograph" if backdrop is not None else "plain",
              "machine": {"python": platform.python_version(), "cpus": os.cpu_count(),
                          "platform": platform.platform(), "load_avg_1m": os.getloadavg()[0]},
              "goals": {"fps": 30, "latency_p95_ms": 40, "tracking_pitch": 0.5},
              "rows": rows, "headroom": capacity}
    name = "live-textured.json" if backdrop is not None else "live.json"
    (out_dir / name).write_text(json.dumps(result, indent=2, default=float))
    print(f"\nwritten: {out_dir / name}")


def _backdrop() -> np.ndarray:
    """The scene behind the objects, 640x480 gray: scikit-image's brick wall if it is
    installed (the bench extra), else matplotlib's sample photograph; dimmed to 60 % so
    that the light objects (grey 210) stand out from all of it, as a lab would light
    them."""
    from vtexp._cv2 import cv2
    from vtexp.stimuli import read_image
    try:
        from skimage import data
        img = np.asarray(data.brick(), np.uint8)
    except ImportError:
        import matplotlib
        img = read_image(Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg")
    img = cv2().resize(img, (640, 480), interpolation=cv2().INTER_AREA)
    return (img * 0.6).astype(np.uint8)


def cases(specs: list[str]):
    """(device argument, device spec, pipeline, video object, plays) for each device and
    each pipeline of its profile (all, unless the argument ends in ``=PROFILE``)."""
    for spec_arg in specs:
        spec, _, only = spec_arg.partition("=")
        for pipeline, obj, _, plays in PIPELINES:
            if not only or LiveSetup.make(pipeline).profile.name == only:
                yield spec_arg, spec, pipeline, obj, plays


def fmt(x, spec=".1f"):
    return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, spec)


def print_table(rows: list[dict], seconds: float) -> None:
    print(f"\nvtexp live vs a naive loop and seed 001's 1 fps; {seconds:g} s of 640x480 "
          f"video at {FPS:g} fps; load average {os.getloadavg()[0]:.1f} on "
          f"{os.cpu_count()} CPUs")
    head = (f"{'device':11s} {'pipeline':16s} {'loop':17s} {'play':10s} {'fps':>5s} "
            f"{'drop':>5s} {'lat p50':>8s} {'p95':>7s} {'p99':>7s} {'track':>6s} "
            f"{'p95':>5s} {'B/s':>7s} {'late':>6s} {'out':>4s}  degradations")
    print(head)
    print("-" * len(head))
    for r in rows:
        deg = ", ".join(f"{k} {v}" for k, v in sorted(r["degradations"].items())) or "-"
        if r["reconnects"]:
            deg += f", reconnects {r['reconnects']}"
        print(f"{r['device']:11s} {r['pipeline']:16s} {r['loop']:17s} {r['play']:10s} "
              f"{r['fps']:5.1f} {r['dropped']:5d} {fmt(r['latency_p50_ms']):>8s} "
              f"{fmt(r['latency_p95_ms']):>7s} {fmt(r['latency_p99_ms']):>7s} "
              f"{fmt(r['tracking_mean'], '.2f'):>6s} {fmt(r['tracking_p95'], '.2f'):>5s} "
              f"{fmt(r['bytes_per_s'], '.0f'):>7s} {fmt(r['deadline_late_max_ms']):>6s} "
              f"{r['changes_left_out']:4d}  {deg}")
    print("\nratios, each vtexp live row / the naive loop, same device and pipeline:")
    for r in rows:
        if r["loop"] != "vtexp live":
            continue
        naive = next(x for x in rows if x["device"] == r["device"]
                     and x["pipeline"] == r["pipeline"] and x["loop"] == "naive")
        print(f"  {r['device']:10s} {r['pipeline']:16s} {r['play']:11s} fps x"
              f"{r['fps'] / max(naive['fps'], 1e-9):.2f}, latency p95 x"
              f"{r['latency_p95_ms'] / naive['latency_p95_ms']:.2f}, tracking x"
              f"{r['tracking_mean'] / naive['tracking_mean']:.2f}")
    print("\ngoals (issue 12): >= 30 fps, p95 latency <= 40 ms, tracking <= 0.5 pitch "
          "(vtexp live's plays; cycle/place, --follow place, is there to compare)")
    for r in rows:
        if r["loop"] != "vtexp live" or r["play"] == "cycle/place":
            continue
        ok = [r["fps"] >= 29.5 and r["dropped"] == 0, r["latency_p95_ms"] <= 40,
              r["tracking_mean"] <= 0.5]
        print(f"  {r['device']:10s} {r['pipeline']:16s} {r['play']:11s} "
              + "  ".join(f"{name} {'met' if k else 'NOT met'}"
                          for name, k in zip(("fps", "latency", "tracking"), ok)))


if __name__ == "__main__":
    main()
