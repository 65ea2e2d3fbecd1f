"""What a model participant feels of a played stimulus.

The percept of a :class:`~vtexp.model.PlayReport` is a field over the skin and
time,

    f(x, t) = sum_a G(x - x_a) u_a(t)                                        (P1)

- ``x_a`` is where site ``a`` is felt on the skin (``geometry.pitch_mm``): an
  actuator's position, moved towards the stimuli before and after it when they
  follow quickly (the low-speed prior, P5, :func:`felt_positions`).
- ``G(x) = exp(-|x|^2 / (2 s^2))`` is the skin's spatial blur, with
  ``s = TPT / 2``: two equal spots ``2 s`` apart are just resolvable, so a
  two-point threshold TPT sets ``s``.
- ``u_a(t)`` is the actuator's perceived intensity through a leaky
  integrator with time constant ``tau``:

      u_a(t) = integral of x_a(t') exp(-(t - t') / tau) / tau dt'            (P2)

  where ``x_a(t)`` is the intensity of the pulses actually played (device
  onsets, not the schedule's).
- Each pulse's intensity is its fraction of the device's strongest drive
  (an SMA pin's: its stroke, P6, :func:`pin_strokes`),
  rounded to the participant's number of distinguishable levels L:
  ``a_q = round(a (L - 1)) / (L - 1)``.

Sensory noise is white. Its level is set by the two-point threshold itself:
two brief pulses (one ``tau`` long) on spots one TPT apart must be told apart
with d' = 1, the threshold. The discriminability of two percepts is then

    d'^2 = eta * integral (f1 - f2)^2 dx dt / N0                             (P3)

with ``N0`` that calibration (:func:`noise_density`) and ``eta`` the
participant's efficiency at identifying whole patterns relative to a
two-point judgement. Because the actuators sit on a grid, the spatial integral
is a quadratic form in the ``u_a`` with the Gaussian overlap matrix

    integral G(x - x_a) G(x - x_b) dx = pi s^2 exp(-|x_a - x_b|^2 / (4 s^2))  (P4)

and :func:`features` returns vectors whose squared Euclidean distances are the
integral in (P3), in units of TPT^2 tau: a square root of (P4) applied to the
sampled ``u(t)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model import DeviceProfile, PlayReport


def pulse_intensities(report: PlayReport, profile: DeviceProfile,
                      pin_thermal: tuple[float, float] | None = None) -> np.ndarray:
    """Each played pulse's drive as a fraction (0-1) of the device's strongest drive.

    Level drives: the level's effective volts over the highest level's. Pulse
    trains without ``pin_thermal``: the train's mean electrical power over that of
    the strongest train the profile allows (amplitude^2 x pulse width x frequency).
    With ``pin_thermal = (heating_ms, cooling_ms)``: the pin's mean stroke per pulse
    over the train (:func:`pin_strokes`, P6) over the stroke of one pulse of the
    widest width from a cool pin.
    """
    drive = profile.drive
    out = np.zeros(len(report.pulses))
    if drive.kind == "levels":
        volts = {lv.level: lv.volts for lv in drive.levels}
        top = max(volts.values()) or 1.0
        for i, p in enumerate(report.pulses):
            out[i] = volts.get(p.level, 0.0) / top if p.level is not None else 1.0
    elif pin_thermal is not None:
        out = pin_strokes(report, drive.amplitude_v, max(drive.pulse_width_ms), *pin_thermal)
    else:
        top = (drive.amplitude_v ** 2 * max(drive.pulse_width_ms) * max(drive.frequencies_hz))
        for i, p in enumerate(report.pulses):
            t = p.train
            out[i] = (t.amplitude_v ** 2 * t.pulse_width_ms * t.frequency_hz / top) if t else 1.0
    return np.clip(out, 0.0, 1.0)


def pin_strokes(report: PlayReport, volts: float, widest_ms: float, heating_ms: float,
                cooling_ms: float) -> np.ndarray:
    """Mean stroke per pulse of each played train, over one widest pulse's from cool (P6).

    An SMA pin contracts while a current pulse heats its wire and relaxes as the
    wire cools. In a first-order model of the wire (the contracted fraction ``x``
    moves towards 1 with time constant ``tau_h`` while a pulse heats it, and
    decays towards 0 with ``tau_c`` while it cools),

        x -> 1 - (1 - x) exp(-w (V / V0)^2 / tau_h)   during a pulse of width w
        x -> x exp(-t / tau_c)                           over t without current     (P6)

    each pulse moves the pin by ``(1 - x)(1 - exp(-w (V/V0)^2 / tau_h))``: a pin that
    has not cooled since the last pulse (``x`` near 1) moves less. Heating scales
    with electrical power, so with ``V^2`` relative to the profile's amplitude
    ``V0``. The state carries over from one train on a pin to the next. What is felt
    is the vibration's amplitude, the stroke: for a contactor as small as a pin the
    vibrotactile threshold does not depend on frequency (Verrillo 1963, *JASA*
    35:1962), so the frequency itself adds no weight.
    """
    out = np.ones(len(report.pulses))
    ref = 1.0 - np.exp(-widest_ms / heating_ms)
    state: dict[tuple[int, int], tuple[float, float]] = {}     # pin -> (x, time of x)
    for i in sorted(range(len(report.pulses)), key=lambda j: report.pulses[j].onset_ms):
        p = report.pulses[i]
        t = p.train
        if t is None:
            continue
        x, at = state.get((p.row, p.col), (0.0, p.onset_ms))
        x *= np.exp(-max(p.onset_ms - at, 0.0) / cooling_ms)
        period = 1000.0 / t.frequency_hz
        n = max(1, int(round(p.duration_ms / period)))
        gain = 1.0 - np.exp(-t.pulse_width_ms * (t.amplitude_v / volts) ** 2 / heating_ms)
        relax = np.exp(-max(period - t.pulse_width_ms, 0.0) / cooling_ms)
        total = 0.0
        for _ in range(n):
            stroke = (1.0 - x) * gain
            total += stroke
            x = (x + stroke) * relax
        out[i] = total / n / ref
        state[(p.row, p.col)] = (x, p.onset_ms + n * period)
    return out


def quantize(a: np.ndarray, levels: int) -> np.ndarray:
    """Round intensities to ``levels`` distinguishable steps from 0 to 1."""
    return np.round(a * (levels - 1)) / (levels - 1)


@dataclass(frozen=True)
class Skin:
    """The part of a participant that shapes the percept."""

    two_point_threshold_mm: float
    integration_ms: float
    intensity_levels: int
    localisation_sd_mm: float = 0.0     # sigma_s of (P5); 0: positions as played
    speed_sd_mm_s: float = 0.0          # sigma_v of (P5); 0: no low-speed prior
    pin_thermal: tuple[float, float] | None = None   # (heating_ms, cooling_ms) of (P6)

    @property
    def sigma_mm(self) -> float:
        return self.two_point_threshold_mm / 2.0

    @property
    def dt_ms(self) -> float:
        return self.integration_ms / 2.0


def activity(reports: list[PlayReport], profile: DeviceProfile, skin: Skin,
             support: np.ndarray | None = None, *,
             felt: list[np.ndarray] | None = None) -> np.ndarray:
    """``u_a(t)`` (P2) of each report on a common time grid: shape (reports, sites, bins).

    The sites are where pulses are felt (:func:`felt_positions`: the actuators, or
    places between them under the low-speed prior, P5), as rows of ``support``
    (``(row, col)`` in actuator units; default: every site any report uses, in
    :func:`support_of`'s order). A flat 1-D array of actuator indices (row * cols + col)
    is taken as those actuators' positions. ``felt``: each report's felt positions,
    when the caller has them (default: :func:`felt_positions`).
    """
    dt, tau = skin.dt_ms, skin.integration_ms
    if felt is None:
        felt = [felt_positions(r, profile, skin) for r in reports]
    support = support_of(felt) if support is None else as_positions(support, profile)
    end = max((max((p.onset_ms + p.duration_ms for p in r.pulses), default=0.0)
               for r in reports), default=0.0)
    n_bins = int(np.ceil((end + 3 * tau) / dt)) + 1
    index = {_site_key(rc): i for i, rc in enumerate(support)}
    x = np.zeros((len(reports), len(support), n_bins))
    for k, r in enumerate(reports):
        a = quantize(pulse_intensities(r, profile, skin.pin_thermal), skin.intensity_levels)
        for p, amp, rc in zip(r.pulses, a.tolist(), felt[k], strict=True):
            if amp <= 0:
                continue
            row = x[k, index[_site_key(rc)]]
            t0, t1 = p.onset_ms, p.onset_ms + p.duration_ms     # the pulse covers [t0, t1)
            b0, b1 = int(t0 // dt), min(int(np.ceil(t1 / dt)), n_bins)
            if b1 - b0 == 1:
                row[b0] += amp * (t1 - t0) / dt
            elif b1 > b0:
                row[b0] += amp * ((b0 + 1) * dt - t0) / dt
                row[b0 + 1:b1 - 1] += amp
                row[b1 - 1] += amp * (min(t1, b1 * dt) - (b1 - 1) * dt) / dt
    return leaky(x, dt, tau)


def _site_key(rc) -> tuple[float, float]:
    return (round(float(rc[0]), 6), round(float(rc[1]), 6))


def as_positions(support: np.ndarray, profile: DeviceProfile) -> np.ndarray:
    """``support`` as (row, col) positions: flat actuator indices are converted."""
    support = np.asarray(support)
    if support.ndim == 1:
        cols = profile.geometry.cols
        return np.stack([support // cols, support % cols], axis=1).astype(float)
    return support.astype(float)


def support_of(felt: list[np.ndarray]) -> np.ndarray:
    """Every distinct felt site of the reports, sorted: shape (sites, 2)."""
    keys = sorted({_site_key(rc) for f in felt for rc in f})
    return np.array(keys, dtype=float).reshape(-1, 2)


def felt_positions(report: PlayReport, profile: DeviceProfile, skin: Skin) -> np.ndarray:
    """Where each pulse is felt, (row, col) in actuator units: shape (pulses, 2).

    Successive stimuli are drawn towards one another when they follow quickly
    (the tau effect, the cutaneous rabbit, the length contraction of apparent
    motion). Goldreich (2007, *PLoS ONE* 2:e333; Goldreich & Tong 2013, *Front.
    Psychol.* 4:221) derives them from a Bayesian observer who expects slow
    movement: with measured positions ``m_i`` (localisation SD ``sigma_s``) and a
    prior on the speed between successive stimuli (SD ``sigma_v``), the felt
    positions minimise

        sum_i |x_i - m_i|^2 / sigma_s^2
          + sum_i |x_{i+1} - x_i|^2 / (sigma_v dt_i)^2                          (P5)

    (two taps ``l`` apart and ``dt`` apart are felt ``l / (1 + 2 (sigma_s / (sigma_v
    dt))^2)`` apart). A stimulus here is a group of pulses with one onset; ``m_i`` is
    its intensity-weighted centre (where two simultaneous vibrations are felt, between
    them), ``dt_i`` the onset-to-onset interval to the next group, and every pulse of a
    group moves with its centre. A group that is a whole contour ring has its centre
    where the next ring's is, and does not move.
    """
    rc = np.array([[p.row, p.col] for p in report.pulses], dtype=float).reshape(-1, 2)
    if skin.localisation_sd_mm <= 0 or skin.speed_sd_mm_s <= 0 or len(rc) < 2:
        return rc
    onsets = np.array([round(p.onset_ms, 6) for p in report.pulses])
    times, group = np.unique(onsets, return_inverse=True)
    if len(times) < 2:
        return rc
    w = np.clip(pulse_intensities(report, profile, skin.pin_thermal), 1e-9, None)
    pitch = profile.geometry.pitch_mm
    centre = np.zeros((len(times), 2))
    np.add.at(centre, group, rc * w[:, None])
    centre /= np.bincount(group, weights=w, minlength=len(times))[:, None]
    dt_s = np.diff(times) / 1000.0
    k = (skin.localisation_sd_mm / (skin.speed_sd_mm_s * dt_s)) ** 2    # (P5)'s weights
    n = len(times)
    A = np.eye(n)
    i = np.arange(n - 1)
    A[i, i] += k
    A[i + 1, i + 1] += k
    A[i, i + 1] -= k
    A[i + 1, i] -= k
    felt = np.linalg.solve(A, centre * pitch) / pitch
    return rc + (felt - centre)[group]


def leaky(x: np.ndarray, dt: float, tau: float) -> np.ndarray:
    """(P2) on a grid of step ``dt`` along the last axis: u[n] = a u[n-1] + (1 - a) x[n].

    A first-order recursive filter (scipy's ``lfilter``): the same products and sums,
    step by step, as the recursion written out, in C.
    """
    from scipy.signal import lfilter        # a second to import: only where it is used
    alpha = np.exp(-dt / tau)
    return lfilter([1.0 - alpha], [1.0, -alpha], x, axis=-1)


_FACTORS: dict[tuple, np.ndarray] = {}


def overlap_factor(profile: DeviceProfile, skin: Skin, support: np.ndarray) -> np.ndarray:
    """A square root R (R^T R = (P4) / TPT^2) over the ``support`` sites (cached)."""
    support = as_positions(support, profile)
    key = (profile.geometry.pitch_mm, skin.two_point_threshold_mm, support.tobytes())
    R = _FACTORS.get(key)
    if R is None:
        if len(_FACTORS) > 4096:
            _FACTORS.clear()
        R = _FACTORS[key] = _overlap_factor(profile, skin, support)
    return R


def _overlap_factor(profile: DeviceProfile, skin: Skin, support: np.ndarray) -> np.ndarray:
    rc = support * profile.geometry.pitch_mm
    d2 = ((rc[:, None, :] - rc[None, :, :]) ** 2).sum(axis=2)
    s = skin.sigma_mm
    S = np.pi * s * s / skin.two_point_threshold_mm ** 2 * np.exp(-d2 / (4 * s * s))
    w, V = np.linalg.eigh(S)                 # S may be near-singular when TPT >> pitch
    return (V * np.sqrt(np.clip(w, 0, None))).T


def features(reports: list[PlayReport], profile: DeviceProfile, skin: Skin,
             support: np.ndarray | None = None, *,
             felt: list[np.ndarray] | None = None) -> np.ndarray:
    """One vector per report (float32); ``|f_i - f_j|^2`` is the integral of (P3) over
    TPT^2 tau. ``support`` and ``felt``: as :func:`activity`'s (default: every felt
    site)."""
    if felt is None:
        felt = [felt_positions(r, profile, skin) for r in reports]
    if support is None:
        support = support_of(felt)
    u = activity(reports, profile, skin, support, felt=felt)          # (k, a, t)
    R = overlap_factor(profile, skin, support)              # (a, a)
    u *= np.sqrt(skin.dt_ms / skin.integration_ms)
    w = np.matmul(R.astype(np.float32), u.astype(np.float32))
    return w.reshape(len(reports), -1)


def winding_turns(report: PlayReport, profile: DeviceProfile, skin: Skin) -> float:
    """Turns the perceived path makes around its centre.

    The path is the centroid of the percept (P1) over time (the blur does not
    move centroids; the integration time smooths them). Angle steps count only
    while the path is farther than ``TPT / 2`` from the centre: closer in, the
    skin cannot tell where around the centre the touch is.
    """
    support = support_of([felt_positions(report, profile, skin)])
    if len(support) == 0:
        return 0.0
    u = activity([report], profile, skin, support)[0]         # (a, t)
    pos = support * profile.geometry.pitch_mm
    total = u.sum(axis=0)
    live = total > 1e-3 * total.max()
    if live.sum() < 3:
        return 0.0
    c = (u[:, live].T @ pos) / total[live, None]              # (t, 2)
    centre = (total[live, None] * c).sum(axis=0) / total[live].sum()
    v = c - centre
    r = np.hypot(v[:, 0], v[:, 1])
    ang = np.unwrap(np.arctan2(v[:, 0], v[:, 1]))
    far = (r[1:] > skin.sigma_mm) & (r[:-1] > skin.sigma_mm)
    return float(abs(np.diff(ang)[far].sum()) / (2 * np.pi))


def noise_density(skin: Skin) -> float:
    """``N0`` of (P3), in the units of :func:`features`: two pulses one ``tau`` long on spots
    one TPT apart differ by d' = 1 (the definition of the two-point threshold)."""
    s, tpt = skin.sigma_mm, skin.two_point_threshold_mm
    spatial = 2 * np.pi * s * s * (1 - np.exp(-tpt * tpt / (4 * s * s))) / tpt ** 2
    n = max(1, round(skin.integration_ms / skin.dt_ms))
    box = np.zeros(n + int(np.ceil(6 * skin.integration_ms / skin.dt_ms)))
    box[:n] = 1.0
    u = leaky(box, skin.dt_ms, skin.integration_ms)
    return float(spatial * (u * u).sum() * skin.dt_ms / skin.integration_ms)
