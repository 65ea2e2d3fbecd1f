"""The virtual grid of pins plus phantom points, and curves mapped onto it (seed 002, §3.2).

Seed 002 drives 25 pins (5x5) and, by phantom sensation, makes 81 points felt
(9x9, Fig. 9): between two neighbouring pins a point is felt where both are
driven together, and in the middle of four pins where all four are. In pin
units (``row``/``col`` of :class:`vtexp.model.PatternPoint`) the virtual grid is
every multiple of ``1 / subdivisions``: ``subdivisions=2`` gives the paper's
9x9 grid on 5x5 pins, ``subdivisions=1`` the pins alone (the paper's
"without phantom sensation" condition, Fig. 8).

How a curve becomes grid points (decisions):

1. **Fit.** The curve's bounding box is scaled by one factor in both directions
   so that it spans the pins from the first to the last row or column, keeping
   its aspect ratio, and centred (the rule of seed 000 eq. 11, applied to the
   object as the edge trace of seed 001 does). A curve runs *through* pins, so
   the box spans pin centres ``0 .. rows-1``, not cell areas.
2. **Sample.** The curve is sampled at a quarter of the grid step, so that no
   grid point it passes is skipped, and every sample goes to its nearest grid
   point.
3. **Deduplicate, keep order.** Repeats of the same grid point in a row are
   merged. A point whose predecessor and successor are already 8-neighbours on
   the grid is a staircase step and is dropped (a diagonal move is felt as
   one step), unless it is a corner. A grid point met again later (turns of a
   curve closer than the grid step) is kept where it was first met and dropped
   later; the number dropped is reported.
4. **Loop order.** A closed loop runs clockwise as the participant feels it
   (east along the top edge first) and starts at its first point in raster
   order, as the contour following of seed 001 §3.2 does. An open path keeps
   the direction it was given.
"""

from __future__ import annotations

import numpy as np


def fit_to_array(points: np.ndarray, rows: int, cols: int, *, margin: float = 0.0
                 ) -> np.ndarray:
    """Scale and centre image points ``(row, col)`` into pin coordinates.

    The bounding box of ``points`` is scaled by one factor so that it spans
    ``rows - 1 - 2*margin`` pins vertically or ``cols - 1 - 2*margin``
    horizontally, whichever is reached first (aspect ratio kept), and centred
    on the array.

    Parameters
    ----------
    points : (n, 2) array
        Image coordinates, row then column, in pixels.
    rows, cols : int
        Pins of the physical array.
    margin : float
        Pins left free on each side.

    Returns
    -------
    (n, 2) float array
        Positions in pin units, ``0 <= row <= rows-1``, ``0 <= col <= cols-1``.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    centre = np.array([(rows - 1) / 2.0, (cols - 1) / 2.0])
    if pts.size == 0:
        return pts.copy()
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    span = hi - lo
    avail = np.maximum(np.array([rows - 1, cols - 1], dtype=np.float64) - 2 * margin, 0.0)
    scales = [avail[k] / span[k] for k in (0, 1) if span[k] > 1e-12]
    scale = min(scales) if scales else 0.0
    out = (pts - (lo + hi) / 2.0) * scale + centre
    return np.minimum(np.maximum(out, 0.0), [rows - 1, cols - 1])


def _densify(pts: np.ndarray, closed: bool, max_step: float) -> tuple[np.ndarray, np.ndarray]:
    """Points along the polyline at most ``max_step`` apart; returns (samples, index of
    each original vertex among the samples)."""
    starts = pts if closed else pts[:-1]
    seg = (np.roll(pts, -1, axis=0) if closed else pts[1:]) - starts
    n_sub = np.maximum(1, np.ceil(np.hypot(seg[:, 0], seg[:, 1]) / max_step)).astype(np.int64)
    vertex_at = np.concatenate([[0], np.cumsum(n_sub)[:-1]])
    owner = np.repeat(np.arange(len(starts)), n_sub)
    t = (np.arange(int(n_sub.sum())) - vertex_at[owner]) / n_sub[owner]
    dense = starts[owner] + seg[owner] * t[:, None]
    if not closed:
        dense = np.vstack([dense, pts[-1:]])
        vertex_at = np.append(vertex_at, len(dense) - 1)
    return dense, vertex_at


def grid_path(points: np.ndarray, corner: np.ndarray | None, rows: int, cols: int, *,
              closed: bool, subdivisions: int = 2) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Map a curve given in pin units onto the virtual grid (module docstring, steps 2-4).

    Parameters
    ----------
    points : (n, 2) array
        The curve in pin units (``fit_to_array`` output), in order.
    corner : (n,) bool array or None
        Which curve points are corners; their grid points are flagged and never
        dropped as staircase steps.
    rows, cols : int
        Pins of the physical array.
    closed : bool
        Whether the curve is a loop.
    subdivisions : int
        Grid points per pin pitch (2: one phantom point between pins, seed 002
        Fig. 9; 1: pins only, Fig. 8).

    Returns
    -------
    grid : (m, 2) float array
        Grid positions in pin units, in order.
    corner_flags : (m,) bool array
    dropped : int
        Later visits of a grid point dropped (the path stays 8-connected without them).
    repeated : int
        Later visits kept because dropping them would break the path (a spike
        narrower than the grid step, such as a sharp apex, is felt out and back).
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(pts) == 0:
        return np.zeros((0, 2)), np.zeros(0, bool), 0, 0
    corner = np.zeros(len(pts), bool) if corner is None else np.asarray(corner, bool)
    sub = int(subdivisions)
    lim = np.array([(rows - 1) * sub, (cols - 1) * sub])
    # floor(x + 0.5), not rint: rint rounds halves to even and folds the two sides of
    # a symmetric apex onto one grid point.
    if len(pts) == 1:
        q = np.clip(np.floor(pts * sub + 0.5), 0, lim).astype(np.int64)
        return q / sub, corner.copy(), 0, 0
    dense, vertex_at = _densify(pts, closed, 0.25 / sub)
    q = np.clip(np.floor(dense * sub + 0.5), 0, lim).astype(np.int64)
    is_corner = set(map(tuple, q[vertex_at[corner]].tolist()))
    step = np.ones(len(q), bool)
    step[1:] = np.any(q[1:] != q[:-1], axis=1)
    path = list(map(tuple, q[step].tolist()))
    path = _drop_staircase(_merge_repeats(path, closed), closed, is_corner)
    path, dropped, repeated = _drop_revisits(path, closed)
    if dropped:
        path = _drop_staircase(path, closed, is_corner)
    if closed and len(path) >= 3:
        # Shoelace sum in (x = col, y = row): positive is clockwise on screen (rows grow
        # downwards).
        area2 = sum(a[1] * b[0] - b[1] * a[0] for a, b in zip(path, path[1:] + path[:1]))
        if area2 < 0:
            path.reverse()
        head = path.index(min(path))          # first in raster order: least row, then col
        path = path[head:] + path[:head]
    flags = np.array([c in is_corner for c in path], dtype=bool)
    return np.array(path, dtype=np.float64).reshape(-1, 2) / sub, flags, dropped, repeated


def _drop_revisits(path: list[tuple[int, int]], closed: bool
                   ) -> tuple[list[tuple[int, int]], int, int]:
    """Drop later visits of a grid point where the path stays 8-connected without them;
    if dropping the later visit would break the path, drop the earlier one if that
    does not; otherwise keep both. Returns (path, dropped, kept repeats)."""
    dropped = repeated = 0
    out: list[tuple[int, int]] = []
    n = len(path)
    for i, cell in enumerate(path):
        if cell not in out:
            out.append(cell)
            continue
        if i + 1 < n:
            nxt = path[i + 1]
        elif closed and out:
            nxt = out[0]
        else:
            nxt = None                     # the end of an open path stays
        if nxt is not None and out and _cheb(out[-1], nxt) <= 1:
            dropped += 1
            continue
        j = out.index(cell)
        if 0 < j < len(out) - 1 and _cheb(out[j - 1], out[j + 1]) <= 1:
            del out[j]
            dropped += 1
        else:
            repeated += 1
        out.append(cell)
    return _merge_repeats(out, closed), dropped, repeated

def _cheb(a: tuple[int, int], b: tuple[int, int]) -> int:
    return max(abs(a[0] - b[0]), abs(a[1] - b[1]))


def _merge_repeats(path: list[tuple[int, int]], closed: bool) -> list[tuple[int, int]]:
    out: list[tuple[int, int]] = []
    for c in path:
        if not out or out[-1] != c:
            out.append(c)
    while closed and len(out) > 1 and out[0] == out[-1]:
        out.pop()
    return out


def _drop_staircase(path: list[tuple[int, int]], closed: bool,
                    keep: set[tuple[int, int]]) -> list[tuple[int, int]]:
    """Drop points whose neighbours on the path are 8-neighbours already (never a
    point in ``keep``, never an end of an open path), until none is left."""
    changed = True
    while changed and len(path) > 3:
        changed = False
        out = [path[0]]
        n = len(path)
        for i in range(1, n):
            b = path[i]
            if i + 1 < n:
                c = path[i + 1]
            elif closed:
                c = out[0]
            else:
                out.append(b)
                break
            a = out[-1]
            if (abs(a[0] - c[0]) <= 1 and abs(a[1] - c[1]) <= 1 and b not in keep
                    and len(out) + (n - i - 1) >= 3):
                changed = True
                continue
            out.append(b)
        if closed and len(out) > 3 and out[0] not in keep and _cheb(out[-1], out[1]) <= 1:
            out.pop(0)
            changed = True
        path = _merge_repeats(out, closed)
    return path
