"""Synthetic camera videos: an object moving and turning before a plain background, written
with OpenCV's VideoWriter, with where the object truly was in every frame.

They stand in for a camera in the tests and in ``bench/live.py`` (the issue's
benchmark: "an object moving and rotating across 640x480 frames"). The object is one
of the study shapes (``vtexp.stimuli``: triangle, circle, square, rectangle), a
horse's silhouette (an outline with legs, ears and a tail: many corners close
together, the hard case for seed 002's pins), or the shaded ball of seed 000 (for
height contours). It sweeps from one side of the frame to the other and back while
it bobs up and down and turns, at speeds a hand moving an object before a camera
reaches. :func:`write_video` returns, per frame, the object's true centroid (area
centroid of the object as drawn, before noise), in image pixels.
"""

from __future__ import annotations

import json
import math
from functools import lru_cache
from pathlib import Path

import numpy as np

from .._cv2 import cv2
from ..stimuli import render_shape
from ..stimuli.surfaces import render_surface

# A horse standing, facing left, in a unit box (x to the right, y down).
HORSE = ((0.02, 0.30), (0.08, 0.18), (0.14, 0.10), (0.20, 0.06), (0.22, 0.12), (0.26, 0.14),
         (0.32, 0.30), (0.40, 0.36), (0.70, 0.34), (0.82, 0.30), (0.90, 0.28), (0.98, 0.34),
         (0.96, 0.40), (0.90, 0.38), (0.86, 0.44), (0.86, 0.62), (0.90, 0.98), (0.84, 0.98),
         (0.78, 0.66), (0.74, 0.62), (0.70, 0.98), (0.64, 0.98), (0.66, 0.62), (0.42, 0.62),
         (0.40, 0.98), (0.34, 0.98), (0.34, 0.62), (0.30, 0.58), (0.26, 0.98), (0.20, 0.98),
         (0.22, 0.56), (0.20, 0.44), (0.18, 0.30), (0.12, 0.36), (0.06, 0.38))

OBJECTS = ("triangle", "circle", "square", "rectangle", "horse", "ball")
BACKGROUND, FOREGROUND = 40, 210


def render_horse(*, width: int = 640, height: int = 480, size: float = 0.5,
                 center_x: float = 0.5, center_y: float = 0.5, rotation_deg: float = 0.0
                 ) -> np.ndarray:
    """A horse's silhouette (:data:`HORSE`), ``size`` of the image height, antialiased."""
    cv = cv2()
    ss = 4
    img = np.full((height * ss, width * ss), BACKGROUND, np.uint8)
    p = np.array(HORSE) - 0.5
    a = math.radians(rotation_deg)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    p = (p @ rot.T) * size * height + [center_x * width, center_y * height]
    cv.fillPoly(img, [np.round(p * ss).astype(np.int32)], FOREGROUND, cv.LINE_AA)
    return cv.resize(img, (width, height), interpolation=cv.INTER_AREA)


def render_object(kind: str, *, width: int, height: int, size: float, center_x: float,
                  center_y: float, rotation_deg: float) -> np.ndarray:
    if kind == "horse":
        return render_horse(width=width, height=height, size=size, center_x=center_x,
                            center_y=center_y, rotation_deg=rotation_deg)
    if kind == "ball":
        # seed 000's shaded ball, lit from the viewer: moved, it looks the same (and turned
        # too), so one rendering is shifted (rendering it anew takes most of a second).
        cv = cv2()
        ball = _ball(width, height, size)
        m = np.float32([[1, 0, (center_x - 0.5) * width], [0, 1, (center_y - 0.5) * height]])
        return cv.warpAffine(ball, m, (width, height), flags=cv.INTER_LINEAR,
                             borderMode=cv.BORDER_CONSTANT, borderValue=int(ball[0, 0]))
    return render_shape(shape=kind, width=width, height=height, size=size, center_x=center_x,
                        center_y=center_y, rotation_deg=rotation_deg, background=BACKGROUND,
                        foreground=FOREGROUND)


@lru_cache(maxsize=4)
def _ball(width: int, height: int, size: float) -> np.ndarray:
    return render_surface(surface="ball", width=width, height=height, size=size)


def true_centroid(img: np.ndarray) -> tuple[float, float]:
    """Area centroid (row, col) of the object in a noise-free frame: pixels weighted by how
    much of them the object covers (the antialiased edge counts in part)."""
    g = img.astype(np.float64)
    bg = float(np.median(np.concatenate([g[0], g[-1], g[:, 0], g[:, -1]])))
    w = np.abs(g - bg)
    w[w < 2.0] = 0.0
    total = w.sum()
    rows = w.sum(axis=1) @ np.arange(w.shape[0], dtype=np.float64)
    cols = w.sum(axis=0) @ np.arange(w.shape[1], dtype=np.float64)
    return float(rows / total), float(cols / total)


def write_video(path: str | Path, kind: str = "rectangle", *, seconds: float = 5.0,
                fps: float = 30.0, width: int = 640, height: int = 480, size: float = 0.35,
                sweeps: float = 1.0, turn_deg_per_s: float = 36.0, noise_sd: float = 4.0,
                seed: int = 0, backdrop: np.ndarray | None = None,
                empty_s: float = 0.0) -> list[dict]:
    """Write an MJPG video of ``kind`` moving and turning (module docstring); return per
    frame ``{"frame", "t_s", "center_x", "center_y", "rotation_deg", "centroid_row",
    "centroid_col"}`` and write it beside the video as ``<path>.truth.json``.

    The object crosses from 25 % to 75 % of the width and back ``sweeps`` times over the
    video, bobs ±8 % of the height and turns ``turn_deg_per_s``. ``backdrop`` (a gray
    image, e.g. a photograph; scaled to the frame) is the scene behind the object instead
    of a plain background; ``empty_s``: that long of the empty scene first (the object's
    rows then say ``None`` for its centroid).
    """
    if kind not in OBJECTS:
        raise ValueError(f"unknown object {kind!r}; one of {', '.join(OBJECTS)}")
    cv = cv2()
    path = Path(path)
    n = max(1, int(round(seconds * fps)))
    writer = cv.VideoWriter(str(path), cv.VideoWriter_fourcc(*"MJPG"), fps, (width, height),
                            False)
    if not writer.isOpened():
        raise OSError(f"cannot write a video to {path}")
    rng = np.random.default_rng(seed)
    scene = None if backdrop is None else cv.resize(np.asarray(backdrop, np.uint8),
                                                    (width, height), interpolation=cv.INTER_AREA)
    n_empty = int(round(empty_s * fps))
    truth = []
    try:
        for k in range(n_empty + n):
            t = k / fps
            u = (max(k - n_empty, 0) / n) * sweeps
            cx = 0.5 - 0.25 * math.cos(2 * math.pi * u)        # 0.25 .. 0.75 and back
            cy = 0.5 + 0.08 * math.sin(2 * math.pi * 2 * u)
            rot = turn_deg_per_s * t
            img = render_object(kind, width=width, height=height, size=size, center_x=cx,
                                center_y=cy, rotation_deg=rot)
            r, c = true_centroid(img)
            if scene is not None:              # the object over the scene, by its mask
                img = np.where(img != img[0, 0], img, scene) if k >= n_empty else scene.copy()
            if k < n_empty:
                img = scene.copy() if scene is not None else np.full_like(img, img[0, 0])
                r = c = None
            if noise_sd > 0:                   # in float32: a third less time per frame
                noisy = rng.standard_normal(img.shape, dtype=np.float32)
                noisy *= noise_sd
                noisy += img
                img = np.clip(noisy, 0, 255, out=noisy).astype(np.uint8)
            writer.write(img)
            truth.append({"frame": k, "t_s": t, "center_x": cx, "center_y": cy,
                          "rotation_deg": rot, "centroid_row": r, "centroid_col": c})
    finally:
        writer.release()
    Path(str(path) + ".truth.json").write_text(json.dumps(truth))
    return truth


def tracking_errors(frames, truth: list[dict], to_array) -> np.ndarray:
    """Per processed frame with an object, the distance in actuator pitches between the
    centroid of the points its cycle actuated (``frames``: a record's ``frames.tsv``) and
    the object's true centroid mapped onto the array (``to_array``:
    :class:`~vtexp.encoding.mapping.ImageToArray`)."""
    by_frame = {t["frame"]: t for t in truth}
    out = []
    for f, r, c in zip(frames["frame"], frames["centroid_row"], frames["centroid_col"]):
        if f not in by_frame or r != r or c != c:        # NaN: no object found
            continue
        if by_frame[f]["centroid_row"] is None:          # the empty scene before it
            continue
        tr = to_array.to_array([[by_frame[f]["centroid_row"], by_frame[f]["centroid_col"]]])[0]
        out.append(math.hypot(r - tr[0], c - tr[1]))
    return np.array(out)
