"""Device backends behind one protocol (:class:`vtexp.devices.base.Device`).

Specs for :func:`open_device` (and ``--device`` on the command line):

- ``sim`` (the embedded default), ``sim:realtime``: in-process, virtual clock;
- ``serial:PORT``: a device speaking wire protocol v1 (``docs/protocol.md``)
  on any port pyserial opens: ``serial:/dev/ttyACM0``, ``serial:COM3``,
  ``serial:/dev/pts/4``, ``serial:socket://host:7000``; link settings after
  commas: ``serial:/dev/ttyACM0,baud=115200,heartbeat_ms=500,watchdog_ms=1000``
  (:data:`SERIAL_OPTIONS`; ``reply_ms`` is how long a reply is waited for
  before a request is sent again, beyond the frame's own time on the line;
  ``lockstep=FILE`` keeps time by a simulated chip's clock, for the ATmega2560 in
  simavr as ``vtexp device emulate --firmware avr --lockstep`` serves it);
- ``emulator``: the same serial backend talking to an emulated device that
  it starts on a pseudo-terminal (byte-exact, no hardware), in real time;
  ``emulator:virtual``: the same emulated device in-process on a virtual clock
  (:class:`~vtexp.clock.VirtualClock`): the same bytes on the line, time passing as
  fast as the computer goes (a rehearsal of a whole study with a scripted or model
  participant in seconds; not for a person, who would feel nothing in time). The
  serial link settings follow as for a port: ``emulator:watchdog_ms=1000``,
  ``emulator:virtual,heartbeat_ms=100`` (not ``lockstep``).

``open_device(spec, profile, clock=...)`` gives the device a clock of the caller's
(:mod:`vtexp.clock`; the real one by default).

Backends are imported when first used, so importing this package (and the
command line) stays fast.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ..errors import InputError

if TYPE_CHECKING:
    from ..model import DeviceProfile
    from .base import Device, DeviceBase
    from .sim import SimDevice

BACKENDS = ("sim", "serial", "emulator")
#: ``serial:PORT,KEY=VALUE,...``: what may follow the port, and the SerialDevice argument.
SERIAL_OPTIONS = {"baud": "baudrate", "heartbeat_ms": "heartbeat_ms",
                  "watchdog_ms": "watchdog_ms", "reply_ms": "reply_timeout_ms",
                  "timing": "timing", "lockstep": "clock"}


def _serial_options(arg: str, example: str = "serial:/dev/ttyACM0,heartbeat_ms=500",
                    keys: dict[str, str] = SERIAL_OPTIONS) -> tuple[str, dict[str, Any]]:
    port, *items = arg.split(",")
    options: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or key not in keys:
            raise InputError(f"unknown link option {item!r}; after the "
                             f"{'port' if example.startswith('serial') else 'emulator'}: "
                             + ", ".join(f"{k}=..." for k in keys)
                             + f" (e.g. {example})", key="--device")
        if key == "timing":
            if value not in ("device", "host"):
                raise InputError(f"timing must be device or host (got {value!r})",
                                 key="--device")
            options["timing"] = value
            continue
        if key == "lockstep":
            from .cfirmware import ChipClock
            options["clock"] = ChipClock(value)
            continue
        try:
            n = int(value)
        except ValueError:
            n = 0
        if n <= 0:
            raise InputError(f"{key} must be a whole number above 0 (got {value!r})",
                             key="--device")
        options[SERIAL_OPTIONS[key]] = n
    return port, options


def open_device(spec: str, profile: DeviceProfile, **options: Any) -> DeviceBase:
    """Create (not yet open) the device named by ``spec`` (see the module docstring)."""
    kind, _, arg = spec.partition(":")
    if kind == "sim":
        if arg not in ("", "realtime"):
            raise InputError(f"unknown sim option {arg!r}; use 'sim' or 'sim:realtime'",
                             key="--device")
        from .sim import SimDevice
        return SimDevice(profile, realtime=(arg == "realtime"), **options)
    if kind == "serial":
        if not arg:
            raise InputError("give the port after 'serial:', e.g. serial:/dev/ttyACM0, "
                             "serial:COM3 or serial:socket://HOST:PORT ('vtexp device list' "
                             "shows the ports found)", key="--device")
        from .serial_device import SerialDevice
        port, from_spec = _serial_options(arg)
        return SerialDevice(profile, port, **{**options, **from_spec})
    if kind == "emulator":
        mode = arg.split(",")[0]
        if "=" in mode:                          # link settings only: emulator:watchdog_ms=..
            mode, arg = "", "," + arg
        if mode not in ("", "virtual"):
            raise InputError(f"unknown emulator option {mode!r}; use 'emulator' or "
                             "'emulator:virtual', and link settings after them "
                             "(emulator:watchdog_ms=1000); to drive an emulator started with "
                             "'vtexp device emulate', use serial:PORT", key="--device")
        link = {k: v for k, v in SERIAL_OPTIONS.items() if k != "lockstep"}
        _, from_spec = _serial_options(arg, "emulator:watchdog_ms=1000", link)
        from .serial_device import EmulatedDevice
        if mode == "virtual" and "clock" not in options:
            from ..clock import VirtualClock
            options["clock"] = VirtualClock()
        return EmulatedDevice(profile, **{**options, **from_spec})
    raise InputError(f"unknown device {spec!r}; available: {', '.join(BACKENDS)}",
                     key="--device")


def __getattr__(name: str) -> Any:
    if name in ("Device", "DeviceBase"):
        from . import base
        return getattr(base, name)
    if name == "SimDevice":
        from .sim import SimDevice
        return SimDevice
    if name in ("SerialDevice", "EmulatedDevice"):
        from . import serial_device
        return getattr(serial_device, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["BACKENDS", "Device", "DeviceBase", "SimDevice", "open_device"]
