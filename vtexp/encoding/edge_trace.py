"""Edge trace: an object's outline as an ordered loop of actuators (seed 001, §3).

Seed 001 §3.1 finds the object's edges with the Sobel operator, binarises
them with Otsu's threshold, thins them to one pixel and resamples the result
to the 6 x 8 tactor array with a pyramid; §3.2 then orders the array's edge
cells by contour following with chain codes. This module implements each step:

- :func:`fit_to_array` — the pyramid: the object's bounding box, scaled by one
  factor (aspect ratio kept, seed 000 eq. 11's rule) into a canvas of
  ``cells_per_motor`` pixels per actuator, by Gaussian pyramid levels
  (``cv2.pyrDown``) and a final area resampling.
- :func:`sobel_edges` — Sobel magnitude, Otsu's threshold, Zhang-Suen thinning
  (``cv2.ximgproc.thinning``).
- four ways from the image to the array's edge cells (``mode``):

  ``region`` (default): Otsu's threshold on the intensities gives the object,
  its bounding box is scaled into the array (aspect ratio kept) by area
  averaging, a cell is on if the object covers at least ``fill_threshold``
  of it, and the outline is the on-cells with a 4-neighbour off.
  ``outline``: the paper's Sobel-Otsu-thinning edges (at the pyramid level
  where the object spans about ``cells_per_motor`` pixels per cell), the
  region they enclose filled, then the same coverage rule. ``edges``: the
  paper's direct route, a cell is on if at least ``edge_fraction`` x
  ``cells_per_motor`` thinned edge pixels cross it, then staircase corners are
  pruned to a one-cell line. ``skeleton``: for line drawings and letters, the
  object's thinned centre line instead of its edges.

  On the 6 x 8 vest, with the four study shapes at 18 rotations and 3 sizes,
  ``region`` gives one closed loop in 213 of 216 cases, ``outline`` in 145
  (an edge cut by the image border does not enclose a region) and ``edges``
  in 118 (an edge grazing a row of cells lights two rows). docs/decisions.md.
- :func:`follow_contour` — seed 001 §3.2, in full.

Where on the array (``fit``): ``object`` (default) fits the object's bounding box
into the array, so a shape fills it wherever it stands before the camera;
``frame`` fits the camera's whole frame (aspect ratio kept, centred, as seed 000
eq. 11 maps its image), so an object moving across the frame moves across the
array — what a live camera needs (``vtexp live``). With ``frame`` the mapping is
recorded in ``params["to_array"]`` (:mod:`vtexp.encoding.mapping`).

A figure mask (``mask=``, :mod:`vtexp.encoding.figure`) replaces Otsu's object:
``region`` covers the mask, ``skeleton`` thins it, and ``edges`` and ``outline``
look for edges in :func:`~vtexp.encoding.segment.flatten_background`'s image,
where the background beyond a ring of ``RING`` of the image's shorter side around
the mask has no edges left (on brick or grass the paper's Sobel-Otsu edges are
the background's); ``outline`` closes the object's edges with the mask's outline
(where the object is as bright as the background next to it, it has no edge).
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import Field

from .._cv2 import cv2
from ..model import Model, Pattern, PatternPoint
from .mapping import ImageToArray
from .segment import flatten_background, given_mask, object_mask

#: Width of the ring around a figure mask whose edges are kept, as a share of the
#: image's shorter side (a mask may be a pixel or two off the object's edge).
RING = 0.01

# Chain code of seed 001 Fig. 5: 0 = east, numbered clockwise (rows grow downwards).
DIRECTIONS = ((0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1), (-1, 0), (-1, 1))


class EdgeTraceParams(Model):
    mode: Literal["region", "outline", "edges", "skeleton"] = Field(
        "region", description="how the image becomes array cells (module docstring)")
    cells_per_motor: Annotated[int, Field(ge=2, le=64)] = Field(
        8, description="working resolution in pixels per actuator")
    fill_threshold: Annotated[float, Field(gt=0, le=1)] = Field(
        0.5, description="outline mode: share of a cell the object must cover")
    edge_fraction: Annotated[float, Field(gt=0, le=4)] = Field(
        0.5, description="edges/skeleton modes: edge pixels a cell needs, per pixel of cell width")
    margin_cells: Annotated[float, Field(ge=0, le=10)] = Field(
        0.0, description="empty cells kept around the object's bounding box")
    fit: Literal["object", "frame"] = Field(
        "object", description="fit the object's bounding box into the array, or the whole "
                              "frame (a live camera: the object moves across the array)")


def _bbox(mask: np.ndarray) -> tuple[int, int, int, int] | None:
    rows, cols = np.nonzero(mask.any(axis=1))[0], np.nonzero(mask.any(axis=0))[0]
    if rows.size == 0:
        return None
    return int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1


def fit_to_array(gray: np.ndarray, rows: int, cols: int, *, cells_per_motor: int = 8,
                 margin_cells: float = 0.0,
                 box: tuple[int, int, int, int] | None = None) -> np.ndarray | None:
    """The image resampled so that the object's bounding box fits the array.

    Returns a gray canvas of ``(rows + 2) * k x (cols + 2) * k`` pixels
    (k = ``cells_per_motor``): the array's ``rows*k x cols*k`` in the middle,
    with the object's box scaled by one factor and centred in it, and one cell
    of the surrounding image as a frame, so that edges at the array's border
    are still closed. None if no object is found. Large images are first
    reduced by Gaussian pyramid levels (seed 001 §3.1's pyramid) down to at
    most twice the needed scale. ``box`` (y0, y1, x0, x1) fits that part of the
    image instead of the object's bounding box (the whole frame, ``fit="frame"``).
    """
    cv = cv2()
    g = np.asarray(gray)
    if g.dtype != np.uint8:
        g = cv.normalize(g.astype(np.float32), None, 0, 255, cv.NORM_MINMAX).astype(np.uint8)
    if g.size == 0 or int(g.max()) == int(g.min()):
        return None
    k = cells_per_motor
    if box is not None:
        y0, y1, x0, x1 = box
    else:
        # Locate the object cheaply on a decimated copy, then cut it from the full image.
        step = max(1, min(g.shape) // 120)
        found = _bbox(object_mask(np.ascontiguousarray(g[::step, ::step])))
        if found is None:
            return None
        y0, y1, x0, x1 = found[0] * step, min(found[1] * step, g.shape[0]), \
            found[2] * step, min(found[3] * step, g.shape[1])
    # Cells the box may span, keeping the aspect ratio (eq. 11's rule applied to the object).
    bh, bw = max(y1 - y0, 1), max(x1 - x0, 1)
    px_per_cell = max(bw / max(cols - 2 * margin_cells, 1e-9),
                      bh / max(rows - 2 * margin_cells, 1e-9))
    scale = k / px_per_cell
    src = g
    while scale < 0.5 and min(src.shape) >= 4:          # Gaussian pyramid, one octave at a time
        src = cv.pyrDown(src)
        scale *= 2.0
    f = src.shape[1] / g.shape[1]                       # pyramid reduction actually applied
    cy, cx = (y0 + y1) / 2 * f, (x0 + x1) / 2 * f
    h, w = (rows + 2) * k, (cols + 2) * k
    m = np.array([[scale, 0, w / 2 - cx * scale], [0, scale, h / 2 - cy * scale]])
    interp = cv.INTER_AREA if scale < 1 else cv.INTER_LINEAR
    return cv.warpAffine(src, m, (w, h), flags=interp, borderMode=cv.BORDER_REPLICATE)


def sobel_edges(gray: np.ndarray) -> np.ndarray:
    """Sobel gradient magnitude, Otsu's threshold, thinning (seed 001 §3.1). Bool, 1 px wide."""
    cv = cv2()
    gx = cv.Sobel(gray, cv.CV_32F, 1, 0, ksize=3)
    gy = cv.Sobel(gray, cv.CV_32F, 0, 1, ksize=3)
    mag = cv.magnitude(gx, gy)
    top = float(mag.max())
    if top <= 0:
        return np.zeros(gray.shape, bool)
    m8 = (mag * (255.0 / top)).astype(np.uint8)
    _, edges = cv.threshold(m8, 0, 255, cv.THRESH_BINARY + cv.THRESH_OTSU)
    return cv.ximgproc.thinning(edges) > 0


def cells_covered(mask: np.ndarray, rows: int, cols: int, *, fill_threshold: float = 0.5,
                  margin_cells: float = 0.0, whole: bool = False) -> np.ndarray:
    """Boolean ``rows x cols`` map of the cells an object mask covers.

    With a mask of exactly ``rows*k x cols*k`` pixels the cells are its k x k
    blocks; otherwise the mask's bounding box (with ``whole``, the whole mask:
    ``fit="frame"``) is first fitted into the array (aspect ratio kept, centred).
    """
    cv = cv2()
    mask = np.asarray(mask)
    if whole or mask.shape[0] % rows or mask.shape[1] % cols or \
            mask.shape[0] // rows != mask.shape[1] // cols:
        box = (0, mask.shape[0], 0, mask.shape[1]) if whole else _bbox(mask)
        if box is None:
            return np.zeros((rows, cols), bool)
        y0, y1, x0, x1 = box
        bh, bw = y1 - y0, x1 - x0
        px_per_cell = max(bw / max(cols - 2 * margin_cells, 1e-9),
                          bh / max(rows - 2 * margin_cells, 1e-9))
        # A canvas of exactly rows x cols cells, the box in its middle; area averaging.
        ch, cw = int(round(rows * px_per_cell)), int(round(cols * px_per_cell))
        canvas = np.zeros((max(ch, bh), max(cw, bw)), dtype=np.float32)
        oy, ox = (canvas.shape[0] - bh) // 2, (canvas.shape[1] - bw) // 2
        canvas[oy:oy + bh, ox:ox + bw] = mask[y0:y1, x0:x1]
        mask = canvas
    cover = cv.resize(mask.astype(np.float32), (cols, rows), interpolation=cv.INTER_AREA)
    return cover >= fill_threshold


def boundary(cells: np.ndarray) -> np.ndarray:
    """Cells of ``cells`` with a 4-neighbour outside the object (the outline)."""
    pad = np.pad(cells, 1, constant_values=False)
    inner = pad[1:-1, 1:-1] & pad[:-2, 1:-1] & pad[2:, 1:-1] & pad[1:-1, :-2] & pad[1:-1, 2:]
    return cells & ~inner


def prune_corners(cells: np.ndarray) -> np.ndarray:
    """Remove staircase corners so a line of cells is one cell wide (8-connected).

    A cell with exactly two on-neighbours that are its 4-neighbours at a right
    angle (north and east, ...) is redundant: those two are diagonal neighbours
    of each other. Cells are visited in raster order and removed one at a time.
    """
    g = np.array(cells, bool, copy=True)
    rows, cols = g.shape

    def on(r, c):
        return 0 <= r < rows and 0 <= c < cols and g[r, c]
    changed = True
    while changed:
        changed = False
        for r, c in zip(*np.nonzero(g), strict=True):
            n8 = sum(on(r + dr, c + dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if dr or dc)
            if n8 != 2:
                continue
            for (a, b), (d, e) in (((-1, 0), (0, 1)), ((0, 1), (1, 0)), ((1, 0), (0, -1)),
                                   ((0, -1), (-1, 0))):
                if on(r + a, c + b) and on(r + d, c + e):
                    g[r, c] = False
                    changed = True
                    break
    return g


def follow_contour(cells: np.ndarray) -> list[tuple[list[tuple[int, int]], list[bool], bool]]:
    """Order the non-zero cells of a binary array into loops or paths (seed 001 §3.2).

    The head of each list is the first non-zero cell in raster order (left to
    right, top to bottom); it is a vertex. From each cell the 8-neighbourhood
    is searched clockwise around the direction inherited from the previous step
    (direction 0, east, for the head). The search begins one step (45 degrees)
    counter-clockwise of the inherited direction: on an outline drawn in cells,
    a diagonal edge is a staircase of alternating left and right turns, and a
    search that began exactly at the inherited direction would find a left
    turn last, after cutting into the shape (docs/decisions.md). A neighbour
    that is a dead end (no way on from it, and not next to the head) is taken
    only when there is no other: at a sharp corner drawn in cells a one-cell
    spur would otherwise end the loop early; the spur becomes a list of its
    own. Each cell appended to the list is removed from the array, so no cell
    is visited twice. A cell where the chain code changes is a vertex. When no
    neighbour remains, the list ends; cells left over start the next list.

    Returns
    -------
    list of (cells, vertex flags, closed)
        One entry per loop or open path, cells as (row, col) in order.
    """
    grid = np.array(cells, dtype=bool, copy=True)
    rows, cols = grid.shape
    out = []
    while grid.any():
        r, c = map(int, np.argwhere(grid)[0])          # raster order: first non-zero
        path, codes = [(r, c)], []
        grid[r, c] = False
        d = 0
        head = (r, c)

        def unvisited(rr: int, cc: int) -> bool:
            return 0 <= rr < rows and 0 <= cc < cols and bool(grid[rr, cc])

        def dead_end(rr: int, cc: int) -> bool:
            # No way on from (rr, cc) except back, and not next to the head (no closing).
            if len(path) >= 2 and max(abs(rr - head[0]), abs(cc - head[1])) == 1:
                return False
            return not any(unvisited(rr + a, cc + b) and (rr + a, cc + b) != (r, c)
                           for a, b in DIRECTIONS)
        while True:
            found = None
            for k in range(8):
                nd = (d + 7 + k) % 8        # from d-1, clockwise
                dr, dc = DIRECTIONS[nd]
                if unvisited(r + dr, c + dc):
                    if found is None:
                        found = (r + dr, c + dc, nd)
                    if not dead_end(r + dr, c + dc):
                        found = (r + dr, c + dc, nd)
                        break
            if found is None:
                break
            nr, nc, nd = found
            grid[nr, nc] = False
            path.append((nr, nc))
            codes.append(nd)
            r, c, d = nr, nc, nd
        head, tail = path[0], path[-1]
        closed = len(path) >= 3 and max(abs(head[0] - tail[0]), abs(head[1] - tail[1])) == 1
        if closed:
            # The closing step from tail back to head has a chain code too.
            back = DIRECTIONS.index((head[0] - tail[0], head[1] - tail[1]))
            codes.append(back)
        vertex = [True] * len(path)
        for i in range(1, len(path)):
            incoming = codes[i - 1]
            outgoing = codes[i] if i < len(codes) else None
            vertex[i] = outgoing is not None and outgoing != incoming
        if not closed:
            vertex[-1] = True                          # an open path's end is a vertex
        out.append((path, vertex, closed))
    return out


def edge_cells(gray: np.ndarray, rows: int, cols: int, *, mode: str = "region",
               cells_per_motor: int = 8, fill_threshold: float = 0.5,
               edge_fraction: float = 0.5, margin_cells: float = 0.0,
               fit: str = "object", mask: np.ndarray | None = None) -> np.ndarray:
    """The array's edge cells (bool ``rows x cols``) for ``mode`` and ``fit`` (module
    docstring); ``mask`` is the object (uint8 0/1 of the image's size) if given."""
    cv = cv2()
    k = cells_per_motor
    whole = fit == "frame"
    g = np.asarray(gray)
    box = (0, g.shape[0], 0, g.shape[1]) if whole else None
    if mask is not None:
        mask = given_mask(mask, g.shape, "edge-trace")
        if not mask.any():
            return np.zeros((rows, cols), bool)
        box = box or _bbox(mask)
        if mode in ("edges", "outline"):
            g = flatten_background(g, mask, RING * min(g.shape[:2]))
    if mode == "region":
        # Area coverage of the Otsu object mask, computed from the full-resolution image.
        return boundary(cells_covered(object_mask(g) if mask is None else mask, rows, cols,
                                      fill_threshold=fill_threshold, margin_cells=margin_cells,
                                      whole=whole))
    canvas = fit_to_array(g, rows, cols, cells_per_motor=k, margin_cells=margin_cells, box=box)
    if canvas is None:
        return np.zeros((rows, cols), bool)
    inner = (slice(k, -k), slice(k, -k))               # the array, without the frame
    if mode == "outline":
        # Edges at pyramid level where the object spans about k px per cell, region
        # enclosed by the outer edge contours, then area coverage as in 'region'.
        src = g
        if src.dtype != np.uint8:
            src = cv.normalize(src.astype(np.float32), None, 0, 255,
                               cv.NORM_MINMAX).astype(np.uint8)
        target = k * max(rows, cols) * 2
        while min(src.shape) >= 2 * target and min(src.shape) >= 8:
            src = cv.pyrDown(src)
        edges = sobel_edges(src).astype(np.uint8)
        if mask is not None:
            # The figure's outline closes the gaps where the object's edge is faint
            # against the background next to it.
            level = cv.resize(mask, (src.shape[1], src.shape[0]), interpolation=cv.INTER_AREA)
            outer, _ = cv.findContours(level, cv.RETR_EXTERNAL, cv.CHAIN_APPROX_NONE)
            cv.drawContours(edges, outer, -1, 1, thickness=1)
        contours, _ = cv.findContours(edges, cv.RETR_EXTERNAL, cv.CHAIN_APPROX_NONE)
        filled = np.zeros_like(edges)
        cv.drawContours(filled, contours, -1, 1, thickness=cv.FILLED)
        return boundary(cells_covered(filled, rows, cols, fill_threshold=fill_threshold,
                                      margin_cells=margin_cells, whole=whole))
    if mode == "edges":
        line = sobel_edges(canvas)[inner]
    elif mode == "skeleton":
        obj = object_mask(canvas) if mask is None else _mask_canvas(mask, rows, cols, k,
                                                                    margin_cells, box)
        line = (cv.ximgproc.thinning(obj * np.uint8(255)) > 0)[inner]
    else:
        raise ValueError(f"unknown edge-trace mode {mode!r}")
    counts = line.reshape(rows, k, cols, k).sum(axis=(1, 3))
    return prune_corners(counts >= edge_fraction * k)


def _mask_canvas(mask: np.ndarray, rows: int, cols: int, k: int, margin_cells: float,
                 box: tuple[int, int, int, int]) -> np.ndarray:
    """A figure mask on :func:`fit_to_array`'s canvas (uint8 0/1), as the image is."""
    canvas = fit_to_array(mask * np.uint8(255), rows, cols, cells_per_motor=k,
                          margin_cells=margin_cells, box=box)
    if canvas is None:          # the mask fills the whole image: one value everywhere
        return np.ones(((rows + 2) * k, (cols + 2) * k), np.uint8)
    return (canvas >= 128).astype(np.uint8)


def edge_trace(gray: np.ndarray, rows: int, cols: int, *, mode: str = "region",
               cells_per_motor: int = 8, fill_threshold: float = 0.5,
               edge_fraction: float = 0.5, margin_cells: float = 0.0,
               fit: str = "object", mask: np.ndarray | None = None) -> Pattern:
    """Image -> ordered outline on a ``rows x cols`` array (seed 001 §3).

    Points are numbered in activation order over all lists (loops first in the
    order contour following finds them); ``line`` is the list's index and
    ``closed`` names the lists that are loops. ``mask`` (uint8 0/1 of the image's
    height x width, :mod:`vtexp.encoding.figure`) is the object if given (module
    docstring); an all-zero mask gives an empty Pattern.

    Examples
    --------
    >>> from vtexp.stimuli import render_shape
    >>> pat = edge_trace(render_shape(shape="square"), 8, 6)
    >>> pat.closed, len(pat.points)
    ([0], 20)
    """
    cells = edge_cells(gray, rows, cols, mode=mode, cells_per_motor=cells_per_motor,
                       fill_threshold=fill_threshold, edge_fraction=edge_fraction,
                       margin_cells=margin_cells, fit=fit, mask=mask)
    points: list[PatternPoint] = []
    closed: list[int] = []
    order = 0
    for line, (path, vertex, is_closed) in enumerate(follow_contour(cells)):
        if is_closed:
            closed.append(line)
        for (r, c), v in zip(path, vertex, strict=True):
            points.append(PatternPoint(row=r, col=c, line=line, order=order, vertex=v))
            order += 1
    params = {"mode": mode, "cells_per_motor": cells_per_motor,
              "fill_threshold": fill_threshold, "edge_fraction": edge_fraction,
              "margin_cells": margin_cells}
    if fit == "frame":
        h, w = np.asarray(gray).shape[:2]
        params["fit"] = fit
        params["to_array"] = ImageToArray.fit_frame(h, w, rows, cols,
                                                    margin=margin_cells).as_params()
    return Pattern(rows=rows, cols=cols, points=points, closed=closed, pipeline="edge-trace",
                   params=params)
