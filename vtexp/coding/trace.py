"""Sequential tracing of an ordered outline (seed 001, §3.3 and §4.1)."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

from ..errors import InputError, UnsafeStimulus
from ..model import DeviceProfile, LevelDrive, Model, Ms, Pattern, Pulse, Schedule
from .limits import (
    Unsplittable,
    at_least_ms,
    fit_schedule,
    split_refusal,
    where,
)


class SequentialTraceParams(Model):
    """Sequential tracing of seed 001 §3.3 and §4.1."""

    duration_ms: Ms = Field(300, description="vibration of one tactor")
    soa_ms: Ms = Field(
        200, description="onset-to-onset time between consecutive tactors (the paper's "
                         "'time interval')")
    loops: Annotated[int, Field(ge=1, le=100)] = Field(1, description="times the loop is played")
    level: Annotated[int, Field(ge=1)] = Field(1, description="intensity of ordinary tactors (1 V)")
    vertex_level: Annotated[int, Field(ge=1)] = Field(2, description="intensity at vertices (3 V)")


def sequential_trace(pattern: Pattern, profile: DeviceProfile, *, duration_ms: float = 300,
                     soa_ms: float = 200, loops: int = 1, level: int = 1,
                     vertex_level: int = 2) -> Schedule:
    """Activate the pattern's points one after another (seed 001, §3.3, §4.1).

    Point ``k`` of the ordered list starts at ``k * soa_ms`` and vibrates for
    ``duration_ms``; vertices at ``vertex_level`` (level 2, 3 V), the others at
    ``level`` (level 1, 1 V). The whole sequence is played ``loops`` times
    back to back. ``soa_ms`` is onset to onset, as seed 001 defines its "time
    interval"; ``duration_ms > soa_ms`` makes consecutive tactors overlap.

    Within the device's limits (issue 20). The trace is its onsets, one tactor
    every ``soa_ms``, and its ``duration_ms``, the two values seed 001's Table 1
    varies; neither is changed to fit a limit. A tactor that the order visits again
    while it is still on (an outline that comes back to a cell, a short loop played
    many times) stays on; if that would keep it on longer than ``max_on_ms``, it
    pauses for the profile's rest (``min_off_ms``, or a tenth of ``max_on_ms``: the
    live loop's rest) just before one of its later onsets, so that the onset is felt
    afresh, and an activation that would begin less than ``min_off_ms`` after the
    last one ended ends that much earlier (:func:`vtexp.coding.limits.split_activations`:
    onsets kept, nothing lengthened). What that cannot fit is refused, naming the
    parameter to change: a level above ``max_level``, a pulse too long to split, more
    tactors on at once than ``max_simultaneous``.

    Raises
    ------
    InputError
        If the profile is not driven by levels.
    UnsafeStimulus
        What the limits refuse (above), with the schedule as coded.
    """
    if not isinstance(profile.drive, LevelDrive):
        raise InputError(f"sequential-trace drives intensity levels, but {profile.name} is "
                         f"driven by {profile.drive.kind}")
    ordered = pattern.ordered()
    pulses = []
    n = len(ordered)
    for loop in range(loops):
        for k, p in enumerate(ordered):
            pulses.append(Pulse(row=int(round(p.row)), col=int(round(p.col)),
                                onset_ms=(loop * n + k) * soa_ms, duration_ms=duration_ms,
                                level=vertex_level if p.vertex else level))
    schedule = Schedule(device=profile.name, pulses=pulses, coding="sequential-trace",
                        params={"duration_ms": duration_ms, "soa_ms": soa_ms, "loops": loops,
                                "level": level, "vertex_level": vertex_level})
    return _fit(schedule, profile)


def _fit(schedule: Schedule, profile: DeviceProfile) -> Schedule:
    """``schedule`` within ``profile``'s limits (:func:`sequential_trace`), or refused."""
    lim = profile.limits
    prm = schedule.params
    d, soa = prm["duration_ms"], prm["soa_ms"]

    def refuse(text: str) -> UnsafeStimulus:
        return UnsafeStimulus(f"sequential-trace on {profile.name}: {text}", schedule=schedule)

    for q in schedule.pulses:
        if lim.max_level is not None and q.level > lim.max_level:
            key = "level" if q.level == prm["level"] else "vertex_level"
            raise refuse(f"{where(q.row, q.col, q.onset_ms)}: level {q.level} exceeds "
                         f"max_level {lim.max_level} of {profile.name}: set {key} to at most "
                         f"{lim.max_level}")
    try:
        fitted_schedule, most, when = fit_schedule(schedule, lim)
    except Unsplittable as e:
        # A tactor's pulses chain only where it comes back before its pulse has ended (and
        # rested): at soa_ms >= duration_ms + min_off_ms (and some) none ever does.
        fixes = []
        if d > lim.max_on_ms:
            fixes.append(f"duration_ms to at most {lim.max_on_ms:g}")
        if e.kind == "min_off" or e.end_ms - e.start_ms > d:      # pulses that chain
            fixes.append(f"soa_ms to at least "
                         f"{at_least_ms(min(d, lim.max_on_ms) + lim.min_off_ms)}")
        raise refuse(f"{split_refusal(e, lim)}: set {', and '.join(fixes)}") from None
    if most > lim.max_simultaneous:
        b = lim.max_simultaneous
        raise refuse(f"{most} tactors would be on at once at {when:.1f} ms, above "
                     f"max_simultaneous {b} of {profile.name} (a tactor vibrates "
                     f"{d:g} ms and the next begins {soa:g} ms after it): set duration_ms "
                     f"to at most {b * soa - 1:g}, or soa_ms to at least {at_least_ms(d / b)}")
    return fitted_schedule
