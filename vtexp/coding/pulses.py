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
from collections import defaultdict
from typing import Annotated, Literal

from pydantic import Field

from ..errors import InputError
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
    is played ``loops`` times, the SOA rule running on across the seams.

    Raises
    ------
    InputError
        If the profile is not driven by pulse trains, the pattern was made for
        another array size, or an amplitude exceeds the profile's
        ``max_amplitude_v``.
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
    requests: dict[tuple[int, int], list[tuple[float, float, float, int, PulseTrain]]] = \
        defaultdict(list)
    t = 0.0
    seq = 0
    for _ in range(loops):
        for p in pattern.ordered():
            train, dur = corner if (corner_emphasis and p.corner) else plain
            for pin, intensity in phantom_weights(p.row, p.col, phantom_model):
                # Whole volts at full intensity; shares rounded down to 0.1 mV, never up.
                amp = train.amplitude_v if intensity >= 1.0 else \
                    math.floor(train.amplitude_v * intensity * 1e4) / 1e4
                if amp <= 0:
                    continue
                tr = train.model_copy(update={"amplitude_v": amp})
                power = amp * amp * tr.pulse_width_ms * tr.frequency_hz
                on = _tick(t)
                requests[pin].append((on, on + _tick(dur), power, seq, tr))
            seq += 1
            t += soa_ms if soa_ms is not None else tactile_brush_soa_ms(dur)

    pulses = []
    for (row, col), reqs in requests.items():
        pulses.extend(_resolve_pin(row, col, reqs))
    pulses.sort(key=lambda q: (q.onset_ms, q.row, q.col))
    return Schedule(device=profile.name, pulses=pulses, coding="pulse-trains",
                    params=params.model_dump())


def _resolve_pin(row: int, col: int,
                 reqs: list[tuple[float, float, float, int, PulseTrain]]) -> list[Pulse]:
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
    return [Pulse(row=row, col=col, onset_ms=a, duration_ms=b - a, train=tr)
            for a, b, tr in segments if b > a]


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
