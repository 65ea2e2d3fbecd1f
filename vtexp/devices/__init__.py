"""Device backends behind one protocol (:class:`vtexp.devices.base.Device`).

``open_device("sim", profile)`` is the embedded default. Further backends
(serial, emulator) register here under their names.
"""

from __future__ import annotations

from ..errors import InputError
from ..model import DeviceProfile
from .base import Device, DeviceBase
from .sim import SimDevice

BACKENDS = ("sim",)


def open_device(spec: str, profile: DeviceProfile, **options) -> DeviceBase:
    """Create (not yet open) the device named by ``spec``: ``sim`` or ``sim:realtime``."""
    kind, _, arg = spec.partition(":")
    if kind == "sim":
        if arg not in ("", "realtime"):
            raise InputError(f"unknown sim option {arg!r}; use 'sim' or 'sim:realtime'",
                             key="--device")
        return SimDevice(profile, realtime=(arg == "realtime"), **options)
    raise InputError(f"unknown device {spec!r}; available: {', '.join(BACKENDS)}",
                     key="--device")


__all__ = ["Device", "DeviceBase", "SimDevice", "open_device", "BACKENDS"]
