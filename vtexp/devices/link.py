"""The host end of a wire-protocol-v1 link over any pyserial port.

A :class:`Link` owns the port: a reader thread decodes frames (counting and
dropping bad ones), hands replies to the one request in flight and events to
a callback, and watches for silence; a heartbeat thread keeps the device's
watchdog fed while the host is idle. Its time is a :class:`~vtexp.clock.Clock`'s.
On a port that delivers its bytes itself (one with ``attach``: an in-process
emulator's :class:`~vtexp.devices.emulator.LoopbackPort`, on a virtual clock) there
are no threads: bytes are fed as they arrive, and the heartbeat and the watch for
silence are timers on the clock; everything else is the same code. Requests are stop-and-wait: one frame
in flight, answered by exactly one reply with the same sequence number,
re-sent after a timeout or a ``NAK BAD_FRAME``; the device never executes a
repeated request twice, so a retry cannot actuate twice.

Loss of the device (the port fails, or nothing valid arrives for the
silence limit, just under one heartbeat period, after a frame was sent) is
latched in :attr:`Link.lost`; every waiting or later call raises
:class:`DeviceLost`. Silence is counted from the first frame sent since the
device's last frame: a host that was starved of the CPU and sent nothing has no
answer to miss (the device's watchdog, ``watchdog_ms``, judges that side).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from ..clock import REAL, Clock
from ..errors import DeviceError
from . import wire
from .wire import Message, Nak, NakReason

# Silence after a request longer than this fraction of the heartbeat period means the
# device is gone. Heartbeats go out every fifth of the period (a lost one is sent again
# three times), so it takes two heartbeats and their retries unanswered in a row; the
# first unanswered one goes out at most a fifth of a period after the device's last
# frame, and the reader checks at least every twentieth, so loss is noticed within
# 0.2 + 0.6 + 0.05 of a period.
SILENCE_FRACTION = 0.6
HEARTBEAT_FRACTION = 0.2
# A request may be sent this many times within the silence limit: with the defaults (25 ms
# of reply wait and 200 ms of heartbeat period: 120 ms of silence) four replies lost in a
# row do not lose the device, the fifth attempt's reply still arrives in time.
ATTEMPTS_IN_SILENCE = 5


def suggested_reply_ms(heartbeat_ms: float) -> int:
    """The longest reply wait (``reply_ms``, in 10 ms steps, at least the default 25 ms)
    that lets a request be sent :data:`ATTEMPTS_IN_SILENCE` times within the silence
    limit of a heartbeat period of ``heartbeat_ms``, as the defaults nearly do (25 ms waits
    in a 120 ms limit: 4.8 of them): a link with a slower heartbeat (a simulated chip, a
    busy computer) then survives as many lost replies in a row. A longer wait than this,
    with the same period, survives fewer."""
    return max(25, int(SILENCE_FRACTION * heartbeat_ms / ATTEMPTS_IN_SILENCE) // 10 * 10)


# A pass of the reader's loop takes at most the port's read timeout (10 ms) plus a
# frame's decoding; a pass longer than this means the process was not running.
STARVED_S = 0.05
CHECK_FRACTION = 0.05


class DeviceLost(DeviceError):
    """Contact with the device was lost (cable pulled, power lost, device hung)."""


class DeviceRefused(DeviceError):
    """The device answered a request with a NAK."""

    def __init__(self, message: str, nak: Nak):
        super().__init__(message)
        self.nak = nak


@dataclass
class LinkStats:
    """What the link has seen: the counts behind "detected, retried, counted"."""

    tx_frames: int = 0
    tx_bytes: int = 0
    rx_frames: int = 0
    rx_bytes: int = 0
    rx_bad: dict[str, int] = field(default_factory=dict)   # by kind: bad_crc, bad_cobs, ...
    retries: int = 0            # requests sent again
    timeouts: int = 0           # ... because no reply came in time
    bad_frame_naks: int = 0     # ... because the device could not read our frame
    stale_replies: int = 0      # replies to a request no longer in flight (answered twice)
    device_frames_lost: int = 0  # gaps in the device's sequence numbers
    heartbeats: int = 0
    starved: int = 0            # passes of the reader after the process was not running
    last_rtt_ms: float | None = None

    def as_dict(self) -> dict[str, Any]:
        d = dict(vars(self))
        d["rx_bad"] = dict(self.rx_bad)
        d["rx_bad_total"] = sum(self.rx_bad.values())
        return d


class Link:
    """Requests, replies and events over an open pyserial port (see module docstring).

    Parameters
    ----------
    port:
        An open ``serial.SerialBase`` (``serial.serial_for_url(...)``) whose
        ``timeout`` is short (it bounds how often silence is checked).
    name:
        The port's name, for messages.
    reply_timeout_s:
        How long to wait for a reply before sending again, on top of the
        time the bytes take on the wire at the port's baud rate.
    retries:
        How many times a request is sent again before giving up.
    on_event:
        Called in the reader thread with each event message (ONSET, PLAY_DONE, ALARM).
    on_clock_sample:
        Called with ``(sent_ms, answered_ms, device_ms)`` for each heartbeat answered:
        the ACK carries the device's clock read in between (``devices.clock``).
    may_heartbeat:
        Asked, with the clock's time, before each heartbeat the link would send: false
        holds it back (a frame of the user's is about to go out and feeds the watchdog
        itself; or the user's own loop has stopped checking in, and the device's
        watchdog should end the session).
    trace:
        Called with ``("to_device" | "to_host", message_or_error)`` for every frame.
    clock:
        What the link waits on and stamps with (the real clock unless another is given).
    """

    def __init__(self, port: Any, *, name: str, reply_timeout_s: float = 0.05, retries: int = 8,
                 on_event: Callable[[Message], None] | None = None,
                 on_clock_sample: Callable[[float, float, float], None] | None = None,
                 may_heartbeat: Callable[[float], bool] | None = None,
                 trace: Callable[[str, object], None] | None = None, clock: Clock = REAL):
        self.port = port
        self.clock = clock
        self.name = name
        self.reply_timeout_s = reply_timeout_s
        self.retries = retries
        self.on_event = on_event
        self.trace = trace
        self.stats = LinkStats()
        self.lost: str | None = None
        self.lost_at: float | None = None
        self.heartbeat_s: float | None = None
        self.on_clock_sample = on_clock_sample
        self.may_heartbeat = may_heartbeat
        self._reader = wire.FrameReader()
        self._cond = threading.Condition()
        self._tx_lock = threading.Lock()
        self._req_lock = threading.Lock()
        self._seq = 0
        self._pending: int | None = None
        self._reply: Message | None = None
        self._resend = False
        self._dev_seq: int | None = None
        self.last_rx = clock.now()
        self.last_tx = clock.now()
        # When the first frame sent since the last valid frame received went out: the
        # device is judged silent from then, not from its last frame, so a host that was
        # itself starved of the CPU (and sent nothing) does not take that for a pulled cable.
        self.unanswered_since: float | None = None
        self._closing = threading.Event()
        self._reader_thread: threading.Thread | None = None
        self._hb_thread: threading.Thread | None = None
        # A port that delivers its own bytes (in-process, on a virtual clock): no threads.
        self._fed = hasattr(port, "attach")
        self._hb_timer: Any = None

    # -- lifecycle --------------------------------------------------------------------------
    def start(self) -> None:
        if self._fed:
            self.port.attach(self._feed, self._port_failed)
            return
        self._reader_thread = threading.Thread(target=self._read_loop, daemon=True,
                                               name=f"vtexp-link-reader {self.name}")
        self._reader_thread.start()

    def start_heartbeat(self, period_ms: int) -> None:
        """Send heartbeats and watch for silence from now on (after the handshake)."""
        self.heartbeat_s = period_ms / 1000.0
        self.last_rx = self.clock.now()
        self.unanswered_since = None
        if self._fed:
            self._arm_heartbeat()
            return
        self._hb_thread = threading.Thread(target=self._heartbeat_loop, daemon=True,
                                           name=f"vtexp-link-heartbeat {self.name}")
        self._hb_thread.start()

    def close(self) -> None:
        self._closing.set()
        if self._hb_timer is not None:
            self._hb_timer.cancel()
        with self._cond:
            self._cond.notify_all()
        try:
            self.port.cancel_read()
        except Exception:           # not every pyserial port class can
            pass
        for t in (self._hb_thread, self._reader_thread):
            if t is not None and t is not threading.current_thread():
                t.join(timeout=2)
        try:
            self.port.close()
        except Exception:           # already gone (unplugged): nothing left to release
            pass

    def accept_frames_up_to(self, max_payload: int) -> None:
        """Take device frames of ``max_payload`` + 7 raw bytes if that is more than the
        reader already takes (docs/protocol.md, "The largest frame a host must accept")."""
        need = max_payload + wire.MIN_FRAME
        if need > self._reader.max_frame:
            # in place: the reader thread may be in the middle of the next frame
            self._reader.accept(need)

    # -- state ------------------------------------------------------------------------------
    @property
    def silence_limit_s(self) -> float | None:
        return None if self.heartbeat_s is None else SILENCE_FRACTION * self.heartbeat_s

    def check(self) -> None:
        """Raise :class:`DeviceLost` if the link has been lost."""
        if self.lost is not None:
            raise DeviceLost(self.lost)

    def mark_lost(self, reason: str) -> None:
        with self._cond:
            if self.lost is None:
                self.lost = reason
                self.lost_at = self.clock.now()
            self._cond.notify_all()

    def wait_for(self, predicate: Callable[[], object], timeout: float | None) -> bool:
        """Wait until ``predicate()`` holds (checked whenever a frame arrives or the link
        is lost or closed) or ``timeout`` seconds pass; return whether it holds."""
        return self.clock.wait_for(self._cond, predicate, timeout)

    # -- requests ---------------------------------------------------------------------------
    def reply_timeout_for(self, n_bytes: int, reply_bytes: int = 64) -> float:
        baud = getattr(self.port, "baudrate", None) or 115200
        return self.reply_timeout_s + (n_bytes + reply_bytes) * 10.0 / baud

    def request(self, msg: Message, *, timeout_s: float | None = None,
                retries: int | None = None, blocking: bool = True,
                reply_bytes: int = 64) -> Message | None:
        """Send ``msg`` and return the device's reply (an ACK-like message or a NAK).

        Sent again after ``timeout_s`` without a reply or on ``NAK BAD_FRAME``, up
        to ``retries`` times; then :class:`DeviceError`. ``blocking=False`` returns
        None at once if another request is in flight (heartbeats use it).
        """
        self.check()
        if not self._req_lock.acquire(blocking=blocking):
            return None
        try:
            seq = self._seq
            self._seq = (self._seq + 1) & 0xFF
            frame = wire.encode(msg, seq)
            timeout = timeout_s if timeout_s is not None else self.reply_timeout_for(
                len(frame), reply_bytes)
            retries = self.retries if retries is None else retries
            with self._cond:
                self._pending, self._reply, self._resend = seq, None, False
            attempt = 0
            first_sent = None
            while True:
                sent = self.clock.now()
                first_sent = sent if first_sent is None else first_sent
                self._write(frame, msg)
                self.wait_for(lambda: (self._reply is not None or self._resend
                                       or self.lost is not None or self._closing.is_set()),
                              timeout)
                with self._cond:
                    reply, resend = self._reply, self._resend
                    self._resend = False
                self.check()
                if self._closing.is_set():
                    raise DeviceError(f"the link to {self.name} was closed during a request")
                if reply is not None:
                    if self.on_clock_sample is not None and isinstance(msg, wire.Heartbeat) \
                            and isinstance(reply, wire.Ack):
                        # From the first sending: the reply to a request sent again may be
                        # the first one's, late, or the device's cached copy of it, its
                        # clock read before the repeat left.
                        self.on_clock_sample(first_sent * 1000.0, self.clock.now_ms(),
                                             reply.t_us / 1000.0)
                    return reply
                if attempt >= retries:
                    raise DeviceError(
                        f"the device on {self.name} did not answer {type(msg).__name__} "
                        f"after {attempt + 1} attempts ({timeout * 1000:.0f} ms each)")
                attempt += 1
                self.stats.retries += 1
                if not resend:
                    self.stats.timeouts += 1
        finally:
            with self._cond:
                self._pending = None
            self._req_lock.release()

    def ping(self) -> float:
        """Round-trip time of one HEARTBEAT, in milliseconds."""
        t = self.clock.now()
        self.expect(wire.Heartbeat(), wire.Ack, retries=0)
        rtt = (self.clock.now() - t) * 1000.0
        self.stats.last_rtt_ms = rtt
        return rtt

    def expect(self, msg: Message, reply_type: type, **kw) -> Any:
        """:meth:`request`, raising :class:`DeviceRefused` on a NAK or a reply of another type."""
        reply = self.request(msg, **kw)
        if isinstance(reply, Nak):
            raise DeviceRefused(f"the device on {self.name} refused {type(msg).__name__}: "
                                f"{reply.reason_name} (detail {reply.detail})", reply)
        if not isinstance(reply, reply_type):
            raise DeviceError(f"the device on {self.name} answered {type(msg).__name__} with "
                              f"{type(reply).__name__}, not {reply_type.__name__}: it does not "
                              f"follow {wire.PROTOCOL_NAME}")
        return reply

    def _write(self, frame: bytes, msg: Message) -> None:
        if self.unanswered_since is None:
            self.unanswered_since = self.clock.now()      # before the write: a reply can't precede it
        try:
            with self._tx_lock:
                self.port.write(frame)
        except Exception as e:      # SerialException, OSError, or a port closed under us
            self.mark_lost(f"writing to {self.name} failed ({e})")
            self.check()
        self.last_tx = self.clock.now()
        self.stats.tx_frames += 1
        self.stats.tx_bytes += len(frame)
        if self.trace:
            self.trace("to_device", msg)

    # -- reader ---------------------------------------------------------------------------
    def _read_loop(self) -> None:
        # Whether this thread was kept from running is a question of the computer's time,
        # whatever clock the link keeps.
        ran = time.monotonic()
        while not self._closing.is_set():
            try:
                n = self.port.in_waiting
                data = self.port.read(n if n else 1)
            except Exception as e:  # SerialException/OSError: unplugged; TypeError: closed
                self._port_failed(e)
                return
            if data:
                self._feed(data)
            now = time.monotonic()
            if now - ran > STARVED_S and self.unanswered_since is not None:
                # This thread was not run for a while (the computer was busy): neither,
                # perhaps, was a device in this process or the program feeding the pty.
                # Silence is counted afresh from now rather than from before the gap.
                self.stats.starved += 1
                self.unanswered_since = self.clock.now()
            ran = now
            if self._check_silence():
                return

    def _feed(self, data: bytes) -> None:
        """Bytes from the device: every frame in them dispatched."""
        self.stats.rx_bytes += len(data)
        for item in self._reader.feed(data):
            self._dispatch(item)

    def _port_failed(self, error: BaseException) -> None:
        if not self._closing.is_set():
            self.mark_lost(f"the port {self.name} reported an error ({error})")

    def _check_silence(self) -> bool:
        """Mark the link lost if the device has been silent too long after a request."""
        limit = self.silence_limit_s
        since = self.unanswered_since
        if limit is not None and self.lost is None and since is not None:
            quiet = self.clock.now() - since
            if quiet > limit:
                self.mark_lost(f"nothing valid came back from the device on {self.name} "
                               f"for {quiet * 1000:.0f} ms after a request (heartbeat "
                               f"period {self.heartbeat_s * 1000:.0f} ms)")
                return True
        return False

    def _dispatch(self, item: tuple[int, Message] | wire.WireError) -> None:
        if isinstance(item, wire.WireError):
            self.stats.rx_bad[item.kind] = self.stats.rx_bad.get(item.kind, 0) + 1
            if self.trace:
                self.trace("to_host", item)
            return
        seq, msg = item
        self.last_rx = self.clock.now()
        self.unanswered_since = None
        self.stats.rx_frames += 1
        if self.trace:
            self.trace("to_host", msg)
        if self._dev_seq is not None:
            gap = (seq - self._dev_seq) & 0xFF
            if 1 < gap < 128:
                self.stats.device_frames_lost += gap - 1
            if gap == 0 or gap >= 128:
                seq = self._dev_seq      # a re-sent older reply: keep the newest seq seen
        self._dev_seq = seq
        if msg.REPLY:
            with self._cond:
                if isinstance(msg, Nak) and msg.reason == NakReason.BAD_FRAME:
                    if self._pending is not None:
                        self.stats.bad_frame_naks += 1
                        self._resend = True
                        self._cond.notify_all()
                elif self._pending is not None and msg.ack_seq == self._pending \
                        and self._reply is None:
                    self._reply = msg
                    self._cond.notify_all()
                else:
                    self.stats.stale_replies += 1
        elif self.on_event is not None:
            self.on_event(msg)
            with self._cond:
                self._cond.notify_all()     # whoever waits on what the event says

    # -- heartbeat --------------------------------------------------------------------------
    def _heartbeat_loop(self) -> None:
        assert self.heartbeat_s is not None
        while not self.wait_for(self._closing.is_set, CHECK_FRACTION * self.heartbeat_s):
            if self.lost is not None:
                return
            self._heartbeat_due()

    def _arm_heartbeat(self) -> None:
        """The heartbeat as a timer on the clock (a port that feeds itself)."""
        assert self.heartbeat_s is not None
        self._hb_timer = self.clock.call_later(CHECK_FRACTION * self.heartbeat_s,
                                               self._heartbeat_timer)

    def _heartbeat_timer(self) -> None:
        if self._closing.is_set() or self.lost is not None:
            return
        self._arm_heartbeat()               # first: a heartbeat below waits on the clock
        if not self._check_silence():
            self._heartbeat_due()

    def _heartbeat_due(self) -> None:
        """Send a heartbeat if nothing went out for a fifth of the period."""
        assert self.heartbeat_s is not None
        every = HEARTBEAT_FRACTION * self.heartbeat_s
        now = self.clock.now()
        if now - self.last_tx < every:
            return
        if self.may_heartbeat is not None and not self.may_heartbeat(now):
            return
        try:
            # A lost heartbeat is sent again at once (a few times) so that one bad
            # frame on a noisy line does not look like a pulled cable.
            baud = getattr(self.port, "baudrate", None) or 115200
            wait = max(every / 4, 3 * 32 * 10.0 / baud)   # 32 bytes: both frames
            if self.request(wire.Heartbeat(), retries=3, blocking=False,
                            timeout_s=wait) is not None:
                self.stats.heartbeats += 1
                self.stats.last_rtt_ms = (self.clock.now() - now) * 1000.0
        except DeviceError:
            pass                # silence is judged by the reader, not by one heartbeat
