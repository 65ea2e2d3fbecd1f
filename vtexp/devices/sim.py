"""The ``sim`` backend: an in-process array with a virtual clock.

It records exactly what would have been driven: every play, every all-off,
and the state of each actuator. Its clock is virtual (milliseconds since
open) and advances by each schedule's duration, so a whole study runs in
well under a second; ``realtime=True`` also takes the schedule's real time,
switching ``state`` at each onset and offset, for demonstrations in front of
people. In real time a play polls ``should_stop`` every few ms and, when it
says stop, records how far it got (a ``stopped`` event) and turns all off.

A live stream (``stream``) always takes the host's time (``clock``, a
:class:`~vtexp.clock.Clock`, real unless another is given): while it lasts the
device's clock follows it, and each frame's changes are recorded (a ``frame``
event with ``{(row, col): drive or None}``) at the time they were applied. Like a
device's firmware, it has a watchdog while it streams (``stream_watchdog``, ms):
when the host's loop has not checked in for that long, everything went off then (a
``watchdog`` event at that time) and the next call raises ``StreamCut`` (a
``DeviceError``) saying when.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..clock import REAL, Clock
from ..errors import DeviceError, SessionAborted, StreamCut
from ..model import DeviceInfo, DeviceProfile, PlayedPulse, PlayReport, Pulse, Schedule
from .base import DeviceBase


@dataclass
class SimEvent:
    t_ms: float
    kind: str                 # "play" | "stopped" | "all_off" | "open" | "close" | "wait" | "frame"
    detail: object = None


@dataclass
class SimDevice(DeviceBase):
    profile: DeviceProfile
    realtime: bool = False
    stream_watchdog: float | None = 100.0
    clock_ms: float = 0.0
    history: list[SimEvent] = field(default_factory=list)
    plays: list[PlayReport] = field(default_factory=list)
    clock: Clock = REAL

    backend = "sim"

    def __post_init__(self) -> None:
        DeviceBase.__init__(self, self.profile, self.clock)
        # Drive level (or amplitude) of each actuator right now; all zero when idle.
        self.state = np.zeros((self.profile.rows, self.profile.cols), dtype=float)
        self._stream_mono: float | None = None
        self._checkin_ms: float | None = None

    def _open(self) -> DeviceInfo:
        self.history.append(SimEvent(self.clock_ms, "open"))
        return DeviceInfo(backend="sim", profile=self.profile.name, rows=self.profile.rows,
                          cols=self.profile.cols, firmware="vtexp-sim", protocol="in-process",
                          details={"clock": "virtual" if not self.realtime else "realtime"})

    def _play(self, schedule: Schedule) -> PlayReport:
        start = self.clock_ms
        # The virtual clock has no fixed relation to real time: a play starts, on the
        # host's clock, when it is asked for.
        host_start = self.clock.now_ms()
        self._play_started(start, host_start)
        played = [PlayedPulse(row=p.row, col=p.col, scheduled_onset_ms=p.onset_ms,
                              onset_ms=p.onset_ms, duration_ms=p.duration_ms,
                              level=p.level, train=p.train)
                  for p in schedule.sorted()]
        report = PlayReport(device=self.profile.name, started_at_ms=start,
                            duration_ms=schedule.duration_ms, pulses=played,
                            started_at_host_ms=host_start, host_clock_error_ms=0.0)
        if self.realtime and schedule.duration_ms > 0:
            try:
                self._drive_realtime(schedule, host_start / 1000.0)
            except SessionAborted as e:     # what had started when it was stopped
                elapsed = self.history[-1].detail
                e.played = report.model_copy(update={
                    "pulses": [p for p in played if p.onset_ms <= elapsed],
                    "completed": False})
                raise
        self.clock_ms = start + schedule.duration_ms
        self.history.append(SimEvent(start, "play", report))
        self.plays.append(report)
        self.state[:] = 0.0     # every pulse has ended by the end of the schedule
        return report

    def _drive_realtime(self, schedule: Schedule, t0: float) -> None:
        """Take the schedule's real time from ``t0`` (the clock's seconds), ``state``
        following its pulses."""
        pulses = schedule.sorted()
        instants = sorted({p.onset_ms for p in pulses} | {p.offset_ms for p in pulses}
                          | {schedule.duration_ms})
        try:
            for t in instants:
                self._sleep(t0 + t / 1000.0 - self.clock.now())
                self.state[:] = 0.0
                for p in pulses:        # overlapping pulses: the latest started drives it
                    if p.onset_ms <= t < p.offset_ms:
                        self.state[p.row, p.col] = _drive(p)
        except SessionAborted:
            elapsed = (self.clock.now() - t0) * 1000.0
            self.history.append(SimEvent(self.clock_ms, "stopped", elapsed))
            self.clock_ms += elapsed
            raise

    def wait_ms(self, ms: float) -> None:
        """Let ``ms`` of the device's time pass (inter-trial intervals): real time too
        with ``realtime``."""
        if ms > 0:
            self.history.append(SimEvent(self.clock_ms, "wait", ms))
            if self.realtime:
                self._sleep(ms / 1000.0)
            self.clock_ms += ms

    def _now_ms(self) -> float:
        if self._stream_mono is not None:       # streaming: the clock follows real time
            t = self.clock.now()
            self.clock_ms += (t - self._stream_mono) * 1000.0
            self._stream_mono = t
        return self.clock_ms

    def stream_watchdog_ms(self) -> float | None:
        return self.stream_watchdog

    def _stream_started(self) -> None:
        self._stream_mono = self.clock.now()
        self._checkin_ms = self._now_ms()

    def _stream_stopped(self) -> None:
        self._now_ms()
        self._stream_mono = None
        self._checkin_ms = None

    def _stream_checked_in(self) -> None:
        now = self._now_ms()
        last, self._checkin_ms = self._checkin_ms, now
        wd = self.stream_watchdog
        if wd is not None and last is not None and now - last > wd:
            self.state[:] = 0.0
            self.history.append(SimEvent(last + wd, "watchdog"))
            raise StreamCut(f"the sim's watchdog switched everything off: the host's loop "
                            f"was silent for {now - last:.0f} ms (watchdog {wd:g} ms)",
                            off_at_ms=last + wd)

    def _set_outputs(self, changes, *, full: bool = False) -> float:
        t = self._now_ms()
        for (r, c), drive in changes.items():
            self.state[r, c] = 0.0 if drive is None else (
                float(drive) if isinstance(drive, int) else drive.amplitude_v)
        self.history.append(SimEvent(t, "frame", dict(changes)))
        return t

    def _rest(self, ms: float) -> None:
        self.wait_ms(ms)

    def _all_off(self) -> None:
        self.state[:] = 0.0
        self.history.append(SimEvent(self._now_ms(), "all_off"))

    def _close(self) -> None:
        self.history.append(SimEvent(self.clock_ms, "close"))


def _drive(p: Pulse) -> float:
    return float(p.level) if p.level is not None else p.train.amplitude_v
