"""Filled 2-D shapes: triangle, circle, square, rectangle (seeds 001 and 002)."""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import Field

from .._cv2 import cv2
from ..model import Model

SHAPES = ("triangle", "circle", "square", "rectangle")


class ShapeParams(Model):
    """Parameters of :func:`render_shape` (the keys allowed under ``params:``)."""

    shape: Literal["triangle", "circle", "square", "rectangle"]
    width: Annotated[int, Field(ge=16, le=8192)] = 320
    height: Annotated[int, Field(ge=16, le=8192)] = 240
    size: Annotated[float, Field(gt=0, le=1)] = Field(
        0.7, description="object extent as a fraction of the image height")
    center_x: Annotated[float, Field(ge=0, le=1)] = 0.5
    center_y: Annotated[float, Field(ge=0, le=1)] = 0.5
    rotation_deg: float = 0.0
    background: Annotated[int, Field(ge=0, le=255)] = 40
    foreground: Annotated[int, Field(ge=0, le=255)] = 210
    noise_sd: Annotated[float, Field(ge=0)] = 0.0
    seed: int = 0


def _shape_polygon(p: ShapeParams) -> np.ndarray | None:
    s = p.size * p.height
    if p.shape == "square":
        pts = np.array([[-.5, -.5], [.5, -.5], [.5, .5], [-.5, .5]]) * s
    elif p.shape == "rectangle":    # 3:2, wider than tall
        pts = np.array([[-.75, -.5], [.75, -.5], [.75, .5], [-.75, .5]]) * s
    elif p.shape == "triangle":     # equilateral, apex up, centred on its bounding box
        h = np.sqrt(3) / 2
        pts = np.array([[0, -h / 2], [.5, h / 2], [-.5, h / 2]]) * s / h
    else:
        return None
    a = np.deg2rad(p.rotation_deg)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return pts @ rot.T + [p.center_x * p.width, p.center_y * p.height]


def render_shape(**params) -> np.ndarray:
    """Render a filled 2-D shape (triangle, circle, square or rectangle).

    Examples
    --------
    >>> img = render_shape(shape="circle")
    >>> img.shape, img.dtype
    ((240, 320), dtype('uint8'))
    """
    p = ShapeParams(**params)
    cv = cv2()
    img = np.full((p.height, p.width), p.background, dtype=np.uint8)
    poly = _shape_polygon(p)
    # Draw at 16x sub-pixel precision with anti-aliased edges, like a camera's blur.
    shift = 4
    if poly is None:
        c = (int(round(p.center_x * p.width * 16)), int(round(p.center_y * p.height * 16)))
        cv.circle(img, c, int(round(p.size * p.height / 2 * 16)), int(p.foreground),
                  thickness=-1, lineType=cv.LINE_AA, shift=shift)
    else:
        cv.fillPoly(img, [np.round(poly * 16).astype(np.int32)], int(p.foreground),
                    lineType=cv.LINE_AA, shift=shift)
    if p.noise_sd > 0:
        rng = np.random.default_rng(p.seed)
        img = np.clip(img + rng.normal(0, p.noise_sd, img.shape), 0, 255).astype(np.uint8)
    return img
