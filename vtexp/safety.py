"""The one place where a Schedule is checked against a device profile's limits.

Every device backend calls :func:`check_schedule` before anything reaches an
actuator (``vtexp.devices.base.DeviceBase.play``). A refusal names the
actuator, the time and the limit.

Limits that span two plays (an SMA wire must cool for ``min_off_ms`` after
one play before the next drives it again, seed 002 §3.3) are computed here
too, by :func:`cooling_wait_ms`; ``DeviceBase.play`` waits that long before
it starts, rather than refusing a replay the participant asked for.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Mapping

from .errors import UnsafeStimulus
from .model import DeviceProfile, LevelDrive, Pulse, PulseTrainDrive, Schedule

# Two pulses of one actuator closer than this are treated as one continuous activation.
_CONTIGUOUS_MS = 1e-6


def _where(p: Pulse, t_ms: float | None = None) -> str:
    t = p.onset_ms if t_ms is None else t_ms
    return f"actuator (row {p.row}, col {p.col}) at {t:.1f} ms"


def check_schedule(schedule: Schedule, profile: DeviceProfile) -> None:
    """Raise :class:`UnsafeStimulus` if ``schedule`` breaks any limit of ``profile``.

    Checked: actuator inside the array; drive kind matches the profile; level,
    amplitude, frequency and pulse width within limits; continuous on-time per
    actuator (overlapping or touching pulses merged) within ``max_on_ms``; the
    pause between activations at least ``min_off_ms``; at most
    ``max_simultaneous`` actuators on at any moment.
    """
    lim = profile.limits
    name = profile.name
    if schedule.device != name:
        raise UnsafeStimulus(f"schedule was coded for device {schedule.device!r}, "
                             f"not for {name!r}; encode it again for this device")
    by_actuator: dict[tuple[int, int], list[Pulse]] = defaultdict(list)
    for p in schedule.pulses:
        if p.row >= profile.rows or p.col >= profile.cols:
            raise UnsafeStimulus(f"{_where(p)}: outside the {profile.rows}x{profile.cols} "
                                 f"array of {name}")
        if isinstance(profile.drive, LevelDrive):
            if p.level is None:
                raise UnsafeStimulus(f"{_where(p)}: {name} is driven by levels, "
                                     "but the pulse has a pulse train")
            if p.level > lim.max_level:
                raise UnsafeStimulus(f"{_where(p)}: level {p.level} exceeds max_level "
                                     f"{lim.max_level} of {name}")
        elif isinstance(profile.drive, PulseTrainDrive):
            tr = p.train
            if tr is None:
                raise UnsafeStimulus(f"{_where(p)}: {name} is driven by pulse trains, "
                                     "but the pulse has a level")
            if lim.max_amplitude_v is not None and tr.amplitude_v > lim.max_amplitude_v:
                raise UnsafeStimulus(f"{_where(p)}: amplitude {tr.amplitude_v} V exceeds "
                                     f"max_amplitude_v {lim.max_amplitude_v} V of {name}")
            if lim.max_frequency_hz is not None and tr.frequency_hz > lim.max_frequency_hz:
                raise UnsafeStimulus(f"{_where(p)}: frequency {tr.frequency_hz} Hz exceeds "
                                     f"max_frequency_hz {lim.max_frequency_hz} Hz of {name}")
            if lim.max_pulse_width_ms is not None and tr.pulse_width_ms > lim.max_pulse_width_ms:
                raise UnsafeStimulus(f"{_where(p)}: pulse width {tr.pulse_width_ms} ms exceeds "
                                     f"max_pulse_width_ms {lim.max_pulse_width_ms} ms of {name}")
            if tr.pulse_width_ms >= 1000.0 / tr.frequency_hz:
                raise UnsafeStimulus(f"{_where(p)}: pulse width {tr.pulse_width_ms} ms does not "
                                     f"fit in the period of {tr.frequency_hz} Hz (always on)")
        by_actuator[(p.row, p.col)].append(p)

    for pulses in by_actuator.values():
        pulses.sort(key=lambda q: q.onset_ms)
        start = pulses[0].onset_ms
        end = pulses[0].offset_ms
        first = pulses[0]
        for q in pulses[1:]:
            if q.onset_ms <= end + _CONTIGUOUS_MS:      # overlapping or touching: one activation
                end = max(end, q.offset_ms)
                continue
            _check_on(first, start, end, lim.max_on_ms, name)
            gap = q.onset_ms - end
            if gap < lim.min_off_ms:
                raise UnsafeStimulus(f"{_where(q)}: only {gap:.1f} ms off since the last "
                                     f"activation, below min_off_ms {lim.min_off_ms} ms of "
                                     f"{name} (cooling)")
            first, start, end = q, q.onset_ms, q.offset_ms
        _check_on(first, start, end, lim.max_on_ms, name)

    # Sweep over on/off events: offsets sort before onsets at the same time.
    events = sorted([(p.onset_ms, 1, p) for p in schedule.pulses]
                    + [(p.offset_ms, -1, p) for p in schedule.pulses],
                    key=lambda e: (e[0], e[1]))
    on: dict[tuple[int, int], int] = defaultdict(int)
    for t, delta, p in events:
        key = (p.row, p.col)
        on[key] += delta
        if on[key] == 0:
            del on[key]
        if len(on) > lim.max_simultaneous:
            raise UnsafeStimulus(f"{_where(p, t)}: {len(on)} actuators on at once, above "
                                 f"max_simultaneous {lim.max_simultaneous} of {name}")


def _check_on(p: Pulse, start: float, end: float, max_on_ms: float, name: str) -> None:
    if end - start > max_on_ms:
        raise UnsafeStimulus(f"{_where(p, start)}: on for {end - start:.1f} ms without a "
                             f"pause, above max_on_ms {max_on_ms} ms of {name}")


def cooling_wait_ms(schedule: Schedule, profile: DeviceProfile,
                    last_off_ms: Mapping[tuple[int, int], float], now_ms: float) -> float:
    """How long to wait before starting ``schedule`` so that no actuator is driven
    again less than ``min_off_ms`` after an earlier play last switched it off.

    ``last_off_ms`` maps ``(row, col)`` to the time, on the same clock as
    ``now_ms``, at which an earlier play left that actuator off. Within one
    schedule the pause is :func:`check_schedule`'s business.
    """
    rest = profile.limits.min_off_ms
    if rest <= 0 or not last_off_ms:
        return 0.0
    first: dict[tuple[int, int], float] = {}
    for p in schedule.pulses:
        key = (p.row, p.col)
        first[key] = min(first.get(key, p.onset_ms), p.onset_ms)
    wait = 0.0
    for key, onset in first.items():
        off = last_off_ms.get(key)
        if off is not None:
            wait = max(wait, rest - (now_ms - off) - onset)
    return wait
