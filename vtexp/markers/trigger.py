"""Trigger boxes: one byte per event, sent when it happens (``serial:PORT``, ``parallel:ADDRESS``).

A trigger box (a USB serial "TriggerBox", an Arduino, a parallel port wired to the
amplifier's trigger input) turns each byte into TTL lines that the recorder stores
with its own samples, so the byte's *arrival* is the event's time. The codes are
:data:`vtexp.markers.CODES`; a stimulus's code is sent when the device confirms the
play has started (a device-timed play: the TRIGGER's ACK, within the link's round
trip of the real start; a host-timed one: the first frame's ACK). Pulses inside a
stimulus get no code of their own: their device-reported onsets are in the events
file and in the LSL stream, and the firmware's sync output gives each onset
instant as a TTL edge with µs precision (``docs/firmware.md``).

``reset_ms=N`` writes 0 that many ms after each code (boxes that hold their lines
until told otherwise); a parallel port is always reset (``pulse_ms``, default 5).
"""

from __future__ import annotations

import threading

from ..errors import InputError
from . import CODES, MarkerError, MarkerSink


class _ByteTrigger(MarkerSink):
    """Sends :data:`CODES` as the session's records come, each at the moment of its
    event; subclasses write a byte."""

    #: The record type's name -> the event whose code it sends.
    EVENTS = {"SessionStarted": "session_start", "TrialStarted": "trial_start",
              "PlayStarted": "stimulus", "Answered": "answer", "TrialDone": "trial_end",
              "SessionEnded": "session_end"}

    def __init__(self, reset_ms: float | None, warn=None, clock=None):
        super().__init__(warn, clock)
        self.reset_ms = reset_ms
        self.sent: list[tuple[float, int]] = []      # (the clock's monotonic s, code)
        self._lock = threading.Lock()
        self._timer: threading.Timer | None = None

    def _write(self, code: int) -> None:
        raise NotImplementedError

    def send(self, event: str) -> None:
        code = CODES[event]
        with self._lock:
            if self._timer is not None:
                self._timer.cancel()
                self._timer = None
            try:
                self._write(code)
                self.sent.append((self.clock.now(), code))
            except Exception as e:
                self.failed(f"code {code} ({event}) could not be sent ({e})")
                return
            if self.reset_ms:
                self._timer = threading.Timer(self.reset_ms / 1000.0, self._reset)
                self._timer.daemon = True
                self._timer.start()

    def _reset(self) -> None:
        with self._lock:
            try:
                self._write(0)
            except Exception as e:
                self.failed(f"the reset to 0 could not be sent ({e})")

    def __call__(self, record) -> None:
        event = self.EVENTS.get(type(record).__name__)
        if event is not None:
            self.send(event)

    def close(self) -> None:
        with self._lock:
            if self._timer is not None:
                self._timer.cancel()
                self._timer = None
                try:
                    self._write(0)
                except Exception:
                    pass


def _known(opts: dict, spec: str, allowed: tuple[str, ...]) -> None:
    """Refuse an option of ``spec`` that is not one of ``allowed`` (each a number)."""
    unknown = set(opts) - set(allowed)
    if unknown:
        raise InputError(f"{spec}: unknown option {sorted(unknown)[0]!r} ("
                         + ", ".join(f"{k}=N" for k in allowed) + ")", key="--markers")


def _number(opts: dict, key: str, default: float | None, spec: str) -> float | None:
    if key not in opts:
        return default
    try:
        v = float(opts[key])
    except ValueError:
        raise InputError(f"{spec}: {key} must be a number (got {opts[key]!r})",
                         key="--markers") from None
    if v < 0:
        raise InputError(f"{spec}: {key} must be 0 or more", key="--markers")
    return v


class SerialTrigger(_ByteTrigger):
    """A trigger box on a serial port (``serial:PORT[,baud=N,reset_ms=N]``)."""

    def __init__(self, port, name: str, reset_ms: float | None, warn=None, clock=None):
        super().__init__(reset_ms, warn, clock)
        self.port = port
        self.description = f"trigger box on {name}"

    @classmethod
    def open(cls, target: str, opts: dict, warn=None, clock=None) -> SerialTrigger:
        import serial

        spec = f"serial:{target}"
        _known(opts, spec, ("baud", "reset_ms"))
        baud = _number(opts, "baud", 115200, spec)
        reset = _number(opts, "reset_ms", None, spec)
        try:
            port = serial.serial_for_url(target, baudrate=int(baud), write_timeout=0.5,
                                         exclusive=True)
        except (serial.SerialException, ValueError, OSError) as e:
            raise MarkerError(f"cannot open the trigger box on {target!r}: {e}. "
                              "'vtexp device list' shows the serial ports found.") from None
        return cls(port, target, reset, warn, clock)

    def _write(self, code: int) -> None:
        self.port.write(bytes((code,)))
        self.port.flush()

    def close(self) -> None:
        super().close()
        try:
            self.port.close()
        except Exception:
            pass


class ParallelTrigger(_ByteTrigger):
    """A parallel port's data lines (``parallel:ADDRESS``: ``/dev/parport0`` on Linux,
    ``0x378`` on Windows), through PsychoPy's ``psychopy.parallel`` (the ``gui`` extra)."""

    def __init__(self, port, name: str, pulse_ms: float, warn=None, clock=None):
        super().__init__(pulse_ms, warn, clock)
        self.port = port
        self.description = f"parallel port {name}"

    @classmethod
    def open(cls, target: str, opts: dict, warn=None, clock=None) -> ParallelTrigger:
        spec = f"parallel:{target}"
        _known(opts, spec, ("pulse_ms",))
        pulse = _number(opts, "pulse_ms", 5.0, spec) or 5.0
        address: str | int = target
        if target.lower().startswith("0x"):
            try:
                address = int(target, 16)
            except ValueError:
                raise InputError(f"{spec}: not an address", key="--markers") from None
        try:
            from psychopy import parallel     # noqa: PLC0415 (optional, heavy)
        except Exception as e:
            raise MarkerError(f"the parallel port needs PsychoPy's psychopy.parallel (the "
                              f"'gui' extra), which could not be loaded: {e}") from None
        try:
            port = parallel.ParallelPort(address=address)
            port.setData(0)
        except Exception as e:
            raise MarkerError(
                f"cannot open the parallel port {target!r}: {e}. On Linux the port is "
                "/dev/parport0 (kernel module ppdev loaded, your user in group lp); on "
                "Windows an address such as 0x378 with the inpout32 driver installed.") from None
        return cls(port, target, pulse, warn, clock)

    def _write(self, code: int) -> None:
        self.port.setData(code)
