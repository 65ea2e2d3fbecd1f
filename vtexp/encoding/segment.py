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
    return mask.astype(np.uint8)
