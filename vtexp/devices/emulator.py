"""A vtexp array emulated behind a real pseudo-terminal.

:class:`PtyEmulator` runs :class:`~vtexp.devices.firmware.Firmware` in a
thread on the master side of a pty; the host opens the slave side (the path
in :attr:`PtyEmulator.port`) with pyserial like any USB serial port, so the
serial backend is exercised byte for byte without hardware.

The emulated device has its own clock (``time.perf_counter_ns`` from its own
power-on, optionally skewed by ``clock_ppm`` like a real crystal) and plays
schedules from it: the loop sleeps in ``select`` until shortly before the
next due event and then spins, so an onset is stamped within microseconds
of its due time when the machine is not overloaded.

Faults, for tests and for rehearsing a session:

- :class:`Faults`: drop or corrupt bytes at a given rate (each direction or
  one), delay every frame the device sends;
- :meth:`PtyEmulator.unplug`: the cable is pulled; the port disappears (the
  host's next read or write fails) while the device, on its own supply,
  turns everything off by its watchdog;
- :meth:`PtyEmulator.mute`: the device goes silent (hung USB bridge, broken
  TX line) while the port stays open; only heartbeats can tell.
"""

from __future__ import annotations

import errno
import os
import random
import select
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Literal

from typing_extensions import Self

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


class PtyEmulator:
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
        self.config = config
        self.spin_us = spin_us
        self._origin_ns = time.perf_counter_ns()
        self._rate = 1.0 + clock_ppm * 1e-6
        self.firmware = Firmware(config, self.clock_us)
        self.lock = threading.RLock()
        self.fault_counts = {"to_device": FaultCounts(), "to_host": FaultCounts()}
        self._faults = faults or Faults()
        self._rng = random.Random(self._faults.seed)
        self.trace = trace
        self._trace_readers = {"to_device": wire.FrameReader(), "to_host": wire.FrameReader()}
        self._tx: deque[tuple[float, bytes]] = deque()    # (release time, bytes)
        self._master: int | None = None
        self._slave: int | None = None
        self.port = ""
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._unplugged = False
        self._muted = False
        self.error: BaseException | None = None

    @classmethod
    def for_profile(cls, profile: DeviceProfile, **kw) -> PtyEmulator:
        """An emulator of a device built to ``profile``. Keywords that are fields of
        :class:`FirmwareConfig` (``rows=16``, ``max_level=1``, ...) make a device that
        differs from it; the others go to the emulator (``faults``, ``clock_ppm``...)."""
        names = {f.name for f in fields(FirmwareConfig)}
        over = {k: kw.pop(k) for k in list(kw) if k in names}
        return cls(FirmwareConfig.for_profile(profile, **over), **kw)

    # -- clock ------------------------------------------------------------------------------
    def clock_us(self) -> int:
        """The device's own clock: microseconds since it was powered on."""
        return int((time.perf_counter_ns() - self._origin_ns) * self._rate) // 1000

    # -- lifecycle --------------------------------------------------------------------------
    def _open_pty(self) -> str:
        try:
            import tty
        except ImportError:             # Windows
            tty = None
        if tty is None or not hasattr(os, "openpty"):
            raise DeviceError("the emulated device (vtexp device emulate, --device emulator) "
                              "needs a pseudo-terminal, which this system does not have (Linux "
                              "and macOS do); rehearse with --device sim, or run on the real "
                              "device: serial:PORT (e.g. serial:COM3)")
        master, slave = os.openpty()
        # Raw at once: a cooked pty would echo the device's bytes back to it and turn CR
        # into LF before the host's pyserial gets to set raw mode itself.
        tty.setraw(slave)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        # The emulator keeps the slave open too, so the host may close and reopen the
        # port (a real device stays plugged in when the host program exits).
        self.port = os.ttyname(slave)
        return self.port

    def start(self) -> str:
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

    def __enter__(self) -> Self:
        if self._thread is None:
            self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def faults(self) -> Faults:
        return self._faults

    @faults.setter
    def faults(self, f: Faults) -> None:
        with self.lock:
            if f.seed != self._faults.seed:
                self._rng = random.Random(f.seed)
            self._faults = f

    def unplug(self) -> None:
        """Pull the cable: the port goes away; the device keeps running on its own."""
        with self.lock:
            self._unplugged = True
            self._close_fds()

    def replug(self) -> str:
        """Plug the cable back in: a new port (a pty gets a new path, as a USB serial
        device may), the same device, still running on its own clock."""
        with self.lock:
            self._close_fds()
            self._tx.clear()
            self._trace_readers = {k: wire.FrameReader() for k in self._trace_readers}
            self._unplugged = False
            return self._open_pty()

    def mute(self, muted: bool = True) -> None:
        """Stop (or resume) sending and receiving, leaving the port open."""
        with self.lock:
            self._muted = muted

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

    # -- the loop ---------------------------------------------------------------------------
    def _close_fds(self) -> None:
        for fd in (self._master, self._slave):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = None

    def _next_deadline_us(self) -> int | None:
        d = self.firmware.next_deadline_us()
        if self._tx:
            release = int(self._tx[0][0])
            d = release if d is None else min(d, release)
        return d

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                with self.lock:
                    deadline = self._next_deadline_us()
                    fd = None if (self._unplugged or self._muted) else self._master
                now = self.clock_us()
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
                        data = self._mangle(data, "to_device")
                        self._trace("to_device", data)
                        out = self.firmware.receive(data)
                    else:
                        out = self.firmware.tick()
                    self._queue(out)
                    self._flush()
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

    def _queue(self, frames: list[bytes]) -> None:
        if not frames:
            return
        f = self._faults
        delay_us = f.delay_ms * 1000 if f.applies("to_host") else 0
        release = self.clock_us() + delay_us
        for b in frames:
            self._tx.append((release, b))

    def _flush(self) -> None:
        now = self.clock_us()
        while self._tx and self._tx[0][0] <= now:
            _, b = self._tx.popleft()
            if self._unplugged or self._muted or self._master is None:
                continue                    # the UART sends into nothing
            self._trace("to_host", b)
            b = self._mangle(b, "to_host")
            try:
                os.write(self._master, b)
            except BlockingIOError:
                pass                        # host not reading: a UART drops, it never blocks
            except OSError as e:
                if e.errno not in (errno.EIO, errno.EBADF):
                    raise

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


def check_alive(emu: PtyEmulator) -> None:
    """Raise if the emulator thread died (a bug in it must not pass as a line fault)."""
    if emu.error is not None:
        raise DeviceError(f"the emulator on {emu.port} crashed: {emu.error!r}")


__all__ = ["FaultCounts", "Faults", "FirmwareConfig", "PtyEmulator", "check_alive"]
