"""Separating the object from its background, shared by the pipelines."""

from __future__ import annotations

import numpy as np

from .._cv2 import cv2


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
