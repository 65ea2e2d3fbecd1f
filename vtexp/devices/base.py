"""The Device protocol and the base class that enforces safety for every backend."""

from __future__ import annotations

import time
from typing import Protocol, runtime_checkable

from typing_extensions import Self

from ..model import DeviceInfo, DeviceProfile, PlayReport, Schedule
from ..safety import check_schedule, cooling_wait_ms


@runtime_checkable
class Device(Protocol):
    """A tactile array that plays Schedules.

    ``open`` connects and returns what the device reports about itself;
    ``play`` blocks until the schedule has been played and returns what was
    actually played, with onsets; ``all_off`` stops every actuator at once;
    ``close`` turns everything off and disconnects. Usable as a context
    manager (``with open_device(...) as dev:``).
    """

    profile: DeviceProfile

    def open(self) -> DeviceInfo: ...

    def info(self) -> DeviceInfo: ...

    def play(self, schedule: Schedule) -> PlayReport: ...

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
    previous play used (``safety.cooling_wait_ms``).
    """

    backend = "base"

    def __init__(self, profile: DeviceProfile):
        self.profile = profile
        self._info: DeviceInfo | None = None
        self._last_off_ms: dict[tuple[int, int], float] = {}

    # -- public API -------------------------------------------------------------------------
    def open(self) -> DeviceInfo:
        if self._info is None:
            self._info = self._open()
        return self._info

    def info(self) -> DeviceInfo:
        return self.open()

    def play(self, schedule: Schedule) -> PlayReport:
        check_schedule(schedule, self.profile)
        self.open()
        rest = cooling_wait_ms(schedule, self.profile, self._last_off_ms, self._now_ms())
        if rest > 0:
            self._rest(rest)
        try:
            report = self._play(schedule)
        except BaseException:
            try:
                self.all_off()
            finally:
                self._mark_off(schedule)
            raise
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
        time.sleep(ms / 1000.0)
