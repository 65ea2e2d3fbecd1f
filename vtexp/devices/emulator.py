"""A vtexp array emulated: the firmware and its serial line, behind a real
pseudo-terminal or in-process on a clock.

:class:`EmulatedLine` is the device's end of a serial line without any I/O: the
firmware (:class:`~vtexp.devices.firmware.Firmware`, a state machine), the faults
of the line and the frames on their way to the host, each released at its time.
Two adapters serve it:

- :class:`PtyEmulator` runs it in a thread on the master side of a real pty; the
  host opens the slave side (the path in :attr:`PtyEmulator.port`) with pyserial
  like any USB serial port. Its clock is the computer's (``time.perf_counter_ns``
  from its own power-on, optionally skewed by ``clock_ppm`` like a real crystal);
  the loop sleeps in ``select`` until shortly before the next due event and then
  spins, so an onset is stamped within microseconds of its due time when the
  machine is not overloaded.
- :class:`LoopbackEmulator` runs it in-process on a :class:`~vtexp.clock.VirtualClock`:
  its firmware's deadlines and the frames it sends are timers on that clock, and the
  host reaches it through :func:`open_port` with the name in :attr:`LoopbackEmulator.port`
  (``loopback:N``, as ``serial:loopback:N``). The bytes on the line are the same as on
  the pty; a session of a hundred trials passes in seconds.

Faults, for tests and for rehearsing a session:

- :class:`Faults`: drop or corrupt bytes at a given rate (each direction or
  one), delay every frame the device sends;
- ``unplug()``: the cable is pulled; the port disappears (the host's next
  read or write fails) while the device, on its own supply, turns everything
  off by its watchdog;
- ``mute()``: the device goes silent (hung USB bridge, broken TX line) while
  the port stays open; only heartbeats can tell.
"""

from __future__ import annotations

import errno
import itertools
import os
import random
import select
import threading
import time
import weakref
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any, Literal

from typing_extensions import Self

from ..clock import Clock, Timer, VirtualClock
from ..errors import DeviceError
from ..model import DeviceProfile
from . import wire
from .firmware import Actuation, Firmware, FirmwareConfig

Direction = Literal["both", "to_device", "to_host"]


@dataclass(frozen=True)
class Faults:
    """Line faults injected by the emulator (seeded, so a run can be repeated)."""

    drop_rate: float = 0.0        # probability that a byte is lost
    corrupt_rate: float = 0.0     # probability that a byte arrives altered
    delay_ms: float = 0.0         # added to every frame the device sends
    direction: Direction = "both"
    seed: int = 0

    def applies(self, direction: str) -> bool:
        return self.direction in ("both", direction)


@dataclass
class FaultCounts:
    dropped: int = 0
    corrupted: int = 0


class EmulatedLine:
    """The device's end of a serial line, without I/O (see the module docstring).

    ``from_host(data)`` takes bytes that reached the device; ``tick()`` applies what
    is due; ``due_us()`` says when something is due next (a firmware deadline, or a
    frame to release); ``released()`` returns the frames whose time has come, as
    they reach the host (faults applied; nothing while unplugged or muted). The
    caller holds :attr:`lock` around each call when it has threads.
    """

    def __init__(self, config: FirmwareConfig, clock_us: Callable[[], int], *,
                 faults: Faults | None = None,
                 trace: Callable[[str, object], None] | None = None):
        self.config = config
        self.clock_us = clock_us
        self.firmware = Firmware(config, clock_us)
        self.lock = threading.RLock()
        self.fault_counts = {"to_device": FaultCounts(), "to_host": FaultCounts()}
        self._faults = faults or Faults()
        self._rng = random.Random(self._faults.seed)
        self.trace = trace
        self._trace_readers = {"to_device": wire.FrameReader(), "to_host": wire.FrameReader()}
        self._tx: deque[tuple[float, bytes]] = deque()    # (release time, bytes)
        self.unplugged = False
        self.muted = False

    @property
    def faults(self) -> Faults:
        return self._faults

    @faults.setter
    def faults(self, f: Faults) -> None:
        with self.lock:
            if f.seed != self._faults.seed:
                self._rng = random.Random(f.seed)
            self._faults = f

    @property
    def connected(self) -> bool:
        """Bytes go both ways: the cable is in and the device not muted."""
        return not (self.unplugged or self.muted)

    def replugged(self) -> None:
        """The cable is back: what was on its way is gone, the frame readers start afresh."""
        self._tx.clear()
        self._trace_readers = {k: wire.FrameReader() for k in self._trace_readers}
        self.unplugged = False

    # -- the line --------------------------------------------------------------------------
    def from_host(self, data: bytes) -> None:
        data = self._mangle(data, "to_device")
        self._trace("to_device", data)
        self._queue(self.firmware.receive(data))

    def tick(self) -> None:
        self._queue(self.firmware.tick())

    def due_us(self) -> int | None:
        d = self.firmware.next_deadline_us()
        if self._tx:
            release = int(self._tx[0][0])
            d = release if d is None else min(d, release)
        return d

    def released(self) -> list[bytes]:
        """The frames released by now, as the host receives them."""
        now = self.clock_us()
        out = []
        while self._tx and self._tx[0][0] <= now:
            _, b = self._tx.popleft()
            if not self.connected:
                continue                    # the UART sends into nothing
            self._trace("to_host", b)
            out.append(self._mangle(b, "to_host"))
        return out

    def _queue(self, frames: list[bytes]) -> None:
        if not frames:
            return
        f = self._faults
        delay_us = f.delay_ms * 1000 if f.applies("to_host") else 0
        release = self.clock_us() + delay_us
        for b in frames:
            self._tx.append((release, b))

    def _mangle(self, data: bytes, direction: str) -> bytes:
        f = self._faults
        if not f.applies(direction) or (f.drop_rate == 0 and f.corrupt_rate == 0):
            return data
        counts = self.fault_counts[direction]
        out = bytearray()
        rng = self._rng
        for b in data:
            if f.drop_rate and rng.random() < f.drop_rate:
                counts.dropped += 1
                continue
            if f.corrupt_rate and rng.random() < f.corrupt_rate:
                counts.corrupted += 1
                b ^= rng.randrange(1, 256)
            out.append(b)
        return bytes(out)

    def _trace(self, direction: str, data: bytes) -> None:
        if self.trace is None:
            return
        for item in self._trace_readers[direction].feed(data):
            self.trace(direction, item if isinstance(item, wire.WireError) else item[1])


class _Emulator:
    """What both adapters offer: the device, its faults, and what it did."""

    line: EmulatedLine
    port: str

    @classmethod
    def for_profile(cls, profile: DeviceProfile, **kw) -> Self:
        """An emulator of a device built to ``profile``. Keywords that are fields of
        :class:`FirmwareConfig` (``rows=16``, ``max_level=1``, ...) make a device that
        differs from it; the others go to the emulator (``faults``, ``clock_ppm``...)."""
        names = {f.name for f in fields(FirmwareConfig)}
        over = {k: kw.pop(k) for k in list(kw) if k in names}
        return cls(FirmwareConfig.for_profile(profile, **over), **kw)

    @property
    def config(self) -> FirmwareConfig:
        return self.line.config

    @property
    def firmware(self) -> Firmware:
        return self.line.firmware

    @property
    def lock(self) -> threading.RLock:
        return self.line.lock

    @property
    def fault_counts(self) -> dict[str, FaultCounts]:
        return self.line.fault_counts

    @property
    def faults(self) -> Faults:
        return self.line.faults

    @faults.setter
    def faults(self, f: Faults) -> None:
        self.line.faults = f

    @property
    def trace(self) -> Callable[[str, object], None] | None:
        """Called with ``(direction, message_or_error)`` for every frame; may be replaced."""
        return self.line.trace

    @trace.setter
    def trace(self, f: Callable[[str, object], None] | None) -> None:
        self.line.trace = f

    def clock_us(self) -> int:
        """The device's own clock: microseconds since it was powered on."""
        return self.line.clock_us()

    def mute(self, muted: bool = True) -> None:
        """Stop (or resume) sending and receiving, leaving the port open."""
        with self.lock:
            self.line.muted = muted

    # -- what the device did ----------------------------------------------------------------
    def actuations(self) -> list[Actuation]:
        with self.lock:
            return list(self.firmware.history)

    def outputs(self) -> list[wire.Setting]:
        with self.lock:
            return list(self.firmware.outputs)

    def all_outputs_off(self) -> bool:
        with self.lock:
            return all(s.is_off for s in self.firmware.outputs)

    def __enter__(self) -> Self:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class PtyEmulator(_Emulator):
    """Serve a firmware on a fresh pseudo-terminal until :meth:`stop`.

    Parameters
    ----------
    config:
        The device to emulate (:meth:`FirmwareConfig.for_profile`).
    faults:
        Line faults; may be replaced at any time through :attr:`faults`.
    spin_us:
        How long before a due event the loop stops sleeping and spins.
    clock_ppm:
        Rate error of the device clock against the host's, in parts per million.
    trace:
        Called with ``(direction, message_or_error)`` for every frame (monitoring).
    """

    def __init__(self, config: FirmwareConfig, *, faults: Faults | None = None,
                 spin_us: int = 3000, clock_ppm: float = 0.0,
                 trace: Callable[[str, object], None] | None = None):
        self.spin_us = spin_us
        self._origin_ns = time.perf_counter_ns()
        self._rate = 1.0 + clock_ppm * 1e-6
        self.line = EmulatedLine(config, self._clock_us, faults=faults, trace=trace)
        self._master: int | None = None
        self._slave: int | None = None
        self.port = ""
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.error: BaseException | None = None

    def _clock_us(self) -> int:
        return int((time.perf_counter_ns() - self._origin_ns) * self._rate) // 1000

    # -- lifecycle --------------------------------------------------------------------------
    def _open_pty(self) -> str:
        master, slave, self.port = open_raw_pty(
            "the emulated device on a pseudo-terminal (vtexp device emulate, --device "
            "emulator)", "rehearse in-process with --device emulator:virtual or --device sim, "
            "or run on the real device: serial:PORT (e.g. serial:COM3)")
        os.set_blocking(master, False)
        # The emulator keeps the slave open too, so the host may close and reopen the
        # port (a real device stays plugged in when the host program exits).
        self._master, self._slave = master, slave
        return self.port

    def start(self) -> str:
        if self._thread is None:
            self._open_pty()
            self._thread = threading.Thread(target=self._run, name=f"vtexp-emulator {self.port}",
                                            daemon=True)
            self._thread.start()
        return self.port

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None
        self._close_fds()

    def unplug(self) -> None:
        """Pull the cable: the port goes away; the device keeps running on its own."""
        with self.lock:
            self.line.unplugged = True
            self._close_fds()

    def replug(self) -> str:
        """Plug the cable back in: a new port (a pty gets a new path, as a USB serial
        device may), the same device, still running on its own clock."""
        with self.lock:
            self._close_fds()
            self.line.replugged()
            return self._open_pty()

    # -- the loop ---------------------------------------------------------------------------
    def _close_fds(self) -> None:
        for fd in (self._master, self._slave):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = None

    def _run(self) -> None:
        line = self.line
        try:
            while not self._stop.is_set():
                with self.lock:
                    deadline = line.due_us()
                    fd = self._master if line.connected else None
                now = line.clock_us()
                wait_us = None if deadline is None else deadline - now
                if wait_us is None or wait_us > self.spin_us:
                    # Sleep until shortly before the deadline (at most 50 ms, to see stop()).
                    timeout = 0.05 if wait_us is None else min(0.05, (wait_us - self.spin_us) / 1e6)
                else:
                    timeout = 0.0               # spinning: poll the port, check the clock
                data = b""
                if fd is not None:
                    try:
                        ready, _, _ = select.select([fd], [], [], timeout)
                    except (OSError, ValueError):   # unplugged under our feet
                        ready = []
                    if ready:
                        data = self._read(fd)
                elif timeout > 0:
                    self._stop.wait(timeout)
                with self.lock:
                    if data:
                        line.from_host(data)
                    else:
                        line.tick()
                    self._write(line.released())
        except BaseException as e:  # pragma: no cover - surfaced to tests through .error
            self.error = e
            raise

    def _read(self, fd: int) -> bytes:
        try:
            return os.read(fd, 4096)
        except BlockingIOError:
            return b""
        except OSError as e:
            if e.errno in (errno.EIO, errno.EBADF):     # nobody on the slave side / unplugged
                return b""
            raise

    def _write(self, frames: list[bytes]) -> None:
        for b in frames:
            if self._master is None:
                return
            try:
                os.write(self._master, b)
            except BlockingIOError:
                pass                        # host not reading: a UART drops, it never blocks
            except OSError as e:
                if e.errno not in (errno.EIO, errno.EBADF):
                    raise


def open_raw_pty(what: str, instead: str) -> tuple[int, int, str]:
    """A new pseudo-terminal in raw mode: ``(master, slave, the slave's path)``. Where the
    system has none (Windows), one line saying that ``what`` needs one, and ``instead``."""
    try:
        import tty
    except ImportError:             # Windows
        tty = None
    if tty is None or not hasattr(os, "openpty"):
        raise DeviceError(f"{what} needs a pseudo-terminal, which this system does not have "
                          f"(Linux and macOS do); {instead}")
    master, slave = os.openpty()
    # Raw at once: a cooked pty would echo the device's bytes back to it and turn CR into
    # LF before the host's pyserial gets to set raw mode itself.
    tty.setraw(slave)
    return master, slave, os.ttyname(slave)


#: Loopback ports by name (``loopback:N``), while their emulator lives.
_LOOPBACKS: weakref.WeakValueDictionary[str, LoopbackEmulator] = weakref.WeakValueDictionary()
_LOOPBACK_NUMBERS = itertools.count(1)


class LoopbackEmulator(_Emulator):
    """The emulated device in-process, on a :class:`~vtexp.clock.VirtualClock`.

    Its firmware's deadlines and the frames it sends are timers on the clock; the
    host writes to it through the port :func:`open_port` gives for :attr:`port`
    (``loopback:N``), and what it sends reaches the host when the host next waits on
    the clock. Parameters as :class:`PtyEmulator`'s (``spin_us`` does not apply: every
    event happens exactly at its time).
    """

    def __init__(self, config: FirmwareConfig, *, clock: VirtualClock,
                 faults: Faults | None = None, clock_ppm: float = 0.0,
                 trace: Callable[[str, object], None] | None = None,
                 baudrate: int = 1_000_000, **_: Any):
        if not getattr(clock, "virtual", False) or not hasattr(clock, "call_at"):
            raise DeviceError("the in-process emulator runs on a virtual clock; on the "
                              "computer's clock, use the emulator on a pseudo-terminal")
        self.clock = clock
        self._origin = clock.now()
        self._rate = 1.0 + clock_ppm * 1e-6
        self.line = EmulatedLine(config, self._clock_us, faults=faults, trace=trace)
        self.port = ""
        self.host: LoopbackPort | None = None
        self._timer: Timer | None = None
        self._held: list[bytes] = []        # sent to a muted device: waiting, as in a UART
        self.error: BaseException | None = None
        # Bytes take their time on the line, one direction at a time each way (10 bits
        # a byte: start, 8 data, stop).
        self.byte_s = 10.0 / baudrate
        self._to_device_free = self._to_host_free = clock.now()

    def _clock_us(self) -> int:
        return int(round((self.clock.now() - self._origin) * self._rate * 1e6))

    def _host_time(self, device_us: int) -> float:
        return self._origin + device_us / 1e6 / self._rate

    def start(self) -> str:
        if not self.port:
            self._name()
        return self.port

    def _name(self) -> str:
        self.port = f"loopback:{next(_LOOPBACK_NUMBERS)}"
        _LOOPBACKS[self.port] = self
        return self.port

    def stop(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        _LOOPBACKS.pop(self.port, None)
        if self.host is not None:
            self.host.gone(OSError(errno.EIO, "the emulator was stopped"))

    def unplug(self) -> None:
        """Pull the cable: the port goes away; the device keeps running on its own."""
        self.line.unplugged = True
        _LOOPBACKS.pop(self.port, None)
        if self.host is not None:
            self.host.gone(OSError(errno.EIO, "the device was disconnected"))
        self._arm()

    def replug(self) -> str:
        """Plug the cable back in: a new port name, the same device on its own clock."""
        self.line.replugged()
        self._arm()
        return self._name()

    # -- the line, on the clock -------------------------------------------------------------
    def connect(self, port: LoopbackPort) -> None:
        if self.host is not None and not self.host.closed:
            # as pyserial says of a port another program holds (exclusive=True)
            raise OSError(errno.EBUSY, f"could not exclusively lock port {self.port}: it is "
                                       "open in another program")
        self.host = port

    def mute(self, muted: bool = True) -> None:
        """Stop (or resume) sending and receiving, leaving the port open; what the host
        sent meanwhile is read when it resumes, as from a UART's buffer."""
        self.line.muted = muted
        if not muted and self._held:
            held, self._held = b"".join(self._held), []
            self._arrived(held)
        self._arm()

    def from_host(self, data: bytes) -> None:
        """Bytes written by the host: they reach the device once they are through the line."""
        self._to_device_free = max(self._to_device_free, self.clock.now()) + \
            len(data) * self.byte_s
        self.clock.call_at(self._to_device_free, lambda: self._arrived(data))

    def _arrived(self, data: bytes) -> None:
        if self.line.unplugged:
            return
        if self.line.muted:
            self._held.append(data)
            return
        self.line.from_host(data)
        self._arm()

    def _arm(self) -> None:
        """One timer at the next thing due (a firmware deadline or a frame to release)."""
        due = self.line.due_us()
        if self._timer is not None:
            if due is not None and self._timer.t == self._host_time(due) \
                    and not self._timer.cancelled:
                return
            self._timer.cancel()
            self._timer = None
        if due is not None:
            self._timer = self.clock.call_at(self._host_time(due), self._due)

    def _due(self) -> None:
        self._timer = None
        try:
            self.line.tick()
            frames = self.line.released()
        except BaseException as e:
            self.error = e
            raise
        for frame in frames:
            self._to_host_free = max(self._to_host_free, self.clock.now()) + \
                len(frame) * self.byte_s
            self.clock.call_at(self._to_host_free, lambda f=frame: self._deliver(f))
        self._arm()

    def _deliver(self, frame: bytes) -> None:
        host = self.host
        if host is not None and not host.closed and self.line.connected:
            host.receive(frame)


class LoopbackPort:
    """The host's end of a :class:`LoopbackEmulator`'s line: what :func:`open_port` gives.

    Not a pyserial port: the :class:`~vtexp.devices.link.Link` sees :meth:`attach` and
    takes bytes as they arrive instead of reading in a thread.
    """

    def __init__(self, emulator: LoopbackEmulator, baudrate: int):
        self.emulator = emulator
        self.name = emulator.port
        self.baudrate = baudrate
        self.closed = False
        self._lost: OSError | None = None
        self._on_data: Callable[[bytes], None] | None = None
        self._on_error: Callable[[BaseException], None] | None = None
        emulator.connect(self)

    def attach(self, on_data: Callable[[bytes], None],
               on_error: Callable[[BaseException], None]) -> None:
        self._on_data, self._on_error = on_data, on_error

    def write(self, data: bytes) -> int:
        if self.closed:
            raise OSError(errno.EBADF, "the port is closed")
        if self._lost is not None:
            raise self._lost
        self.emulator.from_host(bytes(data))
        return len(data)

    def receive(self, data: bytes) -> None:
        if self._on_data is not None:
            self._on_data(data)

    def gone(self, error: OSError) -> None:
        """The port went away under the host (unplugged): its next read or write fails."""
        self._lost = error
        if self._on_error is not None and not self.closed:
            self._on_error(error)

    def reset_input_buffer(self) -> None:
        pass

    def cancel_read(self) -> None:
        pass

    def close(self) -> None:
        self.closed = True


def open_port(name: str, *, baudrate: int, clock: Clock, timeout: float = 0.01,
              write_timeout: float = 2.0) -> Any:
    """The port a :class:`~vtexp.devices.serial_device.SerialDevice` talks through: a
    :class:`LoopbackPort` for ``loopback:N`` (an in-process emulator on ``clock``),
    else whatever pyserial opens (raises its errors)."""
    if name.startswith("loopback:"):
        emu = _LOOPBACKS.get(name)
        if emu is None:
            raise OSError(errno.ENOENT, f"no emulator is serving {name}")
        if emu.clock is not clock:
            raise DeviceError(f"{name} runs on another clock than this device's; give both "
                              "the same VirtualClock")
        return LoopbackPort(emu, baudrate)
    import serial  # pyserial; imported here so that 'vtexp --help' stays fast

    # exclusive: two programs driving one array would interleave their frames
    return serial.serial_for_url(name, baudrate=baudrate, timeout=timeout,
                                 write_timeout=write_timeout, exclusive=True)


def check_alive(emu: PtyEmulator | LoopbackEmulator) -> None:
    """Raise if the emulator thread died (a bug in it must not pass as a line fault)."""
    if emu.error is not None:
        raise DeviceError(f"the emulator on {emu.port} crashed: {emu.error!r}")


__all__ = ["EmulatedLine", "FaultCounts", "Faults", "FirmwareConfig", "LoopbackEmulator",
           "LoopbackPort", "PtyEmulator", "check_alive", "open_port", "open_raw_pty"]
