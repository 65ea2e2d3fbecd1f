"""The Device protocol and the base class that enforces safety for every backend."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

from typing_extensions import Self

from ..clock import REAL, Clock
from ..errors import InputError, SessionAborted
from ..model import DeviceInfo, DeviceProfile, PlayReport, Schedule
from ..safety import Actuator, Degradation, Drive, StreamGuard, check_schedule, cooling_wait_ms

#: ``play``'s ``should_stop``: true (or a reason, as text) stops the play.
StopPoll = Callable[[], bool | str | None]

#: ``play``'s ``on_started``: called as the play starts, with its start on the device's
#: clock (ms) and on the host's (the device's :class:`~vtexp.clock.Clock`, ms; None when
#: not known): a trigger box sends its code then.
PlayStarted = Callable[[float, float | None], None]

#: How often a play polls ``should_stop`` while it waits, seconds.
STOP_POLL_S = 0.005


@dataclass
class StreamReport:
    """What :meth:`DeviceBase.stream` did with one frame of outputs.

    ``applied``: what the array does now (actuator -> drive; every other one off),
    after :class:`~vtexp.safety.StreamGuard`; ``changed``: how many outputs that
    changed; ``t_device_ms``: when the change took effect, on the device's clock
    as the device reported it (None when nothing changed); ``host_before_ms`` and
    ``host_after_ms``: the device's clock (:class:`~vtexp.clock.Clock`) in ms just before
    sending and once the device confirmed, which bracket ``t_device_ms`` (to map the device's clock onto
    the host's); ``degradations``: what the guard left out, and why.
    """

    applied: dict[Actuator, Drive]
    changed: int
    t_device_ms: float | None
    host_before_ms: float
    host_after_ms: float
    degradations: list[Degradation] = field(default_factory=list)


@runtime_checkable
class Device(Protocol):
    """A tactile array that plays Schedules.

    ``open`` connects and returns what the device reports about itself;
    ``play`` blocks until the schedule has been played and returns what was
    actually played, with onsets; ``all_off`` stops every actuator at once;
    ``close`` turns everything off and disconnects. Usable as a context
    manager (``with open_device(...) as dev:``).

    ``stream(frame)`` sets the outputs now (a live stream of frames: only the
    changes are sent), within the limits of :class:`~vtexp.safety.StreamGuard`.

    ``play(schedule, should_stop=f)``: ``f`` is called before the play starts and
    every few milliseconds (:data:`STOP_POLL_S`) while it waits for the schedule
    to be played; when it returns true, every actuator is turned off at once and
    ``play`` raises :class:`~vtexp.errors.SessionAborted` (with ``f``'s return
    value as the reason when that is text). A backend that does not wait (the
    virtual-clock ``sim``) calls it only before the play. ``on_started(device_ms,
    host_ms)`` is called as the play starts (:data:`PlayStarted`).

    ``wait_ms(ms)`` lets ``ms`` pass with nothing played (the pause between trials),
    on the device's clock (``clock``: a :class:`~vtexp.clock.Clock`, the real one
    unless another was given).
    """

    profile: DeviceProfile
    clock: Clock

    def open(self) -> DeviceInfo: ...

    def info(self) -> DeviceInfo: ...

    def play(self, schedule: Schedule, *, should_stop: StopPoll | None = None,
             on_started: PlayStarted | None = None) -> PlayReport: ...

    def wait_ms(self, ms: float) -> None: ...

    def all_off(self) -> None: ...

    def stream(self, frame: Mapping[Actuator, Drive], *, full: bool = False) -> StreamReport: ...

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

    def __init__(self, profile: DeviceProfile, clock: Clock = REAL):
        self.profile = profile
        self.clock = clock
        self._info: DeviceInfo | None = None
        self._last_off_ms: dict[tuple[int, int], float] = {}
        self._should_stop: StopPoll | None = None
        self._guard: StreamGuard | None = None
        self._stream_state: dict[Actuator, Drive] = {}
        self._streaming = False
        self._alive_at = 0.0
        self._on_started: PlayStarted | None = None

    # -- public API -------------------------------------------------------------------------
    def open(self) -> DeviceInfo:
        if self._info is None:
            self._info = self._open()
        return self._info

    def info(self) -> DeviceInfo:
        return self.open()

    def play(self, schedule: Schedule, *, should_stop: StopPoll | None = None,
             on_started: PlayStarted | None = None) -> PlayReport:
        check_schedule(schedule, self.profile)
        self.open()
        if self._streaming:
            self.all_off()              # a stream ends before a play starts
        self._should_stop = should_stop
        self._on_started = on_started
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
            self._on_started = None
        self._mark_off(schedule)
        return report

    def wait_ms(self, ms: float) -> None:
        """Let ``ms`` pass with nothing played (a pause between trials)."""
        if ms > 0:
            self._rest(ms)

    def _play_started(self, device_ms: float, host_ms: float | None) -> None:
        """Backends call this as a play starts; it tells ``play``'s ``on_started``."""
        if self._on_started is not None:
            self._on_started(device_ms, host_ms)

    def _mark_off(self, schedule: Schedule) -> None:
        # Stamped when play returns, which is no earlier than the last pulse ended:
        # the cooling measured from here is never shorter than the real one.
        now = self._now_ms()
        for p in schedule.pulses:
            self._last_off_ms[(p.row, p.col)] = now

    def all_off(self) -> None:
        if self._info is not None:
            try:
                self._all_off()
            finally:
                self._stream_ended()

    def close(self) -> None:
        if self._info is not None:
            try:
                self._all_off()
            finally:
                self._stream_ended()
                self._close()
                self._info = None

    # -- live stream ------------------------------------------------------------------------
    #: How much earlier than ``max_on_ms`` a stream switches an actuator off, on a device
    #: without a watchdog: the time the frame that does it may take to reach the device.
    stream_margin_ms = 50.0
    #: A stream's loop checks in (``stream`` or ``stream_alive``) at least this often; on a
    #: device with a watchdog, nothing keeps the device's session alive once it stops, so
    #: a stalled host is switched off by the device itself (see ``_stream_margin``).
    stream_checkin_ms = 50.0

    def stream_watchdog_ms(self) -> float | None:
        """The device's watchdog while streaming (everything off after this long without a
        frame from the host), or None if it has none."""
        return None

    def stream_watchdog_limit_ms(self) -> int:
        """The longest device watchdog with which this profile can be streamed
        (:func:`stream_watchdog_limit_ms`)."""
        return stream_watchdog_limit_ms(self.profile, self.stream_checkin_ms)

    def _stream_margin(self) -> float:
        """How long before ``max_on_ms`` the guard cuts a train. With a watchdog: the
        check-in period, the watchdog and 10 ms for the last frame on the wire, so that even
        if the host stalls right after a frame, the device's watchdog switches every
        actuator off before any exceeds its on-time."""
        wd = self.stream_watchdog_ms()
        return self.stream_margin_ms if wd is None else self.stream_checkin_ms + wd + 10.0

    def _spec_with_watchdog(self, watchdog_ms: int) -> str | None:
        """The ``--device`` spec of this device with that watchdog, if it has one."""
        return None

    def stream_alive(self) -> None:
        """The stream's loop checks in without sending anything (nothing changed)."""
        self._alive_at = self.clock.now()
        self._stream_checked_in()

    def stream(self, frame: Mapping[Actuator, Drive], *, full: bool = False) -> StreamReport:
        """Set the outputs now: ``frame`` maps (row, col) to a level or a pulse train;
        every actuator not in it is off.

        The frame first passes :class:`~vtexp.safety.StreamGuard` (maximum on-time,
        cooling, power budget, one setting's limits, held across frames and across
        plays), which leaves out what is not safe now and says so in the report;
        then only the outputs that change are sent. A frame is needed at least by
        :meth:`stream_deadline_s` (a train to cut), and the loop checks in (a frame or
        :meth:`stream_alive`) at least every :attr:`stream_checkin_ms`: on a device with
        a watchdog, a loop that stops checking in no longer keeps the device's session
        alive, and the device switches everything off itself before any on-time limit
        is reached (the guard cuts trains early enough for that). On any error every
        actuator is turned off. :meth:`all_off` ends the stream; a :meth:`play` ends it
        too. ``full=True`` sends every actuator's setting each time, as a naive host
        does (``bench/live.py``'s baseline).
        """
        self.open()
        if self._guard is None:
            margin = self._stream_margin()
            if margin > self.profile.limits.max_on_ms / 2:
                limit = self.stream_watchdog_limit_ms()
                spec = self._spec_with_watchdog(limit)
                raise InputError(
                    f"the device's watchdog ({self.stream_watchdog_ms():g} ms) is too long to "
                    f"stream to {self.profile.name} safely: a train would have to stop "
                    f"{margin:g} ms before max_on_ms {self.profile.limits.max_on_ms:g}; open it "
                    f"with a watchdog of at most {limit} ms"
                    + (f": --device {spec}" if spec else ""), key="--device")
            self._guard = StreamGuard(self.profile, self._last_off_ms, margin_ms=margin)
        if not self._streaming:
            self._alive_at = self.clock.now()
            self._streaming = True
            self._stream_started()
        try:
            self.stream_alive()
        except BaseException:
            self.all_off()
            raise
        guard = self._guard
        before = self._now_ms()
        allowed, notes = guard.admit(frame, before)
        old = self._stream_state
        changes = {k: allowed.get(k) for k in old.keys() | allowed.keys()
                   if old.get(k) != allowed.get(k)}
        host_before = self.clock.now_ms()
        t_device = None
        if changes or full:
            try:
                t_device = self._set_outputs(changes, full=full)
            except BaseException:
                self.all_off()          # ends the stream, marking every actuator off
                raise
        host_after = self.clock.now_ms()
        known = len(guard.overruns)
        guard.commit(allowed, before, self._now_ms())
        late = guard.overruns[known:]
        if late:
            (k0, on0) = max(late, key=lambda x: x[1])
            notes = [*notes, Degradation(
                "late", tuple(k for k, _ in late),
                f"late: (row {k0[0]}, col {k0[1]}) was on {on0:.0f} ms, above max_on_ms "
                f"{guard.max_on_ms:g}: the frame that stopped it came late")]
        self._stream_state = allowed
        return StreamReport(dict(allowed), len(changes), t_device, host_before, host_after,
                            notes)

    def stream_deadline_s(self) -> float | None:
        """Seconds from now by which the stream needs its next frame even if nothing
        else changes (a train to cut at its maximum on-time, a rest that ends); None
        if no actuator is on or held off."""
        if self._guard is None or not self._streaming:
            return None
        t = self._guard.next_deadline_ms()
        return None if t is None else max(0.0, (t - self._now_ms()) / 1000.0)

    def _stream_ended(self) -> None:
        if self._streaming:
            if self._guard is not None:
                self._guard.all_off(self._now_ms())
            self._stream_state = {}
            self._streaming = False
            self._stream_stopped()

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

    def _set_outputs(self, changes: Mapping[Actuator, Drive | None], *,
                     full: bool = False) -> float:
        """Apply ``changes`` (None = off) at once — with ``full``, as a frame that sets
        every actuator — and return when they took effect, on the device's clock in ms
        (the device's report)."""
        raise NotImplementedError(f"the {self.backend} device cannot stream frames")

    def _stream_started(self) -> None:
        """A stream begins (a backend with a virtual clock lets it follow real time)."""

    def _stream_stopped(self) -> None:
        """The stream ended with every actuator off."""

    def _stream_checked_in(self) -> None:
        """The loop checked in (a backend that models a watchdog checks it here)."""

    def _now_ms(self) -> float:
        """The clock that cooling times are measured on."""
        return self.clock.now_ms()

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
        clock = self.clock
        end = clock.now() + seconds
        if self._should_stop is None:
            clock.sleep(seconds)
            return
        while (left := end - clock.now()) > 0:
            clock.sleep(min(left, STOP_POLL_S))
            self._check_stop()


def stream_watchdog_limit_ms(profile: DeviceProfile,
                             checkin_ms: float = DeviceBase.stream_checkin_ms) -> int:
    """The longest device watchdog (ms, whole tens) with which ``profile`` can be streamed:
    the guard cuts trains the check-in period, the watchdog and 10 ms before
    ``max_on_ms`` (:meth:`DeviceBase._stream_margin`), and that margin may be at most half
    of ``max_on_ms``."""
    return int((profile.limits.max_on_ms / 2.0 - checkin_ms - 10.0) // 10 * 10)
