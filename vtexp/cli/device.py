"""``vtexp device ...``: tools for the person at the bench.

- ``list``: the serial ports found;
- ``check --device serial:PORT --profile NAME``: handshake, firmware, round-trip
  latency and every actuator off (:func:`check_ready`, which ``vtexp run`` also
  makes before the first trial), then every actuator in turn at a low level,
  asking whether it moved (``--yes`` plays them all without asking, for scripts);
- ``monitor --device serial:PORT``: a tap that decodes and prints the traffic;
- ``emulate --profile NAME``: an emulated device on a pseudo-terminal, until
  stopped (Ctrl-C or SIGTERM), optionally with line faults;
- ``conform --device serial:PORT``: the device's firmware against the protocol's
  rules and (through its vector runner) every vector, as a pass/fail table
  (:mod:`vtexp.devices.conform`).

The checks themselves are :mod:`vtexp.devices.check` (``vtexp run`` makes them
too). Only argparse is imported here; each command imports what it needs, so
that ``vtexp --help`` stays fast. Errors are :class:`~vtexp.errors.VtexpError`, which
the ``vtexp`` command prints as one message.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ._io import out


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``vtexp device`` and its subcommands to the main parser's subparsers."""
    dev = sub.add_parser("device", help="list, check, monitor or emulate tactile devices")
    ds = dev.add_subparsers(dest="device_command", metavar="DEVICE_COMMAND", required=True)

    s = ds.add_parser("list", help="serial ports found on this computer (--audio: sound "
                                   "outputs)")
    s.add_argument("--audio", action="store_true",
                   help="list the sound outputs the participant window's audio mode can play "
                        "on instead (chosen with --responder window:audio,device=NAME)")
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
    s.add_argument("--baud", type=int, default=1_000_000,
                   help="UART baud rate (default 1000000, the reference firmware's)")
    s.set_defaults(func=cmd_check)

    s = ds.add_parser("monitor", help="decode and print the traffic to and from a device")
    s.add_argument("--device", required=True, help="serial:PORT of the device")
    s.add_argument("--baud", type=int, default=1_000_000,
                   help="UART baud rate (default 1000000, the reference firmware's)")
    s.set_defaults(func=cmd_monitor)

    s = ds.add_parser("emulate", help="serve an emulated device on a pseudo-terminal")
    s.add_argument("--profile", required=True, help="device profile to emulate")
    s.add_argument("--firmware", choices=["python", "host", "avr"], default="python",
                   help="what answers: python (vtexp's model of the firmware, default), host "
                        "(the reference firmware in C, built for this computer) or avr (the "
                        "reference firmware's ATmega2560 build, the .elf a lab flashes, in "
                        "simavr)")
    s.add_argument("--trace", metavar="FILE",
                   help="with --firmware avr or host: write what the outputs did to FILE "
                        "(JSON lines; for avr, the chip's pins with CPU cycles)")
    s.add_argument("--lockstep", action="store_true",
                   help="with --firmware avr: vtexp keeps time by the simulated chip instead "
                        "of the chip keeping to the wall clock; the chip runs as fast as "
                        "this computer goes (a study rehearsed on the .elf in a fraction of "
                        "its time) and the device spec printed says so (lockstep=FILE)")
    s.add_argument("--insert", type=float, default=0.0, metavar="RATE",
                   help="with --firmware avr or host: probability that a random byte is "
                        "inserted after each byte")
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

    s = ds.add_parser("conform", help="check a device's firmware against wire protocol v1 "
                                      "(every rule, and every vector through its runner)")
    s.add_argument("--device", required=True,
                   help="serial:PORT (a device as flashed), or a built-in one: emulator, "
                        "emulator:host (the C firmware on this computer), emulator:avr "
                        "(the ATmega2560 build in simavr)")
    s.add_argument("--vectors", metavar="RUNNER",
                   help="where the vectors run: serial:PORT of the firmware's vector runner "
                        "(docs/firmware.md), or python, host, avr; the built-in devices "
                        "bring their own")
    s.add_argument("--profile", default="vest_6x8",
                   help="with a built-in device: the profile it is built to (default "
                        "vest_6x8)")
    s.add_argument("--baud", type=int, default=1_000_000,
                   help="UART baud rate (default 1000000, the reference firmware's)")
    s.set_defaults(func=cmd_conform)


# --------------------------------------------------------------------------- list

def cmd_list(args: argparse.Namespace) -> int:
    if getattr(args, "audio", False):
        return _list_audio()
    from serial.tools import list_ports

    ports = sorted(list_ports.comports(), key=lambda p: p.device)
    if not ports:
        out("no serial ports found. A USB device appears as /dev/ttyACM* or /dev/ttyUSB* "
            "(Linux), /dev/cu.usbmodem* (macOS) or COM* (Windows).")
    else:
        w = max(len(p.device) for p in ports)
        out(f"{'PORT':<{w}}  DESCRIPTION  (HARDWARE ID)")
        for p in ports:
            out(f"{p.device:<{w}}  {p.description}  ({p.hwid})")
    if _has_pty():
        out("No hardware? 'vtexp device emulate --profile pad_20x20' serves an emulated one.")
    else:                   # Windows: the emulator needs a pseudo-terminal
        out("No hardware? 'vtexp run ... --device sim' runs a session on the simulated one.")
    return 0


def _list_audio() -> int:
    """The sound outputs PortAudio sees, as the audio mode chooses among them."""
    from ..responders.speech import output_devices

    devices = output_devices()
    if not devices:
        out("no sound output found: PortAudio sees no sound card, headphones or sound "
            "server (PulseAudio, PipeWire). Attach one or start the server, then list again.")
        return 0
    w = max(len(d["name"]) for d in devices)
    out(f"{'#':>3}  {'NAME':<{w}}  {'HOST API':<10}  CHANNELS")
    for d in devices:
        out(f"{d['index']:>3}  {d['name']:<{w}}  {d['hostapi']:<10}  {d['channels']}"
            + ("  (default)" if d["default"] else ""))
    out("Choose one with --responder window:audio,device=NAME (a part of its name, or its "
        "number); without device= the default plays.")
    return 0


def _has_pty() -> bool:
    """Whether this system has pseudo-terminals (what the emulator and the monitor serve)."""
    import importlib.util
    import os
    return hasattr(os, "openpty") and importlib.util.find_spec("tty") is not None


# --------------------------------------------------------------------------- check

def cmd_check(args: argparse.Namespace) -> int:
    from ..devices import open_device
    from ..devices.check import check_ready, low_pulse
    from ..errors import InputError
    from ..model import DeviceProfile, Schedule

    profile = DeviceProfile.load(args.profile)
    on_ms = min(args.on_ms, profile.limits.max_on_ms)
    if on_ms <= 0:
        raise InputError("must be more than 0 ms", key="--on-ms")
    options = {"baudrate": args.baud} if args.device.startswith("serial:") else {}
    dev = open_device(args.device, profile, **options)
    with dev:
        check_ready(dev, profile, pings=args.pings)
        n = profile.rows * profile.cols
        low = low_pulse(profile, 0, 0, on_ms)
        what = (f"level {low.level}" if low.level is not None else
                f"{low.train.amplitude_v:g} V, {low.train.frequency_hz:g} Hz, "
                f"{low.train.pulse_width_ms:g} ms pulses")
        out(f"each of the {n} actuators in turn, {what} for {on_ms:g} ms"
            + ("" if args.yes else "; answer y (it moved), n (it did not), r (again), "
                                    "q (stop)"))
        failed: list[tuple[int, int]] = []
        played = 0
        for row in range(profile.rows):
            for col in range(profile.cols):
                pulse = low_pulse(profile, row, col, on_ms)
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
                    out(f"stopped after {played} of {n} actuators")
                    return _check_summary(failed, played, n, dev, args.yes)
                played += 1
                if answer.startswith("n"):
                    failed.append((row, col))
        return _check_summary(failed, played, n, dev, args.yes)


def _check_summary(failed, played, n, dev, unattended: bool) -> int:
    stats = dev.link_stats() if hasattr(dev, "link_stats") else {}
    if stats:
        out(f"link: {stats['tx_frames']} frames sent, {stats['rx_frames']} received, "
            f"{stats['rx_bad_total']} bad frames received, {stats['retries']} resent")
    if failed:
        out(f"{len(failed)} of {played} actuators did not move: "
            + ", ".join(f"(row {r}, col {c})" for r, c in failed))
        return 1
    out(f"{played} of {n} actuators played"
        + (" (not confirmed by a person: --yes)" if unattended else " and confirmed"))
    return 0 if played == n else 1


# --------------------------------------------------------------------------- monitor

def cmd_conform(args: argparse.Namespace) -> int:
    from ..devices.conform import conform, table

    rows = conform(args.device, profile=args.profile, vectors=args.vectors, baud=args.baud)
    out(table(rows))
    return 1 if any(r.outcome == "FAIL" for r in rows) else 0


def cmd_monitor(args: argparse.Namespace) -> int:
    from ..devices.monitor import open_tap

    tap = open_tap(args.device, args.baud, sys.stdout)
    port = tap.start()
    out(f"monitoring {args.device}; connect the experiment to serial:{port} "
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
    out("monitor stopped")
    return 0


# --------------------------------------------------------------------------- emulate

def cmd_emulate(args: argparse.Namespace) -> int:
    from ..devices import wire
    from ..devices.emulator import Faults, PtyEmulator
    from ..errors import InputError
    from ..model import DeviceProfile

    profile = DeviceProfile.load(args.profile)
    for name in ("drop", "corrupt", "insert"):
        v = getattr(args, name)
        if not 0 <= v < 1:
            raise InputError(f"a probability from 0 to 1 is needed (got {v})", key=f"--{name}")
    if args.firmware != "python":
        return _emulate_c_firmware(args, profile)
    if args.trace or args.insert:
        raise InputError("applies to --firmware avr or host only",
                         key="--trace" if args.trace else "--insert")
    trace = None                # or, with --verbose, each message as it passes
    if args.verbose:
        t0 = time.perf_counter()

        def verbose(direction: str, item: object) -> None:
            from ..devices.monitor import ARROWS
            t = (time.perf_counter() - t0) * 1000
            text = (f"BAD FRAME ({item.kind}: {item})" if isinstance(item, wire.WireError)
                    else wire.describe(item))
            print(f"{t:10.3f} ms  {ARROWS[direction]}  {text}", file=sys.stderr, flush=True)
        trace = verbose
    over = {k: v for k, v in (("rows", args.rows), ("cols", args.cols)) if v is not None}
    emu = PtyEmulator.for_profile(
        profile, faults=Faults(drop_rate=args.drop, corrupt_rate=args.corrupt,
                               delay_ms=args.delay_ms, seed=args.seed),
        clock_ppm=args.clock_ppm, trace=trace, **over)
    port = emu.start()
    cfg = emu.config
    out(f"emulating {profile.name} ({cfg.rows}x{cfg.cols}, {cfg.firmware}) on {port}")
    out(f"use it with --device serial:{port}   (Ctrl-C to stop)")
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
    out(f"emulator stopped: {c.rx_frames} frames received, {c.rx_bad} bad, "
        f"{c.duplicates} repeats answered from cache, {c.watchdog_trips} watchdog trips")
    return 0


def _emulate_c_firmware(args: argparse.Namespace, profile) -> int:
    """``vtexp device emulate --firmware avr|host``: the reference firmware in C."""
    from ..devices.base import stream_watchdog_limit_ms
    from ..devices.cfirmware import AvrSimulator, HostFirmware
    from ..devices.link import suggested_reply_ms
    from ..errors import InputError

    for flag, value in (("--delay-ms", args.delay_ms), ("--rows", args.rows),
                        ("--cols", args.cols), ("--clock-ppm", args.clock_ppm)):
        if value:
            raise InputError("applies to the Python emulator only (--firmware python)", key=flag)
    if args.verbose:
        raise InputError("applies to the Python emulator only; to watch the traffic, put "
                         "'vtexp device monitor' between it and the experiment", key="--verbose")
    trace = Path(args.trace) if args.trace else None
    faults = (args.drop, args.corrupt, args.insert)
    if args.lockstep and args.firmware != "avr":
        raise InputError("applies to the ATmega2560 in simavr only (--firmware avr)",
                         key="--lockstep")
    if args.firmware == "avr":
        proc = AvrSimulator(profile.name, trace=trace, faults=faults, seed=args.seed,
                            lockstep=args.lockstep)
        what = f"the reference firmware's ATmega2560 build in simavr ({proc.elf})"
    else:
        proc = HostFirmware(profile, trace=trace, faults=faults, seed=args.seed)
        what = "the reference firmware built for this computer"
    port = proc.start()
    out(f"emulating {profile.name} with {what} on {port}")
    # A reply wait that fits five attempts of a request in the silence limit, as the
    # defaults do: four replies lost in a row on a noisy line do not lose the session
    # (a longer wait, 250 ms with a 1 s heartbeat, survived two).
    reply = suggested_reply_ms(1000)
    if args.firmware == "avr" and args.lockstep:
        # the host keeps time by the chip, which runs on while a busy host's threads wait
        # for the processor: the same slower heartbeat
        spec = (f"serial:{port},heartbeat_ms=1000,reply_ms={reply},"
                f"lockstep={proc.lockstep_path}")
        out(f"use it with --device {spec}   (in lockstep: the chip's time, as fast as this "
            "computer goes; Ctrl-C to stop)")
    elif args.firmware == "avr":
        # the simulated chip can fall behind the wall clock on a busy computer: a slower
        # heartbeat keeps that from looking like a lost link (a reply that comes after
        # the wait only costs a resend, answered from the device's cache)
        out(f"use it with --device serial:{port},heartbeat_ms=1000,reply_ms={reply}   "
            "(Ctrl-C to stop)")
        live = stream_watchdog_limit_ms(profile)
        if live < 1000:         # the device's watchdog would be too long to stream with
            out(f"with vtexp live: --device serial:{port},heartbeat_ms={live},"
                f"reply_ms={suggested_reply_ms(live)}")
    else:
        out(f"use it with --device serial:{port}   (Ctrl-C to stop)")
    try:
        while proc.proc is not None and proc.proc.poll() is None:
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        proc.stop()
    if proc.stderr.strip():
        out(proc.stderr.strip().splitlines()[-1])
    if trace is not None:
        out(f"trace written to {trace}")
    return 0
