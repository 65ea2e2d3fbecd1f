"""``vtexp device ...``: tools for the person at the bench.

- ``list``: the serial ports found;
- ``check --device serial:PORT --profile NAME``: handshake, firmware, round-trip
  latency and every actuator off (:func:`check_ready`, which ``vtexp run`` also
  makes before the first trial), then every actuator in turn at a low level,
  asking whether it moved (``--yes`` plays them all without asking, for scripts);
- ``monitor --device serial:PORT``: a tap that decodes and prints the traffic;
- ``emulate --profile NAME``: an emulated device on a pseudo-terminal, until
  stopped (Ctrl-C or SIGTERM), optionally with line faults.

Only argparse is imported here; each command imports what it needs, so that
``vtexp --help`` stays fast. Errors are :class:`~vtexp.errors.VtexpError`, which
the ``vtexp`` command prints as one message.
"""

from __future__ import annotations

import argparse
import sys
import time


def _out(msg: str = "") -> None:
    print(msg, flush=True)


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``vtexp device`` and its subcommands to the main parser's subparsers."""
    dev = sub.add_parser("device", help="list, check, monitor or emulate tactile devices")
    ds = dev.add_subparsers(dest="device_command", metavar="DEVICE_COMMAND", required=True)

    s = ds.add_parser("list", help="serial ports found on this computer")
    s.set_defaults(func=cmd_list)

    s = ds.add_parser("check", help="handshake, latency, and each actuator in turn")
    s.add_argument("--device", required=True,
                   help="serial:PORT (or emulator, sim) — the device to check")
    s.add_argument("--profile", required=True, help="device profile the device should match")
    s.add_argument("--yes", "-y", action="store_true",
                   help="play every actuator without asking (for scripts)")
    s.add_argument("--on-ms", type=float, default=300.0,
                   help="how long each actuator is driven (default 300 ms)")
    s.add_argument("--pings", type=int, default=50, help="round trips measured (default 50)")
    s.add_argument("--baud", type=int, default=115200, help="UART baud rate (default 115200)")
    s.set_defaults(func=cmd_check)

    s = ds.add_parser("monitor", help="decode and print the traffic to and from a device")
    s.add_argument("--device", required=True, help="serial:PORT of the device")
    s.add_argument("--baud", type=int, default=115200)
    s.set_defaults(func=cmd_monitor)

    s = ds.add_parser("emulate", help="serve an emulated device on a pseudo-terminal")
    s.add_argument("--profile", required=True, help="device profile to emulate")
    s.add_argument("--drop", type=float, default=0.0, metavar="RATE",
                   help="probability that a byte is lost (each direction)")
    s.add_argument("--corrupt", type=float, default=0.0, metavar="RATE",
                   help="probability that a byte arrives altered")
    s.add_argument("--delay-ms", type=float, default=0.0,
                   help="delay added to every frame the device sends")
    s.add_argument("--seed", type=int, default=0, help="seed of the fault generator")
    s.add_argument("--rows", type=int, help="report this many rows instead of the profile's")
    s.add_argument("--cols", type=int, help="report this many columns instead of the profile's")
    s.add_argument("--clock-ppm", type=float, default=0.0,
                   help="rate error of the device clock, parts per million")
    s.add_argument("--verbose", "-v", action="store_true",
                   help="print every frame received and sent")
    s.set_defaults(func=cmd_emulate)


# --------------------------------------------------------------------------- list

def cmd_list(args: argparse.Namespace) -> int:
    from serial.tools import list_ports

    ports = sorted(list_ports.comports(), key=lambda p: p.device)
    if not ports:
        _out("no serial ports found. A USB device appears as /dev/ttyACM* or /dev/ttyUSB* "
             "(Linux), /dev/cu.usbmodem* (macOS) or COM* (Windows).")
    else:
        w = max(len(p.device) for p in ports)
        _out(f"{'PORT':<{w}}  DESCRIPTION  (HARDWARE ID)")
        for p in ports:
            _out(f"{p.device:<{w}}  {p.description}  ({p.hwid})")
    _out("No hardware? 'vtexp device emulate --profile pad_20x20' serves an emulated one.")
    return 0


# --------------------------------------------------------------------------- check

def _low_pulse(profile, row: int, col: int, on_ms: float):
    """One pulse at the lowest non-zero intensity the profile declares."""
    from ..model import LevelDrive, Pulse, PulseTrain

    d = profile.drive
    if isinstance(d, LevelDrive):
        return Pulse(row=row, col=col, onset_ms=0, duration_ms=on_ms, level=1)
    lim = profile.limits
    freq = min(d.frequencies_hz)
    width = min(d.pulse_width_ms)
    amp = min(d.amplitude_v, lim.max_amplitude_v or d.amplitude_v)
    return Pulse(row=row, col=col, onset_ms=0, duration_ms=on_ms,
                 train=PulseTrain(amplitude_v=amp, frequency_hz=freq, pulse_width_ms=width))


def _percentile(xs: list[float], q: float) -> float:
    s = sorted(xs)
    k = (len(s) - 1) * q
    lo, hi = int(k), min(int(k) + 1, len(s) - 1)
    return s[lo] + (s[hi] - s[lo]) * (k - lo)


def identity(dev, profile) -> list[str]:
    """What the open device reports about itself, checked against ``profile``.

    Raises :class:`~vtexp.errors.DeviceError` if the device is not the array the
    profile describes (the serial backend already refuses one at its handshake).
    """
    from ..errors import DeviceError

    info = dev.info()
    if (info.profile, info.rows, info.cols) != (profile.name, profile.rows, profile.cols):
        raise DeviceError(f"the device opened reports {info.rows} x {info.cols} actuators "
                          f"(profile {info.profile!r}), but profile {profile.name!r} "
                          f"describes {profile.rows} x {profile.cols}. Nothing was played.")
    lines = [f"device:   {info.backend} {info.port or ''}".rstrip(),
             f"firmware: {info.firmware}   protocol: {info.protocol}",
             (f"geometry: {info.rows} x {info.cols} as profile {profile.name} expects "
              f"({profile.actuator}, {profile.drive.kind})")]
    if info.details:
        lines.append("details:  " + ", ".join(f"{k}={v}" for k, v in info.details.items()))
    return lines


def round_trip(dev, pings: int) -> str | None:
    """Time ``pings`` heartbeats over the link; None for a device without one (sim).

    A heartbeat is timed once, without resending. One left unanswered within the
    reply timeout (a busy computer, a noisy line) is counted, and the device is
    then asked for its status the way a session asks, resent as often as the link
    allows: only if that fails too does the check fail.
    """
    from ..errors import DeviceError
    from .link import DeviceLost, DeviceRefused

    if not hasattr(dev, "ping") or pings <= 0:
        return None
    rtts: list[float] = []
    for _ in range(pings):
        try:
            rtts.append(dev.ping())
        except (DeviceLost, DeviceRefused):
            raise
        except DeviceError:
            dev.status()
    line = f"round trip ({pings} heartbeats): "
    if rtts:
        line += (f"p50 {_percentile(rtts, 0.5):.2f} ms, p95 {_percentile(rtts, 0.95):.2f} ms, "
                 f"max {max(rtts):.2f} ms")
    if len(rtts) < pings:
        line += ("; " if rtts else "") + (f"{pings - len(rtts)} not answered in time (the "
                                          "device answered when asked again)")
    return line


def all_off(dev) -> str:
    """Turn every actuator off and have the device confirm it; raise DeviceError if not."""
    from ..errors import DeviceError
    from .wire import DeviceState

    dev.all_off()
    if hasattr(dev, "status"):                 # a device on the wire: ask it
        state = dev.status().state
        if state != DeviceState.IDLE:
            names = {v: k.lower() for k, v in vars(DeviceState).items() if k.isupper()}
            raise DeviceError(f"the device is {names.get(state, state)} after ALL_OFF, not "
                              "idle; check it with 'vtexp device check' before any trial")
        emulator = getattr(dev, "emulator", None)
        if emulator is not None and not emulator.all_outputs_off():
            raise DeviceError("the emulated device still drives an output after ALL_OFF")
        return "actuators: all off (ALL_OFF acknowledged, the device reports it is idle)"
    state = getattr(dev, "state", None)         # the sim's record of every actuator
    if state is not None and state.any():
        raise DeviceError("the simulated device still drives an actuator after all-off")
    return "actuators: all off"


def check_ready(dev, profile, *, pings: int = 20, say=_out) -> None:
    """Is the open device ready to play? The first part of ``vtexp device check``, and
    what ``vtexp run`` checks before the first trial. It plays nothing.

    The device's identity against the profile, the link's round trip, and every
    actuator off. Each result is passed to ``say`` as it comes; a failure raises
    :class:`~vtexp.errors.DeviceError` (or the device's own error).
    """
    for line in identity(dev, profile):
        say(line)
    line = round_trip(dev, pings)
    if line:
        say(line)
    say(all_off(dev))


def cmd_check(args: argparse.Namespace) -> int:
    from ..errors import InputError
    from ..model import DeviceProfile, Schedule
    from . import open_device

    profile = DeviceProfile.load(args.profile)
    on_ms = min(args.on_ms, profile.limits.max_on_ms)
    if on_ms <= 0:
        raise InputError("must be more than 0 ms", key="--on-ms")
    options = {"baudrate": args.baud} if args.device.startswith("serial:") else {}
    dev = open_device(args.device, profile, **options)
    with dev:
        check_ready(dev, profile, pings=args.pings)
        n = profile.rows * profile.cols
        low = _low_pulse(profile, 0, 0, on_ms)
        what = (f"level {low.level}" if low.level is not None else
                f"{low.train.amplitude_v:g} V, {low.train.frequency_hz:g} Hz, "
                f"{low.train.pulse_width_ms:g} ms pulses")
        _out(f"each of the {n} actuators in turn, {what} for {on_ms:g} ms"
             + ("" if args.yes else "; answer y (it moved), n (it did not), r (again), "
                                    "q (stop)"))
        failed: list[tuple[int, int]] = []
        played = 0
        for row in range(profile.rows):
            for col in range(profile.cols):
                pulse = _low_pulse(profile, row, col, on_ms)
                while True:
                    dev.play(Schedule(device=profile.name, pulses=[pulse]))
                    if args.yes:
                        answer = ""
                        break
                    try:
                        answer = input(f"  actuator (row {row}, col {col}) "
                                       f"[{played + 1}/{n}] moved? [y/n/r/q] ").strip().lower()
                    except EOFError:
                        answer = "q"
                    if answer != "r":
                        break
                if answer == "q":
                    _out(f"stopped after {played} of {n} actuators")
                    return _check_summary(failed, played, n, dev, args.yes)
                played += 1
                if answer.startswith("n"):
                    failed.append((row, col))
        return _check_summary(failed, played, n, dev, args.yes)


def _check_summary(failed, played, n, dev, unattended: bool) -> int:
    stats = dev.link_stats() if hasattr(dev, "link_stats") else {}
    if stats:
        _out(f"link: {stats['tx_frames']} frames sent, {stats['rx_frames']} received, "
             f"{stats['rx_bad_total']} bad frames received, {stats['retries']} resent")
    if failed:
        _out(f"{len(failed)} of {played} actuators did not move: "
             + ", ".join(f"(row {r}, col {c})" for r, c in failed))
        return 1
    _out(f"{played} of {n} actuators played"
         + (" (not confirmed by a person: --yes)" if unattended else " and confirmed"))
    return 0 if played == n else 1


# --------------------------------------------------------------------------- monitor

def cmd_monitor(args: argparse.Namespace) -> int:
    from .monitor import open_tap

    tap = open_tap(args.device, args.baud, sys.stdout)
    port = tap.start()
    _out(f"monitoring {args.device}; connect the experiment to serial:{port} "
         "(Ctrl-C to stop)")
    try:
        while not tap.wait(0.2):
            pass
    except KeyboardInterrupt:
        pass
    finally:
        tap.stop()
    if tap.error:
        from ..errors import DeviceError
        raise DeviceError(f"monitor stopped: {tap.error}")
    _out("monitor stopped")
    return 0


# --------------------------------------------------------------------------- emulate

def cmd_emulate(args: argparse.Namespace) -> int:
    from ..errors import InputError
    from ..model import DeviceProfile
    from . import wire
    from .emulator import Faults, PtyEmulator

    profile = DeviceProfile.load(args.profile)
    for name in ("drop", "corrupt"):
        v = getattr(args, name)
        if not 0 <= v < 1:
            raise InputError(f"a probability from 0 to 1 is needed (got {v})", key=f"--{name}")
    trace = None
    if args.verbose:
        t0 = time.perf_counter()

        def trace(direction: str, item: object) -> None:
            from .monitor import ARROWS
            t = (time.perf_counter() - t0) * 1000
            text = (f"BAD FRAME ({item.kind}: {item})" if isinstance(item, wire.WireError)
                    else wire.describe(item))
            print(f"{t:10.3f} ms  {ARROWS[direction]}  {text}", file=sys.stderr, flush=True)
    over = {k: v for k, v in (("rows", args.rows), ("cols", args.cols)) if v is not None}
    emu = PtyEmulator.for_profile(
        profile, faults=Faults(drop_rate=args.drop, corrupt_rate=args.corrupt,
                               delay_ms=args.delay_ms, seed=args.seed),
        clock_ppm=args.clock_ppm, trace=trace, **over)
    port = emu.start()
    cfg = emu.config
    _out(f"emulating {profile.name} ({cfg.rows}x{cfg.cols}, {cfg.firmware}) on {port}")
    _out(f"use it with --device serial:{port}   (Ctrl-C to stop)")
    try:
        while True:
            time.sleep(0.2)
            if emu.error is not None:
                from ..errors import DeviceError
                raise DeviceError(f"the emulator failed: {emu.error!r}")
    except KeyboardInterrupt:
        pass
    finally:
        emu.stop()
    c = emu.firmware.counters
    _out(f"emulator stopped: {c.rx_frames} frames received, {c.rx_bad} bad, "
         f"{c.duplicates} repeats answered from cache, {c.watchdog_trips} watchdog trips")
    return 0
