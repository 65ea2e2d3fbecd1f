"""The device's clock on this computer's: what a device-reported time was here.

A device stamps onsets on its own clock (µs since it was powered on). Other
recordings of the same session (an EEG amplifier through Lab Streaming Layer, an
eye tracker) keep time on this computer's monotonic clock, so an onset is only
useful to them mapped onto it. Every exchange whose reply carries the device's
time (a heartbeat's ACK, a TRIGGER's ACK with the play's start) is a sample: the
device read its clock between the host's send (``before``) and the reply's arrival
(``after``), so ``device − (before + after) / 2`` is the offset, wrong by at most
half the round trip. :class:`DeviceClock` keeps the recent samples and uses the one
with the shortest round trip among those of the last ``window_s`` seconds: the
window keeps a crystal's drift (tens of ppm: 0.1 ms over 2 s at 50 ppm) out of the
mapping, the shortest round trip its error small.

Host times are the host :class:`~vtexp.clock.Clock`'s milliseconds: on the real clock
``time.monotonic()`` (CLOCK_MONOTONIC on Linux, the clock Lab Streaming Layer's
``local_clock`` reads there too).
"""

from __future__ import annotations

import threading
from collections import deque

from ..clock import REAL, Clock


class DeviceClock:
    """Device time → host time (``host``'s ms), from timed exchanges (thread-safe)."""

    def __init__(self, window_s: float = 2.0, keep: int = 256, host: Clock = REAL):
        self.host = host
        self.window_ms = window_s * 1000.0
        self._samples: deque[tuple[float, float, float]] = deque(maxlen=keep)
        self._lock = threading.Lock()

    def add(self, before_ms: float, after_ms: float, device_ms: float) -> None:
        """One exchange: sent at ``before_ms``, answered at ``after_ms`` (host), the
        device's clock read in between said ``device_ms``."""
        if after_ms < before_ms:
            return
        with self._lock:
            self._samples.append((after_ms, after_ms - before_ms,
                                  device_ms - (before_ms + after_ms) / 2.0))

    def reset(self) -> None:
        """Forget every sample (a device opened again may have restarted its clock)."""
        with self._lock:
            self._samples.clear()

    def _best(self) -> tuple[float, float, float] | None:
        with self._lock:
            if not self._samples:
                return None
            newest = self._samples[-1][0]
            recent = [s for s in self._samples if newest - s[0] <= self.window_ms]
            return min(recent, key=lambda s: s[1])

    def age_ms(self, now_ms: float | None = None) -> float:
        """How long ago (host ms) the newest sample came; infinite if none."""
        with self._lock:
            if not self._samples:
                return float("inf")
            newest = self._samples[-1][0]
        return (self.host.now_ms() if now_ms is None else now_ms) - newest

    def offset_ms(self) -> tuple[float, float] | None:
        """``(device − host offset, error bound)`` in ms, or None before any exchange."""
        best = self._best()
        return None if best is None else (best[2], best[1] / 2.0)

    def to_host_ms(self, device_ms: float) -> float | None:
        """``device_ms`` on the host's clock (ms), or None if unknown."""
        off = self.offset_ms()
        return None if off is None else device_ms - off[0]
