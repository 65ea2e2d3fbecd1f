"""Lambertian renderings of 3-D surfaces, lit from the viewer (seed 000, §2.1.1).

Seed 000 assumes a Lambertian object with the light source at infinity in the
viewing direction, so the brightness of a surface point is the cosine between
its normal and the line of sight:

    E(x, y) = albedo / sqrt(1 + p^2 + q^2),   p = dZ/dx, q = dZ/dy    (seed 000 eq. 1)

:func:`surface_height` gives the true height map of each surface (for
accuracy tests), :func:`render_surface` the image a camera would see.
Surfaces: ``ball`` (hemisphere), ``cone``, ``vase`` (a surface of revolution
about the vertical axis), ``bowl`` (concave hemisphere; under head-on light it
looks exactly like the ball, the classic convex/concave ambiguity), ``disc``
(flat, "plane circular") and ``uneven`` (random smooth bumps on a disc).
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import Field

from ..model import Model

SURFACES = ("ball", "cone", "vase", "bowl", "disc", "uneven")


class SurfaceParams(Model):
    surface: Literal["ball", "cone", "vase", "bowl", "disc", "uneven"]
    width: Annotated[int, Field(ge=16, le=8192)] = 320
    height: Annotated[int, Field(ge=16, le=8192)] = 240
    size: Annotated[float, Field(gt=0, le=1)] = Field(
        0.8, description="object extent as a fraction of the image height")
    center_x: Annotated[float, Field(ge=0, le=1)] = 0.5
    center_y: Annotated[float, Field(ge=0, le=1)] = 0.5
    rotation_deg: float = Field(0.0, description="rotation in the image plane")
    cone_slope: Annotated[float, Field(gt=0, le=10)] = Field(
        1.0, description="cone height / base radius")
    bumps: Annotated[int, Field(ge=1, le=50)] = Field(7, description="bumps of 'uneven'")
    background: Annotated[int, Field(ge=0, le=255)] = 20
    albedo: Annotated[int, Field(ge=1, le=255)] = Field(
        235, description="gray level of a surface facing the camera")
    noise_sd: Annotated[float, Field(ge=0)] = 0.0
    seed: int = 0


def _window(p: SurfaceParams) -> tuple[int, int, int, int]:
    """Rows ``r0:r1`` and columns ``c0:c1`` of the image that hold the whole object and
    two pixels of background round it: every surface lies within 4/3 R of its centre
    (the vase: |y| <= R, |x| <= 0.88 R), 1.5 R is taken."""
    reach = 1.5 * p.size * p.height / 2 + 2
    cx, cy = p.center_x * p.width, p.center_y * p.height
    return (max(0, int(np.floor(cy - reach))), min(p.height, int(np.ceil(cy + reach))),
            max(0, int(np.floor(cx - reach))), min(p.width, int(np.ceil(cx + reach))))


def _coords(p: SurfaceParams, ss: int = 1,
            window: tuple[int, int, int, int] | None = None
            ) -> tuple[np.ndarray, np.ndarray, float]:
    """Object-centred coordinates in pixels (x right, y down), rotated; radius R.

    ``ss`` samples each pixel ``ss x ss`` times (coordinates of the sub-pixel centres);
    ``window`` (rows ``r0:r1``, columns ``c0:c1``) gives those of that part only.
    """
    r0, r1, c0, c1 = window or (0, p.height, 0, p.width)
    yy, xx = np.mgrid[r0 * ss:r1 * ss, c0 * ss:c1 * ss].astype(np.float64)
    x = (xx + 0.5) / ss - p.center_x * p.width
    y = (yy + 0.5) / ss - p.center_y * p.height
    a = np.deg2rad(p.rotation_deg)
    xr = np.cos(a) * x + np.sin(a) * y
    yr = -np.sin(a) * x + np.cos(a) * y
    return xr, yr, p.size * p.height / 2


def vase_radius(v: np.ndarray) -> np.ndarray:
    """Profile of the vase: radius (fraction of R) at height v in [-1, 1] (top to bottom).

    A lip at the top, a narrow neck, a belly below the middle. The profile
    closes at both ends (radius 0 at v = +-1, with a vertical tangent), so the
    silhouette is an occluding contour all round, as shape from shading assumes.
    """
    v = np.clip(v, -1.0, 1.0)
    return (1.0 - v ** 2) ** 0.3 * (0.70 + 0.18 * np.cos(1.1 * np.pi * (v - 0.35)))


def surface_height(_supersample: int = 1, _window: tuple[int, int, int, int] | None = None,
                   **params) -> tuple[np.ndarray, np.ndarray]:
    """True height map (pixels, towards the camera) and object mask of a surface.

    Sampled at pixel centres (``_supersample`` > 1: at sub-pixel centres, for rendering);
    over the whole image, or the part ``_window`` (:func:`_window`) that holds the object.
    """
    p = SurfaceParams(**params)
    x, y, R = _coords(p, _supersample, _window)
    r = np.hypot(x, y)
    if p.surface == "vase":
        v = y / R
        rho = vase_radius(np.clip(v, -1, 1)) * R
        mask = (np.abs(v) <= 1) & (np.abs(x) < rho)
        z = np.sqrt(np.clip(rho ** 2 - x ** 2, 0, None))
        return np.where(mask, z, 0.0), mask
    mask = r < R
    if p.surface == "ball":
        z = np.sqrt(np.clip(R ** 2 - r ** 2, 0, None))
    elif p.surface == "bowl":
        z = R - np.sqrt(np.clip(R ** 2 - r ** 2, 0, None))
    elif p.surface == "cone":
        z = p.cone_slope * (R - r)
    elif p.surface == "disc":
        z = np.zeros_like(r)
    else:  # uneven: smooth random bumps on a disc
        rng = np.random.default_rng(p.seed)
        z = np.zeros_like(r)
        for _ in range(p.bumps):
            cx, cy = rng.uniform(-0.6, 0.6, 2) * R
            s = rng.uniform(0.12, 0.3) * R
            amp = rng.uniform(0.15, 0.4) * R * rng.choice([-1, 1])
            z += amp * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * s ** 2))
        z -= z[mask].min()
    return np.where(mask, z, 0.0), mask


def _masked_gradient(z: np.ndarray, mask: np.ndarray, step: float, axis: int) -> np.ndarray:
    """dZ along ``axis`` from differences between object samples only.

    A difference across the silhouette (object to background) is not a slope of
    the surface; each sample uses the mean of its forward and backward
    differences that stay on the object.
    """
    zf = np.diff(z, axis=axis) / step
    mf = np.logical_and(np.take(mask, range(1, mask.shape[axis]), axis),
                        np.take(mask, range(0, mask.shape[axis] - 1), axis))
    pad = [(0, 0), (0, 0)]
    pad[axis] = (0, 1)
    fwd, fok = np.pad(zf, pad), np.pad(mf, pad)
    pad[axis] = (1, 0)
    bwd, bok = np.pad(zf, pad), np.pad(mf, pad)
    n = fok.astype(np.float64) + bok
    return np.where(n > 0, (fwd * fok + bwd * bok) / np.maximum(n, 1), 0.0)


def shade(z: np.ndarray, mask: np.ndarray, step: float = 1.0) -> np.ndarray:
    """Lambertian brightness in [0, 1] with the light at the viewer (seed 000 eq. 1).

    ``step`` is the sample spacing in the units of ``z`` (pixels).
    """
    p = _masked_gradient(z, mask, step, axis=1)
    q = _masked_gradient(z, mask, step, axis=0)
    e = 1.0 / np.sqrt(1.0 + p ** 2 + q ** 2)
    return np.where(mask, e, 0.0)


SUPERSAMPLE = 4


def render_surface(**params) -> np.ndarray:
    """Render a surface as an 8-bit gray camera image.

    Each pixel shows the mean brightness of the surface inside it, shaded at
    4 x 4 sub-pixels. A pixel belongs to the object if the object covers at
    least half of it; the silhouette is thus sharp (no blending of the dark rim
    with the background, which would look steeper than the surface is).

    Examples
    --------
    >>> img = render_surface(surface="ball")
    >>> img.shape, img.dtype, int(img.max()) > 200
    ((240, 320), dtype('uint8'), True)
    """
    p = SurfaceParams(**params)
    ss = SUPERSAMPLE
    # the object's part of the image only (about a quarter of it for a ball): the rest
    # is background, and the pixels are the same as if the whole image were shaded
    r0, r1, c0, c1 = window = _window(p)
    h, w = r1 - r0, c1 - c0
    z, mask = surface_height(_supersample=ss, _window=window, **params)
    e = shade(z, mask, 1.0 / ss)
    cover = mask.reshape(h, ss, w, ss).mean(axis=(1, 3))
    lit = e.reshape(h, ss, w, ss).sum(axis=(1, 3))
    e_pix = np.zeros((p.height, p.width))
    e_pix[r0:r1, c0:c1] = np.where(cover >= 0.5, lit / np.maximum(cover * ss * ss, 1), 0.0)
    img = p.background + (p.albedo - p.background) * e_pix
    if p.noise_sd > 0:
        img = img + np.random.default_rng(p.seed + 1).normal(0, p.noise_sd, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)
