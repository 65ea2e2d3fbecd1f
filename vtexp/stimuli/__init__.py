"""Stimulus images: generators and image files, as a camera would see them.

Every generator returns a 2-D ``uint8`` grayscale image (a bright object on a
darker background, like a light object before a camera). Generators are
looked up by name in :data:`GENERATORS`, each entry holding the function and
the pydantic model of its parameters (the keys an experiment may declare under
``params:``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._cv2 import cv2
from ..errors import InputError
from .letters import LETTERS, LetterParams, render_letter
from .points import TwoPointParams, render_two_point
from .shapes import SHAPES, ShapeParams, render_shape
from .spiral import WhirlpoolParams, render_whirlpool
from .surfaces import SURFACES, SurfaceParams, render_surface

GENERATORS = {
    "shape": (render_shape, ShapeParams),
    "letter": (render_letter, LetterParams),
    "surface": (render_surface, SurfaceParams),
    "whirlpool": (render_whirlpool, WhirlpoolParams),
    "two_point": (render_two_point, TwoPointParams),
}


def render(generator: str, params: dict, rows: int | None = None,
           cols: int | None = None) -> np.ndarray:
    """``generator``'s image with ``params``; a generator that draws on the array's grid
    (``array_rows``/``array_cols``, e.g. ``two_point``) gets the device's ``rows`` and
    ``cols`` unless the params give them.

    Every generator is a pure function of its parameters, so the last images made are
    kept (:data:`RENDERED`) and a copy returned when the same one is asked again: a
    study renders each stimulus for every condition that shows it, and the model
    participant each answer's image for every condition it is asked in (a shaded
    surface costs about 40 ms).
    """
    fn, model = GENERATORS[generator]
    params = dict(params)
    if rows is not None and "array_rows" in model.model_fields:
        params.setdefault("array_rows", rows)
        params.setdefault("array_cols", cols)
    try:
        key = (generator, tuple(sorted(params.items())))
        hash(key)
    except TypeError:                       # a value that cannot be a key: drawn each time
        return fn(**params)
    img = RENDERED.get(key)
    if img is None:
        img = fn(**params)
        img.setflags(write=False)
        RENDERED[key] = img
        while len(RENDERED) > RENDERED_MAX:
            RENDERED.pop(next(iter(RENDERED)))
    return img.copy()


#: The images :func:`render` made last, by generator and parameters (oldest first).
RENDERED: dict[tuple, np.ndarray] = {}
RENDERED_MAX = 64


def read_image(path: str | Path, *, colour: bool = False) -> np.ndarray:
    """Read an image file (PNG, JPEG, ...; 8 or 16 bit; gray or colour) as 8-bit gray, or
    with ``colour`` as 8-bit BGR (a gray file as three equal channels): the figure-ground
    separation (:mod:`vtexp.encoding.figure`) tells an object from its background by colour
    as well as brightness."""
    p = Path(path)
    try:
        if not p.is_file():
            raise InputError("image file not found", path=str(p))
        data = np.fromfile(str(p), dtype=np.uint8)
    except OSError as e:                    # a name too long, no permission to read, ...
        raise InputError(f"cannot read the image file: {e.strerror or e}",
                         path=str(p)[:300]) from None
    cv = cv2()
    try:
        img = cv.imdecode(data, cv.IMREAD_UNCHANGED) if data.size else None
    except cv.error as e:
        if "CV_IO_MAX_IMAGE_PIXELS" in str(e):
            raise InputError("the image has more pixels than OpenCV reads (2^30, set by the "
                             "OPENCV_IO_MAX_IMAGE_PIXELS environment variable); scale it "
                             "down first", path=str(p)) from None
        raise InputError(f"not a readable image: {str(e).strip().splitlines()[-1]}",
                         path=str(p)) from None
    if img is None:
        raise InputError("not a readable image (expected PNG, JPEG, BMP or TIFF)", path=str(p))
    if img.ndim == 3 and img.shape[2] == 4:
        img = cv.cvtColor(img, cv.COLOR_BGRA2BGR)
    if img.ndim == 3 and not colour:
        img = cv.cvtColor(img, cv.COLOR_BGR2GRAY)
    elif img.ndim == 2 and colour:
        img = cv.cvtColor(img, cv.COLOR_GRAY2BGR)
    if img.dtype == np.uint16:
        img = (img / 257.0).round().astype(np.uint8)
    elif img.dtype != np.uint8:
        img = cv.normalize(img.astype(np.float64), None, 0, 255, cv.NORM_MINMAX).astype(np.uint8)
    return img


def read_camera(index: int = 0, *, warmup_frames: int = 3, colour: bool = False) -> np.ndarray:
    """One frame from an OpenCV VideoCapture device, as 8-bit gray (BGR with ``colour``).

    A few frames are read and dropped first, while the camera adjusts its exposure.
    """
    cv = cv2()
    cap = cv.VideoCapture(index)
    try:
        if not cap.isOpened():
            raise InputError(f"no camera at index {index} (OpenCV VideoCapture could not open "
                             "it); check that it is plugged in and not used by another program")
        frame = None
        for _ in range(warmup_frames + 1):
            ok, f = cap.read()
            if ok:
                frame = f
        if frame is None:
            raise InputError(f"camera {index} opened but gave no frame")
    finally:
        cap.release()
    if colour:
        return frame if frame.ndim == 3 else cv.cvtColor(frame, cv.COLOR_GRAY2BGR)
    return cv.cvtColor(frame, cv.COLOR_BGR2GRAY) if frame.ndim == 3 else frame


__all__ = ["GENERATORS", "TwoPointParams", "render", "render_two_point", "read_camera", "LETTERS", "SHAPES", "SURFACES", "LetterParams", "ShapeParams",
           "SurfaceParams", "read_image", "render_letter",
           "render_shape", "render_surface"]
