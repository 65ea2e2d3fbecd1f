"""Pictures of what the array does: a Pattern as a PNG, a Schedule as an animated GIF.

The array is drawn as seen by the participant (row 0 at the top): grey dots for
idle actuators, coloured dots for the pattern's points (one colour per line,
blue-green-red from the lowest line up, as seed 000 Figs. 3 and 5), their
activation order as numbers and vertices or corners as larger red rings
(seed 001 Figs. 4 and 10). Fractional points (phantom points, seed 002) sit
between the pins. The GIF shows the pulses in time, brightness by level or
amplitude.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ._cv2 import cv2
from .model import DeviceProfile, LevelDrive, Pattern, Schedule

# BGR colours for lines 1, 2, 3, ... (seed 000: blue, green, red for increasing height).
LINE_COLOURS = [(220, 120, 30), (60, 170, 60), (40, 40, 220), (0, 170, 230), (170, 60, 170),
                (170, 170, 40)]
IDLE = (200, 200, 200)
BACKGROUND = (255, 255, 255)


def _geometry(rows: int, cols: int, cell: int) -> tuple[int, int, int]:
    margin = cell
    return cols * cell + 2 * margin, rows * cell + 2 * margin, margin


def _centre(row: float, col: float, cell: int, margin: int) -> tuple[int, int]:
    return (int(round(margin + (col + 0.5) * cell)), int(round(margin + (row + 0.5) * cell)))


def draw_pattern(pattern: Pattern, *, cell: int = 36, title: str = "") -> np.ndarray:
    """The pattern on its array, as a BGR image."""
    cv = cv2()
    w, h, margin = _geometry(pattern.rows, pattern.cols, cell)
    img = np.full((h + (cell if title else 0), w, 3), BACKGROUND, np.uint8)
    top = cell if title else 0
    if title:
        cv.putText(img, title, (margin // 2, int(cell * 0.7)), cv.FONT_HERSHEY_SIMPLEX,
                   cell / 60, (0, 0, 0), 1, cv.LINE_AA)
    for r in range(pattern.rows):
        for c in range(pattern.cols):
            x, y = _centre(r, c, cell, margin)
            cv.circle(img, (x, y + top), max(2, cell // 8), IDLE, -1, cv.LINE_AA)
    ordered = [p for p in pattern.ordered() if p.order is not None]
    if len(ordered) > 1:
        # Arrows between consecutive points of the same line show the sequence.
        for a, b in zip(ordered, ordered[1:], strict=False):
            if a.line != b.line:
                continue
            pa, pb = _centre(a.row, a.col, cell, margin), _centre(b.row, b.col, cell, margin)
            cv.arrowedLine(img, (pa[0], pa[1] + top), (pb[0], pb[1] + top), (150, 150, 150), 1,
                           cv.LINE_AA, tipLength=0.25)
    for p in pattern.points:
        x, y = _centre(p.row, p.col, cell, margin)
        y += top
        colour = LINE_COLOURS[(max(p.line, 1) - 1) % len(LINE_COLOURS)] if p.line > 0 \
            else LINE_COLOURS[0]
        cv.circle(img, (x, y), cell // 4, colour, -1, cv.LINE_AA)
        if p.vertex or p.corner:
            cv.circle(img, (x, y), int(cell * 0.4), (0, 0, 230), 2, cv.LINE_AA)
        if p.order is not None and len(pattern.points) <= 120:
            cv.putText(img, str(p.order + 1), (x - cell // 4, y - cell // 4),
                       cv.FONT_HERSHEY_SIMPLEX, cell / 110, (0, 0, 0), 1, cv.LINE_AA)
    return img


def draw_figure(image: np.ndarray, mask: np.ndarray | None, pattern_img: np.ndarray, *,
                caption: str = "") -> np.ndarray:
    """What vtexp took for the object, beside what the array does: ``image`` (gray or BGR)
    with the outline of ``mask`` (uint8 0/1) in magenta (none drawn for an empty or absent
    mask), scaled to the height of ``pattern_img`` (a :func:`draw_pattern` drawing) and
    set at its left, ``caption`` under the image."""
    cv = cv2()
    img = image if image.ndim == 3 else cv.cvtColor(image, cv.COLOR_GRAY2BGR)
    img = img.copy()
    if mask is not None and mask.any():
        contours, _ = cv.findContours(np.ascontiguousarray(mask, np.uint8), cv.RETR_EXTERNAL,
                                      cv.CHAIN_APPROX_NONE)
        width = max(2, round(max(img.shape[:2]) / 200))
        cv.drawContours(img, contours, -1, (255, 0, 255), width, cv.LINE_AA)
    h = pattern_img.shape[0]
    band_h = max(24, h // 16) if caption else 0
    scale = (h - band_h) / img.shape[0]
    img = cv.resize(img, (max(1, round(img.shape[1] * scale)), h - band_h),
                    interpolation=cv.INTER_AREA if scale < 1 else cv.INTER_LINEAR)
    if caption:
        band = np.full((band_h, img.shape[1], 3), BACKGROUND, np.uint8)
        cv.putText(band, caption, (6, int(band_h * 0.7)), cv.FONT_HERSHEY_SIMPLEX,
                   band_h / 48, (0, 0, 0), 1, cv.LINE_AA)
        img = np.vstack([img, band])
    gap = np.full((h, 12, 3), BACKGROUND, np.uint8)
    return np.hstack([img, gap, pattern_img])


def schedule_frames(schedule: Schedule, profile: DeviceProfile, *, cell: int = 28,
                    step_ms: float = 50.0, max_frames: int = 600) -> list[np.ndarray]:
    """Frames (BGR) of the schedule every ``step_ms``: each pin's drive at that moment."""
    cv = cv2()
    rows, cols = profile.rows, profile.cols
    w, h, margin = _geometry(rows, cols, cell)
    if isinstance(profile.drive, LevelDrive):
        top = float(max(len(profile.drive.levels) - 1, 1))
        strength = [(p, p.level / top) for p in schedule.pulses]
    else:
        amp = float(profile.limits.max_amplitude_v or profile.drive.amplitude_v)
        strength = [(p, min(p.train.amplitude_v / amp, 1.0)) for p in schedule.pulses]
    end = schedule.duration_ms
    n = min(max_frames, int(np.ceil(end / step_ms)) + 1)
    step = end / max(n - 1, 1) if n > 1 else step_ms
    frames = []
    for i in range(n):
        t = i * step
        level = np.zeros((rows, cols))
        for p, s in strength:
            if p.onset_ms <= t < p.offset_ms:
                level[p.row, p.col] = max(level[p.row, p.col], s)
        img = np.full((h + cell, w, 3), BACKGROUND, np.uint8)
        cv.putText(img, f"{t:7.0f} ms", (margin // 2, int(cell * 0.8)), cv.FONT_HERSHEY_SIMPLEX,
                   cell / 50, (0, 0, 0), 1, cv.LINE_AA)
        for r in range(rows):
            for c in range(cols):
                x, y = _centre(r, c, cell, margin)
                v = level[r, c]
                colour = IDLE if v == 0 else (int(60 * (1 - v)), int(60 * (1 - v)),
                                              int(120 + 135 * v))
                rad = max(2, cell // 8) if v == 0 else int(cell * (0.2 + 0.25 * v))
                cv.circle(img, (x, y + cell), rad, colour, -1, cv.LINE_AA)
        frames.append(img)
    return frames


def write_png(img: np.ndarray, path: str | Path) -> None:
    if not cv2().imwrite(str(path), img):
        raise OSError(f"cannot write {path}")


def write_gif(frames: list[np.ndarray], path: str | Path, *, frame_ms: float = 50.0) -> None:
    """Animated GIF (Pillow), looping, one frame every ``frame_ms``."""
    from PIL import Image       # for GIFs only: 'vtexp encode' without --gif needs no Pillow

    cv = cv2()
    rgb = [Image.fromarray(cv.cvtColor(f, cv.COLOR_BGR2RGB)) for f in frames]
    # One palette for the whole animation, from the colours of up to 8 frames spread over
    # it, each frame mapped to it: a palette of its own for every frame (Pillow's default)
    # took most of the time, for frames drawn in the same few colours.
    sample = np.concatenate([np.asarray(im) for im in rgb[::max(1, len(rgb) // 8)]])
    palette = Image.fromarray(sample).quantize(colors=255, method=Image.Quantize.MEDIANCUT)
    images = [im.quantize(palette=palette, dither=Image.Dither.NONE) for im in rgb]
    images[0].save(str(path), save_all=True, append_images=images[1:],
                   duration=int(round(frame_ms)), loop=0, optimize=False)
