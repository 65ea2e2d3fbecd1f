"""Pulse trains on SMA pins with phantom points and apparent movement (seed 002, §2.2, §4).

Seed 002 drives each shape-memory-alloy pin with a train of short voltage
pulses (Fig. 11): amplitude A_p, frequency f, pulse length l_p, vibration time
L — 2 V, 25 or 40 Hz (50 Hz tried), 1 ms, 200 ms (Tables 2-3); at corners
1.5 ms pulses for 400 ms (Table 4). The points of a pattern are played one
after another along their order, each starting a stimulus-onset asynchrony
(SOA) after the previous one, so that the sensation moves (apparent movement,
§2.2, Fig. 3). A point between pins is a phantom point (§2.2, Fig. 2, §3.2):
the two pins of an edge midpoint, or the four of a cell centre, are driven
together.

Decisions:

- **Phantom intensities** follow a declared model. For a point at fractional
  position (row r + β_r, col c + β_c) the four surrounding pins get the
  bilinear shares w = (1−β_r)(1−β_c), (1−β_r)β_c, β_r(1−β_c), β_rβ_c, so an
  edge midpoint (one β = 0) involves two pins with 1−β and β. ``linear``
  drives each pin at intensity w (the intensities sum to 1); ``energy``
  drives it at √w (their squares sum to 1: the energy summation model of
  Tactile Brush, Israr & Poupyrev 2011, A_1 = √(1−β)·A_v, A_2 = √β·A_v). A
  pin with w = 0 is not driven. Seed 002 does not say which split it used.
- **Intensity is pulse amplitude**: a pin at intensity I is driven at
  I × ``amplitude_v`` volts (``corner_amplitude_v`` at corners), with the
  point's own frequency and pulse length. Intensities are at most 1, and
  ``amplitude_v`` may not exceed the profile's ``max_amplitude_v``, so no
  pin is ever driven above it. Seed 002 §3.3 notes that 1.5 V drives its
  pins: a phantom share below 0.75 of 2 V may be too weak to feel (linear
  model at a midpoint: 1 V; energy: 1.41 V; cell centres: 0.5 V and 1 V).
- **Timing** is onset to onset: point k+1 starts ``soa_ms`` after point k;
  if ``soa_ms`` is not given it follows Tactile Brush's rule for apparent
  motion, SOA = 0.32·d + 47.3 ms with d the duration of point k (so 111.3 ms
  after a 200 ms point, 175.3 ms after a 400 ms corner).
- **Times are multiples of 1/64 ms** (15.6 µs, far below a 1 ms pulse):
  binary fractions, so onsets, durations and their sums are exact in floating
  point and a limit such as ``max_on_ms`` = 400 is met exactly rather than
  missed by 1e-13 ms.
- **One pin, overlapping requests.** Consecutive points share pins (a pin
  and the phantom points beside it), and with SOA < d their requests
  overlap in time. A pin can play one pulse train at a time, so in each
  interval it plays the strongest request active then — the one of most
  electrical power, A²·l_p·f, the latest on ties — and the intervals are
  written as consecutive pulses.
- **Within the panel's limits by construction** (issue 20). The percept is
  carried by the points' onsets, one SOA apart (apparent movement: Tactile
  Brush's SOA is onset to onset), and by each point's pins together (a phantom
  point: §3.2); these are kept. What gives way is how long a train lasts, and
  only where a limit needs it, never lengthened:

  - *power budget* (``max_simultaneous``): where a point's onset would bring
    more pins on than the budget, the oldest point still vibrating stops
    there, all its pins together (so that it does not move), preferring one
    that holds a pin no newer point holds; the newest points carry the
    movement (the live loop's guard also keeps what the newest frame asks);
  - *on-time* (``max_on_ms``): with phantom points one pin serves several
    consecutive points (a pin and the points around it) and stays on
    throughout, on long outlines past ``max_on_ms`` (a horse silhouette,
    Grace Hopper's portrait: up to ~1150 ms). The pin rests ``min_off_ms``
    just before the onset of a point that uses it, the latest that leaves at
    most ``max_on_ms`` before the rest, and so on
    (:func:`vtexp.coding.limits.split_activations`). At 40 Hz a pulse comes
    every 25 ms, so a 20 ms rest takes out at most one 1 ms pulse of a train;
    and the point after the rest starts on that pin afresh, as seed 002's
    stimuli begin each point;
  - *cooling* (``min_off_ms``): a pin that would start again less than
    ``min_off_ms`` after it stopped ends its earlier train that much sooner.

  Refused, naming the parameter and a value that works
  (:class:`~vtexp.errors.UnsafeStimulus`): a frequency or pulse width above the
  profile's limits (amplitudes: :class:`~vtexp.errors.InputError`, as before);
  a vibration so long that no onset leaves room for the rest (at most
  ``max_on_ms`` less the rest always does); vibrations or SOAs shorter than the
  rest, which it would leave out whole. With seed 002's values (Tables 2-4,
  Tactile Brush's SOA) none of these happens on sma_5x5.

References
----------
.. [1] C. Jiang, K. Uchida, H. Sawada, IJICIC 10(3), 2014, §2.2, §3.2, §4,
       Tables 2-4, Fig. 11 (seed 002).
.. [2] A. Israr, I. Poupyrev, "Tactile Brush: drawing on skin with a tactile
       grid display", CHI 2011 (SOA = 0.32 d + 47.3; energy model).
"""

from __future__ import annotations

import itertools
import math
import warnings
from collections import Counter, defaultdict
from typing import Annotated, Literal

from pydantic import Field

from ..errors import InputError, UnsafeStimulus
from ..model import (
    DeviceProfile,
    Model,
    Ms,
    Pattern,
    Pulse,
    PulseTrain,
    PulseTrainDrive,
    Schedule,
)
from .limits import (
    Span,
    Unsplittable,
    at_least_ms,
    longest_splittable_ms,
    pause_ms,
    split_activations,
    split_refusal,
    whole_ms_below,
)

PhantomModel = Literal["linear", "energy"]


class PulseTrainParams(Model):
    """Parameters of :func:`pulse_trains` (the keys an experiment may declare)."""

    amplitude_v: Annotated[float, Field(gt=0)] = Field(2.0, description="A_p (Tables 2-3)")
    frequency_hz: Annotated[float, Field(gt=0)] = Field(
        40.0, description="f: 25 (Table 2), 40 (Table 3, adopted in §4), 50 tried")
    pulse_width_ms: Ms = Field(1.0, description="l_p (Tables 2-3)")
    vibration_ms: Ms = Field(
        200.0, description="L, how long one point vibrates (Tables 2-3)")
    corner_emphasis: bool = Field(True, description="play corner points with Table 4")
    corner_amplitude_v: Annotated[float, Field(gt=0)] = Field(2.0, description="Table 4")
    corner_frequency_hz: Annotated[float, Field(gt=0)] = Field(40.0, description="Table 4")
    corner_pulse_width_ms: Ms = Field(1.5, description="Table 4")
    corner_vibration_ms: Ms = Field(400.0, description="Table 4")
    phantom_model: PhantomModel = Field(
        "energy", description="intensity split of a phantom point: linear (1−β, β) or "
                              "energy (√(1−β), √β, Tactile Brush)")
    soa_ms: Ms | None = Field(
        None, description="onset-to-onset time between consecutive points; if absent, "
                          "Tactile Brush's 0.32·d + 47.3 ms")
    loops: Annotated[int, Field(ge=1, le=100)] = Field(1, description="times the path is played")


def tactile_brush_soa_ms(duration_ms: float) -> float:
    """SOA for apparent tactile motion after a stimulus of ``duration_ms``.

    Israr & Poupyrev (2011) found the SOA at which two vibrations are felt as
    one continuous motion to grow linearly with the duration d of each:
    SOA = 0.32·d + 47.3 ms.

    Examples
    --------
    >>> round(tactile_brush_soa_ms(200), 1)
    111.3
    """
    return 0.32 * float(duration_ms) + 47.3


def phantom_weights(row: float, col: float, model: PhantomModel = "energy"
                    ) -> list[tuple[tuple[int, int], float]]:
    """Physical pins and intensities (0..1) that make a point felt at (``row``, ``col``).

    A pin (whole ``row`` and ``col``) is itself, at intensity 1. Otherwise the
    surrounding pins share the point bilinearly, w = (1−β_r)(1−β_c), ... with
    β the fractional parts (an edge midpoint: two pins, 1−β and β; a cell
    centre: four pins); ``linear`` returns w (summing to 1), ``energy`` √w
    (squares summing to 1, Tactile Brush). Pins with w = 0 are left out.

    Examples
    --------
    >>> phantom_weights(0, 0.5, "linear")
    [((0, 0), 0.5), ((0, 1), 0.5)]
    >>> [round(w, 3) for _, w in phantom_weights(1.5, 2.5, "energy")]
    [0.5, 0.5, 0.5, 0.5]
    """
    if model not in ("linear", "energy"):
        raise InputError(f"unknown phantom model {model!r}; use 'linear' or 'energy'",
                         key="phantom_model")
    r0, c0 = math.floor(row), math.floor(col)
    br, bc = row - r0, col - c0
    out = []
    for dr, wr in ((0, 1.0 - br), (1, br)):
        for dc, wc in ((0, 1.0 - bc), (1, bc)):
            w = wr * wc
            if w > 0.0:
                out.append(((r0 + dr, c0 + dc), w if model == "linear" else math.sqrt(w)))
    return out


def pulse_trains(pattern: Pattern, profile: DeviceProfile, *, amplitude_v: float = 2.0,
                 frequency_hz: float = 40.0, pulse_width_ms: float = 1.0,
                 vibration_ms: float = 200.0, corner_emphasis: bool = True,
                 corner_amplitude_v: float = 2.0, corner_frequency_hz: float = 40.0,
                 corner_pulse_width_ms: float = 1.5, corner_vibration_ms: float = 400.0,
                 phantom_model: PhantomModel = "energy", soa_ms: float | None = None,
                 loops: int = 1) -> Schedule:
    """Play a pattern's points in order as pulse trains on SMA pins (seed 002, §4).

    Point k of ``pattern.ordered()`` starts at the sum of the SOAs before it
    and vibrates for ``vibration_ms`` with trains of ``pulse_width_ms`` pulses
    at ``frequency_hz``; a point flagged ``corner`` uses Table 4's values
    instead when ``corner_emphasis`` is on. A phantom point drives its two or
    four pins with intensities from ``phantom_model`` (:func:`phantom_weights`),
    as amplitudes. Where consecutive points' requests for one pin overlap, the
    pin plays the strongest one in each interval (module docstring). The path
    is played ``loops`` times, the SOA rule running on across the seams. Where
    the profile's limits of time and power need it, trains end sooner and pins
    rest before an onset (module docstring, "Within the panel's limits").

    Raises
    ------
    InputError
        If the profile is not driven by pulse trains, the pattern was made for
        another array size, or an amplitude exceeds the profile's
        ``max_amplitude_v``.
    UnsafeStimulus
        What cannot be fitted to the profile's limits, naming the parameter to
        change and a value that works; it carries the schedule as coded.
    """
    params = PulseTrainParams(
        amplitude_v=amplitude_v, frequency_hz=frequency_hz, pulse_width_ms=pulse_width_ms,
        vibration_ms=vibration_ms, corner_emphasis=corner_emphasis,
        corner_amplitude_v=corner_amplitude_v, corner_frequency_hz=corner_frequency_hz,
        corner_pulse_width_ms=corner_pulse_width_ms, corner_vibration_ms=corner_vibration_ms,
        phantom_model=phantom_model, soa_ms=soa_ms, loops=loops)
    _check_profile(params, pattern, profile)
    plain = (PulseTrain(amplitude_v=amplitude_v, frequency_hz=frequency_hz,
                        pulse_width_ms=pulse_width_ms), vibration_ms)
    corner = (PulseTrain(amplitude_v=corner_amplitude_v, frequency_hz=corner_frequency_hz,
                         pulse_width_ms=corner_pulse_width_ms), corner_vibration_ms)

    # Each point asks its pins for a train over [onset, onset + duration).
    points: list[list] = []            # [onset, offset, [(pin, power, train), ...]]
    t = 0.0
    for _ in range(loops):
        for p in pattern.ordered():
            train, dur = corner if (corner_emphasis and p.corner) else plain
            asks = []
            for pin, intensity in phantom_weights(p.row, p.col, phantom_model):
                # Whole volts at full intensity; shares rounded down to 0.1 mV, never up.
                amp = train.amplitude_v if intensity >= 1.0 else \
                    math.floor(train.amplitude_v * intensity * 1e4) / 1e4
                if amp <= 0:
                    continue
                tr = train.model_copy(update={"amplitude_v": amp})
                asks.append((pin, amp * amp * tr.pulse_width_ms * tr.frequency_hz, tr))
            on = _tick(t)
            points.append([on, on + _tick(dur), asks])
            t += soa_ms if soa_ms is not None else tactile_brush_soa_ms(dur)

    fit = _Fit(params, profile, points)
    fit.check_settings(pattern)
    fit.keep_to_budget()
    pulses = []
    for (row, col), reqs in _requests(points).items():
        spans = _resolve_pin(reqs)
        try:
            spans = split_activations(spans, profile.limits, [(r[0], r[1]) for r in reqs])
        except Unsplittable as e:
            e.actuator = (row, col)
            raise fit.refusal_to_split(e) from None
        pulses.extend(Pulse(row=row, col=col, onset_ms=q.onset_ms, duration_ms=q.duration_ms,
                            train=q.what) for q in spans)
    pulses.sort(key=lambda q: (q.onset_ms, q.row, q.col))
    return Schedule(device=profile.name, pulses=pulses, coding="pulse-trains",
                    params=params.model_dump())


def _requests(points: list[list], offsets: list[float] | None = None
              ) -> dict[tuple[int, int], list[tuple[float, float, float, int, PulseTrain]]]:
    """Each pin's requests (onset, offset, power, point's number, train) from the points'
    [onset, offset, asks]; ``offsets`` instead of the points' own, if given."""
    requests = defaultdict(list)
    for seq, (on, off, asks) in enumerate(points):
        off = off if offsets is None else offsets[seq]
        for pin, power, tr in asks:
            requests[pin].append((on, off, power, seq, tr))
    return requests


def _resolve_pin(reqs: list[tuple[float, float, float, int, PulseTrain]]) -> list[Span]:
    """One pin's requests as non-overlapping pulses: the strongest active request in each
    elementary interval (latest on ties); equal neighbours merged."""
    cuts = sorted({x for on, off, *_ in reqs for x in (on, off)})
    segments: list[list] = []          # [start, end, train]
    for a, b in itertools.pairwise(cuts):
        active = [r for r in reqs if r[0] <= a and r[1] >= b]
        if not active:
            continue
        best = max(active, key=lambda r: (r[2], r[3]))
        if segments and segments[-1][1] == a and segments[-1][2] == best[4]:
            segments[-1][1] = b
        else:
            segments.append([a, b, best[4]])
    return [Span(a, b - a, tr) for a, b, tr in segments if b > a]


class _Fit:
    """The profile's limits on one pulse-trains stimulus (module docstring, "Within the
    panel's limits"): the settings of its trains, the power budget, and the refusals that
    name the parameter to change. ``points`` is the coding's list of [onset, offset,
    asks]; :meth:`keep_to_budget` ends some of them earlier."""

    def __init__(self, params: PulseTrainParams, profile: DeviceProfile, points: list[list]):
        self.params = params
        self.profile = profile
        self.points = points
        self._offsets = [pt[1] for pt in points]       # as coded, before any is ended early
        self._unfitted: Schedule | None = None

    def unfitted(self) -> Schedule:
        """What would be played without fitting to the limits (for the live loop, whose
        guard holds the limits itself: :class:`~vtexp.errors.UnsafeStimulus`)."""
        if self._unfitted is None:
            pulses = [Pulse(row=r, col=c, onset_ms=q.onset_ms, duration_ms=q.duration_ms,
                            train=q.what)
                      for (r, c), reqs in _requests(self.points, self._offsets).items()
                      for q in _resolve_pin(reqs)]
            pulses.sort(key=lambda q: (q.onset_ms, q.row, q.col))
            self._unfitted = Schedule(device=self.profile.name, pulses=pulses,
                                      coding="pulse-trains", params=self.params.model_dump())
        return self._unfitted

    def refuse(self, text: str) -> UnsafeStimulus:
        return UnsafeStimulus(f"pulse-trains on {self.profile.name}: {text}",
                              schedule=self.unfitted())

    def _used(self, pattern: Pattern) -> list[str]:
        """'' for the plain trains and/or 'corner_' for Table 4's, as the pattern uses them."""
        corners = self.params.corner_emphasis and any(p.corner for p in pattern.points)
        plain = not self.params.corner_emphasis or any(not p.corner for p in pattern.points)
        return [k for k, used in (("", plain), ("corner_", corners)) if used]

    def check_settings(self, pattern: Pattern) -> None:
        """Frequency and pulse width of the trains the pattern uses, within the profile's
        limits of one pulse (amplitudes: :func:`_check_profile`)."""
        lim = self.profile.limits
        name = self.profile.name
        for k in self._used(pattern):
            f = getattr(self.params, f"{k}frequency_hz")
            w = getattr(self.params, f"{k}pulse_width_ms")
            if lim.max_frequency_hz is not None and f > lim.max_frequency_hz:
                raise self.refuse(f"frequency {f:g} Hz exceeds max_frequency_hz "
                                  f"{lim.max_frequency_hz:g} Hz of {name}: set {k}frequency_hz "
                                  f"to at most {lim.max_frequency_hz:g}")
            if lim.max_pulse_width_ms is not None and w > lim.max_pulse_width_ms:
                raise self.refuse(f"pulse width {w:g} ms exceeds max_pulse_width_ms "
                                  f"{lim.max_pulse_width_ms:g} ms of {name}: set "
                                  f"{k}pulse_width_ms to at most {lim.max_pulse_width_ms:g}")
            if w >= 1000.0 / f:
                raise self.refuse(f"pulse width {w:g} ms does not fit in the period of "
                                  f"{f:g} Hz (always on): set {k}pulse_width_ms below "
                                  f"{1000.0 / f:g}, or {k}frequency_hz below {1000.0 / w:g}")

    def keep_to_budget(self) -> None:
        """At most ``max_simultaneous`` pins on at once: where a point's onset would bring
        more, the oldest point still vibrating that holds a pin no other point holds then
        stops at that onset (its pins together, so that a phantom point does not move; if
        none holds a pin of its own, the oldest), until they fit."""
        budget = self.profile.limits.max_simultaneous
        pts = self.points
        active: list[int] = []
        for k, (on, _, asks) in enumerate(pts):
            if not asks:
                continue
            active = [j for j in active if pts[j][1] > on]
            active.append(k)
            while True:
                holders = Counter(pin for j in active for pin, _, _ in pts[j][2])
                if len(holders) <= budget:
                    break
                older = [j for j in active if pts[j][0] < on]
                oldest = next((j for j in older
                               if any(holders[pin] == 1 for pin, _, _ in pts[j][2])),
                              older[0] if older else None)
                if oldest is None:
                    raise self.refuse(
                        f"{len(holders)} pins would be on at once at {on:.1f} ms (points "
                        f"beginning together there), above max_simultaneous {budget} of "
                        f"{self.profile.name}: encode it without phantom points "
                        f"(subdivisions 1), or set soa_ms to at least 1")
                pts[oldest][1] = on
                active.remove(oldest)

    def refusal_to_split(self, e: Unsplittable) -> UnsafeStimulus:
        """The refusal of a pin that no rest can split (:func:`split_refusal`), naming what
        is too long or too short for it. A pin fails to split only where a request on it
        outlasts ``max_on_ms`` less the rest (a vibration that long), or is shorter than
        the rest (a vibration, or an SOA at which the budget ends a point, that short)."""
        lim = self.profile.limits
        p = self.params
        kinds = [k for k in ("", "corner_") if k == "" or p.corner_emphasis]
        if e.kind == "max_on" and not e.crowded:
            most = longest_splittable_ms(lim)
            keys = [f"{k}vibration_ms" for k in kinds if getattr(p, f"{k}vibration_ms") > most]
            fix = f"{' and '.join(keys) or 'vibration_ms'} to at most {whole_ms_below(most)}"
        else:
            need = pause_ms(lim)
            keys = [f"{k}vibration_ms" for k in kinds
                    if getattr(p, f"{k}vibration_ms") <= need]
            shortest = min(getattr(p, f"{k}vibration_ms") for k in kinds)
            soa = p.soa_ms if p.soa_ms is not None else tactile_brush_soa_ms(shortest)
            if soa <= need:
                keys.insert(0, "soa_ms")
            fix = f"{' and '.join(keys) or 'soa_ms'} to at least {at_least_ms(need)}"
        return self.refuse(f"{split_refusal(e, lim)}: set {fix}")


def _tick(t_ms: float) -> float:
    """``t_ms`` rounded to a multiple of 1/64 ms (exact in binary floating point)."""
    return round(t_ms * 64.0) / 64.0


def _check_profile(params: PulseTrainParams, pattern: Pattern, profile: DeviceProfile) -> None:
    if not isinstance(profile.drive, PulseTrainDrive):
        raise InputError(f"pulse-trains drives SMA pins with pulse trains, but {profile.name} "
                         f"is driven by {profile.drive.kind}; use a coding for that drive")
    if (pattern.rows, pattern.cols) != (profile.rows, profile.cols):
        raise InputError(f"the pattern was encoded for a {pattern.rows}x{pattern.cols} array, "
                         f"but {profile.name} is {profile.rows}x{profile.cols}; encode it "
                         "again for this device")
    lim = profile.limits.max_amplitude_v
    for key in ("amplitude_v", "corner_amplitude_v"):
        v = getattr(params, key)
        if lim is not None and v > lim:
            raise InputError(f"{v} V is above max_amplitude_v {lim} V of {profile.name}",
                             key=key)
    drive = profile.drive
    for key, value, known in (("frequency_hz", params.frequency_hz, drive.frequencies_hz),
                              ("corner_frequency_hz", params.corner_frequency_hz,
                               drive.frequencies_hz),
                              ("pulse_width_ms", params.pulse_width_ms, drive.pulse_width_ms),
                              ("corner_pulse_width_ms", params.corner_pulse_width_ms,
                               drive.pulse_width_ms)):
        if known and not any(abs(value - k) < 1e-9 for k in known):
            warnings.warn(f"pulse-trains: {key} = {value} is not among the values "
                          f"{profile.name} is characterised for ({known})", UserWarning,
                          stacklevel=3)
