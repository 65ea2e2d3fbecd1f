"""Display modes for height contours on the 20x20 pad (seed 000, §3.1, Table 2).

A mode is declared by its three factors rather than by the paper's number:

- ``display``: ``static`` (every contour motor at once, 4000 ms) or
  ``dynamic`` (line after line, the same line's motors together, two cycles);
- ``timing`` (dynamic only): ``fixed`` (every line 900 ms on, 600 ms to the
  next line's onset) or ``varied`` (higher lines longer: 800/600, 1200/1000,
  1600/1400 ms from the lowest line to the highest);
- ``intensity``: ``linear`` (levels 1, 3, 5 from the lowest line to the
  highest: equal steps) or ``nonlinear`` (1, 4, 5: unequal steps).

Seed 000 contradicts itself here; see docs/decisions.md. In short: the text's
``t_D/t_I`` values are used (Table 2 swaps the columns; its static row, 0 ms
of vibration, is only sensible swapped back); ``t_I`` is onset to onset
(Fig. 7), i.e. an SOA; and the value lists (intensities 5, 3, 1; timings
1600/1400, 1200/1000, 800/600) are read from the highest line down, which is
the only order that agrees with "a higher intensity means a larger height"
and "a longer duration ... represents a larger height". Every value can be
given explicitly instead.

The paper's modes 1-6, as its results section uses them: 1 and 2 static
(linear, nonlinear); 3-6 dynamic: fixed-linear, fixed-nonlinear,
varied-linear, varied-nonlinear.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator
from typing_extensions import Self

from ..errors import InputError
from ..model import DeviceProfile, LevelDrive, Model, Ms, Pattern, Pulse, Schedule


class ContourModeParams(Model):
    display: Literal["static", "dynamic"] = "dynamic"
    timing: Literal["fixed", "varied"] = "varied"
    intensity: Literal["linear", "nonlinear"] = "linear"
    cycles: Annotated[int, Field(ge=1, le=20)] = Field(
        2, description="times the dynamic sequence runs (seed 000: two cycles)")
    order: Literal["up", "down"] = Field(
        "up", description="dynamic order of the lines: from the lowest up, or from the top down")
    static_ms: Ms = Field(4000, description="static display time (seed 000: 4000/0 ms)")
    fixed_ms: tuple[Ms, Ms] = Field(
        (900, 600), description="duration and onset-to-onset interval of every line, fixed mode")
    varied_ms: list[tuple[Ms, Ms]] | None = Field(
        None, description="(duration, interval) per line from the lowest up; default: "
                          "800/600 ... 1600/1400 ms spread over the lines")
    levels: list[Annotated[int, Field(ge=0)]] | None = Field(
        None, description="intensity level per line from the lowest up; default from "
                          "'intensity' (3 lines: linear 1, 3, 5; nonlinear 1, 4, 5)")
    low_level: Annotated[int, Field(ge=1)] = 1
    high_level: Annotated[int, Field(ge=1)] = 5

    @model_validator(mode="after")
    def _order(self) -> Self:
        if self.high_level < self.low_level:
            raise ValueError("high_level must not be below low_level")
        return self


def line_levels(n: int, intensity: str, low: int = 1, high: int = 5) -> list[int]:
    """Intensity level of each line from the lowest up.

    ``linear``: equal steps from ``low`` to ``high`` (3 lines: 1, 3, 5).
    ``nonlinear``: the steps shrink towards the top, ``low + (high - low) *
    (1 - (1 - x)^2)`` at ``x = k/(n-1)`` (3 lines: 1, 4, 5, seed 000 Table 2).
    """
    if n == 1:
        return [high]
    out = []
    for k in range(n):
        x = k / (n - 1)
        f = x if intensity == "linear" else 1.0 - (1.0 - x) ** 2
        out.append(int(round(low + (high - low) * f)))
    return out


def line_timing(n: int) -> list[tuple[float, float]]:
    """Default (duration, interval) per line from the lowest up, varied mode.

    Seed 000 gives 800/600, 1200/1000, 1600/1400 ms for three lines; for other
    counts the durations are spread evenly over 800-1600 ms, intervals 200 ms less.
    """
    if n == 1:
        return [(1200.0, 1000.0)]
    return [(800.0 + 800.0 * k / (n - 1), 600.0 + 800.0 * k / (n - 1)) for k in range(n)]


def contour_modes(pattern: Pattern, profile: DeviceProfile, **params) -> Schedule:
    """Schedule a height-contour Pattern in one of seed 000's display modes (Table 2).

    Lines are numbered from 1 (lowest) in ``pattern``. Static: every motor of
    every line starts at 0 and runs ``static_ms`` at its line's level.
    Dynamic: the lines run one after another (from the lowest up, or the top
    down), each line's motors together for the line's duration; the next line
    starts one interval (onset to onset) later; after the last line the next
    cycle starts one interval later.
    """
    p = ContourModeParams(**params)
    if not isinstance(profile.drive, LevelDrive):
        raise InputError(f"contour modes drive intensity levels, but {profile.name} is driven "
                         f"by {profile.drive.kind}")
    lines = pattern.lines()
    lines = [k for k in lines if k > 0]
    n = len(lines)
    levels = p.levels if p.levels is not None else line_levels(n, p.intensity, p.low_level,
                                                               p.high_level)
    if len(levels) != n:
        raise InputError(f"'levels' gives {len(levels)} values but the pattern has {n} lines")
    if p.timing == "fixed":
        timing = [tuple(p.fixed_ms)] * n
    else:
        timing = [tuple(t) for t in p.varied_ms] if p.varied_ms is not None else line_timing(n)
        if len(timing) != n:
            raise InputError(f"'varied_ms' gives {len(timing)} pairs but the pattern has {n} lines")
    cells: dict[int, list[tuple[int, int]]] = {k: [] for k in lines}
    for pt in pattern.points:
        if pt.line > 0:
            cells[pt.line].append((int(round(pt.row)), int(round(pt.col))))
    pulses: list[Pulse] = []
    if p.display == "static":
        for i, k in enumerate(lines):
            for r, c in cells[k]:
                pulses.append(Pulse(row=r, col=c, onset_ms=0.0, duration_ms=p.static_ms,
                                    level=levels[i]))
    else:
        seq = list(range(n)) if p.order == "up" else list(range(n - 1, -1, -1))
        t = 0.0
        for _ in range(p.cycles):
            for i in seq:
                dur, interval = timing[i]
                for r, c in cells[lines[i]]:
                    pulses.append(Pulse(row=r, col=c, onset_ms=t, duration_ms=dur,
                                        level=levels[i]))
                t += interval
    return Schedule(device=profile.name, pulses=pulses, coding="contour-modes",
                    params={**p.model_dump(mode="json"), "line_levels": levels,
                            "line_timing_ms": [list(x) for x in timing]})
