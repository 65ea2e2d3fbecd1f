"""Time as a dependency: the one clock that devices, link, emulator, session and live
loop read, sleep on and wait with.

Everything in vtexp that waits takes a :class:`Clock` (``clock=``), the real one by
default (:data:`REAL`). Under a :class:`VirtualClock` time passes only when the code
asks for it to pass: a sleep or a wait moves the clock on at once, running on the way
whatever was due (an emulated device's tick, a heartbeat, a byte arriving on a
loopback line), in the order it was due. An hour of a session's inter-trial intervals
and stimuli passes in milliseconds, in the same order of events as in real time, as
with trio's ``MockClock`` or SimPy's ``Environment``. A test waits on real time only
when real time is what it tests.

A virtual clock is driven by one thread: the one that sleeps and waits on it. What
would be a thread beside it in real time (a device's firmware, a link's heartbeat)
is a timer on it instead (:meth:`VirtualClock.call_at`).

Times are seconds on a monotonic clock (:meth:`Clock.now`; ``time.monotonic`` on the
real clock) and seconds since the epoch for what people read (:meth:`Clock.wall`:
``time.time``; a virtual clock's wall time starts at the real one when it is made
and moves with it).
"""

from __future__ import annotations

import heapq
import itertools
import sys
import threading
import time
from collections.abc import Callable
from datetime import datetime, timezone
from typing import Protocol, runtime_checkable


@runtime_checkable
class Clock(Protocol):
    """What vtexp needs of time (see the module docstring)."""

    #: True for a clock whose time passes only when asked to (:class:`VirtualClock`).
    virtual: bool

    def now(self) -> float:
        """Monotonic seconds."""
        ...

    def now_ms(self) -> float:
        """Monotonic milliseconds (the host times of device reports and markers)."""
        ...

    def wall(self) -> float:
        """Seconds since the epoch (what timestamps people read say)."""
        ...

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` pass (nothing for zero or less)."""
        ...

    def sleep_until(self, t: float) -> None:
        """Let time pass until :meth:`now` is ``t`` (at once if it is past)."""
        ...

    def wait_for(self, cond: threading.Condition, predicate: Callable[[], object],
                 timeout: float | None) -> bool:
        """Wait until ``predicate()`` is true (checked with ``cond`` held, woken by its
        ``notify``) or ``timeout`` seconds have passed; return whether it is true."""
        ...


#: The computer's monotonic clock: ``time.monotonic``, but on Windows the performance
#: counter (Python 3.11's monotonic clock ticks every 15.6 ms there; Lab Streaming
#: Layer's ``local_clock`` reads the performance counter there too).
_monotonic = time.perf_counter if sys.platform == "win32" else time.monotonic


class RealClock:
    """The computer's clocks: its monotonic clock, ``time.time``, ``time.sleep``."""

    virtual = False

    def now(self) -> float:
        return _monotonic()

    def now_ms(self) -> float:
        return _monotonic() * 1000.0

    def wall(self) -> float:
        return time.time()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)

    def sleep_until(self, t: float) -> None:
        self.sleep(t - _monotonic())

    def wait_for(self, cond: threading.Condition, predicate: Callable[[], object],
                 timeout: float | None) -> bool:
        with cond:
            return bool(cond.wait_for(predicate, timeout))

    def __repr__(self) -> str:
        return "RealClock()"


#: The real clock: what every ``clock=`` defaults to.
REAL = RealClock()


class Timer:
    """A call due on a :class:`VirtualClock`; :meth:`cancel` drops it."""

    __slots__ = ("t", "fn", "cancelled")

    def __init__(self, t: float, fn: Callable[[], None]):
        self.t, self.fn, self.cancelled = t, fn, False

    def cancel(self) -> None:
        self.cancelled = True


class Stalled(RuntimeError):
    """A wait on a virtual clock with no timeout and nothing left that could wake it."""


class VirtualClock:
    """A clock whose time passes only when its thread sleeps or waits on it.

    ``call_at(t, fn)`` runs ``fn`` when the clock reaches ``t``; sleeping until a
    later time runs every call due before it, each at its own time, in order (ties in
    the order they were made). ``wait_for`` runs calls one by one until the predicate
    holds or the timeout is reached; with no timeout and no call left, nothing could
    ever make it true, which raises :class:`Stalled` instead of hanging.
    """

    virtual = True

    def __init__(self, start: float = 0.0, wall_start: float | None = None):
        self._now = float(start)
        self._wall0 = (time.time() if wall_start is None else float(wall_start)) - self._now
        self._timers: list[tuple[float, int, Timer]] = []
        self._order = itertools.count()

    # -- reading ---------------------------------------------------------------------------
    def now(self) -> float:
        return self._now

    def now_ms(self) -> float:
        return self._now * 1000.0

    def wall(self) -> float:
        return self._wall0 + self._now

    # -- timers ----------------------------------------------------------------------------
    def call_at(self, t: float, fn: Callable[[], None]) -> Timer:
        timer = Timer(max(float(t), self._now), fn)
        heapq.heappush(self._timers, (timer.t, next(self._order), timer))
        return timer

    def call_later(self, seconds: float, fn: Callable[[], None]) -> Timer:
        return self.call_at(self._now + max(0.0, seconds), fn)

    def next_due(self) -> float | None:
        """When the next call is due, or None."""
        while self._timers and self._timers[0][2].cancelled:
            heapq.heappop(self._timers)
        return self._timers[0][0] if self._timers else None

    def _run_next(self) -> None:
        _, _, timer = heapq.heappop(self._timers)
        self._now = max(self._now, timer.t)
        timer.fn()

    # -- letting time pass -----------------------------------------------------------------
    def sleep(self, seconds: float) -> None:
        self.sleep_until(self._now + max(0.0, seconds))

    def sleep_until(self, t: float) -> None:
        while (due := self.next_due()) is not None and due <= t:
            self._run_next()
        self._now = max(self._now, t)

    def advance(self, seconds: float) -> None:
        """Let ``seconds`` pass (for tests: :meth:`sleep` under its test name)."""
        self.sleep(seconds)

    def wait_for(self, cond: threading.Condition | None, predicate: Callable[[], object],
                 timeout: float | None) -> bool:
        deadline = None if timeout is None else self._now + max(0.0, timeout)
        while True:
            if predicate():
                return True
            due = self.next_due()
            if due is None or (deadline is not None and due > deadline):
                if deadline is None:
                    raise Stalled("waiting with no timeout on a virtual clock, and nothing is "
                                  "due that could end the wait")
                self._now = max(self._now, deadline)
                return bool(predicate())
            self._run_next()

    def __repr__(self) -> str:
        return f"VirtualClock(now={self._now:.6f})"


def iso(clock: Clock = REAL) -> str:
    """The clock's wall time as ISO 8601 with the local offset, to the millisecond."""
    return datetime.fromtimestamp(clock.wall(), timezone.utc).astimezone().isoformat(
        timespec="milliseconds")


__all__ = ["Clock", "REAL", "RealClock", "Stalled", "Timer", "VirtualClock", "iso"]
