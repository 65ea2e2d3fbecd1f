"""Separating the object from its background, shared by the pipelines.

Without a figure mask the pipelines find the object by :func:`object_mask` (Otsu's
threshold), which holds for a plain background. Given one (``mask=``, found by
:mod:`vtexp.encoding.figure`), they take it instead (:func:`given_mask`), and those
that look at edges look at :func:`flatten_background`'s image, where the background
farther from the object has no edges left.
"""

from __future__ import annotations

import numpy as np

from .._cv2 import cv2
from ..errors import InputError


def object_mask(gray: np.ndarray) -> np.ndarray:
    """Foreground mask (uint8 0/1) by Otsu's threshold.

    The object is the side of the threshold that does not make up most of the
    image border, so a dark object on a light background works as well as a
    light one on a dark background.
    """
    cv = cv2()
    _, mask = cv.threshold(gray, 0, 1, cv.THRESH_BINARY + cv.THRESH_OTSU)
    border = np.concatenate([mask[0], mask[-1], mask[:, 0], mask[:, -1]])
    if border.mean() > 0.5:
        mask = 1 - mask
    return drop_specks(mask.astype(np.uint8))


#: Parts of the mask smaller than this share of its largest part are sensor noise: a
#: few pixels of the background past Otsu's threshold, far from the object, would
#: otherwise stretch the object's bounding box (``fit: object``) and shrink it on the
#: array (a triangle at contrast 60 and noise 7.5: 5 of its 12 cells).
SPECK = 0.01


def drop_specks(mask: np.ndarray) -> np.ndarray:
    """``mask`` (uint8 0/1) without its 8-connected parts under ``SPECK`` of the largest."""
    n, labels, stats, _ = cv2().connectedComponentsWithStats(mask, connectivity=8)
    if n <= 2:                               # the background and at most one part
        return mask
    areas = stats[1:, 4]                     # cv2.CC_STAT_AREA of each part
    keep = np.concatenate([[False], areas >= SPECK * areas.max()])
    return keep[labels].astype(np.uint8)


def given_mask(mask: np.ndarray, shape: tuple[int, ...], pipeline: str) -> np.ndarray:
    """A figure mask given to ``pipeline``, checked against the image's ``shape``:
    uint8 0/1 (any non-zero value is the object) of the image's height x width."""
    m = np.asarray(mask)
    if m.shape != tuple(shape[:2]):
        raise InputError(
            f"{pipeline}: the figure mask has shape {m.shape} but the image is "
            f"{shape[1]}x{shape[0]} pixels; give a mask of the image's height x width "
            "(vtexp.encoding.figure finds one)")
    return (np.nan_to_num(m) != 0).astype(np.uint8)


def flatten_background(gray: np.ndarray, mask: np.ndarray, ring_px: float) -> np.ndarray:
    """``gray`` with the background's edges removed: pixels within ``ring_px`` of the
    object (``mask``, uint8 0/1) keep their value, so the object's own edge stays
    where the image has it even where the mask is a pixel or two off; farther out
    they fade linearly, over another ``ring_px``, to the median of the background
    within ``max(ring_px, 2)`` pixels of the object, so fading makes no strong edge
    of its own. ``ring_px=0``: everything outside the mask is that median (the
    object's silhouette against a plain ground). Same dtype.
    """
    cv = cv2()
    g = np.asarray(gray)
    if not mask.any() or mask.all():
        return g.copy()
    dist = cv.distanceTransform((mask == 0).astype(np.uint8), cv.DIST_L2, 3)
    ring = (dist > 0) & (dist <= max(ring_px, 2.0))
    level = float(np.median(g[ring])) if ring.any() else float(np.median(g[mask == 0]))
    keep = np.clip(2.0 - dist / ring_px, 0.0, 1.0) if ring_px > 0 else \
        (dist == 0).astype(np.float32)
    out = keep * g.astype(np.float32) + (1.0 - keep) * level
    if g.dtype.kind in "ui":
        out = np.clip(np.rint(out), np.iinfo(g.dtype).min, np.iinfo(g.dtype).max)
    return out.astype(g.dtype)
