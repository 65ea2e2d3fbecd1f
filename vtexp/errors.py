"""Errors meant for people.

Every error a user can cause by their input derives from :class:`VtexpError`.
The CLI prints its message (no traceback) and exits non-zero. Messages say
what was wrong, where (file, line, key; or actuator and time), and what to do.
"""

from __future__ import annotations


class VtexpError(Exception):
    """Base class of errors that the CLI reports as one clear message."""

    exit_code = 2


class InputError(VtexpError):
    """A file or value given by the user is wrong.

    Parameters
    ----------
    message:
        What is wrong and what is expected.
    path:
        The file in which it is wrong, if any.
    line:
        1-based line number in ``path``, if known.
    key:
        Dotted path of the offending key (``design.repetitions``), if any.
    """

    def __init__(self, message: str, *, path: str | None = None,
                 line: int | None = None, key: str | None = None):
        self.message = message
        self.path = path
        self.line = line
        self.key = key
        super().__init__(self.format())

    def format(self) -> str:
        where = ""
        if self.path:
            where = str(self.path)
            if self.line:
                where += f":{self.line}"
            where += ": "
        if self.key:
            where += f"{self.key}: "
        return where + self.message


class UnsafeStimulus(VtexpError):
    """A Schedule would exceed the device profile's safety limits.

    Parameters
    ----------
    message:
        Which limit, where (actuator and time), and what to change.
    schedule:
        When a coding refuses a stimulus it cannot fit to the limits, the Schedule it
        would have played, unfitted: for a caller that holds the limits itself as it
        plays (the live loop's :class:`~vtexp.safety.StreamGuard`); otherwise None.
    """

    def __init__(self, message: str, *, schedule=None):
        super().__init__(message)
        self.schedule = schedule


class DeviceError(VtexpError):
    """The device failed or could not be reached."""

    exit_code = 3


class StreamCut(DeviceError):
    """The device's watchdog switched every actuator off during a live stream (the host
    fell silent for longer than the watchdog).

    Attributes
    ----------
    off_at_ms:
        When it did, on the device's clock in ms (its alarm's time), or None if the
        device did not say: a live record stamps its all-off with it.
    """

    def __init__(self, message: str, *, off_at_ms: float | None = None):
        super().__init__(message)
        self.off_at_ms = off_at_ms


class PlayInterrupted(DeviceError):
    """The device stopped a play part-way (its watchdog fired): every actuator is off.

    Attributes
    ----------
    report:
        The :class:`~vtexp.model.PlayReport` of the pulses it did play, each with its
        device-reported onset (``completed`` false); the session logs them as it logs a
        completed play's.
    """

    def __init__(self, message: str, report):
        super().__init__(message)
        self.report = report


class SessionError(VtexpError):
    """A session cannot start or continue (existing data, unwritable disk...)."""


class SessionAborted(VtexpError):
    """The experimenter or participant aborted the session (e.g. Escape in the window).

    ``played``: when a play was stopped (``play(should_stop=...)``), what the device
    reports having played of it until then (a ``PlayReport`` with ``completed`` false;
    None if the device reported nothing, or the stop came before the play started).
    """

    exit_code = 130
    played = None
