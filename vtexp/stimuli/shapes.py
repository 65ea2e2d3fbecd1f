"""Filled 2-D shapes: triangle, circle, square, rectangle (seeds 001 and 002)."""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import Field

from ..model import Model

SHAPES = ("triangle", "circle", "square", "rectangle")


class FlatImageParams(Model):
    """A light figure on a darker ground, as a camera sees a card: frame, placement, contrast."""

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


class ShapeParams(FlatImageParams):
    """Parameters of :func:`render_shape` (the keys allowed under ``params:``)."""

    shape: Literal["triangle", "circle", "square", "rectangle"]


def _shape_polygon(p: ShapeParams) -> np.ndarray | None:
    """Vertices in image coordinates (0 at the frame's edge); None for the circle."""
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


SUPERSAMPLE = 4


def render_shape(**params) -> np.ndarray:
    """Render a filled 2-D shape (triangle, circle, square or rectangle).

    Examples
    --------
    >>> img = render_shape(shape="circle")
    >>> img.shape, img.dtype
    ((240, 320), dtype('uint8'))
    """
    p = ShapeParams(**params)
    ss = SUPERSAMPLE
    # Each pixel shows the share of it the shape covers (a camera integrates light
    # over the pixel): the exact shape is tested at 4 x 4 sub-pixel centres and averaged,
    # within the shape's bounding box.
    poly = _shape_polygon(p)
    if poly is None:
        r = p.size * p.height / 2
        cx, cy = p.center_x * p.width, p.center_y * p.height
        box = (cx - r, cy - r, cx + r, cy + r)
    else:
        box = (poly[:, 0].min(), poly[:, 1].min(), poly[:, 0].max(), poly[:, 1].max())
    x0 = int(np.clip(np.floor(box[0]), 0, p.width))
    y0 = int(np.clip(np.floor(box[1]), 0, p.height))
    x1 = int(np.clip(np.ceil(box[2]) + 1, 0, p.width))
    y1 = int(np.clip(np.ceil(box[3]) + 1, 0, p.height))
    share = np.zeros((p.height, p.width), np.float32)
    if x1 > x0 and y1 > y0:
        x = ((np.arange(x0 * ss, x1 * ss) + 0.5) / ss)[None, :]
        y = ((np.arange(y0 * ss, y1 * ss) + 0.5) / ss)[:, None]
        if poly is None:
            inside = (x - cx) ** 2 + (y - cy) ** 2 <= r * r
        else:
            # Convex, listed clockwise on screen: inside every edge's half-plane.
            inside = np.ones((y.shape[0], x.shape[1]), bool)
            for (ax, ay), (bx, by) in zip(poly, np.roll(poly, -1, axis=0), strict=True):
                inside &= (bx - ax) * (y - ay) - (by - ay) * (x - ax) >= 0
        share[y0:y1, x0:x1] = inside.reshape(y1 - y0, ss, x1 - x0, ss).mean(axis=(1, 3))
    img = p.background + (p.foreground - p.background) * share
    if p.noise_sd > 0:
        img = img + np.random.default_rng(p.seed).normal(0, p.noise_sd, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)
