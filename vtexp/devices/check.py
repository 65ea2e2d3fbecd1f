"""Is a device ready to play? The checks ``vtexp device check`` and ``vtexp run`` make.

:func:`check_ready` (identity against the profile, round trip, every actuator off)
plays nothing; :func:`low_pulse` is the weakest pulse a profile declares, for
checking actuators one by one.
"""

from __future__ import annotations


def low_pulse(profile, row: int, col: int, on_ms: float):
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


def percentile(xs: list[float], q: float) -> float:
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
        line += (f"p50 {percentile(rtts, 0.5):.2f} ms, p95 {percentile(rtts, 0.95):.2f} ms, "
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


def check_ready(dev, profile, *, pings: int = 20, say=print) -> None:
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
