"""Snake and corners: an object's outline on pins plus phantom points (seed 002, §3.1-3.2).

Seed 002 §3.1 finds the outline of an object with OpenCV's ``cvSnakeImage``,
the greedy active contour of Williams & Shah [2]_ minimising eq. 4,

    E = α Σ E_cont,i + β Σ E_curv,i + γ Σ E_img,i,

with E_cont = |d̄ − ‖p_i − p_{i−1}‖|, E_curv = ‖p_{i−1} − 2p_i + p_{i+1}‖² and
E_img = −‖∇I‖ (eqs. 2-3; E_con is not used), and lets corners found by
``cvGoodFeaturesToTrack`` (the smaller eigenvalue of the gradient matrix of
eqs. 5-6, Shi and Tomasi's criterion) "assist the active contours to capture
the most proximate shape". §3.2 maps the outline onto 5x5 pins plus the
phantom points between them (9x9).

The pipeline, :func:`snake_corners`, in order:

1. **Working resolution.** The image is reduced by an integer factor with
   area averaging to about ``work_px`` pixels along its longer side (a
   640x480 frame to 160x120): the array has 5 pins across, so a camera's
   full resolution adds cost, not information.
2. **Initial contour** from a cheap segmentation: Otsu's threshold (the object
   is the side not touching the image border), the largest outer contour,
   resampled to points ``spacing_px`` apart by arc length. It already lies
   within a pixel or two of the edge, so the snake needs few sweeps.
3. **Corners** (:func:`contour_corners`, :func:`refine_corners`): Shi-Tomasi
   corners (``cv2.goodFeaturesToTrack``: the smaller eigenvalue of the
   gradient matrix M of eq. 6 — eq. 5 as printed speaks of second
   derivatives of M, but the text and cvGoodFeaturesToTrack use M's
   eigenvalues) are kept if they lie on the contour and are corners of it
   (the smaller eigenvalue is a fair share of the larger one, which a smooth
   curve's edge never reaches), then moved to sub-pixel precision with
   ``cv2.cornerSubPix``. The nearest contour point is put on each corner and
   held there with β = 0: this is how the corners "assist" the snake.
4. **Greedy snake** (:func:`greedy_snake`), Williams & Shah's algorithm: each
   free point moves to the position in its ``window x window`` neighbourhood
   that minimises α E_cont + β_i E_curv + γ E_img, each term normalised over
   the neighbourhood as Williams & Shah do; after each sweep β_i is set to 0
   at points of high curvature on strong edges (their corner rule); it stops
   when fewer than ``stop_fraction`` of the points moved. The other points
   spread evenly between the held corners.
5. **Sub-pixel edges** (:func:`subpixel_edges`, vtexp's addition): each free
   point moves along its normal to the parabola peak of ‖∇I‖; then all
   points are scaled back to full-resolution pixels.
6. **Grid.** The outline is fitted into the array and mapped to the virtual
   grid (:mod:`vtexp.encoding.phantom_grid`): an ordered closed loop,
   clockwise, with ``corner=True`` where a corner fell. ``fit="frame"`` maps the
   camera's whole frame onto the array instead of the outline's bounding box, so
   that an object moving before the camera moves across the pins.

**Tracking** (:class:`SnakeTracker`, the live camera of ``vtexp live``). Seed 002
§3.1 values the active contour because it is "able to track the object even if
the object moves": the snake of one frame is where the next frame's snake
starts. The tracker starts each frame's greedy snake from the previous frame's
outline (resampled to ``spacing_px``) instead of Otsu's outline. The greedy
algorithm moves a point at most one pixel per sweep and stops when few points
move, so on its own a carried snake trails an object that moves a pixel or more
per frame (its sides parallel to the motion are already on an edge and do not
move). The carried outline is therefore first moved as a whole, by the whole-pixel
shift of at most ``track_px`` that minimises its image energy Σ E_img = −Σ‖∇I‖
(eq. 4's last term for the contour as one rigid body; vtexp's addition), and then
each point by Williams & Shah's algorithm. A snake that no longer lies on the object (fewer than ``lost_fraction`` of its points end on an
edge stronger than ``corner_edge``: the object moved further than the snake can
follow, or left) is started again from Otsu's outline of that frame.

Williams & Shah update points one after another, each seeing its
predecessor's new position. Here the points are updated in two interleaved
half-sweeps (even indices, then odd; a third for the last point of an odd
count), each half-sweep vectorised. A point's energy depends only on itself
and its two neighbours, which do not move during its half-sweep, so every
point makes exactly the move it would make in a sequential sweep that visits
the points in that order (a red-black ordering of the same Gauss-Seidel
sweep); only the visiting order differs from the paper's 0, 1, 2, ...

References
----------
.. [1] C. Jiang, K. Uchida, H. Sawada, "Research and development of vision based
       tactile display system using shape memory alloys", IJICIC 10(3), 2014,
       §3.1 eqs. 1-6 and §3.2 (seed 002).
.. [2] D. J. Williams, M. Shah, "A fast algorithm for active contours and
       curvature estimation", CVGIP: Image Understanding 55(1):14-26, 1992.
.. [3] J. Shi, C. Tomasi, "Good features to track", CVPR 1994.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, field_validator

from .._cv2 import cv2
from ..errors import InputError
from ..model import Model, Pattern
from .mapping import ImageToArray
from .phantom_grid import fit_to_array, grid_path
from .segment import flatten_background, given_mask, object_mask


class SnakeCornersParams(Model):
    """Parameters of :func:`snake_corners` (the keys an experiment may declare)."""

    alpha: Annotated[float, Field(ge=0)] = Field(1.0, description="weight of E_cont (eq. 4)")
    beta: Annotated[float, Field(ge=0)] = Field(1.0, description="weight of E_curv (eq. 4)")
    gamma: Annotated[float, Field(ge=0)] = Field(
        1.2, description="weight of E_img (eq. 4); 1.2 as Williams & Shah")
    window: Annotated[int, Field(ge=3, le=9)] = Field(
        3, description="side of the square neighbourhood searched per point (odd)")
    spacing_px: Annotated[float, Field(ge=2, le=32)] = Field(
        4.0, description="distance between snake points, working-resolution pixels")
    max_iterations: Annotated[int, Field(ge=1, le=10000)] = 100
    stop_fraction: Annotated[float, Field(ge=0, le=1)] = Field(
        0.2, description="stop when fewer than this share of the points moved in a sweep "
                         "(on whole pixels, points keep sliding along straight sides to "
                         "even out their spacing: about a tenth of them, sweep after sweep)")
    corner_curvature: Annotated[float, Field(ge=0, le=4)] = Field(
        0.25, description="Williams & Shah's threshold1 on ‖u_i/|u_i| − u_{i+1}/|u_{i+1}|‖²")
    corner_edge: Annotated[float, Field(ge=0)] = Field(
        10.0, description="Williams & Shah's threshold2: edge strength (grey levels per "
                          "working pixel) above which β_i may be relaxed")
    corners: bool = Field(True, description="let Shi-Tomasi corners assist the snake (§3.1)")
    corner_detector: Literal["shi-tomasi", "harris"] = "shi-tomasi"
    corner_quality: Annotated[float, Field(gt=0, le=1)] = Field(
        0.1, description="goodFeaturesToTrack qualityLevel")
    corner_isotropy: Annotated[float, Field(ge=0, le=1)] = Field(
        0.08, description="smallest λ_min/λ_max of eq. 5 at a corner (a smooth curve stays "
                          "far below)")
    corner_distance_px: Annotated[float, Field(gt=0)] = Field(
        3.0, description="how far from the contour a corner may lie, working pixels")
    max_corners: Annotated[int, Field(ge=1, le=64)] = 12
    corner_block_px: Annotated[int, Field(ge=3, le=15)] = Field(
        5, description="side of the window over which goodFeaturesToTrack sums M (eq. 6), "
                       "working pixels")
    isotropy_block_px: Annotated[int, Field(ge=3, le=15)] = Field(
        7, description="side of the window of the λ_min/λ_max test, working pixels (with 5, "
                       "noise of a quarter of the contrast makes corners on a circle)")
    work_px: Annotated[int, Field(ge=32, le=4096)] = Field(
        160, description="longer side of the working image, pixels")
    blur_sigma: Annotated[float, Field(ge=0, le=10)] = Field(
        1.0, description="Gaussian smoothing before the gradient, working pixels")
    min_area: Annotated[float, Field(ge=0, lt=1)] = Field(
        0.001, description="smallest object, as a share of the image area")
    subdivisions: Annotated[int, Field(ge=1, le=4)] = Field(
        2, description="grid points per pin pitch: 2 = pins + phantom points (9x9 on 5x5), "
                       "1 = pins only")
    margin: Annotated[float, Field(ge=0)] = Field(0.0, description="pins left free per side")
    subpixel: bool = Field(
        True, description="move snake points to the sub-pixel edge along their normal "
                          "(vtexp's addition, not Williams & Shah's)")
    fit: Literal["object", "frame"] = Field(
        "object", description="fit the outline's bounding box into the array, or the whole "
                              "frame (a live camera: the object moves across the pins)")
    track_px: Annotated[int, Field(ge=0, le=32)] = Field(
        6, description="tracking: largest whole-pixel shift (working pixels) of the carried "
                       "outline as a whole before the snake runs (module docstring)")
    lost_fraction: Annotated[float, Field(ge=0, le=1)] = Field(
        0.5, description="tracking: a snake carried over from the previous frame is lost, "
                         "and started again from Otsu's outline, when fewer than this share "
                         "of its points end on an edge stronger than corner_edge")

    @field_validator("window")
    @classmethod
    def _odd(cls, v: int) -> int:
        if v % 2 == 0:
            raise ValueError(f"window must be odd (got {v})")
        return v


@dataclass
class SnakeResult:
    """An outline found by :func:`find_outline`, in full-resolution pixels.

    ``points`` are (row, col); ``corner`` flags the points held on a corner;
    ``shape`` is the image's (height, width); ``init`` says where the snake started
    (``otsu``, or ``carried`` over from the previous frame); ``on_edge`` is the share
    of its free points that ended on a strong edge (``corner_edge``).
    """

    points: np.ndarray
    corner: np.ndarray
    factor: int = 1
    iterations: int = 0
    warnings: list[str] = field(default_factory=list)
    shape: tuple[int, int] | None = None
    init: str = "otsu"
    on_edge: float = 1.0

    @property
    def empty(self) -> bool:
        return len(self.points) == 0


# --------------------------------------------------------------------------- steps


def working_image(gray: np.ndarray, work_px: int) -> tuple[np.ndarray, int]:
    """Reduce ``gray`` by an integer factor (area average) to about ``work_px`` pixels along
    its longer side. Working pixel ``(i, j)`` covers full pixels ``i*f .. i*f+f-1``."""
    h, w = gray.shape
    f = max(1, int(max(h, w) // work_px))
    if f == 1:
        return gray, 1
    hh, ww = h // f, w // f
    cv = cv2()
    return cv.resize(gray[:hh * f, :ww * f], (ww, hh), interpolation=cv.INTER_AREA), f


#: With a figure mask, the working image keeps its edges within this many working
#: pixels of the mask (and fades out over as many more): the snake's start lies on
#: the mask's outline, and the object's edge within a pixel or two of it.
RING_PX = 3.0


def working_mask(mask: np.ndarray, f: int) -> np.ndarray:
    """A full-resolution mask (uint8 0/1) at :func:`working_image`'s resolution: a working
    pixel is the object's if the object covers at least half of it."""
    if f == 1:
        return mask
    h, w = mask.shape[0] // f, mask.shape[1] // f
    cover = cv2().resize(mask[:h * f, :w * f] * np.uint8(255), (w, h),
                         interpolation=cv2().INTER_AREA)
    return (cover >= 128).astype(np.uint8)


def edge_strength(work: np.ndarray, blur_sigma: float = 1.0
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Smoothed image (uint8), its Sobel derivatives and gradient magnitude ‖∇I‖ (seed 002
    eq. 3). The magnitude is in grey levels per pixel (Sobel divided by 8, its weight).
    """
    cv = cv2()
    img = cv.GaussianBlur(work, (0, 0), blur_sigma) if blur_sigma > 0 else work
    gx = cv.Sobel(img, cv.CV_32F, 1, 0, ksize=3)
    gy = cv.Sobel(img, cv.CV_32F, 0, 1, ksize=3)
    mag = cv.magnitude(gx, gy) * np.float32(1 / 8)
    return img, gx, gy, mag


def initial_contour(smooth: np.ndarray, *, spacing_px: float, min_area: float,
                    mask: np.ndarray | None = None) -> np.ndarray | None:
    """Initial snake: Otsu segmentation's largest outer contour (or that of ``mask``, a
    figure mask at the working resolution), resampled every ``spacing_px`` pixels
    along its length (an even number of points, at least 8).

    Returns (n, 2) int (row, col) points, or None if there is no object (uniform image,
    or nothing larger than ``min_area`` of the image).
    """
    cv = cv2()
    img8 = smooth
    if mask is None and int(img8.max()) - int(img8.min()) < 2:
        return None
    if mask is None:
        mask = object_mask(img8)
    contours, _ = cv.findContours(mask, cv.RETR_EXTERNAL, cv.CHAIN_APPROX_NONE)
    if not contours:
        return None
    areas = [cv.contourArea(c) for c in contours]
    best = int(np.argmax(areas))
    if areas[best] < max(min_area * mask.size, 4.0):
        return None
    xy = contours[best][:, 0, :].astype(np.float64)
    return resample_closed(xy[:, ::-1], spacing_px)


def resample_closed(points: np.ndarray, spacing: float) -> np.ndarray:
    """Points spaced evenly by arc length along a closed polyline, rounded to pixels."""
    pts = np.asarray(points, dtype=np.float64)
    seg = np.concatenate([pts[1:], pts[:1]]) - pts
    length = np.hypot(seg[:, 0], seg[:, 1])
    total = float(length.sum())
    n = max(8, round(total / spacing))
    n += n % 2
    cum = np.concatenate([[0.0], np.cumsum(length)])
    s = np.arange(n) * (total / n)
    k = np.minimum(np.searchsorted(cum, s, side="right") - 1, len(pts) - 1)
    t = (s - cum[k]) / np.where(length[k] > 0, length[k], 1.0)
    out = np.rint(pts[k] + seg[k] * t[:, None]).astype(np.int64)
    # Rounding may put two neighbours on one pixel; drop such repeats.
    keep = np.any(out != np.concatenate([out[-1:], out[:-1]]), axis=1)
    return out[keep] if keep.sum() >= 3 else out


def _offsets(window: int) -> np.ndarray:
    h = window // 2
    offs = [(0, 0)] + [(dr, dc) for dr in range(-h, h + 1) for dc in range(-h, h + 1)
                       if (dr, dc) != (0, 0)]
    return np.array(offs, dtype=np.int64)          # the current position first: ties stay


def _colour_groups(n: int) -> list[np.ndarray]:
    idx = np.arange(n)
    if n % 2 == 0:
        return [idx[0::2], idx[1::2]]
    return [idx[0:n - 1:2], idx[1::2], idx[n - 1:]]


def greedy_snake(edge: np.ndarray, init: np.ndarray, *, alpha: float = 1.0,
                 beta: float | np.ndarray = 1.0, gamma: float = 1.2, window: int = 3,
                 max_iterations: int = 100, stop_fraction: float = 0.2,
                 corner_curvature: float = 0.25, corner_edge: float = 10.0,
                 fixed: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """Greedy active contour of Williams & Shah (1992), seed 002 eq. 4.

    For each point ``p_i`` of the closed contour and each position ``v`` of the
    ``window x window`` neighbourhood around it, with ``d̄`` the mean distance
    between neighbouring points at the start of the sweep:

    - E_cont(v) = |d̄ − ‖v − p_{i−1}‖|, divided by its largest value in the
      neighbourhood;
    - E_curv(v) = ‖p_{i−1} − 2v + p_{i+1}‖², divided by its largest value in the
      neighbourhood;
    - E_img(v) = (min − ‖∇I(v)‖) / (max − min), min and max of ‖∇I‖ in the
      neighbourhood, min lowered to max − 5 where they differ by less than 5
      (so a flat neighbourhood does not turn noise into a pull);

    and the point moves to the ``v`` with the least α E_cont + β_i E_curv +
    γ E_img (its current position on ties). After each sweep, β_i is set to 0
    where the curvature c_i = ‖u_i/‖u_i‖ − u_{i+1}/‖u_{i+1}‖‖² (u_i = p_i −
    p_{i−1}) is a local maximum above ``corner_curvature`` on an edge stronger
    than ``corner_edge`` (Williams & Shah's corner rule). It stops when fewer
    than ``stop_fraction`` of the points moved, or after ``max_iterations``.

    Points are visited in two interleaved half-sweeps, each vectorised (module
    docstring); positions are whole pixels, kept ``window // 2`` pixels inside
    the image so that every neighbourhood is whole.

    Parameters
    ----------
    edge : 2-D float array
        ‖∇I‖, the gradient magnitude (:func:`edge_strength`).
    init : (n, 2) int array
        Initial closed contour, (row, col), n >= 3.
    alpha, beta, gamma : float
        Weights of eq. 4; ``beta`` may be an array of per-point weights.
    window : int
        Odd side of the neighbourhood.
    fixed : (n,) bool array, optional
        Points that never move.

    Returns
    -------
    points : (n, 2) int array
    beta : (n,) float array
        Per-point β after corner relaxation (0 at corners).
    iterations : int
        Sweeps made.

    References
    ----------
    Seed 002 §3.1, eqs. 1-4; Williams & Shah 1992, §3 (the greedy algorithm).

    Examples
    --------
    >>> import numpy as np
    >>> yy, xx = np.mgrid[:64, :64]
    >>> edge = np.exp(-((np.hypot(yy - 32, xx - 32) - 20) ** 2) / 4).astype(np.float32) * 50
    >>> t = np.linspace(0, 2 * np.pi, 32, endpoint=False)
    >>> init = np.c_[32 + 24 * np.sin(t), 32 + 24 * np.cos(t)].round().astype(int)
    >>> pts, _, _ = greedy_snake(edge, init)
    >>> bool(np.all(np.abs(np.hypot(pts[:, 0] - 32, pts[:, 1] - 32) - 20) <= 1.5))
    True
    """
    cv = cv2()
    edge = np.ascontiguousarray(edge, dtype=np.float32)
    h_img, w_img = edge.shape
    half = window // 2
    if h_img <= 2 * half or w_img <= 2 * half:
        raise ValueError(f"image of {w_img}x{h_img} pixels is too small for window {window}")
    p = np.array(init, dtype=np.int64).reshape(-1, 2)
    n = len(p)
    if n < 3:
        raise ValueError("a closed snake needs at least 3 points")
    # Points stay `half` pixels inside the image, so every neighbourhood is whole.
    r = np.clip(p[:, 0], half, h_img - 1 - half)
    c = np.clip(p[:, 1], half, w_img - 1 - half)
    betas = np.broadcast_to(np.asarray(beta, dtype=np.float64), (n,)).copy()
    fixed = np.zeros(n, bool) if fixed is None else np.asarray(fixed, bool)
    # E_img normalisation: min and max of ‖∇I‖ over each point's neighbourhood are a
    # grey erosion and dilation of the gradient image, computed once.
    kernel = np.ones((window, window), np.uint8)
    gmax = cv.dilate(edge, kernel, borderType=cv.BORDER_REPLICATE)
    gmin = np.minimum(cv.erode(edge, kernel, borderType=cv.BORDER_REPLICATE), gmax - 5.0)
    # γ is folded into the scale: γ E_img = (min − ‖∇I‖) · γ / (max − min).
    inv = (gamma / (gmax - gmin)).ravel().astype(np.float64)
    gmin = gmin.ravel().astype(np.float64)
    mag = edge.astype(np.float64)
    mag[:half] = mag[h_img - half:] = -1e9     # never step outside the inner box
    mag[:, :half] = mag[:, w_img - half:] = -1e9
    mag = mag.ravel()
    edge_flat = edge.ravel()
    offs = _offsets(window)
    # Positions as complex numbers col + 1j*row (fewer, larger array operations) and
    # as flat indices into the image, both moved together.
    o_z = (offs[:, 1] + 1j * offs[:, 0])
    o_2z = 2.0 * o_z
    o_f = offs[:, 0] * w_img + offs[:, 1]
    z = c + 1j * r
    fl = r * w_img + c
    # Neighbour indices instead of np.roll (whose Python overhead dominates at this size).
    before = np.arange(-1, n - 1) % n
    after = np.arange(1, n + 1) % n
    groups = [g[~fixed[g]] for g in _colour_groups(n)]
    plan = [(g, before[g], after[g]) for g in groups if g.size]
    inv_n = 1.0 / n
    # α and β_i are folded into the normalisations: α E_cont / max = E_cont · (α / max).
    beta_cols = [betas[g][:, None] for g, _, _ in plan]
    iterations = 0
    for iterations in range(1, max_iterations + 1):
        d_mean = float(np.abs(z - z[before]).sum()) * inv_n
        moved = 0
        for (g, gp, gn), beta_g in zip(plan, beta_cols):
            zg, fg = z[g], fl[g]
            zp = z[gp]
            cand = zg[:, None] + o_z
            e_cont = np.abs(d_mean - np.abs(cand - zp[:, None]))
            e_cont *= alpha / np.maximum(e_cont.max(axis=1, keepdims=True), 1e-12)
            e_curv = np.abs((zp + z[gn] - 2.0 * zg)[:, None] - o_2z)
            e_curv *= e_curv
            e_curv *= beta_g / np.maximum(e_curv.max(axis=1, keepdims=True), 1e-12)
            e_cont += e_curv
            e_cont += (gmin[fg][:, None] - mag[fg[:, None] + o_f]) * inv[fg][:, None]
            best = e_cont.argmin(axis=1)
            moved += int(np.count_nonzero(best))
            z[g] = zg + o_z[best]
            fl[g] = fg + o_f[best]
        # Williams & Shah's corner rule: relax β_i at curvature maxima on strong edges.
        u = z - z[before]
        u /= np.maximum(np.abs(u), 1e-12)
        k = u - u[after]
        k = k.real * k.real + k.imag * k.imag
        is_corner = ((k > k[before]) & (k > k[after]) & (k > corner_curvature)
                     & (edge_flat[fl] > corner_edge))
        if is_corner.any():
            betas[is_corner] = 0.0
            beta_cols = [betas[g][:, None] for g, _, _ in plan]
        if moved < stop_fraction * n or moved == 0:
            break
    r = np.rint(z.imag).astype(np.int64)
    c = np.rint(z.real).astype(np.int64)
    p = np.stack([r, c], axis=1)
    return p, betas, iterations


def contour_corners(smooth: np.ndarray, gx: np.ndarray, gy: np.ndarray, contour: np.ndarray,
                    *, detector: str = "shi-tomasi", quality: float = 0.05,
                    isotropy: float = 0.08, max_distance: float = 3.0,
                    max_corners: int = 12, block_size: int = 5,
                    isotropy_block: int = 7) -> np.ndarray:
    """Corners of an outline: Shi-Tomasi (or Harris) corners that lie on it (seed 002 eqs. 5-6).

    ``cv2.goodFeaturesToTrack`` ranks pixels by the smaller eigenvalue of the
    gradient matrix M of eq. 6 summed over ``block_size x block_size`` pixels
    (Shi-Tomasi; ``detector="harris"`` uses Harris's response) and keeps those
    above ``quality`` times the best. That threshold is relative, so on a
    shape without corners it still returns points along the curve. A corner is
    therefore kept only if, in addition,

    - it lies within ``max_distance`` pixels of the contour, and
    - λ_min / λ_max of M, summed over ``isotropy_block`` pixels around it, is
      at least ``isotropy``: on an edge, even a curved one, the gradients
      share one direction and λ_min stays a small fraction of λ_max; at a
      corner two directions meet. The window is larger than the detector's
      so that noise along an edge averages out.

    Returns
    -------
    (k, 2) float array
        Corners, (row, col), strongest first.
    """
    cv = cv2()
    img8 = smooth
    poly = np.asarray(contour, dtype=np.float64)
    span = np.ptp(poly, axis=0).min() if len(poly) else 0
    min_dist = max(3.0, 0.1 * float(span))
    # Only the contour's bounding box (and a margin) can hold a corner of it.
    pad = int(np.ceil(max_distance)) + block_size
    r0 = max(int(poly[:, 0].min()) - pad, 0) if len(poly) else 0
    c0 = max(int(poly[:, 1].min()) - pad, 0) if len(poly) else 0
    r1 = min(int(poly[:, 0].max()) + pad + 1, img8.shape[0]) if len(poly) else img8.shape[0]
    c1 = min(int(poly[:, 1].max()) + pad + 1, img8.shape[1]) if len(poly) else img8.shape[1]
    found = cv.goodFeaturesToTrack(np.ascontiguousarray(img8[r0:r1, c0:c1]),
                                   maxCorners=max_corners, qualityLevel=quality,
                                   minDistance=min_dist, blockSize=block_size,
                                   useHarrisDetector=(detector == "harris"))
    if found is None:
        return np.zeros((0, 2))
    rc = found[:, 0, ::-1].astype(np.float64) + [r0, c0]
    contour_xy = np.ascontiguousarray(poly[:, ::-1], dtype=np.float32).reshape(-1, 1, 2)
    keep = [abs(cv.pointPolygonTest(contour_xy, (float(x), float(y)), True)) <= max_distance
            for y, x in rc]
    rc = rc[np.asarray(keep, bool)]
    if not len(rc):
        return rc
    # λ_min/λ_max of M (eq. 6, box weights) at each remaining corner.
    h, w = gx.shape
    r0 = isotropy_block // 2
    d = np.arange(-r0, r0 + 1)
    ctr = np.rint(rc).astype(np.int64)
    rr = np.clip(ctr[:, 0, None, None] + d[None, :, None], 0, h - 1)
    cc = np.clip(ctr[:, 1, None, None] + d[None, None, :], 0, w - 1)
    ix = gx[rr, cc].astype(np.float64).reshape(len(rc), -1)
    iy = gy[rr, cc].astype(np.float64).reshape(len(rc), -1)
    a, b, dd = (ix * ix).sum(axis=1), (ix * iy).sum(axis=1), (iy * iy).sum(axis=1)
    half_tr = (a + dd) / 2
    disc = np.sqrt(np.maximum(half_tr * half_tr - (a * dd - b * b), 0.0))
    ratios = (half_tr - disc) / np.maximum(half_tr + disc, 1e-12)
    return rc[ratios >= isotropy]


def find_outline(gray: np.ndarray, init: np.ndarray | None = None,
                 mask: np.ndarray | None = None, **params) -> SnakeResult:
    """An object's outline by the snake with corners (steps 1-5 of the module docstring).

    Parameters
    ----------
    gray : 2-D array
        Grayscale image, any size; uint8 or float in 0..255.
    init : (n, 2) array, optional
        Where the snake starts, in full-resolution (row, col): the previous frame's
        outline when tracking (:class:`SnakeTracker`). Default: Otsu's outline.
    mask : 2-D array, optional
        The object (uint8 0/1 of the image's height x width; a figure mask,
        :mod:`vtexp.encoding.figure`). The snake then starts from its outline
        instead of Otsu's, and E_img is the gradient of an image whose background
        beyond ``RING_PX`` working pixels of the mask is flattened
        (:func:`~vtexp.encoding.segment.flatten_background`), so that background
        edges (brick, grass) do not draw the snake away from the object.
    **params
        Keys of :class:`SnakeCornersParams`.

    Returns
    -------
    SnakeResult
        Points (row, col) in full-resolution pixels, in order around the object, and
        which of them are corners; empty, with a warning text, if there is no object.
    """
    p = SnakeCornersParams(**params)
    gray = _as_gray(gray)
    work, f = working_image(gray, p.work_px)
    work_mask = None
    if mask is not None:
        work_mask = working_mask(given_mask(mask, gray.shape, "snake-corners"), f)
        # Corners of the object's silhouette only: background texture beside it made
        # corners on a circle (7-8 px off its outline on the photograph's flag and suit).
        silhouette = edge_strength(flatten_background(work, work_mask, 0), p.blur_sigma)
        work = flatten_background(work, work_mask, RING_PX)
    smooth, gx, gy, edge = edge_strength(work, p.blur_sigma)
    c_smooth, c_gx, c_gy = (smooth, gx, gy) if mask is None else silhouette[:3]
    shape = (int(gray.shape[0]), int(gray.shape[1]))
    started = "otsu"
    if init is not None:
        init = carried_contour(init, f, edge.shape, spacing_px=p.spacing_px,
                               margin=p.window // 2)
        if init is not None:
            init = rigid_shift(edge, init, p.track_px, margin=p.window // 2)
        started = "carried"
    if init is None:
        started = "otsu"
        init = initial_contour(smooth, spacing_px=p.spacing_px, min_area=p.min_area,
                               mask=work_mask)
    if init is None:
        what = "the figure mask is empty or" if work_mask is not None else \
            "the image is uniform or the object is"
        return SnakeResult(np.zeros((0, 2)), np.zeros(0, bool), f, 0,
                           [(f"no object found: {what} smaller than min_area={p.min_area} "
                             "of the image")], shape)
    # Corners first (step 3): found on the initial contour, refined to sub-pixel precision,
    # and held by the nearest snake points, which then do not move and have β = 0.
    pts = init.copy()
    corner = np.zeros(len(pts), bool)
    exact = np.zeros((len(pts), 2))
    if p.corners:
        found = contour_corners(c_smooth, c_gx, c_gy, pts, detector=p.corner_detector,
                                quality=p.corner_quality, isotropy=p.corner_isotropy,
                                max_distance=p.corner_distance_px, max_corners=p.max_corners,
                                block_size=p.corner_block_px,
                                isotropy_block=p.isotropy_block_px)
        if len(found):
            h, w = edge.shape
            for rc in np.clip(refine_corners(c_smooth, found), 0, [h - 1, w - 1]):
                d2 = ((pts - rc) ** 2).sum(axis=1).astype(np.float64)
                d2[corner] = np.inf
                i = int(np.argmin(d2))
                pts[i] = np.floor(rc + 0.5)
                corner[i] = True
                exact[i] = rc
    betas = np.where(corner, 0.0, p.beta)
    pts, betas, its = greedy_snake(edge, pts, alpha=p.alpha, beta=betas, gamma=p.gamma,
                                   window=p.window, max_iterations=p.max_iterations,
                                   stop_fraction=p.stop_fraction,
                                   corner_curvature=p.corner_curvature,
                                   corner_edge=p.corner_edge, fixed=corner)
    free = ~corner
    on_edge = float(np.mean(edge[pts[free, 0], pts[free, 1]] > p.corner_edge)) \
        if free.any() else 1.0
    sub = subpixel_edges(edge, pts, ~corner) if p.subpixel else pts.astype(np.float64)
    if not p.subpixel:
        exact = np.floor(exact + 0.5)
    if corner.any():
        sub[corner] = exact[corner]
    full = sub * float(f) + (f - 1) / 2.0
    return SnakeResult(full, corner, f, its, shape=shape, init=started, on_edge=on_edge)


def carried_contour(points: np.ndarray, factor: int, shape: tuple[int, int], *,
                    spacing_px: float, margin: int = 1) -> np.ndarray | None:
    """A previous frame's outline (full-resolution (row, col)) as the next snake's start:
    in working pixels, resampled every ``spacing_px`` along its length, kept ``margin``
    pixels inside the image. None if fewer than 3 distinct points remain."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(pts) < 3:
        return None
    work = (pts - (factor - 1) / 2.0) / float(factor)
    out = resample_closed(work, spacing_px)
    h, w = shape
    out[:, 0] = np.clip(out[:, 0], margin, h - 1 - margin)
    out[:, 1] = np.clip(out[:, 1], margin, w - 1 - margin)
    keep = np.any(out != np.roll(out, 1, axis=0), axis=1)
    out = out[keep]
    return out if len(out) >= 3 else None


def rigid_shift(edge: np.ndarray, points: np.ndarray, radius: int, *, margin: int = 1
                ) -> np.ndarray:
    """``points`` moved as a whole by the whole-pixel shift (each coordinate within
    ``±radius``) that maximises the sum of ‖∇I‖ under them — the least image energy
    of eq. 4 for the contour as one rigid body; the smallest shift on ties. Points
    stay ``margin`` pixels inside the image."""
    pts = np.asarray(points, dtype=np.int64).reshape(-1, 2)
    if radius <= 0 or not len(pts):
        return pts
    h, w = edge.shape
    d = np.arange(-radius, radius + 1)
    dr, dc = np.meshgrid(d, d, indexing="ij")
    dr, dc = dr.ravel(), dc.ravel()
    rr = np.clip(pts[None, :, 0] + dr[:, None], margin, h - 1 - margin)
    cc = np.clip(pts[None, :, 1] + dc[:, None], margin, w - 1 - margin)
    score = edge[rr, cc].sum(axis=1)
    best = score.max()
    ties = np.flatnonzero(score >= best - 1e-6 * max(abs(best), 1.0))
    k = ties[np.argmin(dr[ties] ** 2 + dc[ties] ** 2)]
    return np.stack([rr[k], cc[k]], axis=1)


class SnakeTracker:
    """Seed 002's snake followed from frame to frame (module docstring, *Tracking*).

    Each call of :meth:`outline` starts the snake from the previous frame's outline;
    when that snake is lost (``lost_fraction``), or there is no previous outline, from
    Otsu's outline of the frame. ``restarts`` counts the frames started again.

    Examples
    --------
    >>> from vtexp.stimuli import render_shape
    >>> tracker = SnakeTracker(fit="frame")
    >>> [tracker.pattern(render_shape(shape="square", center_x=x), 5, 5).params["snake_init"]
    ...  for x in (0.40, 0.42)]
    ['otsu', 'carried']
    """

    def __init__(self, **params):
        self.params = SnakeCornersParams(**params)
        self.previous: SnakeResult | None = None
        self.restarts = 0

    def reset(self) -> None:
        self.previous = None

    def outline(self, gray: np.ndarray, mask: np.ndarray | None = None) -> SnakeResult:
        """This frame's outline; ``mask`` is the frame's figure mask if given
        (:func:`find_outline`)."""
        p = self.params
        kw = p.model_dump()
        gray = _as_gray(gray)
        res = None
        prev = self.previous
        if prev is not None and prev.shape == gray.shape:
            res = find_outline(gray, init=prev.points, mask=mask, **kw)
            if res.empty or res.on_edge < p.lost_fraction:
                self.restarts += 1
                res = None
        if res is None:
            res = find_outline(gray, mask=mask, **kw)
        self.previous = None if res.empty else res
        return res

    def pattern(self, gray: np.ndarray, rows: int, cols: int,
                mask: np.ndarray | None = None) -> Pattern:
        """This frame's Pattern, as :func:`snake_corners` makes it, from the tracked snake;
        ``mask`` is the frame's figure mask if given."""
        p = self.params
        res = self.outline(gray, mask)
        return outline_pattern(res, rows, cols, subdivisions=p.subdivisions, margin=p.margin,
                               closed=True, pipeline="snake-corners",
                               params={**p.model_dump(), "snake_init": res.init},
                               fit=p.fit)


def subpixel_edges(edge: np.ndarray, points: np.ndarray, which: np.ndarray | None = None,
                   *, reach: int = 2) -> np.ndarray:
    """Move contour points to the sub-pixel maximum of ‖∇I‖ along the contour's normal.

    Not part of Williams & Shah's algorithm, whose points sit on whole pixels;
    an addition of vtexp. ‖∇I‖ is sampled (bilinear) at ``-reach .. reach``
    pixels along the normal (the perpendicular of ``p_{i+1} - p_{i-1}``); a
    parabola through the largest sample and its two neighbours gives the
    peak. Points in ``which`` only; the others are returned as they are.

    Returns
    -------
    (n, 2) float array
        (row, col) positions.
    """
    cv = cv2()
    pts = np.asarray(points, dtype=np.float64)
    out = pts.copy()
    if which is None:
        which = np.ones(len(pts), bool)
    if not which.any() or len(pts) < 3:
        return out
    n = len(pts)
    tang = pts[np.arange(1, n + 1) % n] - pts[np.arange(-1, n - 1) % n]
    norm = np.hypot(tang[:, 0], tang[:, 1])
    ok = which & (norm > 0)
    normal = np.stack([tang[:, 1], -tang[:, 0]], axis=1) / np.maximum(norm, 1e-12)[:, None]
    steps = np.arange(-reach, reach + 1, dtype=np.float64)
    sample = pts[ok, None, :] + steps[None, :, None] * normal[ok, None, :]     # (m, S, 2)
    vals = cv.remap(np.ascontiguousarray(edge, dtype=np.float32),
                    sample[..., 1].astype(np.float32), sample[..., 0].astype(np.float32),
                    cv.INTER_LINEAR, borderMode=cv.BORDER_REPLICATE)
    k = np.minimum(np.maximum(vals.argmax(axis=1), 1), len(steps) - 2)
    rows = np.arange(len(k))
    lo, mid, hi = vals[rows, k - 1], vals[rows, k], vals[rows, k + 1]
    den = lo - 2 * mid + hi
    delta = np.where(den < 0, 0.5 * (lo - hi) / np.where(den < 0, den, -1.0), 0.0)
    shift = steps[k] + np.minimum(np.maximum(delta, -0.5), 0.5)
    out[ok] = pts[ok] + shift[:, None] * normal[ok]
    return out


def refine_corners(smooth: np.ndarray, corners: np.ndarray, *, half_window: int = 4
                   ) -> np.ndarray:
    """Corners to sub-pixel precision with ``cv2.cornerSubPix`` on the smoothed working image.

    cornerSubPix finds the point where the gradients of the window are
    orthogonal to the lines joining it to their pixels: the meeting point of
    the two edges. On the smoothed working image it is both cheaper and less
    disturbed by noise than on the camera's full-resolution pixels. A corner
    whose refinement wanders more than ``half_window`` pixels keeps its
    detected position.
    """
    cv = cv2()
    rc = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    h, w = smooth.shape
    if not len(rc) or h < 2 * half_window + 5 or w < 2 * half_window + 5:
        return rc.copy()
    pts = np.ascontiguousarray(rc[:, ::-1], dtype=np.float32).reshape(-1, 1, 2)
    crit = (cv.TERM_CRITERIA_EPS + cv.TERM_CRITERIA_MAX_ITER, 30, 0.01)
    try:
        cv.cornerSubPix(np.ascontiguousarray(smooth), pts,
                        (half_window, half_window), (-1, -1), crit)
    except cv.error:
        return rc.copy()
    refined = pts[:, 0, ::-1].astype(np.float64)
    bad = np.hypot(*(refined - rc).T) > half_window
    refined[bad] = rc[bad]
    return refined


def outline_mask(points: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Pixels whose centres lie inside the closed polygon ``points`` ((row, col)).

    Even-odd rule on each row of pixel centres; unlike ``cv2.fillPoly`` it adds
    no boundary pixels, so a polygon and the shape it outlines can be compared
    without a half-pixel bias (used to measure IoU).
    """
    h, w = shape
    pts = np.asarray(points, dtype=np.float64)
    mask = np.zeros((h, w), bool)
    if len(pts) < 3:
        return mask
    y0, x0 = pts[:, 0], pts[:, 1]
    y1, x1 = np.roll(y0, -1), np.roll(x0, -1)
    ys = np.arange(h, dtype=np.float64)[:, None]
    crosses = (y0[None] <= ys) != (y1[None] <= ys)                   # (h, edges)
    with np.errstate(divide="ignore", invalid="ignore"):
        xs = x0[None] + (ys - y0[None]) * (x1 - x0)[None] / (y1 - y0)[None]
    xs = np.where(crosses, xs, np.inf)
    xs.sort(axis=1)
    cols = np.arange(w, dtype=np.float64)
    for r in range(h):
        k = int(np.count_nonzero(crosses[r]))
        for a, b in zip(xs[r, 0:k:2], xs[r, 1:k:2]):
            mask[r, (cols > a) & (cols < b)] = True
    return mask


def _as_gray(gray: np.ndarray, pipeline: str = "snake-corners") -> np.ndarray:
    img = np.asarray(gray)
    if img.ndim != 2:
        raise InputError(f"{pipeline} needs a 2-D grayscale image, got an array of shape "
                         f"{img.shape}")
    if img.shape[0] < 16 or img.shape[1] < 16:
        raise InputError(f"{pipeline} needs an image of at least 16x16 pixels, got "
                         f"{img.shape[1]}x{img.shape[0]}")
    if img.dtype != np.uint8:
        img = np.clip(np.nan_to_num(img.astype(np.float64)), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(img)


# --------------------------------------------------------------------------- pipeline


def snake_corners(gray: np.ndarray, rows: int, cols: int, *, mask: np.ndarray | None = None,
                  **params) -> Pattern:
    """Image -> ordered outline on pins plus phantom points (seed 002, §3.1-3.2).

    The outline of :func:`find_outline` is fitted into the ``rows x cols`` array
    keeping its aspect ratio and mapped onto the virtual grid of pins and
    phantom points (``subdivisions=2``: a 9x9 grid on 5x5 pins, positions at
    half-pin steps) by :func:`vtexp.encoding.phantom_grid.grid_path`: one closed
    loop (``line`` 0), clockwise, starting at its first point in raster order,
    ``order`` counting along it, ``corner=True`` where a Shi-Tomasi corner fell.

    An image without an object (uniform, empty) gives an empty Pattern and a
    ``UserWarning``; the reason is also in ``pattern.params["warnings"]``.

    Parameters
    ----------
    gray : 2-D array
        Grayscale image.
    rows, cols : int
        Pins of the device.
    mask : 2-D array, optional
        The object, uint8 0/1 of the image's height x width (:func:`find_outline`);
        an all-zero mask gives an empty Pattern.
    **params
        Keys of :class:`SnakeCornersParams`.

    Returns
    -------
    Pattern

    Examples
    --------
    >>> from vtexp.stimuli import render_shape
    >>> pat = snake_corners(render_shape(shape="square"), 5, 5)
    >>> len(pat.closed), sum(p.corner for p in pat.points)
    (1, 4)
    >>> sorted({p.col for p in pat.points})
    [0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0]
    """
    p = SnakeCornersParams(**params)
    res = find_outline(gray, mask=mask, **p.model_dump())
    return outline_pattern(res, rows, cols, subdivisions=p.subdivisions, margin=p.margin,
                           closed=True, pipeline="snake-corners", params=p.model_dump(),
                           fit=p.fit)


def outline_pattern(res: SnakeResult, rows: int, cols: int, *, subdivisions: int,
                    margin: float, closed: bool, pipeline: str, params: dict,
                    fit: str = "object") -> Pattern:
    """A Pattern of one loop or path from image points (shared with ``spiral-path``).

    ``fit="frame"`` maps the image's whole frame onto the array (recorded in
    ``params["to_array"]``); ``object``, the points' bounding box."""
    notes = list(res.warnings)
    if fit == "frame" and res.shape is not None:
        to_array = ImageToArray.fit_frame(res.shape[0], res.shape[1], rows, cols, margin=margin)
        params = {**params, "to_array": to_array.as_params()}
    if res.empty:
        for w in notes:
            warnings.warn(f"{pipeline}: {w}; the pattern is empty", UserWarning, stacklevel=3)
        return Pattern(rows=rows, cols=cols, points=[], closed=[], pipeline=pipeline,
                       params={**params, "warnings": notes})
    if fit == "frame" and res.shape is not None:
        arr = np.minimum(np.maximum(to_array.to_array(res.points), 0.0), [rows - 1, cols - 1])
    else:
        arr = fit_to_array(res.points, rows, cols, margin=margin)
    grid, flags, dropped, repeated = grid_path(arr, res.corner, rows, cols, closed=closed,
                                               subdivisions=subdivisions)
    if dropped:
        notes.append(f"{dropped} later visit(s) of a grid point were dropped (parts of the "
                     "curve closer than the grid step)")
    if repeated:
        notes.append(f"{repeated} grid point(s) are visited twice (a spike or turns of the "
                     "curve narrower than the grid step)")
    pts = [{"row": r, "col": c, "line": 0, "order": k, "corner": fl}
           for k, ((r, c), fl) in enumerate(zip(grid.tolist(), flags.tolist()))]
    # One validation of plain dicts (pydantic's core) is several times faster than
    # building the points one by one.
    return Pattern.model_validate({
        "rows": rows, "cols": cols, "points": pts,
        "closed": [0] if closed and len(pts) >= 3 else [], "pipeline": pipeline,
        "params": {**params, "warnings": notes} if notes else params})
