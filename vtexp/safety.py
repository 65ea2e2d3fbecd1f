"""The one place where a Schedule is checked against a device profile's limits.

Every device backend calls :func:`check_schedule` before anything reaches an
actuator (``vtexp.devices.base.DeviceBase.play``). A refusal names the
actuator, the time and the limit.

Limits that span two plays (an SMA wire must cool for ``min_off_ms`` after
one play before the next drives it again, seed 002 §3.3) are computed here
too, by :func:`cooling_wait_ms`; ``DeviceBase.play`` waits that long before
it starts, rather than refusing a replay the participant asked for.

A live stream (``vtexp live``) has no schedule to check in advance: each frame
of outputs passes :class:`StreamGuard`, which holds the same limits across
frames — maximum on-time, cooling, power budget — by leaving out what would
break them, and says what it left out (:class:`Degradation`).
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Mapping
from dataclasses import dataclass

from .errors import UnsafeStimulus
from .model import DeviceProfile, LevelDrive, Pulse, PulseTrain, Schedule

# Two pulses of one actuator closer than this are treated as one continuous activation.
_CONTIGUOUS_MS = 1e-6


def _where(p: Pulse, t_ms: float | None = None) -> str:
    t = p.onset_ms if t_ms is None else t_ms
    return f"actuator (row {p.row}, col {p.col}) at {t:.1f} ms"


def setting_problem(row: int, col: int, level: int | None, train: PulseTrain | None,
                    profile: DeviceProfile) -> str | None:
    """What is wrong with driving actuator (``row``, ``col``) at ``level`` or with
    ``train`` on ``profile``, or None: inside the array, the profile's drive kind,
    level, amplitude, frequency and pulse width within limits, a pulse shorter
    than its period. The limits of one setting, whatever its timing."""
    lim = profile.limits
    name = profile.name
    if row < 0 or col < 0 or row >= profile.rows or col >= profile.cols:
        return f"outside the {profile.rows}x{profile.cols} array of {name}"
    if isinstance(profile.drive, LevelDrive):
        if level is None:
            return f"{name} is driven by levels, but the pulse has a pulse train"
        if level > lim.max_level:
            return f"level {level} exceeds max_level {lim.max_level} of {name}"
        return None
    tr = train
    if tr is None:
        return f"{name} is driven by pulse trains, but the pulse has a level"
    if lim.max_amplitude_v is not None and tr.amplitude_v > lim.max_amplitude_v:
        return (f"amplitude {tr.amplitude_v} V exceeds max_amplitude_v "
                f"{lim.max_amplitude_v} V of {name}")
    if lim.max_frequency_hz is not None and tr.frequency_hz > lim.max_frequency_hz:
        return (f"frequency {tr.frequency_hz} Hz exceeds max_frequency_hz "
                f"{lim.max_frequency_hz} Hz of {name}")
    if lim.max_pulse_width_ms is not None and tr.pulse_width_ms > lim.max_pulse_width_ms:
        return (f"pulse width {tr.pulse_width_ms} ms exceeds max_pulse_width_ms "
                f"{lim.max_pulse_width_ms} ms of {name}")
    if tr.pulse_width_ms >= 1000.0 / tr.frequency_hz:
        return (f"pulse width {tr.pulse_width_ms} ms does not fit in the period of "
                f"{tr.frequency_hz} Hz (always on)")
    return None


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
    checked: set[tuple] = set()             # a setting repeats on many pulses: judged once
    for p in schedule.pulses:
        tr = p.train
        setting = (p.row, p.col, p.level,
                   None if tr is None else (tr.amplitude_v, tr.frequency_hz, tr.pulse_width_ms))
        if setting not in checked:
            problem = setting_problem(p.row, p.col, p.level, tr, profile)
            if problem:
                raise UnsafeStimulus(f"{_where(p)}: {problem}")
            checked.add(setting)
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


# --------------------------------------------------------------------------- limits across frames

#: Added to a pause the guard waits out, so that a pause it allows is never shorter
#: than the limit once times are rounded (``outputs_schedule``) or subtracted.
_SLACK_MS = 0.002

#: What one actuator does in a frame of outputs: a level, or a pulse train.
Drive = int | PulseTrain
Actuator = tuple[int, int]


@dataclass(frozen=True)
class Degradation:
    """What :meth:`StreamGuard.admit` changed in a frame, and why (for the screen and the log).

    ``kind``: ``refused`` (a setting beyond a limit of one pulse: never driven),
    ``max_on`` (on for ``max_on_ms``: switched off, the train cut short),
    ``rest`` (resting after such a cut), ``cooling`` (off less than ``min_off_ms``
    since it last stopped), ``budget`` (more than ``max_simultaneous`` asked for:
    skipped); and ``late``: not a degradation but a fault, an actuator that was on
    longer than ``max_on_ms`` because the frame that switched it off came later than
    the guard's deadline (a host too busy to keep it).
    """

    kind: str
    actuators: tuple[Actuator, ...]
    text: str


class StreamGuard:
    """The profile's limits over a stream of output frames (live drive), degrading
    rather than refusing.

    A frame says what every actuator should do now; there is no schedule to
    check in advance, and a stream has no end. :meth:`admit` therefore returns the
    part of a frame that is safe now, and what it left out:

    - **maximum on-time**: an actuator on for ``max_on_ms`` (less ``margin_ms``,
      the time the frame that stops it may take to reach the device) is switched
      off — its train is cut short — and rests for ``rest_ms``: ``min_off_ms``, or,
      for a profile without a cooling time, a tenth of ``max_on_ms``, so that it
      still gets a real pause (at most 91 % on);
    - **cooling**: an actuator that stopped less than ``min_off_ms`` ago stays off
      (SMA wires, seed 002 §3.3), whether a frame or a play stopped it;
    - **power budget**: of more than ``max_simultaneous`` actuators asked for, the
      strongest (level, or pulse power A²·width·f) are kept first; among equals, those
      the previous frame did not ask for (where the object has just moved: the newest
      frame is what plays), then those already on, then in raster order; the rest are
      skipped;
    - **one setting's limits** (:func:`setting_problem`): such an actuator is never
      driven.

    Times are on the caller's clock in ms. :meth:`commit` is told what was applied,
    stamped before the frame was sent (an actuator switched on is counted as on from
    then) and after the device confirmed it (one switched off is counted as on until
    then), so the on-times and pauses it measures are never shorter than the
    device's. ``last_off_ms`` may be shared with the cooling of plays
    (:func:`cooling_wait_ms`). :meth:`next_deadline_ms` says when the guard next
    needs a frame even if nothing else changes (a train to cut, a rest that ends).
    """

    def __init__(self, profile: DeviceProfile,
                 last_off_ms: dict[Actuator, float] | None = None, *,
                 margin_ms: float = 50.0, rest_ms: float | None = None):
        lim = profile.limits
        self.profile = profile
        self.max_on_ms = lim.max_on_ms
        self.min_off_ms = lim.min_off_ms
        self.budget = lim.max_simultaneous
        self.margin_ms = min(margin_ms, lim.max_on_ms / 2)
        self.rest_ms = rest_ms if rest_ms is not None else lim.rest_ms
        self.last_off_ms = last_off_ms if last_off_ms is not None else {}
        self.on_since: dict[Actuator, float] = {}
        self.rest_until: dict[Actuator, float] = {}
        self._held: dict[Actuator, float] = {}
        self._cut: set[Actuator] = set()
        self._problems: dict[tuple[Actuator, Drive], str | None] = {}
        #: (actuator, on-time in ms) of every activation that outlasted max_on_ms.
        self.overruns: list[tuple[Actuator, float]] = []
        self._asked: set[Actuator] = set()

    # -- one frame ---------------------------------------------------------------------------
    def admit(self, desired: Mapping[Actuator, Drive], now_ms: float
              ) -> tuple[dict[Actuator, Drive], list[Degradation]]:
        """The part of ``desired`` (actuator -> drive; every other actuator off) that may
        be applied at ``now_ms``, and what was left out (:class:`Degradation`)."""
        allowed: dict[Actuator, Drive] = {}
        refused: list[tuple[Actuator, str]] = []
        cut: list[Actuator] = []
        resting: list[Actuator] = []
        cooling: list[Actuator] = []
        held: dict[Actuator, float] = {}
        self._cut = set()
        for key, drive in desired.items():
            if isinstance(drive, int) and not isinstance(drive, bool) and drive == 0:
                continue                                # level 0: off
            problem = self._problem(key, drive)
            if problem:
                refused.append((key, problem))
                continue
            since = self.on_since.get(key)
            if since is not None:
                if now_ms + self.margin_ms >= since + self.max_on_ms:
                    cut.append(key)
                    self._cut.add(key)
                    held[key] = now_ms + self.rest_ms
                    continue
            else:
                rest = self.rest_until.get(key, -math.inf)
                cool = self.last_off_ms.get(key, -math.inf) + self.min_off_ms + _SLACK_MS
                if rest > now_ms or cool > now_ms:
                    (resting if rest >= cool else cooling).append(key)
                    held[key] = max(rest, cool)
                    continue
            allowed[key] = drive
        skipped: list[Actuator] = []
        if len(allowed) > self.budget:
            before = self._asked
            ranked = sorted(allowed, key=lambda k: (-_strength(allowed[k]), k in before,
                                                    k not in self.on_since, k))
            for key in ranked[self.budget:]:
                skipped.append(key)
                del allowed[key]
        self._held = held
        self._asked = set(desired)
        notes: list[Degradation] = []
        if refused:
            (k0, why), n = refused[0], len(refused)
            notes.append(Degradation("refused", tuple(k for k, _ in refused),
                                     f"{n} actuator(s) never driven: (row {k0[0]}, col "
                                     f"{k0[1]}) {why}"))
        if cut:
            notes.append(Degradation("max_on", tuple(cut),
                                     f"max on-time: {len(cut)} train(s) cut short at "
                                     f"{self.max_on_ms - self.margin_ms:g} ms (limit "
                                     f"{self.max_on_ms:g} ms), resting {self.rest_ms:g} ms"))
        if resting:
            notes.append(Degradation("rest", tuple(resting),
                                     f"resting after max on-time: {len(resting)} held off"))
        if cooling:
            notes.append(Degradation("cooling", tuple(cooling),
                                     f"cooling: {len(cooling)} held off (min_off_ms "
                                     f"{self.min_off_ms:g})"))
        if skipped:
            notes.append(Degradation("budget", tuple(skipped),
                                     f"power budget: {len(skipped)} of "
                                     f"{len(skipped) + len(allowed)} skipped "
                                     f"(max_simultaneous {self.budget})"))
        return allowed, notes

    def commit(self, applied: Mapping[Actuator, Drive], before_ms: float,
               after_ms: float) -> None:
        """Record that ``applied`` is what the array does now (sent at ``before_ms``,
        confirmed by ``after_ms``)."""
        for key in [k for k in self.on_since if k not in applied]:
            on_ms = after_ms - self.on_since.pop(key)
            if on_ms > self.max_on_ms:
                self.overruns.append((key, on_ms))
            self.last_off_ms[key] = after_ms
            if key in self._cut:
                self.rest_until[key] = after_ms + self.rest_ms + _SLACK_MS
        for key in applied:
            if key not in self.on_since:
                self.on_since[key] = before_ms
        self._cut = set()

    def all_off(self, after_ms: float) -> None:
        """Every actuator was switched off (confirmed by ``after_ms``)."""
        self.commit({}, after_ms, after_ms)
        self._held = {}

    def next_deadline_ms(self) -> float | None:
        """When a frame is next needed even if nothing else changes: the earliest train
        to cut, or the earliest actuator held off that may then go on."""
        times = [t + self.max_on_ms - self.margin_ms for t in self.on_since.values()]
        times.extend(self._held.values())
        return min(times) if times else None

    def _problem(self, key: Actuator, drive: Drive) -> str | None:
        memo = (key, drive) if isinstance(drive, int) else None
        if memo is not None and memo in self._problems:
            return self._problems[memo]
        if isinstance(drive, PulseTrain):
            why = setting_problem(key[0], key[1], None, drive, self.profile)
        elif isinstance(drive, int) and not isinstance(drive, bool) and drive > 0:
            why = setting_problem(key[0], key[1], drive, None, self.profile)
        else:
            why = f"{drive!r} is not a drive (a level above 0, or a pulse train)"
        if memo is not None:
            self._problems[memo] = why
        return why


def _strength(drive: Drive) -> float:
    if isinstance(drive, PulseTrain):
        return drive.amplitude_v ** 2 * drive.pulse_width_ms * drive.frequency_hz
    return float(drive)


def outputs_schedule(changes: list[tuple[float, Actuator, Drive | None]],
                     profile: DeviceProfile, end_ms: float | None = None) -> Schedule:
    """What an array actually did, as a Schedule that :func:`check_schedule` can audit.

    ``changes`` are output changes ``(t_ms, (row, col), drive or None for off)`` in
    any order, on one clock (a device's output history: the emulated firmware's
    actuations, the sim's frames). Each stretch of constant drive becomes a pulse,
    so a continuous activation is a run of touching pulses (``check_schedule``
    merges them); an actuator still on at the end runs to ``end_ms`` (default: the
    last change). Times start at the first change and are rounded to 1/1024 ms, so
    that onsets, durations and their sums are exact in binary floating point (an
    offset and an onset at one instant stay at one instant).
    """
    ordered = sorted(changes, key=lambda e: e[0])
    if not ordered:
        return Schedule(device=profile.name, pulses=[], coding="outputs")
    t0 = ordered[0][0]

    def tick(t: float) -> float:
        return round((t - t0) * 1024.0) / 1024.0

    ordered = [(tick(t), key, d) for t, key, d in ordered]
    end = max(ordered[-1][0], tick(end_ms) if end_ms is not None else ordered[-1][0])
    current: dict[Actuator, tuple[float, Drive]] = {}
    pulses: list[Pulse] = []

    def close(key: Actuator, t: float) -> None:
        start, drive = current.pop(key)
        if t > start:
            kw = {"train": drive} if isinstance(drive, PulseTrain) else {"level": int(drive)}
            pulses.append(Pulse(row=key[0], col=key[1], onset_ms=start,
                                duration_ms=t - start, **kw))

    for t, key, drive in ordered:
        if key in current:
            if current[key][1] == drive:
                continue
            close(key, t)
        off = drive is None or (isinstance(drive, int) and drive == 0)
        if not off:
            current[key] = (t, drive)
    for key in list(current):
        close(key, end)
    return Schedule(device=profile.name, pulses=pulses, coding="outputs")
