"""``vtexp device monitor``: a transparent tap that decodes wire-protocol-v1 traffic.

The tap opens the device's port and offers the host a pseudo-terminal in its
place; every byte is passed on unchanged in both directions, and every frame
is decoded and printed with its time and direction (bad frames too, with
what was wrong). Point the experiment at the tap's port instead of the
device's to see what they say to each other.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from typing import Any, TextIO

from ..errors import DeviceError
from . import wire

ARROWS = {"to_device": "host -> device", "to_host": "device -> host"}


def format_event(t_ms: float, direction: str, item: tuple[int, wire.Message] | wire.WireError
                 ) -> str:
    """One line of monitor output."""
    if isinstance(item, wire.WireError):
        return f"{t_ms:10.3f} ms  {ARROWS[direction]}  BAD FRAME ({item.kind}: {item})"
    seq, msg = item
    return f"{t_ms:10.3f} ms  {ARROWS[direction]}  seq {seq:3d}  {wire.describe(msg)}"


class Tap:
    """Forward bytes between ``port`` (the device) and a new pty (the host), decoding both.

    Parameters
    ----------
    port:
        An open pyserial port to the device.
    emit:
        Called with each formatted line.
    """

    def __init__(self, port: Any, emit: Callable[[str], None], master: int, slave: int,
                 name: str):
        self.port = port
        self.emit = emit
        self._t0 = time.perf_counter()
        self._readers = {"to_device": wire.FrameReader(), "to_host": wire.FrameReader()}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.master = master
        self._slave = slave                   # kept open: the host may reconnect
        self.host_port = name
        self.error: str | None = None
        self._threads = [threading.Thread(target=self._device_to_host, daemon=True),
                         threading.Thread(target=self._host_to_device, daemon=True)]

    def start(self) -> str:
        for t in self._threads:
            t.start()
        return self.host_port

    def stop(self) -> None:
        self._stop.set()
        try:
            self.port.cancel_read()
        except Exception:
            pass
        for t in self._threads:
            t.join(timeout=1)
        for fd in (self.master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def wait(self, timeout: float | None = None) -> bool:
        """Until stopped or the device is gone; True if stopped."""
        return self._stop.wait(timeout)

    def _show(self, direction: str, data: bytes) -> None:
        t = (time.perf_counter() - self._t0) * 1000.0
        with self._lock:
            for item in self._readers[direction].feed(data):
                self.emit(format_event(t, direction, item))

    def _device_to_host(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.port.read(self.port.in_waiting or 1)
            except Exception as e:          # the device was unplugged
                if not self._stop.is_set():
                    self.error = f"the device's port failed ({e})"
                    self._stop.set()
                return
            if data:
                self._show("to_host", data)
                try:
                    os.write(self.master, data)
                except OSError:
                    pass                    # no host connected: a UART would drop it too

    def _host_to_device(self) -> None:
        import select

        while not self._stop.is_set():
            r, _, _ = select.select([self.master], [], [], 0.05)
            if not r:
                continue
            try:
                data = os.read(self.master, 4096)
            except OSError:
                continue                    # host closed its end; it may open it again
            if data:
                self._show("to_device", data)
                try:
                    self.port.write(data)
                except Exception as e:
                    self.error = f"writing to the device failed ({e})"
                    self._stop.set()
                    return


def open_tap(spec: str, baudrate: int, out: TextIO) -> Tap:
    from .emulator import open_raw_pty

    master, slave, name = open_raw_pty(
        "vtexp device monitor (to stand in for the device)",
        "run the experiment directly on serial:PORT (e.g. serial:COM3)")
    import serial

    port_name = spec.partition(":")[2] if spec.startswith("serial:") else spec
    try:
        port = serial.serial_for_url(port_name, baudrate=baudrate, timeout=0.05)
    except (serial.SerialException, ValueError, OSError) as e:
        os.close(master)
        os.close(slave)
        raise DeviceError(f"cannot open the serial port {port_name!r}: {e}. "
                          "'vtexp device list' shows the ports found.") from None
    return Tap(port, lambda line: print(line, file=out, flush=True), master, slave, name)
