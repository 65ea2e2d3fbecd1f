"""Filled 2-D shapes: triangle, circle, square, rectangle (seeds 001 and 002)."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Annotated, Literal, NamedTuple

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
#: Pixels are decided TILE x TILE at a time first (:func:`_covered_samples`).
TILE = 8
#: A box of at most this many pixels is tested sample by sample, all of it: the tiles'
#: bookkeeping costs more than it saves there (measured crossover about 50 x 50).
SMALL_BOX_PX = 2500
#: The share of a pixel that k of its samples cover, k = 0, 1, ..., SUPERSAMPLE^2.
_SHARES = (np.arange(SUPERSAMPLE ** 2 + 1) / SUPERSAMPLE ** 2).astype(np.float32)


class _Test(NamedTuple):
    """One inequality of the shape: the sample in row i, column j of the box passes it if
    ``holds(u[i], v[j])``, ``u`` holding a term per sample row, ``v`` one per column.

    ``holds`` is one rounded operation and a comparison (``u - v >= 0``). Rounding is
    monotone, so ``holds`` never turns from false to true as ``u`` moves towards
    ``u_worst`` (``np.minimum`` or ``np.maximum``) or ``v`` towards ``v_worst``.
    """

    holds: Callable[[np.ndarray, np.ndarray], np.ndarray]
    u: np.ndarray
    v: np.ndarray
    u_worst: np.ufunc
    v_worst: np.ufunc


def _extremes(terms: np.ndarray, ss: int, worst: np.ufunc) -> tuple:
    """The worst and the best of ``terms`` (one per sample along an axis) over each pixel's
    ``ss`` samples and over each tile's ``TILE`` pixels: ``((pixel_worst, pixel_best),
    (tile_worst, tile_best))``."""
    best = np.maximum if worst is np.minimum else np.minimum
    px = [terms[i::ss] for i in range(ss)]   # (a reduce along a short axis is slow)
    px_worst, px_best = functools.reduce(worst, px), functools.reduce(best, px)
    starts = np.arange(0, len(px_worst), TILE)
    return ((px_worst, px_best),
            (worst.reduceat(px_worst, starts), best.reduceat(px_best, starts)))


def _covered_samples(tests: list[_Test], ss: int) -> np.ndarray:
    """How many of each pixel's ``ss`` x ``ss`` sub-pixel samples pass every test (uint8).

    All samples of a block pass a test exactly when the block's worst ``u`` with its worst
    ``v`` passes, and none does exactly when its best pair fails (:class:`_Test`: ``holds``
    is monotone). Each pair is one sample's own, so that is the very comparison the sample
    makes, and no tolerance is needed. Tiles of ``TILE`` x ``TILE`` pixels are decided so,
    then the pixels of the tiles the outline crosses, and only the pixels it crosses are
    counted sample by sample: the work goes with the perimeter rather than with the area,
    and every count is the one testing all samples gives.
    """
    rows, cols = len(tests[0].u) // ss, len(tests[0].v) // ss
    if rows * cols <= SMALL_BOX_PX:
        inside = np.ones((rows * ss, cols * ss), bool)
        for test in tests:
            inside &= test.holds(test.u[:, None], test.v[None, :])
        by_rows = sum(inside[i::ss].view(np.uint8) for i in range(ss))
        return sum(by_rows[:, i::ss] for i in range(ss))
    extremes = [(_extremes(test.u, ss, test.u_worst), _extremes(test.v, ss, test.v_worst))
                for test in tests]

    def decide(level, ri, ci):
        """(all samples pass, none passes) for the pixels (level 0) or tiles (1) at
        rows ``ri``, columns ``ci``."""
        full, empty = True, False
        for test, (u_ext, v_ext) in zip(tests, extremes, strict=True):
            (u_worst, u_best), (v_worst, v_best) = u_ext[level], v_ext[level]
            full = full & test.holds(u_worst[ri], v_worst[ci])
            empty = empty | ~test.holds(u_best[ri], v_best[ci])
        return full, empty

    t = TILE
    full, empty = decide(1, np.arange(-(-rows // t))[:, None], np.arange(-(-cols // t)))
    count = np.where(full, np.uint8(ss * ss), np.uint8(0))
    count = count.repeat(t, axis=0)[:rows].repeat(t, axis=1)[:, :cols]
    # The pixels of the crossed tiles (a tile past the box's edge repeats its last pixel).
    ti, tj = np.nonzero(~(full | empty))
    pr = np.minimum(ti[:, None] * t + np.arange(t), rows - 1)[:, :, None]
    pc = np.minimum(tj[:, None] * t + np.arange(t), cols - 1)[:, None, :]
    full, empty = decide(0, pr, pc)
    tile_count = np.where(full, np.uint8(ss * ss), np.uint8(0))
    # The crossed pixels' samples, the pixels along the last axis (summing over the
    # first two adds whole rows, which is fast).
    k, a, b = np.nonzero(~(full | empty))
    sr = (pr[k, a, 0] * ss + np.arange(ss)[:, None])[:, None, :]
    sc = (pc[k, 0, b] * ss + np.arange(ss)[:, None])[None, :, :]
    inside = np.ones((ss, ss, len(k)), bool)
    for test in tests:
        inside &= test.holds(test.u[sr], test.v[sc])
    tile_count[k, a, b] = inside.reshape(ss * ss, -1).sum(axis=0, dtype=np.uint8)
    count[pr, pc] = tile_count
    return count


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
    # within the shape's bounding box. Only the pixels on the outline need all 16 tests
    # (_covered_samples); the others are decided whole, with the same result.
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
    count = np.zeros((y1 - y0, x1 - x0), np.uint8)   # of each pixel's ss * ss samples
    if x1 > x0 and y1 > y0:
        x = (np.arange(x0 * ss, x1 * ss) + 0.5) / ss
        y = (np.arange(y0 * ss, y1 * ss) + 0.5) / ss
        if poly is None:
            # In the disc, (x - cx)^2 + (y - cy)^2 <= r^2: the farther, the worse.
            tests = [_Test(lambda u, v: v + u <= r * r, (y - cy) ** 2, (x - cx) ** 2,
                           np.maximum, np.maximum)]
        else:
            # Convex, listed clockwise on screen: inside every edge's half-plane,
            # (bx - ax)(y - ay) - (by - ay)(x - ax) >= 0: the smaller the first term
            # and the larger the second, the worse.
            tests = [_Test(lambda u, v: u - v >= 0, (bx - ax) * (y - ay),
                           (by - ay) * (x - ax), np.minimum, np.maximum)
                     for (ax, ay), (bx, by) in zip(poly, np.roll(poly, -1, axis=0),
                                                   strict=True)]
        count = _covered_samples(tests, ss)
    # A pixel's share is one of ss^2 + 1 values, count / ss^2: the gray level of each is
    # worked out once and looked up per pixel (the same float32 numbers as pixel by pixel).
    level = p.background + (p.foreground - p.background) * _SHARES
    if p.noise_sd > 0:
        clean = np.full((p.height, p.width), level[0])
        clean[y0:y1, x0:x1] = level.take(count)
        img = np.random.default_rng(p.seed).normal(0, p.noise_sd, clean.shape)
        img += clean        # in place, the same float64 sums as clean + noise
        return np.clip(np.round(img, out=img), 0, 255, out=img).astype(np.uint8)
    gray = np.clip(np.round(level), 0, 255).astype(np.uint8)
    img = np.full((p.height, p.width), gray[0])
    img[y0:y1, x0:x1] = gray.take(count)
    return img
