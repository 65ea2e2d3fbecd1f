"""The experimenter's preview: the camera, the extracted contour and the array, side by side.

:func:`compose` draws one picture (BGR, OpenCV) from the run's newest
:class:`~vtexp.live.loop.Snapshot`: the camera image with the pattern's points drawn
where they lie in it (when the pipeline records its image-to-array mapping) and the
array's extent; the pattern on the array, in its order, as ``vtexp encode --png``
draws it; the array's state right now, each actuator by its drive; and a status line
with the measured frame rate, dropped frames, glass-to-skin latency (p50, p95) and
processing time, and what the safety guard is leaving out (trains cut short, pins
held off to cool, pins skipped for the power budget), in orange, as long as it lasts.

:class:`PreviewWindow` shows those pictures in a PsychoPy window (the project's
window toolkit; the OpenCV vtexp installs has no windows) at up to ``max_fps`` (15:
drawing shares the processor, and the interpreter, with the loop that drives the
array); Escape or ``q`` in it ends the run.
"""

from __future__ import annotations

import math
import textwrap
import time
from collections.abc import Callable

import numpy as np

from .._cv2 import cv2
from ..draw import LINE_COLOURS, draw_pattern
from ..encoding.mapping import ImageToArray
from ..model import DeviceProfile, LevelDrive, PulseTrain
from .loop import Snapshot

PANEL_H = 360
BG = (24, 24, 24)
FG = (235, 235, 235)
DIM = (110, 110, 110)
WARN = (0, 150, 255)
ON = (60, 200, 255)


def _fit(img: np.ndarray, h: int) -> tuple[np.ndarray, float]:
    cv = cv2()
    s = h / img.shape[0]
    w = max(1, int(round(img.shape[1] * s)))
    return cv.resize(img, (w, h), interpolation=cv.INTER_AREA if s < 1 else cv.INTER_LINEAR), s


def _camera_panel(snap: Snapshot, h: int) -> np.ndarray:
    cv = cv2()
    if snap.frame is None:
        panel = np.full((h, int(h * 4 / 3), 3), BG, np.uint8)
        cv.putText(panel, "waiting for the first frame", (10, h // 2), cv.FONT_HERSHEY_SIMPLEX,
                   0.5, FG, 1, cv.LINE_AA)
        return panel
    gray, s = _fit(snap.frame.image, h)
    panel = cv.cvtColor(gray, cv.COLOR_GRAY2BGR) if gray.ndim == 2 else gray.copy()
    enc = snap.encoded
    figure = enc.figure if enc is not None else None
    if figure is not None and not figure.empty:
        # what was taken for the object (magenta), as `vtexp encode --png` draws it
        mask = cv.resize(figure.mask, (panel.shape[1], panel.shape[0]),
                         interpolation=cv.INTER_NEAREST)
        contours, _ = cv.findContours(mask, cv.RETR_EXTERNAL, cv.CHAIN_APPROX_NONE)
        cv.drawContours(panel, contours, -1, (255, 0, 255), 2, cv.LINE_AA)
    m = ImageToArray.from_params(enc.pattern.params) if enc is not None else None
    if m is not None:
        p = enc.pattern
        # The array's extent over the image: actuator centres -0.5 .. n-0.5.
        corners = m.to_image(np.array([[-0.5, -0.5], [p.rows - 0.5, p.cols - 0.5]])) * s
        (y0, x0), (y1, x1) = corners
        cv.rectangle(panel, (int(x0), int(y0)), (int(x1), int(y1)), DIM, 1, cv.LINE_AA)
        pts = [q for q in p.ordered()]
        if pts:
            xy = m.to_image(np.array([[q.row, q.col] for q in pts])) * s
            poly = np.round(xy[:, ::-1]).astype(np.int32)
            closed = bool(p.closed)
            if len(poly) > 1 and all(q.order is not None for q in pts):
                cv.polylines(panel, [poly.reshape(-1, 1, 2)], closed, (60, 200, 60), 2,
                             cv.LINE_AA)
            lined = len(p.lines()) > 1          # height contours: one colour per line
            for (x, y), q in zip(poly, pts, strict=True):
                mark = q.corner or q.vertex
                colour = LINE_COLOURS[(max(q.line, 1) - 1) % len(LINE_COLOURS)] if lined \
                    else ((40, 40, 230) if mark else (60, 200, 60))
                cv.circle(panel, (int(x), int(y)), 6 if mark else 4, colour, -1, cv.LINE_AA)
    return panel


def _array_panel(snap: Snapshot, profile: DeviceProfile, h: int) -> np.ndarray:
    cv = cv2()
    rows, cols = profile.rows, profile.cols
    cell = max(8, int((h - 40) / max(rows, 1)))
    w = cols * cell + 40
    panel = np.full((h, max(w, 160), 3), BG, np.uint8)
    cv.putText(panel, "array now", (10, 22), cv.FONT_HERSHEY_SIMPLEX, 0.55, FG, 1, cv.LINE_AA)
    if isinstance(profile.drive, LevelDrive):
        top = float(max(profile.limits.max_level or 1, 1))
    else:
        top = float(profile.limits.max_amplitude_v or profile.drive.amplitude_v)
    ox, oy = 20, 30
    for r in range(rows):
        for c in range(cols):
            x, y = ox + int((c + 0.5) * cell), oy + int((r + 0.5) * cell)
            d = snap.applied.get((r, c))
            if d is None:
                cv.circle(panel, (x, y), max(2, cell // 8), DIM, -1, cv.LINE_AA)
                continue
            v = (d.amplitude_v if isinstance(d, PulseTrain) else float(d)) / top
            v = min(max(v, 0.0), 1.0)
            colour = (int(ON[0] * v), int(60 + (ON[1] - 60) * v), 255)
            cv.circle(panel, (x, y), max(3, int(cell * (0.18 + 0.25 * v))), colour, -1,
                      cv.LINE_AA)
    return panel


def _pattern_panel(snap: Snapshot, profile: DeviceProfile, h: int) -> np.ndarray:
    cv = cv2()
    if snap.encoded is None or not snap.encoded.pattern.points:
        panel = np.full((h, h, 3), BG, np.uint8)
        cv.putText(panel, "no object found", (10, h // 2), cv.FONT_HERSHEY_SIMPLEX, 0.6, FG,
                   1, cv.LINE_AA)
        figure = snap.encoded.figure if snap.encoded is not None else None
        if figure is not None and figure.reason:     # why: learning, an empty stage, ...
            for k, line in enumerate(textwrap.wrap(figure.reason, 40)[:6]):
                cv.putText(panel, line, (10, h // 2 + 24 + 18 * k), cv.FONT_HERSHEY_SIMPLEX,
                           0.42, DIM, 1, cv.LINE_AA)
        return panel
    img = draw_pattern(snap.encoded.pattern, cell=max(10, int(h / (profile.rows + 2))),
                       title="contour on the array")
    return _fit(img, h)[0]


def status_lines(snap: Snapshot, profile: DeviceProfile) -> list[tuple[str, tuple]]:
    st = snap.stats
    p50, p95 = st.latency(50), st.latency(95)
    lat = "latency -" if math.isnan(p50) else f"latency p50 {p50:.1f} ms  p95 {p95:.1f} ms"
    proc = f"{np.median(st.process_ms[-64:]):.1f} ms/frame" if st.process_ms else "-"
    lines = [(f"{st.recent_fps:5.1f} fps   dropped {st.frames_dropped}   {lat}   "
              f"processing {proc}", FG),
             (f"frames {st.frames_processed}   {profile.name}   on now "
              f"{len(snap.applied)}/{profile.limits.max_simultaneous} allowed", DIM)]
    if snap.notes:
        lines += [("safety: " + n, WARN) for n in snap.notes[:3]]
    return lines


def compose(snap: Snapshot, profile: DeviceProfile, *, height: int = PANEL_H) -> np.ndarray:
    """The preview picture (BGR) of ``snap`` (module docstring)."""
    cv = cv2()
    panels = [_camera_panel(snap, height), _pattern_panel(snap, profile, height),
              _array_panel(snap, profile, height)]
    gap = np.full((height, 8, 3), BG, np.uint8)
    row = np.hstack([x for p in panels for x in (p, gap)][:-1])
    lines = status_lines(snap, profile)
    footer = np.full((16 + 26 * len(lines), row.shape[1], 3), BG, np.uint8)
    for i, (text, colour) in enumerate(lines):
        cv.putText(footer, text, (10, 28 + 26 * i), cv.FONT_HERSHEY_SIMPLEX, 0.6, colour, 1,
                   cv.LINE_AA)
    return np.vstack([row, footer])


class PreviewWindow:
    """A PsychoPy window showing :func:`compose`'s pictures (module docstring)."""

    def __init__(self, profile: DeviceProfile, *, size: tuple[int, int] = (1280, 560),
                 max_fps: float = 15.0, fullscreen: bool = False, screen: int = 0):
        from ..responders.window import import_psychopy

        self.profile = profile
        self.max_fps = max_fps
        _, self._event, self._visual = import_psychopy()
        self.win = self._visual.Window(size=size, fullscr=fullscreen, screen=screen,
                                       color=(-0.8, -0.8, -0.8), units="pix",
                                       allowGUI=True, winType="pyglet",
                                       title="vtexp live preview", checkTiming=False)
        self._stim = None
        self.last_image: np.ndarray | None = None

    def show(self, snap: Snapshot) -> None:
        img = compose(snap, self.profile)
        self.last_image = img
        cv = cv2()
        w, h = self.win.size
        fit = min(w / img.shape[1], h / img.shape[0], 1.0)
        if fit < 1.0:
            img = cv.resize(img, (int(img.shape[1] * fit), int(img.shape[0] * fit)),
                            interpolation=cv.INTER_AREA)
        from PIL import Image

        data = Image.fromarray(cv.cvtColor(img, cv.COLOR_BGR2RGB))   # PsychoPy's own way in
        size = (img.shape[1], img.shape[0])
        if self._stim is None or tuple(self._stim.size) != size:
            self._stim = self._visual.ImageStim(self.win, image=data, units="pix", size=size)
        else:
            self._stim.image = data
        self._stim.draw()
        self.win.flip()

    def stop_requested(self) -> bool:
        return bool(self._event.getKeys(keyList=["escape", "q"]))

    def screenshot(self, path: str) -> None:
        """Save the picture on show as a PNG, read back from the window (drawn into the
        back buffer again, not flipped)."""
        from pathlib import Path as _Path

        if self._stim is None:
            raise RuntimeError("nothing is on show")
        self._stim.draw()
        frame = self.win.getMovieFrame(buffer="back")
        self.win.movieFrames.remove(frame)
        self.win.clearBuffer()
        out = _Path(path)
        out.parent.mkdir(parents=True, exist_ok=True)
        frame.save(out)

    def run(self, latest: Callable[[], Snapshot | None], running: Callable[[], bool],
            stop: Callable[[str], None], *, screenshot: str | None = None,
            screenshot_after_s: float = 1.5) -> None:
        """Show the newest snapshot at up to ``max_fps`` while ``running()``; Escape or ``q``
        calls ``stop``. With ``screenshot``, the picture on show ``screenshot_after_s``
        after the start is saved there."""
        period = 1.0 / self.max_fps
        shown = None
        shot_at = time.monotonic() + screenshot_after_s if screenshot else math.inf
        while running():
            t = time.monotonic()
            snap = latest()
            if snap is not None and snap is not shown:
                self.show(snap)
                shown = snap
                if t >= shot_at:
                    self.screenshot(screenshot)
                    shot_at = math.inf
            if self.stop_requested():
                stop("preview closed by the experimenter (Escape)")
                break
            time.sleep(max(0.0, period - (time.monotonic() - t)))

    def close(self) -> None:
        try:
            self.win.close()
        except Exception:
            pass
