"""Edge trace: an object's outline as an ordered loop of actuators (seed 001, §3).

This module holds the contour-following algorithm of seed 001 §3.2 in full,
and a first mapping from the image to the array: Otsu segmentation of the
object, its bounding box fitted into the array keeping the aspect ratio, the
cells the object covers, and their outer boundary. (The paper's Sobel,
thinning and pyramid chain replaces the mapping in a later revision.)
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
from pydantic import Field

from .._cv2 import cv2
from ..model import Model, Pattern, PatternPoint

# Chain code of seed 001 Fig. 5: 0 = east, numbered clockwise (rows grow downwards).
DIRECTIONS = ((0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1), (-1, 0), (-1, 1))


class EdgeTraceParams(Model):
    fill_threshold: Annotated[float, Field(gt=0, le=1)] = Field(
        0.5, description="share of a cell the object must cover for the cell to count")
    margin_cells: Annotated[float, Field(ge=0)] = Field(
        0.0, description="empty cells kept around the object's bounding box")


def object_mask(gray: np.ndarray) -> np.ndarray:
    """Foreground mask by Otsu's threshold; the object is the side not touching the border."""
    cv = cv2()
    _, mask = cv.threshold(gray, 0, 1, cv.THRESH_BINARY + cv.THRESH_OTSU)
    border = np.concatenate([mask[0], mask[-1], mask[:, 0], mask[:, -1]])
    if border.mean() > 0.5:
        mask = 1 - mask
    return mask.astype(np.uint8)


def cells_covered(mask: np.ndarray, rows: int, cols: int, *, fill_threshold: float = 0.5,
                  margin_cells: float = 0.0) -> np.ndarray:
    """Boolean ``rows x cols`` map of the cells the object covers.

    The object's bounding box (plus ``margin_cells``) is scaled by one factor in
    both directions so that it fits the array, keeping the aspect ratio (the
    rule of seed 000 eq. 11, applied to the object), and centred.
    """
    cv = cv2()
    ys, xs = np.nonzero(mask)
    if ys.size == 0:
        return np.zeros((rows, cols), dtype=bool)
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    bh, bw = y1 - y0, x1 - x0
    px_per_cell = max(bw / max(cols - 2 * margin_cells, 1e-9),
                      bh / max(rows - 2 * margin_cells, 1e-9))
    # Canvas of exactly rows x cols cells, the box in its middle.
    ch, cw = int(round(rows * px_per_cell)), int(round(cols * px_per_cell))
    canvas = np.zeros((max(ch, 1), max(cw, 1)), dtype=np.float32)
    oy, ox = (canvas.shape[0] - bh) // 2, (canvas.shape[1] - bw) // 2
    canvas[oy:oy + bh, ox:ox + bw] = mask[y0:y1, x0:x1]
    cover = cv.resize(canvas, (cols, rows), interpolation=cv.INTER_AREA)
    return cover >= fill_threshold


def boundary(cells: np.ndarray) -> np.ndarray:
    """Cells of ``cells`` with a 4-neighbour outside the object (the outline)."""
    pad = np.pad(cells, 1, constant_values=False)
    inner = pad[1:-1, 1:-1] & pad[:-2, 1:-1] & pad[2:, 1:-1] & pad[1:-1, :-2] & pad[1:-1, 2:]
    return cells & ~inner


def follow_contour(cells: np.ndarray) -> list[tuple[list[tuple[int, int]], list[bool], bool]]:
    """Order the non-zero cells of a binary array into loops or paths (seed 001 §3.2).

    The head of each list is the first non-zero cell in raster order (left to
    right, top to bottom); it is a vertex. From each cell the 8-neighbourhood
    is searched clockwise around the direction inherited from the previous step
    (direction 0, east, for the head). The search begins one step (45 degrees)
    counter-clockwise of the inherited direction: on an outline drawn in cells,
    a diagonal edge is a staircase of alternating left and right turns, and a
    search that began exactly at the inherited direction would find a left
    turn last, after cutting into the shape (docs/decisions.md). Each cell
    appended to the list is removed from the array, so no cell is visited
    twice. A cell where the chain code changes is a vertex. When no neighbour
    remains, the list ends; cells left over start the next list.

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
        while True:
            for k in range(8):
                nd = (d + 7 + k) % 8        # from d-1, clockwise
                dr, dc = DIRECTIONS[nd]
                nr, nc = r + dr, c + dc
                if 0 <= nr < rows and 0 <= nc < cols and grid[nr, nc]:
                    break
            else:
                break
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


def edge_trace(gray: np.ndarray, rows: int, cols: int, *, fill_threshold: float = 0.5,
               margin_cells: float = 0.0) -> Pattern:
    """Image -> ordered outline on a ``rows x cols`` array (seed 001 §3).

    Examples
    --------
    >>> from vtexp.stimuli import render_shape
    >>> pat = edge_trace(render_shape(shape="square"), 8, 6)
    >>> len(pat.closed)
    1
    """
    mask = object_mask(np.asarray(gray))
    outline = boundary(cells_covered(mask, rows, cols, fill_threshold=fill_threshold,
                                     margin_cells=margin_cells))
    points: list[PatternPoint] = []
    closed: list[int] = []
    order = 0
    for line, (path, vertex, is_closed) in enumerate(follow_contour(outline)):
        if is_closed:
            closed.append(line)
        for (r, c), v in zip(path, vertex):
            points.append(PatternPoint(row=r, col=c, line=line, order=order, vertex=v))
            order += 1
    return Pattern(rows=rows, cols=cols, points=points, closed=closed, pipeline="edge-trace",
                   params={"fill_threshold": fill_threshold, "margin_cells": margin_cells})
