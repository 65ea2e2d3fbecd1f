"""Where live frames come from, and the one-frame mailbox between capture and processing.

A source (:func:`open_source`) is a camera (``camera:N``), a video file, a folder of
images, or another program writing raw frames to standard input (``-``). Its
:meth:`~FrameSource.frames` yields :class:`Frame`\\ s, each stamped with the clock's
time (:class:`~vtexp.clock.Clock`, ``time.monotonic`` on the real one) when it was
captured. :class:`Capture` reads a source in its own thread into a
:class:`LatestFrame`, which holds only the newest frame: a frame that the loop had
no time for is replaced by the next one and counted as dropped, never queued, so
the frame processed is always the newest the camera gave. On a virtual clock a
video, a folder or arrays are read by timers on the clock instead, each frame when
it is due; a camera and standard input run on the real clock only.

A video file or a folder stands in for a camera: by default its frames are
delivered at their frame rate (``pace``), each stamped when it became due, as a
camera would deliver them; ``pace=False`` delivers them as fast as the loop takes
them (for throughput measurements), and then nothing is dropped.

Every frame is checked: 8-bit, gray or colour (made gray), at least 16 x 16 pixels,
and the same size as the first. A source that cannot be opened, stops delivering,
or gives a wrong frame raises :class:`~vtexp.errors.InputError` naming the source
(and file, and frame).
"""

from __future__ import annotations

import math
import os
import sys
import threading
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np

from .._cv2 import cv2
from ..clock import REAL, Clock
from ..errors import InputError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")
PIXEL_FORMATS = {"gray8": 1, "bgr24": 3}


@dataclass
class Frame:
    """One captured frame: ``index`` counts every frame the source gave (dropped ones too),
    ``t_capture`` is the clock's time at capture (s), ``image`` is 8-bit gray."""

    index: int
    t_capture: float
    image: np.ndarray
    name: str = ""


class FrameSource:
    """A source of frames (see the module docstring)."""

    #: How the source is named in messages (``camera 0``, ``video clip.avi``...).
    label = "source"
    #: Frames per second the source delivers at, if known.
    fps: float | None = None
    #: A file's frames delivered at their rate (a camera is always "paced" by itself).
    pace: bool = True
    #: Frames that exist before they are read (a file, a folder, arrays), which a
    #: virtual clock can deliver each at its time; a camera's or a pipe's come when
    #: they come, in real time.
    stored = False

    def open(self) -> None:
        """Open the source, or raise :class:`InputError` saying why it cannot be."""

    def frames(self, stop: threading.Event, clock: Clock = REAL
               ) -> Iterator[Frame]:  # pragma: no cover
        """The frames, each stamped on ``clock`` (paced on it, for a file)."""
        raise NotImplementedError

    def close(self) -> None:
        pass


class FrameChecker:
    """Makes frames 8-bit gray and refuses a wrong one (type, size, a size change)."""

    def __init__(self, label: str):
        self.label = label
        self.shape: tuple[int, int] | None = None

    def __call__(self, image: object, index: int, where: str = "") -> np.ndarray:
        at = f"frame {index}{f' ({where})' if where else ''} of {self.label}"
        img = np.asarray(image)
        if img.dtype != np.uint8:
            raise InputError(f"{at} is {img.dtype} {'x'.join(map(str, img.shape))}; expected "
                             "8-bit pixels (gray, BGR or BGRA)")
        if img.ndim == 3 and img.shape[2] in (3, 4):
            cv = cv2()
            img = cv.cvtColor(img, cv.COLOR_BGR2GRAY if img.shape[2] == 3 else cv.COLOR_BGRA2GRAY)
        elif img.ndim == 3 and img.shape[2] == 1:
            img = img[:, :, 0]
        if img.ndim != 2:
            raise InputError(f"{at} has shape {img.shape}; expected a gray (H x W) or colour "
                             "(H x W x 3) image")
        h, w = img.shape
        if h < 16 or w < 16:
            raise InputError(f"{at} is {w}x{h} pixels; at least 16x16 are needed")
        if self.shape is None:
            self.shape = (h, w)
        elif self.shape != (h, w):
            raise InputError(f"{at} is {w}x{h} pixels, but the run started at "
                             f"{self.shape[1]}x{self.shape[0]}; every frame must have the "
                             "same size")
        return np.ascontiguousarray(img)


class _QuietOpenCV:
    """OpenCV's own log silenced while a capture is opened or read: a missing camera or a
    damaged file is said once, by vtexp, not by OpenCV's warnings on stderr. With
    ``all_stderr`` (opening only), what FFmpeg and OpenCV's container readers print
    straight to the process's stderr is discarded too."""

    def __init__(self, all_stderr: bool = False):
        self.all_stderr = all_stderr
        self._saved: int | None = None

    def __enter__(self):
        self._log = cv2().utils.logging
        self._level = self._log.getLogLevel()
        self._log.setLogLevel(self._log.LOG_LEVEL_SILENT)
        if self.all_stderr:
            try:
                sys.stderr.flush()
                self._saved = os.dup(2)
                null = os.open(os.devnull, os.O_WRONLY)
                os.dup2(null, 2)
                os.close(null)
            except OSError:
                self._saved = None
        return self

    def __exit__(self, *exc):
        if self._saved is not None:
            os.dup2(self._saved, 2)
            os.close(self._saved)
            self._saved = None
        self._log.setLogLevel(self._level)


def _paced(stop: threading.Event, clock: Clock, t0: float, k: int, fps: float) -> float:
    """Wait until frame ``k`` is due at ``fps`` from ``t0`` and return that time: when a
    camera would have captured it (a frame delivered late keeps its capture time, so
    the lateness counts in its latency). On a virtual clock, frames are asked for when
    they are due (:class:`Capture`): nothing to wait."""
    due = t0 + k / fps
    while not stop.is_set():
        left = due - clock.now()
        if left <= 0 or clock.virtual:
            break
        stop.wait(min(left, 0.05))
    return due


class CameraSource(FrameSource):
    """``camera:N``: an OpenCV VideoCapture device."""

    def __init__(self, index: int, *, stall_s: float = 2.0):
        self.index = index
        self.label = f"camera {index}"
        self.stall_s = stall_s
        self._cap = None

    def open(self) -> None:
        if self._cap is not None:
            return
        cv = cv2()
        with _QuietOpenCV(all_stderr=True):
            cap = cv.VideoCapture(self.index)
        if not cap.isOpened():
            cap.release()
            raise InputError(f"no camera at index {self.index} (OpenCV could not open it); "
                             "check that it is plugged in and not used by another program",
                             key="SOURCE")
        self._cap = cap
        fps = cap.get(cv.CAP_PROP_FPS)
        self.fps = fps if fps and math.isfinite(fps) and fps > 0 else None

    def frames(self, stop: threading.Event, clock: Clock = REAL) -> Iterator[Frame]:
        check = FrameChecker(self.label)
        k = 0
        failing_since: float | None = None
        while not stop.is_set():
            with _QuietOpenCV():
                ok, img = self._cap.read()
            t = clock.now()
            if not ok or img is None:
                failing_since = failing_since or t
                if t - failing_since > self.stall_s:
                    raise InputError(f"{self.label} stopped delivering frames (none for "
                                     f"{self.stall_s:g} s); was it unplugged?", key="SOURCE")
                stop.wait(0.01)
                continue
            failing_since = None
            yield Frame(k, t, check(img, k))
            k += 1

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None


class VideoSource(FrameSource):
    """A video file, delivered at its frame rate (``pace``) or as fast as it is taken."""

    stored = True

    def __init__(self, path: str | Path, *, pace: bool = True, fps: float | None = None):
        self.path = Path(path)
        self.label = f"video {self.path}"
        self.pace = pace
        self._fps_override = fps
        self._cap = None

    def open(self) -> None:
        if self._cap is not None:
            return
        if not self.path.is_file():
            raise InputError("video file not found", path=str(self.path))
        cv = cv2()
        with _QuietOpenCV(all_stderr=True):
            cap = cv.VideoCapture(str(self.path))
            ok, first = cap.read() if cap.isOpened() else (False, None)
        if not cap.isOpened():
            cap.release()
            raise InputError("not a readable video (OpenCV could not open it)",
                             path=str(self.path))
        if not ok or first is None:
            cap.release()
            raise InputError("not a readable video (no frame could be decoded)",
                             path=str(self.path))
        self._first = first
        self._cap = cap
        fps = cap.get(cv.CAP_PROP_FPS)
        self.fps = self._fps_override or (fps if fps and math.isfinite(fps) and 0 < fps <= 1000
                                          else 30.0)

    def frames(self, stop: threading.Event, clock: Clock = REAL) -> Iterator[Frame]:
        check = FrameChecker(self.label)
        img = self._first
        t0 = clock.now()
        k = 0
        while img is not None and not stop.is_set():
            t = _paced(stop, clock, t0, k, self.fps) if self.pace else clock.now()
            if stop.is_set():
                return
            yield Frame(k, t, check(img, k))
            k += 1
            with _QuietOpenCV():
                ok, img = self._cap.read()
            if not ok:
                img = None

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None


class FolderSource(FrameSource):
    """A folder of images, in name order, at ``fps`` (``pace``)."""

    stored = True

    def __init__(self, path: str | Path, *, fps: float = 30.0, pace: bool = True):
        self.path = Path(path)
        self.label = f"folder {self.path}"
        self.fps = fps
        self.pace = pace
        self.files: list[Path] = []

    def open(self) -> None:
        if self.files:
            return
        if not self.path.is_dir():
            raise InputError("folder not found", path=str(self.path))
        self.files = sorted(p for p in self.path.iterdir()
                            if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
        if not self.files:
            raise InputError(f"no images in the folder (looked for "
                             f"{', '.join(IMAGE_SUFFIXES)})", path=str(self.path))

    def frames(self, stop: threading.Event, clock: Clock = REAL) -> Iterator[Frame]:
        from ..stimuli import read_image

        check = FrameChecker(self.label)
        t0 = clock.now()
        for k, f in enumerate(self.files):
            if stop.is_set():
                return
            img = read_image(f)
            t = _paced(stop, clock, t0, k, self.fps) if self.pace else clock.now()
            yield Frame(k, t, check(img, k, f.name), f.name)


class StreamSource(FrameSource):
    """``-``: raw frames from another program on standard input (or any byte stream),
    ``width x height`` pixels of ``gray8`` or ``bgr24`` each, as ``ffmpeg -f rawvideo``
    writes them."""

    def __init__(self, stream: BinaryIO | None, *, size: tuple[int, int] | None,
                 pixel_format: str = "gray8"):
        self.stream = stream
        self.label = "standard input"
        if size is None:
            raise InputError("frames on standard input need their size: --frame-size WxH "
                             "(and --pixel-format gray8 or bgr24)", key="--frame-size")
        if pixel_format not in PIXEL_FORMATS:
            raise InputError(f"unknown pixel format {pixel_format!r}; use "
                             f"{' or '.join(PIXEL_FORMATS)}", key="--pixel-format")
        self.size = size
        self.pixel_format = pixel_format

    def open(self) -> None:
        if self.stream is None:
            self.stream = sys.stdin.buffer

    def frames(self, stop: threading.Event, clock: Clock = REAL) -> Iterator[Frame]:
        w, h = self.size
        ch = PIXEL_FORMATS[self.pixel_format]
        n = w * h * ch
        check = FrameChecker(self.label)
        k = 0
        fd = self.stream.fileno() if hasattr(self.stream, "fileno") else None
        while not stop.is_set():
            data = _read_exactly(self.stream, fd, n)
            t = clock.now()
            if not data:
                return
            if len(data) < n:
                raise InputError(f"standard input ended in the middle of frame {k}: "
                                 f"{len(data)} of {n} bytes ({w}x{h} {self.pixel_format}); "
                                 "are --frame-size and --pixel-format right?", key="SOURCE")
            img = np.frombuffer(data, np.uint8).reshape((h, w, ch) if ch > 1 else (h, w))
            yield Frame(k, t, check(img, k))
            k += 1


def _read_exactly(stream: BinaryIO, fd: int | None, n: int) -> bytes:
    parts, got = [], 0
    while got < n:
        chunk = os.read(fd, n - got) if fd is not None else stream.read(n - got)
        if not chunk:
            break
        parts.append(chunk)
        got += len(chunk)
    return b"".join(parts)


class ArraySource(FrameSource):
    """Frames given as arrays (tests, and programs that use vtexp as a library)."""

    stored = True

    def __init__(self, images: Iterable[np.ndarray], *, fps: float = 30.0, pace: bool = True,
                 label: str = "frames"):
        self.images = images
        self.fps = fps
        self.pace = pace
        self.label = label

    def frames(self, stop: threading.Event, clock: Clock = REAL) -> Iterator[Frame]:
        check = FrameChecker(self.label)
        t0 = clock.now()
        for k, img in enumerate(self.images):
            if stop.is_set():
                return
            t = _paced(stop, clock, t0, k, self.fps) if self.pace else clock.now()
            yield Frame(k, t, check(img, k))


def open_source(spec: str, *, pace: bool = True, fps: float | None = None,
                frame_size: tuple[int, int] | None = None, pixel_format: str = "gray8",
                stall_s: float = 2.0) -> FrameSource:
    """The source named by ``spec``: ``camera:N`` (or ``camera``), ``-`` (standard input),
    a folder of images, or a video file. Not yet opened."""
    head, _, rest = spec.partition(":")
    if spec == "camera" or head == "camera":
        if rest and not rest.isdigit():
            raise InputError(f"camera:N takes a camera number, not {rest!r}", key="SOURCE")
        return CameraSource(int(rest or 0), stall_s=stall_s)
    if spec == "-":
        return StreamSource(None, size=frame_size, pixel_format=pixel_format)
    p = Path(spec)
    if p.is_dir():
        return FolderSource(p, fps=fps or 30.0, pace=pace)
    if not p.exists():
        raise InputError("no such video file or folder (SOURCE is camera:N, a video file, a "
                         "folder of images, or - for frames on standard input)", path=spec)
    return VideoSource(p, pace=pace, fps=fps)


# --------------------------------------------------------------------------- the mailbox


class SourceEnded(Exception):
    """The source has no more frames (end of a video or folder, standard input closed)."""


class LatestFrame:
    """A one-frame mailbox: :meth:`put` replaces a frame not yet taken (counted in
    ``dropped``); :meth:`take` returns the newest frame, re-raises the capture thread's
    error, or raises :class:`SourceEnded`. :meth:`wait` waits on ``clock``."""

    def __init__(self, clock: Clock = REAL) -> None:
        self.clock = clock
        self._cond = threading.Condition()
        self._frame: Frame | None = None
        self._error: BaseException | None = None
        self._ended = False
        self._woken = False
        self.dropped = 0
        self.captured = 0
        self.last_capture: float | None = None
        #: Called when a frame is taken (a virtual clock's capture of a file that is not
        #: paced reads the next one then).
        self.on_taken: Callable[[], None] | None = None

    def put(self, frame: Frame, *, block: bool = False,
            stop: threading.Event | None = None) -> None:
        """Leave ``frame`` for :meth:`take`, replacing one not yet taken (dropped); with
        ``block``, wait until the last one was taken instead (or ``stop`` is set)."""
        with self._cond:
            while block and self._frame is not None and not (stop and stop.is_set()):
                self._cond.wait(0.05)
            if self._frame is not None:
                self.dropped += 1
            self._frame = frame
            self.captured += 1
            self.last_capture = frame.t_capture
            self._cond.notify_all()

    def fail(self, error: BaseException) -> None:
        with self._cond:
            self._error = error
            self._cond.notify_all()

    def end(self) -> None:
        with self._cond:
            self._ended = True
            self._cond.notify_all()

    def take(self) -> Frame | None:
        """The newest frame not yet taken, or None (never waits)."""
        with self._cond:
            if self._error is not None:
                raise self._error
            f, self._frame = self._frame, None
            if f is None and self._ended:
                raise SourceEnded()
            if f is not None:
                self._cond.notify_all()         # a blocked put may go on
        if f is not None and self.on_taken is not None:
            self.on_taken()
        return f

    def wait(self, timeout: float) -> None:
        """Wait at most ``timeout`` seconds for a frame, an error, the end or
        :meth:`notify`."""
        self.clock.wait_for(self._cond, lambda: (self._frame is not None or self._woken
                                                 or self._error is not None or self._ended),
                            max(0.0, timeout))
        with self._cond:
            self._woken = False

    def notify(self) -> None:
        """Wake a :meth:`wait` (to stop)."""
        with self._cond:
            self._woken = True
            self._cond.notify_all()


class Capture:
    """Reads a source into a :class:`LatestFrame`: in its own thread on the real clock; on
    a virtual clock (the mailbox's), by timers, each frame of a stored source when it is
    due (at its rate, or, not paced, when the loop has taken the one before)."""

    def __init__(self, source: FrameSource, mailbox: LatestFrame):
        self.source = source
        self.mailbox = mailbox
        self.clock = mailbox.clock
        self.stop_event = threading.Event()
        self._frames: Iterator[Frame] | None = None
        self._t0 = 0.0
        self._k = 0
        self._timer = None
        self._thread = None
        if self.clock.virtual:
            if not source.stored:
                raise InputError(f"{source.label} delivers frames in real time; it cannot be "
                                 "read on a virtual clock", key="SOURCE")
        else:
            self._thread = threading.Thread(target=self._run, daemon=True,
                                            name=f"vtexp-capture {source.label}")

    def start(self) -> None:
        if self._thread is not None:
            self._thread.start()
            return
        self._frames = self.source.frames(self.stop_event, self.clock)
        self._t0 = self.clock.now()
        if not self.source.pace:
            self.mailbox.on_taken = lambda: self._later(self.clock.now())
        self._later(self._t0)

    def _run(self) -> None:
        # A file or folder not paced at its frame rate waits for the loop to take each
        # frame (every frame processed, as fast as the loop goes); a camera never waits.
        block = self.source.pace is False
        try:
            for frame in self.source.frames(self.stop_event, self.clock):
                self.mailbox.put(frame, block=block, stop=self.stop_event)
                if self.stop_event.is_set():
                    break
            self.mailbox.end()
        except BaseException as e:          # handed to the loop, which says it and stops
            self.mailbox.fail(e)

    # -- on a virtual clock -----------------------------------------------------------------
    def _later(self, t: float) -> None:
        if not self.stop_event.is_set():
            self._timer = self.clock.call_at(t, self._next)

    def _next(self) -> None:
        self._timer = None
        if self.stop_event.is_set() or self._frames is None:
            return
        try:
            frame = next(self._frames)
        except StopIteration:
            self.mailbox.end()
            return
        except BaseException as e:          # handed to the loop, which says it and stops
            self.mailbox.fail(e)
            return
        self.mailbox.put(frame)
        self._k += 1
        if self.source.pace:
            self._later(self._t0 + self._k / (self.source.fps or 30.0))

    def stop(self, close: bool = True) -> None:
        """Stop reading (and close the source, unless ``close`` is false: another reader
        follows, as a live camera trial's loop follows its still frame)."""
        self.stop_event.set()
        self.mailbox.notify()
        if self._timer is not None:
            self._timer.cancel()
        self.mailbox.on_taken = None
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        if close:
            self.source.close()
