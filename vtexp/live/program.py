"""A frame's Schedule played round and round: what the array does at each moment of a cycle.

Live, each frame's pattern is coded by the paper's own coding (``vtexp.coding``) into
one cycle of a Schedule — a static pattern held for ``static_ms``, a trace of every
point one after another, apparent movement along the outline — and that cycle is
played again and again until a newer frame gives another. :class:`Program` turns
the cycle into the outputs it asks for at each phase: piecewise-constant segments,
computed once per frame, with the tails of pulses that run past the end of the
cycle wrapped into the start of the next one (a trace's last point overlapping its
first, as ``loops`` would play them). Where pulses of one actuator overlap, the one
started last drives it, as the firmware does.

Held instead (``hold``, ``vtexp live --play hold``), the cycle becomes one state:
every actuator it drives, on together at the strongest drive the cycle gives it (a
pin shared by phantom points at its strongest share) — a static pattern refreshed
as the frame changes, whatever the coding.

When a newer frame's program replaces the current one, it never starts over at its
first point (at 30 frames per second a trace restarted at each frame would never get
past it). By default (``follow="change"``, :func:`change_epoch`) it goes on from the
first place ahead where it differs from the cycle playing (the two compared in step,
phase for phase): the change is felt at once, and the stretch of the outline that
stayed as it was, felt on the pass before, is skipped. With ``follow="place"`` it
takes over at the same *fraction* of its cycle (:func:`carried_epoch`), the same
place along the new outline, and a change elsewhere along the outline is felt when
the trace gets there (up to a whole cycle later).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field

from ..model import Pattern, PulseTrain, Schedule
from ..safety import Actuator, Drive


@dataclass
class Program:
    """One frame's cycle: ``times`` (ms, from 0, increasing) where ``states`` begin; the
    last state lasts until ``cycle_ms``."""

    schedule: Schedule
    pattern: Pattern
    cycle_ms: float
    frame: int
    t_capture: float
    times: list[float] = field(default_factory=list)
    states: list[dict[Actuator, Drive]] = field(default_factory=list)
    signature: tuple = ()

    @classmethod
    def build(cls, schedule: Schedule, pattern: Pattern, cycle_ms: float, *, frame: int = 0,
              t_capture: float = 0.0, hold: bool = False) -> Program:
        p = cls(schedule, pattern, max(float(cycle_ms), 1e-3), frame, t_capture)
        p.times, p.states = ([0.0], [held(schedule)]) if hold else segments(schedule,
                                                                            p.cycle_ms)
        # Held, a cycle is its one state: a frame that changes only the timing of the
        # schedule (not what is held) changes nothing.
        p.signature = (True, *_state_key(p.states[0])) if hold else \
            (False, *signature(schedule, p.cycle_ms))
        return p

    def phase(self, now_s: float, epoch_s: float) -> float:
        """Phase (ms within the cycle) at host time ``now_s`` for a program started at
        ``epoch_s``."""
        return ((now_s - epoch_s) * 1000.0) % self.cycle_ms

    def state_at(self, phase_ms: float) -> dict[Actuator, Drive]:
        k = bisect.bisect_right(self.times, phase_ms) - 1
        return self.states[max(k, 0)] if self.states else {}

    def ms_to_next_change(self, phase_ms: float) -> float:
        """Milliseconds from ``phase_ms`` to the next segment boundary (the cycle's end
        counts as one when the state there changes)."""
        if len(self.times) <= 1:
            return math.inf
        k = bisect.bisect_right(self.times, phase_ms)
        nxt = self.times[k] if k < len(self.times) else self.cycle_ms
        return max(nxt - phase_ms, 0.0)

    @property
    def actuated(self) -> list[tuple[float, float]]:
        """Where the cycle is felt: the pattern's points that its pulses play (phantom
        points at their perceived positions), in array coordinates."""
        return [(p.row, p.col) for p in self.pattern.points]


def segments(schedule: Schedule, cycle_ms: float
             ) -> tuple[list[float], list[dict[Actuator, Drive]]]:
    """Piecewise-constant outputs of ``schedule`` played every ``cycle_ms`` (module
    docstring): boundaries in [0, cycle) and the state from each."""
    period = cycle_ms
    # Each pulse, and the copies of it shifted back by whole cycles that still reach into
    # [0, period): (start in the cycle, end in the cycle, when it started, drive, actuator).
    pieces: list[tuple[float, float, float, Drive, Actuator]] = []
    for p in schedule.pulses:
        drive: Drive = p.level if p.level is not None else p.train
        m = 0
        while True:
            on, off = p.onset_ms - m * period, p.offset_ms - m * period
            if off <= 0:
                break
            a, b = max(on, 0.0), min(off, period)
            if b > a:
                pieces.append((a, b, on, drive, (p.row, p.col)))
            m += 1
            if m > 1000:                    # a pulse a thousand cycles long: held on anyway
                break
    cuts = sorted({0.0} | {x for a, b, *_ in pieces for x in (a, b) if x < period})
    starts: dict[float, list[int]] = {}
    ends: dict[float, list[int]] = {}
    for i, (a, b, *_rest) in enumerate(pieces):
        starts.setdefault(a, []).append(i)
        ends.setdefault(b, []).append(i)
    active: dict[Actuator, dict[int, float]] = {}
    times: list[float] = []
    states: list[dict[Actuator, Drive]] = []
    for t in cuts:
        for i in ends.get(t, ()):
            key = pieces[i][4]
            active[key].pop(i, None)
            if not active[key]:
                del active[key]
        for i in starts.get(t, ()):
            active.setdefault(pieces[i][4], {})[i] = pieces[i][2]
        state = {key: pieces[max(ids, key=ids.get)][3] for key, ids in active.items()}
        if states and state == states[-1]:
            continue
        times.append(t)
        states.append(state)
    if not states:
        times, states = [0.0], [{}]
    return times, states


def held(schedule: Schedule) -> dict[Actuator, Drive]:
    """Every actuator of ``schedule`` at the strongest drive it gets (level, or pulse
    power A²·width·f)."""
    best: dict[Actuator, tuple[float, Drive]] = {}
    for p in schedule.pulses:
        if p.level is not None:
            drive, strength = p.level, float(p.level)
        else:
            t = p.train
            drive, strength = t, t.amplitude_v ** 2 * t.pulse_width_ms * t.frequency_hz
        key = (p.row, p.col)
        if key not in best or strength > best[key][0]:
            best[key] = (strength, drive)
    return {k: d for k, (_, d) in best.items()}


def signature(schedule: Schedule, cycle_ms: float) -> tuple:
    """What makes two cycles the same (a frame that changed nothing keeps the program)."""
    return (round(cycle_ms, 6),) + tuple(
        (p.row, p.col, round(p.onset_ms, 6), round(p.duration_ms, 6), p.level,
         None if p.train is None else _train_key(p.train))
        for p in schedule.pulses)


def _train_key(train: PulseTrain) -> tuple:
    return (train.amplitude_v, train.frequency_hz, train.pulse_width_ms)


def carried_epoch(now_s: float, old: Program | None, old_epoch: float | None,
                  new: Program) -> float:
    """The epoch at which ``new`` starts so that, at ``now_s``, it is at the fraction of its
    cycle that ``old`` has reached (0 if there was none)."""
    if old is None or old_epoch is None:
        return now_s
    fraction = old.phase(now_s, old_epoch) / old.cycle_ms
    return now_s - fraction * new.cycle_ms / 1000.0


FOLLOWS = ("change", "place")
#: A stretch shorter than this (ms) is passed over by :func:`change_epoch`: it could end
#: between the new cycle taking over and the loop sending its outputs.
_STRETCH_MS = 2.0


def change_epoch(now_s: float, old: Program | None, old_epoch: float | None,
                 new: Program, showing: dict[Actuator, Drive] | None = None,
                 before: dict[Actuator, Drive] | None = None) -> float:
    """The epoch at which ``new`` starts when it takes over from ``old`` with
    ``follow="change"`` (module docstring).

    The two cycles are compared in step from where ``old`` is now (the same phase, in
    ms: a trace plays its n-th point at the same time in both, so the part of the outline
    before a change lines up), stretch by stretch, as far as the longer cycle; ``new``
    starts at the first stretch where it asks an output to differ from what ``old``
    asks there, from what the array is ``showing`` and from what would play now
    without the change (``before``; default: ``old`` now). An outline shifted along the
    trace may ask, a point further on, for what is playing already: nothing would be
    felt there, so it is passed over. Where ``new`` is shorter than the phase ``old``
    has reached, it goes round (its next pass). If there is no such stretch, ``new``
    takes over at the same phase."""
    if old is None or old_epoch is None:
        return now_s
    p = old.phase(now_s, old_epoch)
    now_old = old.state_at(p)
    before = now_old if before is None else before
    showing = now_old if showing is None else showing
    span = max(old.cycle_ms, new.cycle_ms)
    cuts = {p, p + span}
    for prog in (old, new):
        m = math.floor(p / prog.cycle_ms)
        while m * prog.cycle_ms < p + span:
            cuts.update(u for t in prog.times if p < (u := m * prog.cycle_ms + t) < p + span)
            m += 1
    edges = sorted(cuts)
    for a, b in zip(edges, edges[1:]):
        if b - a < _STRETCH_MS:       # over before the loop sends it
            continue
        mid = (a + b) / 2.0         # within the stretch: a boundary, rounded, may fall aside
        x, y = new.state_at(mid % new.cycle_ms), old.state_at(mid % old.cycle_ms)
        if any(x.get(k) != y.get(k) and x.get(k) != showing.get(k) and x.get(k) != before.get(k)
               for k in x.keys() | y.keys()):
            start = p if a == p else a + min(1e-6, (b - a) / 4.0)
            return now_s - (start % new.cycle_ms) / 1000.0
    return now_s - (p % new.cycle_ms) / 1000.0


def _state_key(state: dict[Actuator, Drive]) -> tuple:
    return tuple((k, d if isinstance(d, int) else _train_key(d))
                 for k, d in sorted(state.items()))
