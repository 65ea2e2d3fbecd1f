"""The live loop: newest frame -> pattern -> cycle -> the device, changes only.

One thread (:meth:`LiveRun.run`) does everything that touches the device, in this
order, as often as something happens:

1. take the newest frame from the capture thread's mailbox, if there is one
   (frames it had no time for were dropped there, never queued); encode and code
   it (:class:`~vtexp.live.encoder.LiveEncoder`); a cycle that differs from the one
   playing replaces it, going on from the first place ahead where it differs
   (``follow="change"``, :func:`~vtexp.live.program.change_epoch`) or from the same
   place (``follow="place"``, :func:`~vtexp.live.program.carried_epoch`);
2. work out what the array should do now (the cycle's state at this phase) and,
   if that changed, or the device's guard needs a frame (a train to cut at its
   maximum on-time, a rest that ends), send it: ``device.stream`` holds the
   profile's limits across frames (:class:`~vtexp.safety.StreamGuard`) and sends
   only the outputs that change;
3. sleep until the next of: a new frame, the cycle's next change, the guard's next
   deadline, the end of the run — and never longer than half the device's check-in
   period (``stream_checkin_ms``): a loop that stops checking in lets the device's
   watchdog switch everything off. If that happened (the host stalled), the device is
   opened again and the run goes on (counted as ``reconnects``, said on screen).

It stops at the end of the source, after ``duration_s``, when ``should_stop`` says
so (the preview's Escape, Ctrl-C), or on an error — a source that cannot be read,
stops delivering (nothing for ``stall_s``; for the first frame, at least
FIRST_FRAME_S) or gives a wrong frame; a device fault —
and in every case every actuator is off before :meth:`LiveRun.run` returns or
raises.

**Glass-to-skin latency** of a change is the time from the capture of the frame
that first showed it to the device-reported onset of the first output it changed:
the first output sent that differs from what the cycle playing before that frame
would have asked at that moment, to what the new cycle asks. A frame whose cycle
equals the one playing changed nothing (counted as unchanged, no latency). Frames
that change the cycle again before the first change was felt join that change
(counted as merged): its latency still runs from the first of them, so slow changes
are not left out of the figures. A change may wait for the safety guard (a pin
resting or cooling) or, with ``follow="place"``, for a trace to reach the place that
changed. A change with no onset to measure is counted apart: one already so on the
array (it switches off outputs that the guard was holding off:
``changes_in_place``), and one whose outputs the guard leaves out (over the power
budget, or beyond a limit: ``changes_left_out``). The device reports onsets on its
own clock; they are put on the host's clock by :class:`ClockMap`.

The loop's time is the device's :class:`~vtexp.clock.Clock` (``device.clock``): the
real clock, or on a virtual one (an emulator in-process) the frames of a file come by
timers when they are due and a run of seconds passes in the time its frames take to
process; what a frame's processing costs is then not on the timeline (the host is
infinitely fast there: ``bench/live.py`` measures the real loop).
"""

from __future__ import annotations

import math
import sys
import threading
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..clock import REAL, Clock
from ..devices.base import DeviceBase, StreamReport
from ..errors import DeviceError, InputError, SessionAborted
from ..safety import Actuator, Drive
from .encoder import Encoded, LiveEncoder
from .program import Program, carried_epoch, change_epoch
from .sources import Capture, Frame, FrameSource, LatestFrame, SourceEnded

#: The first frame may take this long (seconds) even when ``stall_s`` is shorter: a
#: camera opening, a program on standard input importing its libraries (under a busy
#: machine's load a Python producer took over 2 s).
FIRST_FRAME_S = 10.0


class ClockMap:
    """The device's clock on the host's: offset from the exchange with the shortest round
    trip among the last ``window`` (the device stamped the change between the host's
    before and after, so the error is at most half that round trip)."""

    def __init__(self, window: int = 256):
        self._samples: deque[tuple[float, float]] = deque(maxlen=window)
        self._best: tuple[float, float] | None = None

    def add(self, before_ms: float, after_ms: float, device_ms: float) -> None:
        rtt = after_ms - before_ms
        sample = (rtt, device_ms - (before_ms + after_ms) / 2.0)
        self._samples.append(sample)
        if self._best is None or rtt <= self._best[0] or len(self._samples) % 32 == 0:
            self._best = min(self._samples)

    @property
    def uncertainty_ms(self) -> float:
        return math.inf if self._best is None else self._best[0] / 2.0

    def to_host_ms(self, device_ms: float) -> float:
        if self._best is None:
            raise ValueError("no exchange with the device yet")
        return device_ms - self._best[1]


@dataclass
class LiveStats:
    """What a run measured (also what the preview shows)."""

    started: float = 0.0
    ended: float = 0.0
    frames_captured: int = 0
    frames_processed: int = 0
    frames_dropped: int = 0
    frames_unchanged: int = 0
    frames_merged: int = 0
    frames_empty: int = 0
    changes_in_place: int = 0
    changes_left_out: int = 0
    latencies_ms: list[float] = field(default_factory=list)
    process_ms: list[float] = field(default_factory=list)
    deadline_late_ms: list[float] = field(default_factory=list)
    outputs_sent: int = 0
    changes_sent: int = 0
    reconnects: int = 0
    degradations: Counter = field(default_factory=Counter)
    last_notes: list[str] = field(default_factory=list)
    last_notes_at: float = 0.0
    recent: deque = field(default_factory=lambda: deque(maxlen=64))
    end_reason: str = ""
    clock: Clock = field(default=REAL, repr=False)

    @property
    def elapsed_s(self) -> float:
        return max((self.ended or self.clock.now()) - self.started, 1e-9)

    @property
    def fps(self) -> float:
        """Frames processed per second over the run."""
        return self.frames_processed / self.elapsed_s

    @property
    def recent_fps(self) -> float:
        """Frames processed per second over the last (up to) 64 frames."""
        if len(self.recent) < 2:
            return 0.0
        return (len(self.recent) - 1) / max(self.recent[-1] - self.recent[0], 1e-9)

    def latency(self, q: float) -> float:
        return float(np.percentile(self.latencies_ms, q)) if self.latencies_ms else math.nan

    def summary(self) -> dict:
        lat = self.latencies_ms
        return {
            "elapsed_s": round(self.elapsed_s, 3),
            "frames_captured": self.frames_captured,
            "frames_processed": self.frames_processed,
            "frames_dropped": self.frames_dropped,
            "frames_unchanged": self.frames_unchanged,
            "frames_merged": self.frames_merged,
            "frames_empty": self.frames_empty,
            "changes_in_place": self.changes_in_place,
            "changes_left_out": self.changes_left_out,
            "fps": round(self.fps, 2),
            "latency_ms": {"n": len(lat), **{f"p{q}": round(self.latency(q), 3)
                                            for q in (50, 95, 99)},
                           "max": round(max(lat), 3) if lat else None},
            "process_ms": {"p50": round(float(np.median(self.process_ms)), 3)
                           if self.process_ms else None,
                           "p95": round(float(np.percentile(self.process_ms, 95)), 3)
                           if self.process_ms else None},
            "safety_deadlines": {
                "n": len(self.deadline_late_ms),
                "late_p99_ms": round(float(np.percentile(self.deadline_late_ms, 99)), 3)
                if self.deadline_late_ms else None,
                "late_max_ms": round(max(self.deadline_late_ms), 3)
                if self.deadline_late_ms else None},
            "outputs_sent": self.outputs_sent,
            "changes_sent": self.changes_sent,
            "reconnects": self.reconnects,
            "degradations": dict(self.degradations),
            "end": self.end_reason,
        }


@dataclass
class Snapshot:
    """The newest state of the run, for the preview."""

    frame: Frame | None
    encoded: Encoded | None
    applied: dict[Actuator, Drive]
    stats: LiveStats
    notes: list[str]


@dataclass
class _Pending:
    """A change not yet felt: the first frame that showed it, and the cycle that was
    playing before (what would have played without it)."""

    frame: int
    t_capture: float
    old: Program | None
    old_epoch: float | None

    def before(self, now: float) -> dict[Actuator, Drive]:
        """What would play at ``now`` without the change."""
        old = self.old
        return old.state_at(old.phase(now, self.old_epoch)) if old is not None else {}


@dataclass
class _Loop:
    """What one run of the loop carries from one turn to the next."""

    last_frame_at: float                # host time of the newest frame taken
    end_at: float                       # host time the run's duration ends (inf: none)
    last_desired: dict[Actuator, Drive] | None = None   # the outputs last streamed
    pending: _Pending | None = None
    deadline_at: float | None = None    # when the device's deadline fell due
    failures: int = 0                   # streams failed in a row
    seen: bool = False                  # a frame was taken


class LiveRun:
    """A live run (module docstring). ``sinks`` are called with each event the run
    records: ``("frame", dict)`` per frame processed, ``("program", dict)`` per new
    cycle, ``("output", dict)`` per frame of outputs sent (the recorder is one)."""

    def __init__(self, source: FrameSource, encoder: LiveEncoder, device: DeviceBase, *,
                 duration_s: float | None = None, stall_s: float = 2.0,
                 should_stop: Callable[[], bool | str | None] | None = None,
                 sinks: list[Callable[[str, dict], None]] | None = None,
                 on_snapshot: Callable[[Snapshot], None] | None = None,
                 reconnect: bool = True):
        self.source = source
        self.encoder = encoder
        self.device = device
        self.duration_s = duration_s
        self.stall_s = stall_s
        self.should_stop = should_stop
        self.sinks = list(sinks or [])
        self.on_snapshot = on_snapshot
        self.reconnect = reconnect
        self.clock: Clock = device.clock
        self.stats = LiveStats(clock=self.clock)
        self.clock_map = ClockMap()
        self.mailbox = LatestFrame(self.clock)
        self._stop = threading.Event()
        self.program: Program | None = None
        self.epoch: float | None = None
        self.last_frame: Frame | None = None
        self.last_encoded: Encoded | None = None
        self._applied: dict[Actuator, Drive] = {}

    def stop(self, reason: str = "stopped") -> None:
        """Ask the run to end (from another thread: the preview, a signal handler)."""
        if not self.stats.end_reason:
            self.stats.end_reason = reason
        self._stop.set()
        self.mailbox.notify()

    # -- the loop ---------------------------------------------------------------------------
    def run(self) -> LiveStats:
        st = self.stats
        capture = self._open()
        clock = self.clock
        st.started = clock.now()
        capture.start()
        loop = _Loop(last_frame_at=st.started,
                     end_at=st.started + self.duration_s if self.duration_s else math.inf)
        switch = sys.getswitchinterval()
        sys.setswitchinterval(0.0005)       # the loop wakes on time while others compute
        try:
            while not self._should_end(loop):
                if self._stream(loop):
                    self._sleep(loop)
        except KeyboardInterrupt:
            self.stop("interrupted (Ctrl-C)")
            raise
        except SessionAborted as e:
            self.stop(str(e) or "aborted")
            raise
        except BaseException as e:
            self.stop(f"error: {e}")
            raise
        finally:
            sys.setswitchinterval(switch)
            self._close(capture)
        return st

    def _open(self) -> Capture:
        """The source, the device and the capture thread (not started), or nothing open."""
        self.source.open()
        try:
            self.device.open()
            return Capture(self.source, self.mailbox)
        except BaseException:
            self.source.close()
            raise

    def _should_end(self, loop: _Loop) -> bool:
        """Whether the run ends now (stopped, asked to, its duration over, the source
        ended); else the newest frame, if any, is processed."""
        now = self.clock.now()
        if self._stop.is_set():
            return True
        if self.should_stop is not None:
            why = self.should_stop()
            if why:
                self.stop(why if isinstance(why, str) else "stopped")
                return True
        if now >= loop.end_at:
            self.stop(f"{self.duration_s:g} s elapsed")
            return True
        try:
            frame = self.mailbox.take()
        except SourceEnded:
            self.stop(f"end of {self.source.label}")
            return True
        if frame is not None:
            loop.last_frame_at, loop.seen = now, True
            loop.pending = self._process(frame, loop.pending)
        elif now - loop.last_frame_at > self._stall_limit(loop):
            if not loop.seen:
                raise InputError(f"{self.source.label} gave no frame in its first "
                                 f"{self._stall_limit(loop):g} s", key="SOURCE")
            raise InputError(f"{self.source.label} stopped delivering frames (none for "
                             f"{self.stall_s:g} s)", key="SOURCE")
        return False

    def _stall_limit(self, loop: _Loop) -> float:
        """How long the source may give no frame: ``stall_s``, and at least FIRST_FRAME_S
        for the first (a camera opening, a program on standard input starting up)."""
        return self.stall_s if loop.seen else max(self.stall_s, FIRST_FRAME_S)

    def _stream(self, loop: _Loop) -> bool:
        """The program's outputs now to the device (or that the host is alive); False if
        the device had to be opened again (the loop goes round at once)."""
        dev, st = self.device, self.stats
        now = self.clock.now()
        prog = self.program
        desired = prog.state_at(prog.phase(now, self.epoch)) if prog else {}
        deadline = dev.stream_deadline_s()
        due = deadline is not None and deadline <= 0
        if due and loop.deadline_at is not None:
            st.deadline_late_ms.append((now - loop.deadline_at) * 1000.0)
        try:
            if desired != loop.last_desired or due:
                rep = dev.stream(desired)
                loop.last_desired = desired
                loop.pending = self._sent(rep, desired, loop.pending, now)
            else:
                dev.stream_alive()
            loop.failures = 0
        except DeviceError as e:
            # A stalled loop lets the device's watchdog end the session (every
            # actuator off); open it again and go on, unless that keeps failing.
            loop.failures += 1
            if loop.failures > 3 or self.reconnect is False:
                raise
            self._reconnect(e)
            loop.last_desired = None
            return False
        return True

    def _sleep(self, loop: _Loop) -> None:
        """Sleep until something happens: a frame, the program's next change, the device's
        deadline or check-in, a stall, the end."""
        dev = self.device
        now = self.clock.now()
        waits = [loop.end_at - now,
                 self._stall_limit(loop) - (now - loop.last_frame_at) + 0.001,
                 dev.stream_checkin_ms / 2000.0]
        prog = self.program
        if prog is not None:
            waits.append(prog.ms_to_next_change(prog.phase(now, self.epoch)) / 1000.0
                         + 0.0002)
        deadline = dev.stream_deadline_s()
        loop.deadline_at = None if deadline is None else now + deadline
        if deadline is not None:
            waits.append(deadline)
        self.mailbox.wait(max(0.0, min(waits)))

    def _close(self, capture: Capture) -> None:
        """Every actuator off (recorded), the capture stopped, the run's end recorded."""
        st, clock = self.stats, self.clock
        try:
            t_off = clock.now()
            self.device.all_off()
            self._emit("output", {
                "t_host": t_off, "t_device_ms": None, "t_onset_host": None, "frame": None,
                "changed": len(self._applied), "on": 0, "applied": {}, "degradations": [],
                "latency_ms": None, "latency_frame": None})
            self._applied = {}
        finally:
            st.ended = clock.now()
            capture.stop()
            st.frames_captured = self.mailbox.captured
            st.frames_dropped = self.mailbox.dropped
            self._emit("end", st.summary())
            self._snapshot({})

    def _reconnect(self, error: DeviceError) -> None:
        st = self.stats
        st.reconnects += 1
        st.last_notes = [f"device: {error}"[:160], "reconnected: every actuator was off"]
        st.last_notes_at = self.clock.now()
        # the device's watchdog says when it switched everything off, on its clock
        self._emit("output", {
            "t_host": self.clock.now(), "t_device_ms": getattr(error, "off_at_ms", None),
            "t_onset_host": None,
            "frame": None, "changed": len(self._applied), "on": 0, "applied": {},
            "degradations": [], "latency_ms": None, "latency_frame": None})
        self._applied = {}
        try:
            self.device.close()
        except Exception:
            pass                    # it is off: by its watchdog, or it is gone
        try:
            self.device.open()
        except Exception:
            raise error from None
        # a device opened again may have restarted its clock (an emulator is started
        # anew; a board resets when its port opens): map it afresh
        self.clock_map = ClockMap()

    def _process(self, frame: Frame, pending: _Pending | None) -> _Pending | None:
        st = self.stats
        enc = self.encoder.process(frame.image, frame=frame.index, t_capture=frame.t_capture)
        now = self.clock.now()          # the new cycle takes over from here, not from before
        st.frames_processed += 1
        st.frames_captured = self.mailbox.captured
        st.frames_dropped = self.mailbox.dropped
        st.recent.append(now)
        st.process_ms.append(enc.encode_ms + enc.code_ms)
        self.last_frame, self.last_encoded = frame, enc
        new = enc.program
        old = self.program
        changed = (new is None) != (old is None) or (
            new is not None and old is not None and new.signature != old.signature)
        if new is None:
            st.frames_empty += 1
        if changed:
            if pending is not None:
                st.frames_merged += 1
            else:
                pending = _Pending(frame.index, frame.t_capture, old, self.epoch)
            if new is None:
                self.epoch = None
            elif self.encoder.setup.follow == "change":
                # from the cycle playing, to a place where the array will change to what
                # would not have played without the change(s) not yet felt
                self.epoch = change_epoch(now, old, self.epoch, new, self._applied,
                                          pending.before(now))
            else:
                self.epoch = carried_epoch(now, old, self.epoch, new)
            self.program = new
            if new is not None:
                self._emit("program", {"frame": frame.index, "cycle_ms": new.cycle_ms,
                                       "pattern": new.pattern, "schedule": new.schedule})
        else:
            st.frames_unchanged += 1
        c = _centroid(new)
        self._emit("frame", {
            "frame": frame.index, "t_capture": frame.t_capture, "t_processed": self.clock.now(),
            "process_ms": enc.encode_ms + enc.code_ms, "encode_ms": enc.encode_ms,
            "dropped_so_far": self.mailbox.dropped, "points": len(enc.pattern.points),
            "centroid_row": c[0], "centroid_col": c[1],
            "cycle_ms": new.cycle_ms if new is not None else None,
            "program": "new" if changed and new is not None else
                       ("none" if new is None else "same"),
            "snake_init": enc.pattern.params.get("snake_init"), "name": frame.name})
        self._snapshot(self.device._stream_state)
        return pending

    def _sent(self, rep: StreamReport, desired: dict[Actuator, Drive],
              pending: _Pending | None, now: float) -> _Pending | None:
        st = self.stats
        st.outputs_sent += 1
        st.changes_sent += rep.changed
        onset_host = None
        if rep.t_device_ms is not None:
            self.clock_map.add(rep.host_before_ms, rep.host_after_ms, rep.t_device_ms)
            onset_host = self.clock_map.to_host_ms(rep.t_device_ms)
        for d in rep.degradations:
            st.degradations[d.kind] += 1
        if rep.degradations:
            st.last_notes = [d.text for d in rep.degradations]
            st.last_notes_at = now
        latency = None
        resolved = None
        prev, self._applied = self._applied, rep.applied
        if pending is not None:
            before = pending.before(now)
            now_on = rep.applied
            asked = [k for k in desired.keys() | before.keys() if desired.get(k) != before.get(k)]
            # Felt: an output that the change asks to differ was changed, to what it asks.
            if rep.changed and onset_host is not None and any(
                    prev.get(k) != now_on.get(k) and now_on.get(k) == desired.get(k)
                    for k in asked):
                latency = onset_host - pending.t_capture * 1000.0
                st.latencies_ms.append(latency)
                resolved = pending.frame
                pending = None
            elif asked:
                # Not felt now. Held for a while (a pin resting or cooling): it will be, and
                # its latency runs on. Otherwise nothing will change for it, and it is not
                # carried into the next change's latency: it is already so on the array
                # (the outputs it switches off were off, held by the guard), or what it
                # switches on the guard leaves out (over the power budget, or never driven).
                left_out = {k for d in rep.degradations if d.kind in ("budget", "refused")
                            for k in d.actuators}
                waiting = [k for k in asked if now_on.get(k) != desired.get(k)
                           and k not in left_out]
                if not waiting:
                    if all(prev.get(k) == now_on.get(k) == desired.get(k) for k in asked):
                        st.changes_in_place += 1
                    else:
                        st.changes_left_out += 1
                    pending = None
        self._emit("output", {
            "t_host": rep.host_before_ms / 1000.0, "t_device_ms": rep.t_device_ms,
            "t_onset_host": None if onset_host is None else onset_host / 1000.0,
            "frame": self.program.frame if self.program is not None else None,
            "changed": rep.changed, "on": len(rep.applied), "applied": rep.applied,
            "degradations": rep.degradations, "latency_ms": latency, "latency_frame": resolved})
        self._snapshot(rep.applied)
        return pending

    def _emit(self, kind: str, event: dict) -> None:
        for sink in self.sinks:
            sink(kind, event)

    def _snapshot(self, applied: dict[Actuator, Drive]) -> None:
        if self.on_snapshot is not None:
            st = self.stats
            notes = st.last_notes if self.clock.now() - st.last_notes_at < 2.0 else []
            self.on_snapshot(Snapshot(self.last_frame, self.last_encoded, dict(applied), st,
                                      list(notes)))


def _centroid(program: Program | None) -> tuple[float | None, float | None]:
    if program is None or not program.pattern.points:
        return (None, None)
    pts = np.array(program.actuated, dtype=np.float64)
    return (float(pts[:, 0].mean()), float(pts[:, 1].mean()))
