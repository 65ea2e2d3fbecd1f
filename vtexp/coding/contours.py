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

from ..errors import InputError, UnsafeStimulus
from ..model import (
    DeviceProfile,
    LevelDrive,
    Model,
    Ms,
    Pattern,
    Pulse,
    SafetyLimits,
    Schedule,
)
from .limits import (
    Unsplittable,
    at_least_ms,
    fit_schedule,
    longest_splittable_ms,
    most_on_at_once,
    pause_ms,
    split_refusal,
    where,
    whole_ms_below,
)


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

    Within the device's limits (issue 20). A mode is its levels, its durations and
    intervals, and a line's motors together (Table 2); none of these is changed to
    fit a limit. A motor that is still on when its line comes round again (one line,
    or few, over several cycles; a cell on two lines) stays on; if that would keep it
    on past ``max_on_ms``, it rests for the profile's rest (a tenth of ``max_on_ms`` on
    the pad and the vest, which have no cooling time: the live loop's rest) just
    before one of its later onsets (:func:`vtexp.coding.limits.split_activations`:
    onsets kept, nothing lengthened). Refused, naming the parameter and a value that
    works: a level above ``max_level`` (seed 000's 1, 3, 5 are the pad's; the vest
    has 0-2: ``high_level`` or ``levels``); a static display or a line longer than
    ``max_on_ms`` allows (``static_ms``, ``fixed_ms``, ``varied_ms``); more motors on
    at once than ``max_simultaneous`` (``display`` dynamic, or intervals at least the
    durations; a single line with more motors than that: another coding, or an
    encoding with fewer). With seed 000's values the pad's ball and photographs play.

    Raises
    ------
    InputError
        If the profile is not driven by levels, or ``levels`` or ``varied_ms`` do not
        match the pattern's lines.
    UnsafeStimulus
        What cannot be fitted (above), with the schedule as coded.
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
        for i, t, dur in _dynamic(p, timing):
            for r, c in cells[lines[i]]:
                pulses.append(Pulse(row=r, col=c, onset_ms=t, duration_ms=dur,
                                    level=levels[i]))
    schedule = Schedule(device=profile.name, pulses=pulses, coding="contour-modes",
                        params={**p.model_dump(mode="json"), "line_levels": levels,
                                "line_timing_ms": [list(x) for x in timing]})
    return _fit(schedule, profile, p, pattern, lines, cells, levels, timing)


def _dynamic(p: ContourModeParams, timing: list[tuple[float, float]]):
    """(line index, onset, duration) of the dynamic display, in playing order: the lines
    one after another from the lowest up (or the top down), ``cycles`` times."""
    n = len(timing)
    seq = list(range(n)) if p.order == "up" else list(range(n - 1, -1, -1))
    t = 0.0
    for _ in range(p.cycles):
        for i in seq:
            dur, interval = timing[i]
            yield i, t, dur
            t += interval


def _fit(schedule: Schedule, profile: DeviceProfile, p: ContourModeParams, pattern: Pattern,
         lines: list[int],
         cells: dict[int, list[tuple[int, int]]], levels: list[int],
         timing: list[tuple[float, float]]) -> Schedule:
    """``schedule`` within ``profile``'s limits (:func:`contour_modes`), or refused."""
    lim = profile.limits
    name = profile.name

    def refuse(text: str) -> UnsafeStimulus:
        return UnsafeStimulus(f"contour-modes on {name}: {text}", schedule=schedule)

    if lim.max_level is not None and max(levels, default=0) > lim.max_level:
        i = max(range(len(levels)), key=lambda j: levels[j])
        r, c = cells[lines[i]][0] if cells[lines[i]] else (0, 0)
        if p.levels is not None:
            fix = f"set levels to values of at most {lim.max_level}"
        else:
            top = line_levels(len(levels), p.intensity, min(p.low_level, lim.max_level),
                              lim.max_level)
            fix = (f"set high_level to at most {lim.max_level} (levels "
                   f"{', '.join(map(str, top))}), or give levels")
        raise refuse(f"{where(r, c, _first_onset(schedule, r, c))}: level {levels[i]} of line "
                     f"{lines[i]} exceeds max_level {lim.max_level} of {name} (levels "
                     f"{', '.join(map(str, levels))} from the lowest line up): {fix}")

    try:
        fitted_schedule, most, when = fit_schedule(schedule, lim)
    except Unsplittable as e:
        raise refuse(f"{split_refusal(e, lim)}: set {_split_fix(p, lim, e)}") from None
    if most > lim.max_simultaneous:
        raise refuse(_budget_refusal(p, pattern, lim, name, lines, cells, timing, most, when))
    return fitted_schedule


def _first_onset(schedule: Schedule, row: int, col: int) -> float:
    return min((q.onset_ms for q in schedule.pulses if (q.row, q.col) == (row, col)),
               default=0.0)


def _split_fix(p: ContourModeParams, lim: SafetyLimits, e: Unsplittable) -> str:
    """What to set where a motor cannot rest (:func:`split_refusal`): a static display
    that outlasts ``max_on_ms``; dynamic lines longer than ``max_on_ms`` less the rest
    (then no onset leaves room for it), or durations or intervals shorter than the rest."""
    if p.display == "static":
        return f"static_ms to at most {whole_ms_below(lim.max_on_ms)}"
    key = "fixed_ms" if p.timing == "fixed" else "varied_ms"
    if e.kind == "max_on" and not e.crowded:
        return f"every duration in {key} to at most {whole_ms_below(longest_splittable_ms(lim))}"
    return f"every duration and interval in {key} to at least {at_least_ms(pause_ms(lim))}"


def _budget_refusal(p: ContourModeParams, pattern: Pattern, lim, name: str, lines: list[int],
                    cells: dict[int, list[tuple[int, int]]], timing: list[tuple[float, float]],
                    most: int, when: float) -> str:
    """Why more than ``max_simultaneous`` motors would be on, and what would play it."""
    b = lim.max_simultaneous
    sizes = [len(set(cells[k])) for k in lines]
    head = (f"{most} motors would be on at once at {when:.1f} ms, above max_simultaneous {b} "
            f"of {name}")
    if max(sizes, default=0) > b:
        k = lines[max(range(len(sizes)), key=lambda i: sizes[i])]
        fewer = "encode the image with fewer motors on one line"
        if pattern.pipeline == "covered-cells":     # every covered cell is on line 1
            fewer = (f"{fewer} (set fill_threshold above "
                     f"{pattern.params.get('fill_threshold', 0.5):g}, or show less of the "
                     f"object)")
        return (f"{head}: line {k} alone has {max(sizes)} motors, and a line's motors play "
                f"together (seed 000 Table 2); no contour-modes parameter changes that: "
                f"use the coding sequential-trace (one motor after another), or {fewer}")
    key = "fixed_ms" if p.timing == "fixed" else "varied_ms"
    apart = [[d, max(d, i)] for d, i in timing]          # one line at a time
    apart_text = f"set {key} to {apart[0] if p.timing == 'fixed' else apart}"
    if p.display == "static":
        dyn, _ = most_on_at_once((cell, t, t + d) for i, t, d in _dynamic(p, timing)
                                 for cell in cells[lines[i]])
        if dyn <= b:
            return (f"{head}: every line plays at once in the static display; set display "
                    f"to dynamic (with timing {p.timing}: at most {dyn} motors at once)")
        return (f"{head}: every line plays at once in the static display; set display to "
                f"dynamic and {apart_text} (each interval at least its duration: one line "
                f"at a time, at most {max(sizes)} motors)")
    return (f"{head}: consecutive lines overlap where a line's duration outlasts its "
            f"interval; {apart_text} (each interval at least its duration: one line at a "
            f"time, at most {max(sizes)} motors)")
