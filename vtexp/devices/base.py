"""The Device protocol and the base class that enforces safety for every backend."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Protocol, runtime_checkable

from typing_extensions import Self

from ..errors import SessionAborted
from ..model import DeviceInfo, DeviceProfile, PlayReport, Schedule
from ..safety import check_schedule, cooling_wait_ms

#: ``play``'s ``should_stop``: true (or a reason, as text) stops the play.
StopPoll = Callable[[], bool | str | None]

#: How often a play polls ``should_stop`` while it waits, seconds.
STOP_POLL_S = 0.005


@runtime_checkable
class Device(Protocol):
    """A tactile array that plays Schedules.

    ``open`` connects and returns what the device reports about itself;
    ``play`` blocks until the schedule has been played and returns what was
    actually played, with onsets; ``all_off`` stops every actuator at once;
    ``close`` turns everything off and disconnects. Usable as a context
    manager (``with open_device(...) as dev:``).

    ``play(schedule, should_stop=f)``: ``f`` is called before the play starts and
    every few milliseconds (:data:`STOP_POLL_S`) while it waits for the schedule
    to be played; when it returns true, every actuator is turned off at once and
    ``play`` raises :class:`~vtexp.errors.SessionAborted` (with ``f``'s return
    value as the reason when that is text). A backend that does not wait (the
    virtual-clock ``sim``) calls it only before the play.
    """

    profile: DeviceProfile

    def open(self) -> DeviceInfo: ...

    def info(self) -> DeviceInfo: ...

    def play(self, schedule: Schedule, *, should_stop: StopPoll | None = None
             ) -> PlayReport: ...

    def all_off(self) -> None: ...

    def close(self) -> None: ...

    def __enter__(self) -> Self: ...

    def __exit__(self, *exc: object) -> None: ...


class DeviceBase:
    """Shared behaviour: safety check before play, all-off on close and on errors.

    Backends implement ``_open``, ``_play`` and ``_all_off`` (and may extend
    ``_close``; ``_now_ms``/``_rest`` if they keep their own clock). :meth:`play`
    is the only way in, so the safety check cannot be skipped. Between plays it
    also waits out the cooling time (``limits.min_off_ms``) of any actuator the
    previous play used (``safety.cooling_wait_ms``). Backends that wait during
    ``_play`` call :meth:`_check_stop` every few ms (or wait with :meth:`_sleep`,
    which does), so that ``should_stop`` can end the play.
    """

    backend = "base"

    def __init__(self, profile: DeviceProfile):
        self.profile = profile
        self._info: DeviceInfo | None = None
        self._last_off_ms: dict[tuple[int, int], float] = {}
        self._should_stop: StopPoll | None = None

    # -- public API -------------------------------------------------------------------------
    def open(self) -> DeviceInfo:
        if self._info is None:
            self._info = self._open()
        return self._info

    def info(self) -> DeviceInfo:
        return self.open()

    def play(self, schedule: Schedule, *, should_stop: StopPoll | None = None) -> PlayReport:
        check_schedule(schedule, self.profile)
        self.open()
        self._should_stop = should_stop
        try:
            rest = cooling_wait_ms(schedule, self.profile, self._last_off_ms, self._now_ms())
            if rest > 0:
                self._rest(rest)
            self._check_stop()          # stopped before it started: nothing is played
            try:
                report = self._play(schedule)
            except BaseException:
                try:
                    self.all_off()      # first, on any error; a stop by should_stop too
                finally:
                    self._mark_off(schedule)
                raise
        finally:
            self._should_stop = None
        self._mark_off(schedule)
        return report

    def _mark_off(self, schedule: Schedule) -> None:
        # Stamped when play returns, which is no earlier than the last pulse ended:
        # the cooling measured from here is never shorter than the real one.
        now = self._now_ms()
        for p in schedule.pulses:
            self._last_off_ms[(p.row, p.col)] = now

    def all_off(self) -> None:
        if self._info is not None:
            self._all_off()

    def close(self) -> None:
        if self._info is not None:
            try:
                self._all_off()
            finally:
                self._close()
                self._info = None

    def __enter__(self):
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- for backends -----------------------------------------------------------------------
    def _open(self) -> DeviceInfo:  # pragma: no cover - abstract
        raise NotImplementedError

    def _play(self, schedule: Schedule) -> PlayReport:  # pragma: no cover - abstract
        raise NotImplementedError

    def _all_off(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _close(self) -> None:
        pass

    def _now_ms(self) -> float:
        """The clock that cooling times are measured on."""
        return time.monotonic() * 1000.0

    def _rest(self, ms: float) -> None:
        """Let ``ms`` pass with every actuator off."""
        self._sleep(ms / 1000.0)

    def _check_stop(self) -> None:
        """Raise :class:`SessionAborted` if the play's ``should_stop`` says so.

        ``play`` then turns every actuator off before the error goes further.
        """
        poll = self._should_stop
        if poll is None:
            return
        why = poll()
        if why:
            self._should_stop = None
            raise SessionAborted(why if isinstance(why, str) else
                                 "stopped while the stimulus played")

    def _sleep(self, seconds: float) -> None:
        """Sleep, polling ``should_stop`` every :data:`STOP_POLL_S` during a play."""
        end = time.monotonic() + seconds
        if self._should_stop is None:
            time.sleep(max(0.0, seconds))
            return
        while (left := end - time.monotonic()) > 0:
            time.sleep(min(left, STOP_POLL_S))
            self._check_stop()
