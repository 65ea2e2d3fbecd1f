"""A drawn line, such as the whirlpool, as an ordered open path on pins plus phantom points.

Seed 002 §4 plays a whirlpool (Fig. 10) on the 5x5 pins, without and with
phantom points, by apparent movement along it: the participant counts its
turns. Fig. 10 is a chart of the path; the paper does not say how it was
made from an image. :func:`spiral_path` makes it from a picture of a line:

1. the image is reduced to about ``work_px`` pixels along its longer side
   (area average, as the snake pipeline does);
2. the line is segmented by Otsu's threshold (the side not touching the
   image border) and thinned to one pixel (Zhang-Suen, ``cv2.ximgproc``);
3. its largest 8-connected piece is ordered end to end along the longest
   shortest path through it (two Dijkstra passes over the pixel graph, steps
   of 1 or √2), which drops the short spurs that thinning leaves;
4. the direction is chosen: ``inward`` (default) starts at the end farther
   from the centre of the line's bounding box — the outer end of a spiral —
   and runs to the centre, ``outward`` the reverse. Seed 002 does not say
   which way its whirlpool ran; inward is the sense of a whirlpool;
5. the path is fitted into the array keeping its aspect ratio and mapped onto
   the virtual grid (:mod:`vtexp.encoding.phantom_grid`, ``closed=False``).

Where turns of the line come closer than the grid step, grid points are met
twice; the later visit is dropped if the path stays connected without it
and the Pattern's ``params["warnings"]`` says how many. On the 9x9 grid of
5x5 pins an Archimedean whirlpool keeps its turns apart up to about two
turns (tests/test_pulses.py measures the winding of the mapped path).
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import Field

from .._cv2 import cv2
from ..model import Model, Pattern
from .segment import given_mask, object_mask
from .snake import SnakeResult, _as_gray, outline_pattern, working_image, working_mask


class SpiralPathParams(Model):
    """Parameters of :func:`spiral_path` (the keys an experiment may declare)."""

    direction: Literal["inward", "outward"] = Field(
        "inward", description="inward: from the outer end to the centre")
    work_px: Annotated[int, Field(ge=32, le=4096)] = Field(
        320, description="longer side of the working image, pixels")
    blur_sigma: Annotated[float, Field(ge=0, le=10)] = Field(
        0.7, description="Gaussian smoothing before the threshold, working pixels")
    min_pixels: Annotated[int, Field(ge=2)] = Field(
        10, description="fewest skeleton pixels that count as a line")
    subdivisions: Annotated[int, Field(ge=1, le=4)] = Field(
        2, description="grid points per pin pitch: 2 = pins + phantom points, 1 = pins only")
    margin: Annotated[float, Field(ge=0)] = Field(0.0, description="pins left free per side")


def line_skeleton_path(gray: np.ndarray, *, work_px: int = 320, blur_sigma: float = 0.7,
                       min_pixels: int = 10, mask: np.ndarray | None = None
                       ) -> tuple[np.ndarray, int]:
    """The longest path through the thinned line, (row, col) working pixels, and the
    working-resolution factor; an empty array if there is no line. ``mask`` (uint8
    0/1, the image's size; a figure mask) is the line instead of Otsu's threshold."""
    # Here: SciPy's sparse graphs take a third of a second to import, for this alone.
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    cv = cv2()
    work, f = working_image(gray, work_px)
    if mask is not None:
        mask = working_mask(mask, f) * np.uint8(255)
    else:
        if blur_sigma > 0:
            work = cv.GaussianBlur(work, (0, 0), blur_sigma)
        if int(work.max()) - int(work.min()) < 2:
            return np.zeros((0, 2), np.int64), f
        mask = object_mask(work) * np.uint8(255)
    skel = cv.ximgproc.thinning(mask)
    n_lab, labels, stats, _ = cv.connectedComponentsWithStats((skel > 0).astype(np.uint8),
                                                              connectivity=8)
    if n_lab < 2:
        return np.zeros((0, 2), np.int64), f
    best = 1 + int(np.argmax(stats[1:, cv.CC_STAT_AREA]))
    if stats[best, cv.CC_STAT_AREA] < min_pixels:
        return np.zeros((0, 2), np.int64), f
    rc = np.argwhere(labels == best)
    index = -np.ones(labels.shape, np.int64)
    index[rc[:, 0], rc[:, 1]] = np.arange(len(rc))
    src, dst, wts = [], [], []
    h, w = labels.shape
    for dr, dc in ((0, 1), (1, -1), (1, 0), (1, 1)):
        r2, c2 = rc[:, 0] + dr, rc[:, 1] + dc
        ok = (r2 >= 0) & (r2 < h) & (c2 >= 0) & (c2 < w)
        j = np.full(len(rc), -1)
        j[ok] = index[r2[ok], c2[ok]]
        sel = j >= 0
        src.append(np.nonzero(sel)[0])
        dst.append(j[sel])
        wts.append(np.full(int(sel.sum()), np.hypot(dr, dc)))
    s, d, wt = np.concatenate(src), np.concatenate(dst), np.concatenate(wts)
    graph = coo_matrix((wt, (s, d)), shape=(len(rc), len(rc))).tocsr()
    dist = dijkstra(graph, directed=False, indices=0)
    a = int(np.argmax(np.where(np.isfinite(dist), dist, -1)))
    dist, pred = dijkstra(graph, directed=False, indices=a, return_predecessors=True)
    b = int(np.argmax(np.where(np.isfinite(dist), dist, -1)))
    order = [b]
    while order[-1] != a:
        order.append(int(pred[order[-1]]))
    return rc[np.array(order[::-1])], f


def spiral_path(gray: np.ndarray, rows: int, cols: int, *, mask: np.ndarray | None = None,
                **params) -> Pattern:
    """Image of a line (the whirlpool) -> ordered open path on pins plus phantom points.

    See the module docstring for the steps. One open path (``line`` 0,
    ``closed == []``), ``order`` counting from its start. An image without a
    line gives an empty Pattern and a ``UserWarning``. ``mask`` (uint8 0/1 of the
    image's height x width, :mod:`vtexp.encoding.figure`) is the line if given,
    instead of step 2's threshold; an all-zero mask gives an empty Pattern.

    Examples
    --------
    >>> from vtexp.stimuli.spiral import render_whirlpool
    >>> pat = spiral_path(render_whirlpool(turns=1.5), 5, 5)
    >>> pat.closed, pat.points[0].order
    ([], 0)
    """
    p = SpiralPathParams(**params)
    img = _as_gray(gray, "spiral-path")
    if mask is not None:
        mask = given_mask(mask, img.shape, "spiral-path")
    path, f = line_skeleton_path(img, work_px=p.work_px, blur_sigma=p.blur_sigma,
                                 min_pixels=p.min_pixels, mask=mask)
    if len(path) == 0:
        what = "the figure mask is empty" if mask is not None else "the image is uniform"
        res = SnakeResult(np.zeros((0, 2)), np.zeros(0, bool), f, 0,
                          [(f"no line found: {what} or the line is shorter "
                            f"than {p.min_pixels} pixels")])
    else:
        full = path * float(f) + (f - 1) / 2.0
        centre = (full.min(axis=0) + full.max(axis=0)) / 2.0
        d0 = float(np.hypot(*(full[0] - centre)))
        d1 = float(np.hypot(*(full[-1] - centre)))
        starts_outside = d0 >= d1
        if starts_outside != (p.direction == "inward"):
            full = full[::-1]
        res = SnakeResult(full, np.zeros(len(full), bool), f, 0)
    return outline_pattern(res, rows, cols, subdivisions=p.subdivisions, margin=p.margin,
                           closed=False, pipeline="spiral-path", params=p.model_dump())
