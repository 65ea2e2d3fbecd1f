"""The whirlpool of seed 002 (§4, Fig. 10): an Archimedean spiral drawn as a bright line."""

from __future__ import annotations

from typing import Annotated

import numpy as np
from pydantic import Field

from .._cv2 import cv2
from ..model import Model


class WhirlpoolParams(Model):
    """Parameters of :func:`render_whirlpool` (the keys allowed under ``params:``)."""

    width: Annotated[int, Field(ge=16, le=8192)] = 320
    height: Annotated[int, Field(ge=16, le=8192)] = 240
    turns: Annotated[float, Field(gt=0, le=20)] = Field(
        2.0, description="full turns from the centre to the outer end")
    size: Annotated[float, Field(gt=0, le=1)] = Field(
        0.8, description="outer diameter as a fraction of the image height")
    inner: Annotated[float, Field(ge=0, lt=1)] = Field(
        0.2, description="radius where the line starts, as a fraction of the outer radius "
                         "(turns tighter than the array's grid step collapse onto one point)")
    center_x: Annotated[float, Field(ge=0, le=1)] = 0.5
    center_y: Annotated[float, Field(ge=0, le=1)] = 0.5
    rotation_deg: float = Field(0.0, description="angle of the outer end, clockwise from east")
    clockwise: bool = Field(True, description="the line turns clockwise going outward, as seen")
    line_width_px: Annotated[float, Field(ge=1, le=64)] = 3.0
    background: Annotated[int, Field(ge=0, le=255)] = 40
    foreground: Annotated[int, Field(ge=0, le=255)] = 210
    noise_sd: Annotated[float, Field(ge=0)] = 0.0
    seed: int = 0


def spiral_points(**params) -> np.ndarray:
    """The whirlpool's centre line as image points ``(x, y)``, from the centre outward.

    An Archimedean spiral, r(θ) = r_in + (R − r_in)·θ / (2π·turns) for θ in
    [0, 2π·turns], R = size·height/2, sampled at most half a pixel apart. The
    outer end lies at ``rotation_deg`` (clockwise from east, image rows grow
    downwards).
    """
    p = WhirlpoolParams(**params)
    big_r = p.size * p.height / 2.0
    r_in = p.inner * big_r
    theta_end = 2.0 * np.pi * p.turns
    n = max(16, int(np.ceil(theta_end * big_r / 0.5)))
    theta = np.linspace(0.0, theta_end, n)
    r = r_in + (big_r - r_in) * theta / theta_end
    sign = 1.0 if p.clockwise else -1.0
    # Angle measured so that the outer end (theta_end) lands at rotation_deg.
    ang = np.deg2rad(p.rotation_deg) + sign * (theta - theta_end)
    x = p.center_x * p.width + r * np.cos(ang)
    y = p.center_y * p.height + r * np.sin(ang)
    return np.stack([x, y], axis=1)


def render_whirlpool(**params) -> np.ndarray:
    """Render the whirlpool of seed 002 Fig. 10: a bright spiral line on a darker ground.

    Examples
    --------
    >>> img = render_whirlpool(turns=2)
    >>> img.shape, img.dtype, int(img.max()) > int(img[0, 0])
    ((240, 320), dtype('uint8'), True)
    """
    p = WhirlpoolParams(**params)
    cv = cv2()
    img = np.full((p.height, p.width), p.background, dtype=np.uint8)
    pts = spiral_points(**p.model_dump())
    # Anti-aliased at 1/16 pixel, like a camera's blur (as render_shape draws).
    cv.polylines(img, [np.round(pts * 16).astype(np.int32)], False, int(p.foreground),
                 thickness=max(1, round(p.line_width_px)), lineType=cv.LINE_AA, shift=4)
    if p.noise_sd > 0:
        rng = np.random.default_rng(p.seed)
        img = np.clip(img + rng.normal(0, p.noise_sd, img.shape), 0, 255).astype(np.uint8)
    return img
