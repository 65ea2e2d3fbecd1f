"""``vtexp firmware ...``: the reference firmware for the lab's microcontroller.

- ``build [--profile NAME]``: compile it (avr-gcc) and say where the .hex is, with its
  flash and RAM use;
- ``flash --profile NAME --port PORT``: write it to an Arduino Mega 2560 with avrdude
  (``--dry-run`` prints the command);
- ``vectors (--host | --simavr | --device serial:PORT)``: replay the wire protocol's test
  vectors against the firmware's vector runner: built for this computer, on the
  ATmega2560 in simavr, or flashed on a board (``build --profile vectors``).

Only argparse is imported here; each command imports what it needs.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess

from ._io import out

PROFILES = ("pad_20x20", "vest_6x8", "sma_5x5")


def register(sub) -> None:
    """Add ``vtexp firmware`` and its subcommands to the ``vtexp`` parser."""
    fw = sub.add_parser("firmware", help="build, flash and test the reference firmware")
    fs = fw.add_subparsers(dest="firmware_command", metavar="FIRMWARE_COMMAND", required=True)

    s = fs.add_parser("build", help="compile the firmware for an Arduino Mega 2560")
    s.add_argument("--profile", choices=[*PROFILES, "vectors", "all"], default="all",
                   help="the array it drives (default: all three, and the vector runner)")
    s.set_defaults(func=cmd_build)

    s = fs.add_parser("flash", help="write the firmware to an Arduino Mega 2560 (avrdude)")
    s.add_argument("--profile", choices=[*PROFILES, "vectors"], required=True)
    s.add_argument("--port", required=True, help="the board's serial port, e.g. /dev/ttyACM0")
    s.add_argument("--dry-run", action="store_true", help="print the avrdude command only")
    s.set_defaults(func=cmd_flash)

    s = fs.add_parser("vectors", help="replay the wire protocol's test vectors")
    where = s.add_mutually_exclusive_group(required=True)
    where.add_argument("--host", action="store_true", help="the firmware built for this computer")
    where.add_argument("--simavr", action="store_true",
                       help="the ATmega2560 build, in simavr")
    where.add_argument("--device", metavar="serial:PORT",
                       help="a board running the vector runner (firmware flash --profile "
                            "vectors)")
    s.set_defaults(func=cmd_vectors)


def _hex(built, profile: str):
    if profile == "vectors":
        return built / "avr" / "vectors" / "vtexp-fw-vectors.hex"
    return built / "avr" / profile / "vtexp-fw.hex"


def _sizes(elf) -> tuple[int, int]:
    r = subprocess.run(["avr-size", "-A", str(elf)], capture_output=True, text=True, check=True)
    sizes = {ln.split()[0]: int(ln.split()[1]) for ln in r.stdout.splitlines()
             if ln.startswith(".")}
    flash = sizes.get(".text", 0) + sizes.get(".data", 0)
    ram = sizes.get(".data", 0) + sizes.get(".bss", 0) + sizes.get(".noinit", 0)
    return flash, ram


def cmd_build(args: argparse.Namespace) -> int:
    from ..devices.cfirmware import build

    built = build("avr-all")
    profiles = [*PROFILES, "vectors"] if args.profile == "all" else [args.profile]
    out(f"{'profile':<10} {'flash':>8} {'RAM':>8}  file")
    for p in profiles:
        hx = _hex(built, p)
        flash, ram = _sizes(hx.with_suffix(".elf"))
        out(f"{p:<10} {flash:>8} {ram:>8}  {hx}")
    out("RAM is static data; the stack takes the rest of the 8192 bytes. Write a build to a "
        "board with: vtexp firmware flash --profile NAME --port /dev/ttyACM0")
    return 0


def cmd_flash(args: argparse.Namespace) -> int:
    from ..devices.cfirmware import build
    from ..errors import DeviceError

    hx = _hex(build("avr-all"), args.profile)
    # The Mega 2560's bootloader speaks STK500v2 ("wiring") at 115200 baud; -D keeps the
    # bootloader (no chip erase).
    cmd = ["avrdude", "-p", "atmega2560", "-c", "wiring", "-P", args.port, "-b", "115200",
           "-D", "-U", f"flash:w:{hx}:i"]
    out(" ".join(cmd))
    if args.dry_run:
        return 0
    if shutil.which("avrdude") is None:
        raise DeviceError("avrdude is not installed: sudo apt-get install avrdude (or run the "
                          "command above where it is)")
    r = subprocess.run(cmd)
    if r.returncode != 0:
        raise DeviceError(f"avrdude failed (exit {r.returncode}); is the board on {args.port} "
                          "('vtexp device list')?")
    out(f"flashed {args.profile} to {args.port}")
    return 0


def cmd_vectors(args: argparse.Namespace) -> int:
    from ..devices import vectors
    from ..devices.cfirmware import AvrSimulator, build, elf_path
    from ..errors import DeviceError, InputError

    sim = None
    if args.host:
        runner = vectors.ProcessRunner(build("host") / "host" / "vtexp-fw-vectors")
        where = "the host build"
    elif args.simavr:
        sim = AvrSimulator(None, elf=elf_path("vectors"))
        runner = vectors.SerialRunner(sim.start())
        where = "the ATmega2560 build in simavr"
    else:
        if not args.device.startswith("serial:"):
            raise InputError("give serial:PORT", key="--device")
        runner = vectors.SerialRunner(args.device.partition(":")[2])
        where = args.device
    try:
        n, bad = vectors.replay(runner)
    finally:
        runner.close()
        if sim is not None:
            sim.stop()
    for m in bad:
        out(f"MISMATCH {m.section} {m.name}: {m.detail}")
    if bad:
        raise DeviceError(f"{len(bad)} of {n} vector checks failed on {where}")
    out(f"{n} vector checks passed on {where}, byte for byte")
    return 0
