"""Capital letters A-Z as a camera would see a printed card (seed 001, §4.2)."""

from __future__ import annotations

import string
from typing import Annotated

import numpy as np
from pydantic import Field, field_validator

from .._cv2 import cv2
from .shapes import FlatImageParams

LETTERS = tuple(string.ascii_uppercase)


class LetterParams(FlatImageParams):
    letter: str = Field(description="one capital letter, A-Z")
    size: Annotated[float, Field(gt=0, le=1)] = Field(
        0.7, description="letter height as a fraction of the image height")
    stroke: Annotated[float, Field(gt=0, le=0.5)] = Field(
        0.12, description="stroke width as a fraction of the letter height")

    @field_validator("letter")
    @classmethod
    def _capital(cls, v: str) -> str:
        if v not in LETTERS:
            raise ValueError("expected one capital letter A-Z")
        return v


def render_letter(**params) -> np.ndarray:
    """Render a capital letter in OpenCV's simplex stroke font, centred and scaled.

    Examples
    --------
    >>> img = render_letter(letter="A")
    >>> img.shape, bool(img.max() > img.min())
    ((240, 320), True)
    """
    p = LetterParams(**params)
    cv = cv2()
    font = cv.FONT_HERSHEY_SIMPLEX
    # Draw large on its own canvas, crop to the ink, then place it scaled and rotated.
    base = 200
    scale = cv.getFontScaleFromHeight(font, base)
    thick = max(1, int(round(p.stroke * base)))
    (tw, th), bl = cv.getTextSize(p.letter, font, scale, thick)
    canvas = np.zeros((th + bl + 2 * thick + 4, tw + 2 * thick + 4), np.uint8)
    cv.putText(canvas, p.letter, (thick + 2, th + thick + 2), font, scale, 255, thick,
               cv.LINE_AA)
    ys, xs = np.nonzero(canvas)
    ink = canvas[ys.min():ys.max() + 1, xs.min():xs.max() + 1]
    s = p.size * p.height / ink.shape[0]
    m = cv.getRotationMatrix2D((ink.shape[1] / 2, ink.shape[0] / 2), -p.rotation_deg, s)
    m[:, 2] += (p.center_x * p.width - ink.shape[1] / 2, p.center_y * p.height - ink.shape[0] / 2)
    alpha = cv.warpAffine(ink, m, (p.width, p.height), flags=cv.INTER_LINEAR) / 255.0
    img = p.background + (p.foreground - p.background) * alpha
    if p.noise_sd > 0:
        img = img + np.random.default_rng(p.seed).normal(0, p.noise_sd, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)
