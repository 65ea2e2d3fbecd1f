"""How a coding keeps its stimulus within a device's limits, or says what to change.

Every Schedule is checked by :func:`vtexp.safety.check_schedule` before it is played, and
that check only refuses. The codings therefore build their Schedules to pass it (issue 20,
"safe by construction"): where a coding's definition allows, an activation that would
break ``max_on_ms`` or ``min_off_ms`` is split by a pause, as the live loop already does
across frames (:class:`vtexp.safety.StreamGuard`); where it does not, the coding raises
:class:`~vtexp.errors.UnsafeStimulus` naming the parameter to change and a value that
works. This module holds what the three codings share; each coding's docstring states
its own rule and why it keeps its paper's percept.

The split (:func:`split_activations`), for the pulses of one actuator:

- an *activation* is a run of its pulses that overlap or touch, merged as
  ``check_schedule`` merges them;
- **nothing is lengthened, and no pulse is left out whole**: a pause is made by ending
  what came before it earlier; a piece of a pulse that falls in a pause is left out;
- an activation longer than ``max_on_ms`` gets a pause just before the latest onset of a
  pulse in it that leaves at most ``max_on_ms`` of it before the pause, and so on from
  that onset (in a trace or a train of apparent movement an onset is where the next
  point begins: the pause makes it a fresh start of that actuator). **Onsets are kept**:
  a pause that would take in another pulse's onset is taken only where no other will
  do, and then that pulse starts when the pause ends (it is shortened from its start,
  by less than the pause);
- an activation that begins less than ``min_off_ms`` after the previous one ended: the
  previous one ends a pause before it begins;
- the pause is :attr:`~vtexp.model.SafetyLimits.rest_ms` (``min_off_ms``, or a tenth of
  ``max_on_ms`` on a profile without a cooling time: the live loop's rest), plus one
  1/64 ms tick so that floating-point rounding never leaves it shorter than the limit.

It fails (:class:`Unsplittable`) only where no onset leaves room for the pause: a pulse
longer than ``max_on_ms`` less the pause (one that holds the actuator on past
``max_on_ms`` from the start of its activation), or pulses shorter than the pause that it
would leave out whole (``crowded``: onsets closer together than the pause), or an
activation too short to end a pause before the next one begins.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Hashable, Iterable
from dataclasses import dataclass
from typing import Any

from ..model import Pulse, SafetyLimits, Schedule

#: As ``vtexp.safety``: two pulses of one actuator closer than this are one activation.
CONTIGUOUS_MS = 1e-6
#: Added to every pause (a binary fraction: times that are multiples of 1/64 ms stay so).
TICK_MS = 1.0 / 64.0


@dataclass(frozen=True)
class Span:
    """One pulse of one actuator: ``onset_ms``, ``duration_ms`` and what it plays
    (``what``: a level, a train, or the index of the coding's own pulse)."""

    onset_ms: float
    duration_ms: float
    what: Any = None

    @property
    def offset_ms(self) -> float:
        # The same arithmetic as Pulse.offset_ms, so that runs and gaps are measured
        # exactly as check_schedule measures them.
        return self.onset_ms + self.duration_ms


class Unsplittable(Exception):
    """No pause can be made: ``kind`` ``max_on`` (the activation ``start_ms``..``end_ms``
    is too long, and no onset in it leaves room for a pause: none late enough, or,
    ``crowded``, every one would leave out a whole pulse that began less than a pause
    before it) or ``min_off`` (it is too short, or ends too soon after a pulse began, to
    end a pause before the next one begins at ``next_ms``)."""

    def __init__(self, kind: str, start_ms: float, end_ms: float,
                 next_ms: float | None = None, *, crowded: bool = False):
        super().__init__(kind)
        self.kind = kind
        self.start_ms = start_ms
        self.end_ms = end_ms
        self.next_ms = next_ms
        self.crowded = crowded
        #: (row, col), set by :func:`split_pulses`
        self.actuator: tuple[int, int] | None = None


def pause_ms(limits: SafetyLimits) -> float:
    """The pause a split makes: ``limits.rest_ms`` and one tick."""
    return limits.rest_ms + TICK_MS


def longest_splittable_ms(limits: SafetyLimits) -> float:
    """The longest pulse that a split always finds room for: ``max_on_ms`` less the pause
    (any pulse of at most this length, in any pattern, can be split; a longer one may not)."""
    return limits.max_on_ms - pause_ms(limits)


def activations(spans: list[Span]) -> list[tuple[float, float]]:
    """(start, end) of each activation of ``spans`` (sorted by onset), merged as
    ``check_schedule`` merges pulses that overlap or touch."""
    out: list[tuple[float, float]] = []
    start = end = None
    for q in spans:
        if end is not None and q.onset_ms <= end + CONTIGUOUS_MS:
            end = max(end, q.offset_ms)
            continue
        if end is not None:
            out.append((start, end))
        start, end = q.onset_ms, q.offset_ms
    if end is not None:
        out.append((start, end))
    return out


def split_activations(spans: list[Span], limits: SafetyLimits,
                      requests: Iterable[tuple[float, float]] | None = None) -> list[Span]:
    """One actuator's pulses with the pauses that ``max_on_ms`` and ``min_off_ms`` need
    (module docstring), sorted by onset; ``spans`` itself if none is needed.

    ``requests``: the (onset, offset) of what the pulses play, if not the pulses
    themselves (a coding whose pulses are pieces of overlapping requests, one per point,
    gives the requests): a pause ends at the onset of one, and none is left out whole.
    A pause that keeps every onset is preferred; failing that, one that only delays the
    start of a request that began less than a pause before it (shortened from its start).

    Raises
    ------
    Unsplittable
        Where no onset leaves room for the pause.
    """
    if not spans:
        return spans
    pause = pause_ms(limits)
    asks = sorted(requests if requests is not None
                  else ((q.onset_ms, q.offset_ms) for q in spans))
    out = sorted(spans, key=lambda q: q.onset_ms)
    changed = False
    for _ in range(4 * len(asks) + 4):           # each cut settles one more onset
        runs = activations(out)
        cut = None
        for i, (s, e) in enumerate(runs):
            if e - s > limits.max_on_ms:
                # Onsets that leave [s, onset - pause) within max_on_ms (by a tick:
                # rounding never takes it over) and not empty; the latest that keeps every
                # onset, else the latest that leaves no request out whole.
                top = s + limits.max_on_ms + limits.rest_ms
                fits = [t for t, _ in asks if s + pause < t <= top and t < e]
                keep = [t for t in fits if not any(t - pause <= a < t for a, _ in asks)]
                whole = [t for t in fits
                         if not any(t - pause <= a < t and b <= t for a, b in asks)]
                if not (keep or whole):
                    raise Unsplittable("max_on", s, e, crowded=bool(fits))
                cut = max(keep or whole)
                break
            if i + 1 < len(runs) and runs[i + 1][0] - e < limits.min_off_ms:
                nxt = runs[i + 1][0]
                if nxt - pause <= s or any(nxt - pause <= a < nxt for a, _ in asks):
                    raise Unsplittable("min_off", s, e, nxt)
                cut = nxt
                break
        if cut is None:
            return out if changed else spans
        out = sorted(_clip(out, cut - pause, cut), key=lambda q: q.onset_ms)
        changed = True
    raise AssertionError("split_activations did not settle")     # pragma: no cover


def split_pulses(pulses: list[Pulse], limits: SafetyLimits) -> list[Pulse]:
    """``pulses`` (of any actuators, each pulse its own request) with the pauses their
    actuators need (:func:`split_activations`): a pulse cut by a pause becomes its
    pieces, in its place; ``pulses`` itself if no pause is needed.

    Raises
    ------
    Unsplittable
        With ``actuator`` set, where no onset leaves room for the pause.
    """
    by_actuator: dict[tuple[int, int], list[Span]] = defaultdict(list)
    for i, q in enumerate(pulses):
        by_actuator[(q.row, q.col)].append(Span(q.onset_ms, q.duration_ms, i))
    pieces: dict[int, list[Span]] = {}
    for key, spans in by_actuator.items():
        try:
            fitted = split_activations(spans, limits)
        except Unsplittable as e:
            e.actuator = key
            raise
        if fitted is not spans:
            for q in spans:
                pieces[q.what] = []
            for q in fitted:
                pieces[q.what].append(q)
    if not pieces:
        return pulses
    out = []
    for i, q in enumerate(pulses):
        if i not in pieces:
            out.append(q)
            continue
        out.extend(q.model_copy(update={"onset_ms": s.onset_ms, "duration_ms": s.duration_ms})
                   for s in sorted(pieces[i], key=lambda s: s.onset_ms))
    return out


def fit_schedule(schedule: Schedule, limits: SafetyLimits
                 ) -> tuple[Schedule, int, float | None]:
    """``schedule`` with the pauses its actuators need (:func:`split_pulses`; the same
    object if none is), and the most of its actuators on at one moment and when
    (:func:`most_on_at_once`), for the coding to hold against ``max_simultaneous``.

    Raises
    ------
    Unsplittable
        As :func:`split_pulses`.
    """
    pulses = split_pulses(schedule.pulses, limits)
    fitted = schedule if pulses is schedule.pulses else \
        schedule.model_copy(update={"pulses": pulses})
    most, when = most_on_at_once(((q.row, q.col), q.onset_ms, q.offset_ms)
                                 for q in fitted.pulses)
    return fitted, most, when


def _clip(spans: list[Span], lo: float, hi: float) -> list[Span]:
    """``spans`` without what falls in [lo, hi): never lengthened, onsets kept."""
    out = []
    for q in spans:
        a, b = q.onset_ms, q.offset_ms
        if b <= lo or a >= hi:
            out.append(q)
            continue
        if a < lo:
            d = duration_to(a, lo)
            if d > 0:
                out.append(Span(a, d, q.what))
        if b > hi:
            d = duration_to(hi, b)
            if d > 0:
                out.append(Span(hi, d, q.what))
    return out


def duration_to(onset_ms: float, end_ms: float) -> float:
    """The longest duration whose pulse from ``onset_ms`` ends by ``end_ms`` in floating
    point (``onset_ms + duration <= end_ms``): a shortened pulse never ends later."""
    d = end_ms - onset_ms
    while d > 0 and onset_ms + d > end_ms:
        d = math.nextafter(d, 0.0)
    return d


def most_on_at_once(pulses: Iterable[tuple[Hashable, float, float]]
                    ) -> tuple[int, float | None]:
    """The most actuators on at one moment, and the first moment it happens, for
    ``pulses`` given as (actuator, onset_ms, offset_ms): swept as ``check_schedule``
    sweeps them (at one instant, what ends goes off before what begins)."""
    events = []
    for key, on, off in pulses:
        events.append((on, 1, key))
        events.append((off, -1, key))
    events.sort(key=lambda e: (e[0], e[1]))
    count: dict[Hashable, int] = defaultdict(int)
    best, when = 0, None
    for t, delta, key in events:
        count[key] += delta
        if count[key] == 0:
            del count[key]
        if len(count) > best:
            best, when = len(count), t
    return best, when


def split_refusal(e: Unsplittable, limits: SafetyLimits) -> str:
    """What :class:`Unsplittable` ``e`` (``actuator`` set) refuses, for the coding to add
    what to change."""
    row, col = e.actuator
    length = e.end_ms - e.start_ms
    if e.kind == "max_on":
        why = ("every pause would leave out a whole pulse that began less than a pause "
               "before it" if e.crowded else "no onset in it is late enough")
        return (f"{where(row, col, e.start_ms)} would be on for {length:.1f} ms without a "
                f"pause, above max_on_ms {limits.max_on_ms:g} ms, and it cannot rest "
                f"{limits.rest_ms:g} ms before an onset: {why}")
    return (f"{where(row, col, e.start_ms)} is on for {length:.1f} ms and begins again at "
            f"{e.next_ms:.1f} ms, too soon to rest min_off_ms {limits.min_off_ms:g} ms "
            f"between without leaving out a whole pulse")


def at_least_ms(x_ms: float) -> int:
    """The smallest whole number of ms above ``x_ms`` (a value to suggest for "at least")."""
    return math.floor(x_ms) + 1


def whole_ms_below(x_ms: float) -> int:
    """The largest whole number of ms at most ``x_ms`` (a value to suggest for "at most")."""
    return int(math.floor(x_ms + 1e-9))


def where(row: int, col: int, t_ms: float) -> str:
    """An actuator and a time, as :mod:`vtexp.safety` names them."""
    return f"actuator (row {row}, col {col}) at {t_ms:.1f} ms"
