"""Sequential tracing of an ordered outline (seed 001, §3.3 and §4.1)."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

from ..errors import InputError
from ..model import DeviceProfile, LevelDrive, Model, Ms, Pattern, Pulse, Schedule


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
    return Schedule(device=profile.name, pulses=pulses, coding="sequential-trace",
                    params={"duration_ms": duration_ms, "soa_ms": soa_ms, "loops": loops,
                            "level": level, "vertex_level": vertex_level})
