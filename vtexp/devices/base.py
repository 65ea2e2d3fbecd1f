"""The Device protocol and the base class that enforces safety for every backend."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from ..model import DeviceInfo, DeviceProfile, PlayReport, Schedule
from ..safety import check_schedule


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

    def __enter__(self) -> Device: ...

    def __exit__(self, *exc: object) -> None: ...


class DeviceBase:
    """Shared behaviour: safety check before play, all-off on close and on errors.

    Backends implement ``_open``, ``_play`` and ``_all_off`` (and may extend
    ``_close``). :meth:`play` is the only way in, so the safety check cannot be
    skipped.
    """

    backend = "base"

    def __init__(self, profile: DeviceProfile):
        self.profile = profile
        self._info: DeviceInfo | None = None

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
        try:
            return self._play(schedule)
        except BaseException:
            self.all_off()
            raise

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
