"""Height contours: a 3-D shape as a few contour lines on the array (seed 000, §2.1-2.2).

The pipeline, each step a function:

1. :func:`reflectance` — gray image -> normalised brightness E and object mask.
2. :func:`shape_from_shading` — E -> height map H (Tsai-Shah discretisation,
   eqs. 1-6, light at the viewer), unless :func:`is_flat` finds the object's
   shading to be an uneven light and noise on a surface facing the camera.
3. :func:`normalise_height` — eq. 7, min-max over the object.
4. :func:`count_lines` — the variance rule, eqs. 8-9 and step (4): 1, 3 or 5 lines.
5. :func:`line_heights` — eq. 10.
6. :func:`sharpen` — §2.2.1, 8-neighbour rule into 1-px lines: the contour map S.
7. :func:`map_to_array` — §2.2.2, eq. 11 and the proportion / majority rules: M.

:func:`height_contours` chains them and returns a :class:`~vtexp.model.Pattern`
whose points carry their line index (1 = lowest). It works at a resolution of
``cells_per_motor`` pixels per actuator, not the camera's: the array cannot show
more, and the shading, heights and contours are all resolution-free.

Seed 000 assumes a monochromatic background (assumption 1), which Otsu's threshold
separates from the object. On any other background give the object as a figure
mask (``mask=``, :mod:`vtexp.encoding.figure`): step 1 is then
:func:`masked_reflectance`.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

import numpy as np
from pydantic import Field

from .._cv2 import cv2
from ..model import Model, Pattern
from .segment import given_mask

# Values of seed 000 §2.1.2 step (4).
VARIANCE_THRESHOLDS = (0.02, 0.06)
# Seed 000 §2.2.2 rules (2) and (3).
PROPORTION = 0.01
#: An object is flat when most of its inside faces the camera: with a planar light ramp
#: taken out of its brightness, the median slope that shape from shading reads there
#: (``sqrt(1/E^2 - 1)``, eq. 1) is under this (a tilt of 22 degrees, E = 0.93;
#: :func:`is_flat`). On ``bench/scenes.py``'s dev seeds (5000, 6000) cards under a light
#: ramp, with camera noise, blur and JPEG, give 0.09-0.16 with the exact mask (up to
#: 0.46 through a poor figure mask over a photograph); the study's surfaces 0.69 (a ball
#: through a figure mask) to 1.3 (docs/decisions.md).
FLAT_SLOPE = 0.4


class HeightContourParams(Model):
    lines: Literal["variance", 1, 2, 3, 4, 5] = Field(
        "variance", description="number of contour lines, or 'variance' for the rule of eqs. 8-9")
    levels: Literal["interior", "paper", "outline"] = Field(
        "interior", description="where the lines lie between h_min and h_max (see line_heights)")
    proportion: Annotated[float, Field(ge=0, lt=1)] = Field(
        PROPORTION, description="share of a region's pixels a line needs to claim its motor")
    cells_per_motor: Annotated[int, Field(ge=1, le=64)] = Field(
        4, description="working resolution in pixels per actuator")
    align: Literal["center", "top-left"] = Field(
        "center", description="where the w x h lattice of eq. 11 sits on a larger array")
    min_brightness: Annotated[float, Field(gt=0, lt=1)] = Field(
        0.02, description="E below this is taken as this (limits slopes at the silhouette)")
    albedo: Annotated[float, Field(gt=0, le=65535)] | None = Field(
        None, description="gray level of a surface facing the camera; default: estimated")
    ambient: Annotated[float, Field(ge=0, le=65535)] | None = Field(
        None, description="gray level of zero reflectance; default: the background's median "
                          "(with a figure mask: 0, the camera's black level)")


# --------------------------------------------------------------------------- steps

def _otsu(hist: np.ndarray) -> int:
    """Otsu's threshold of a 256-bin histogram: pixels > t are the bright class."""
    levels = np.arange(256, dtype=np.float64)
    w0 = np.cumsum(hist)
    w1 = w0[-1] - w0
    m0 = np.cumsum(hist * levels)
    mu0 = m0 / np.maximum(w0, 1e-12)
    mu1 = (m0[-1] - m0) / np.maximum(w1, 1e-12)
    between = w0 * w1 * (mu0 - mu1) ** 2
    return int(np.argmax(between[:-1]))


def _percentile(hist: np.ndarray, q: float) -> float:
    c = np.cumsum(hist)
    return float(np.searchsorted(c, q / 100.0 * c[-1]))


def reflectance(gray: np.ndarray, *, size: tuple[int, int] | None = None,
                albedo: float | None = None, ambient: float | None = None,
                threshold: float = 0.04, mask: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """Normalised brightness ``E = (I - ambient) / (albedo - ambient)`` and the object mask.

    Otsu's threshold splits the image into the (monochromatic, seed 000
    assumption 1) background and the object. ``ambient`` defaults to the
    background's median; ``albedo``, the gray level of a surface facing the
    camera, to the object's 99th percentile (under a light at the viewer the
    surface facing the camera is the brightest). A cone has no such surface:
    its shading is uniform, and the default would take it for flat; give the
    calibrated ``albedo`` (e.g. the gray level of a white card) instead.

    Under a light at the viewer an object's silhouette is dark (E -> 0), so the
    mask is not Otsu's bright class but every pixel with ``E > threshold`` (or
    three background noise deviations, if more), keeping connected pieces of
    at least a tenth of the largest.

    ``size = (width, height)`` resamples to a working resolution. A working
    pixel belongs to the object if the object covers at least half of it, and
    its E is the mean over the object's part only: averaging in the background
    would make the silhouette look steeper than it is.

    ``mask`` (a figure mask, :mod:`vtexp.encoding.figure`) gives the object instead of
    Otsu's threshold, and then ``ambient`` defaults to 0 and the background is not
    looked at (:func:`masked_reflectance`).

    Returns (E as float32 in [0, 1], mask), both of ``size`` if given.
    """
    if mask is not None:
        return masked_reflectance(gray, mask, size=size, albedo=albedo, ambient=ambient)
    cv = cv2()
    g = np.asarray(gray)
    if g.dtype != np.uint8:
        g = cv.normalize(g.astype(np.float32), None, 0, 255, cv.NORM_MINMAX).astype(np.uint8)
    out_hw = (size[1], size[0]) if size else g.shape
    empty = (np.zeros(out_hw, np.float32), np.zeros(out_hw, bool))
    if g.size == 0 or int(g.max()) == int(g.min()):
        return empty
    # Gray-level statistics from every other pixel of every other row: plenty for
    # a histogram, and a quarter of the work on a camera frame.
    sub = g[::2, ::2] if min(g.shape) >= 64 else g
    hist = cv.calcHist([np.ascontiguousarray(sub)], [0], None, [256], [0, 256]).ravel()
    t = _otsu(hist.astype(np.float64))
    border = np.concatenate([g[0], g[-1], g[:, 0], g[:, -1]]) > t
    if border.mean() > 0.5:                 # dark object on a light background
        g = cv.bitwise_not(g)
        hist = hist[::-1].copy()
        t = 254 - t
    hist = hist.astype(np.float64)
    dark, light = hist.copy(), hist.copy()
    dark[t + 1:] = 0
    light[:t + 1] = 0
    if dark.sum() == 0 or light.sum() == 0:
        return empty
    amb = _percentile(dark, 50) if ambient is None else float(ambient)
    alb = _percentile(light, 99) if albedo is None else float(albedo)
    if alb - amb < 1.0:
        return empty
    mad = _percentile(np.bincount(np.abs(np.arange(256) - int(amb)), weights=dark,
                                  minlength=256), 50)
    e_min = max(threshold, 3.0 * 1.4826 * mad / (alb - amb))
    level = amb + e_min * (alb - amb)
    _, full_mask = cv.threshold(g, level, 1, cv.THRESH_BINARY)
    return _working(g, full_mask, size, amb, alb, empty)


def _working(g: np.ndarray, full_mask: np.ndarray, size: tuple[int, int] | None, amb: float,
             alb: float, empty: tuple[np.ndarray, np.ndarray], *, soft: bool = False
             ) -> tuple[np.ndarray, np.ndarray]:
    """E and the object mask at the working ``size`` (:func:`reflectance`'s last steps).
    ``soft``: ``g`` is already ``amb`` outside the mask, and a working pixel's brightness
    is its whole average (the object's edge darker where it covers it in part), not the
    average of the object's pixels in it."""
    cv = cv2()
    if size is not None and size != (g.shape[1], g.shape[0]):
        # Averages over each working pixel (INTER_AREA on 8-bit data keeps 1/255 steps,
        # well below the brightness resolution that matters here).
        cover = cv.resize(full_mask * np.uint8(255), size, interpolation=cv.INTER_AREA)
        mask = cover >= 128
        if soft:
            gm = cv.resize(g, size, interpolation=cv.INTER_AREA)
        else:
            lit = cv.resize(g * full_mask, size, interpolation=cv.INTER_AREA).astype(np.float32)
            cover = cover.astype(np.float32) / 255.0
            gm = np.where(mask, lit / np.maximum(cover, 1e-6), amb)
    else:
        mask = full_mask.astype(bool)
        gm = g.astype(np.float32)
    n, labels, stats, _ = cv.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if n <= 1:
        return empty
    areas = stats[1:, cv.CC_STAT_AREA]
    keep = np.zeros(n, bool)
    keep[1:] = areas >= 0.1 * areas.max()
    mask = keep[labels]
    e = np.clip((gm.astype(np.float32) - amb) / (alb - amb), 0.0, 1.0)
    return (e * mask).astype(np.float32), mask


def masked_reflectance(gray: np.ndarray, mask: np.ndarray, *,
                       size: tuple[int, int] | None = None, albedo: float | None = None,
                       ambient: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`reflectance` for an object given by a figure mask (uint8 0/1, the image's
    size; :mod:`vtexp.encoding.figure`) instead of Otsu's threshold.

    The object is the mask. If its median is darker than the background's (outside
    the mask), the image is inverted, as :func:`reflectance` does for a dark object on
    a light background. Nothing else of the background is used: the object is seen as
    on the paper's plain ground of zero reflectance. ``ambient``, the gray level of
    zero reflectance, defaults to 0 (the camera's black level); the background's
    median, :func:`reflectance`'s default, is no such level on a textured or unevenly
    lit background. Outside the mask the image is taken as ``ambient``, so a working
    pixel the object covers in part is darker in proportion, as an occluding edge is.
    ``albedo`` defaults to the object's 99th percentile, as in :func:`reflectance`.
    Returns (E, mask) as it does.

    Measured (``bench/scenes.py --figures truth``, 36 composites, the exact mask; IoU of
    the area): with the object's 1st percentile as ambient (or the median of the
    background next to it if darker) and the edge's working pixels at the object's mean,
    0.71 on a plain ground and 0.67 on photographs, against 0.76 for today's pipeline
    on the plain ground; the darker edge alone 0.81 and 0.77; with ambient 0 as well
    0.83 and 0.83, whatever the ground. On seed 000's surfaces on a photograph with a
    light sky, the percentile rule gave 1 line instead of 3 (the vase, the uneven
    surface); ambient 0 gave 3 (docs/decisions.md).
    """
    cv = cv2()
    g = np.asarray(gray)
    if g.dtype != np.uint8:
        g = cv.normalize(g.astype(np.float32), None, 0, 255, cv.NORM_MINMAX).astype(np.uint8)
    full_mask = (np.asarray(mask) != 0).astype(np.uint8)
    out_hw = (size[1], size[0]) if size else g.shape
    empty = (np.zeros(out_hw, np.float32), np.zeros(out_hw, bool))
    # Gray levels counted, not sorted: a frame's medians by histogram are exact and
    # several times faster than numpy's (2.6 ms of a live frame's 27 went to them);
    # OpenCV counts under the mask in half the time numpy's bincount takes to select.
    inside = _histogram(g, full_mask)
    if not inside.any():
        return empty
    outside = _histogram(g) - inside
    if outside.any() and u8_quantile(outside, 0.5) > u8_quantile(inside, 0.5):
        g = cv.bitwise_not(g)                  # dark object on a light background
        inside = inside[::-1]
    amb = 0.0 if ambient is None else float(ambient)
    alb = u8_quantile(inside, 0.99) if albedo is None else float(albedo)
    if alb - amb < 1.0:
        return empty
    # Outside the mask is ``amb``: the edge's working pixels darker where the object
    # covers them in part (at the object's own mean the lowest line fell inside the
    # outline).
    if amb == 0.0:
        flat = cv.multiply(g, full_mask).astype(np.float32)
    else:
        flat = np.where(full_mask > 0, g.astype(np.float32), np.float32(amb))
    return _working(flat, full_mask, size, amb, alb, empty, soft=True)


def _histogram(g: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Counts (int64, 256) of the uint8 ``g``'s levels, where ``mask`` (uint8) is set.
    OpenCV returns float32 counts, exact up to 2**24: larger images are counted by numpy."""
    if g.size >= 1 << 24:
        return np.bincount((g if mask is None else g[mask > 0]).ravel(), minlength=256)
    return cv2().calcHist([g], [0], mask, [256], [0, 256]).ravel().astype(np.int64)


def u8_quantile(counts: np.ndarray, q: float) -> float:
    """``np.percentile(values, 100 * q)`` (its linear interpolation, to the last bit) of
    uint8 ``values`` given as their ``np.bincount`` (at least one value)."""
    cum = np.cumsum(counts)
    n = int(cum[-1])
    at = (n - 1) * q
    lo = math.floor(at)
    t = at - lo
    a = float(np.searchsorted(cum, lo, side="right"))
    b = float(np.searchsorted(cum, min(lo + 1, n - 1), side="right"))
    return b - (b - a) * (1 - t) if t >= 0.5 else a + (b - a) * t


_ROW = np.array([[1, 0, 1]], np.uint8)
_COL = _ROW.T.copy()


def shape_from_shading(e: np.ndarray, mask: np.ndarray, *, min_brightness: float = 0.02,
                       max_iterations: int | None = None) -> np.ndarray:
    """Height map from shading, light at the viewer (seed 000 §2.1.1, eqs. 1-6).

    With the light in the viewing direction the Lambertian reflectance is
    ``R(p, q) = 1 / sqrt(1 + p^2 + q^2)`` (eq. 1), and Tsai and Shah discretise
    ``p``, ``q`` by differences with the neighbouring pixels (eqs. 2-3) to get
    one equation per pixel, ``f(Z) = E - R(p(Z), q(Z)) = 0`` (eq. 4), which they
    solve by Newton's method (eqs. 5-6).

    For this light source Newton's update degenerates: ``df/dZ`` is proportional
    to ``p + q``, which is zero on the flat initial estimate ``Z = 0`` (the
    iteration never leaves it) and small near the silhouette, where ``E -> 0``
    and the steps overshoot. But with ``R`` as above, eq. 4 at a pixel is a
    quadratic in ``Z`` once its neighbours are fixed,
    ``(Z - a)^2 + (Z - b)^2 = 1/E^2 - 1``, so each Newton iteration's fixed
    point has a closed form: we take that root. The differences are taken
    towards the lower neighbour in each direction (``a``, ``b``; upwind), so
    heights grow from the silhouette (``Z = 0``) inwards and the scheme picks
    the convex surface of the two that shading alone cannot tell apart (a ball
    and a bowl look the same under a light at the viewer). Iterates until no
    pixel changes (at most the object's width in iterations).

    Parameters
    ----------
    e : array of float
        Brightness normalised to the albedo, in [0, 1].
    mask : array of bool
        Object pixels; the height is 0 elsewhere.
    min_brightness : float
        ``E`` is clipped below at this value: slopes at the silhouette are at
        most ``sqrt(1/min_brightness^2 - 1)``.

    Returns
    -------
    Z : array of float32, heights in pixels.

    References
    ----------
    Tsai, P.-S. and Shah, M. (1994), Shape from shading using linear
    approximation, Image Vision Comput. 12, 487-498. Seed 000, eqs. 1-6.
    """
    cv = cv2()
    full = np.asarray(mask, bool)
    out = np.zeros(full.shape, np.float32)
    if not full.any():
        return out
    # Work on the object's bounding box with a one-pixel background margin.
    rs, cs = np.nonzero(full.any(axis=1))[0], np.nonzero(full.any(axis=0))[0]
    r0, r1 = max(rs[0] - 1, 0), min(rs[-1] + 2, full.shape[0])
    c0, c1 = max(cs[0] - 1, 0), min(cs[-1] + 2, full.shape[1])
    m = full[r0:r1, c0:c1]
    e = np.clip(np.asarray(e, np.float32)[r0:r1, c0:c1], min_brightness, 1.0)
    slope = np.sqrt(1.0 / (e * e) - 1.0).astype(np.float32)   # |grad Z| demanded by eq. 1
    slope2 = slope * slope
    two_s2 = 2.0 * slope2
    inside = m.astype(np.float32)
    z = np.where(m, np.float32(1e9), np.float32(0.0)).astype(np.float32)
    limit = max_iterations or (m.shape[0] + m.shape[1])
    # Work arrays allocated once: the loop runs tens of times on a few thousand pixels,
    # where allocation would cost as much as the arithmetic.
    a, b, d2, root, one = (np.empty_like(z) for _ in range(5))
    new = np.empty_like(z)
    for it in range(limit):
        # Lower neighbour left/right (a) and up/down (b); outside the box is background.
        cv.erode(z, _ROW, dst=a, borderType=cv.BORDER_CONSTANT, borderValue=0)
        cv.erode(z, _COL, dst=b, borderType=cv.BORDER_CONSTANT, borderValue=0)
        np.subtract(a, b, out=d2)
        np.multiply(d2, d2, out=d2)
        # Both neighbours upwind: the root of (Z-a)^2 + (Z-b)^2 = slope^2 ...
        np.subtract(two_s2, d2, out=root)
        np.maximum(root, 0.0, out=root)
        np.sqrt(root, out=root)
        np.add(root, a, out=root)
        np.add(root, b, out=root)
        root *= 0.5
        # ... unless they differ by more than the slope: then only the lower one counts.
        np.minimum(a, b, out=one)
        one += slope
        np.copyto(root, one, where=d2 >= slope2)
        np.minimum(z, root, out=new)
        new *= inside
        # At the fixed point an iteration changes nothing, so testing for it only
        # every fourth iteration costs at most three idle iterations.
        if it % 4 == 3 and np.array_equal(new, z):
            break
        z, new = new, z
    z[z >= 1e9] = 0.0          # pixels never reached (cannot happen for a connected object)
    out[r0:r1, c0:c1] = z
    return out


def even_light(e: np.ndarray, mask: np.ndarray, *, calibrated: bool = False) -> np.ndarray:
    """E with a planar light ramp taken out: ``log E`` over the object's pixels off its
    rim fitted by a plane, E divided by the plane's slope (about the object's centre)
    and normalised again to its 99th percentile, as the albedo is estimated
    (:func:`reflectance`); with a ``calibrated`` albedo it is not normalised again.

    Seed 000 assumes one light at the viewer (assumption 2), under which a surface
    facing the camera is evenly bright. A lamp to one side brightens a card towards it;
    shape from shading reads the ramp as a slope. A ball's shading is symmetric about
    its centre and has no planar part to take out. Returns E unchanged for an object
    under 12 pixels off its rim.
    """
    cv = cv2()
    m = np.asarray(mask, bool)
    inner = cv.erode(m.astype(np.uint8), _EIGHT).astype(bool) & (e > 0)
    if inner.sum() < 12:
        return e
    ys, xs = np.nonzero(inner)
    x, y = xs - xs.mean(), ys - ys.mean()
    v = np.log(e[inner].astype(np.float64))
    # Least squares for log E = c + a x + b y (x, y centred, so c drops out).
    gram = np.array([[x @ x, x @ y], [x @ y, y @ y]])
    if abs(np.linalg.det(gram)) < 1e-9:
        return e
    a, b = np.linalg.solve(gram, [x @ v, y @ v])
    ramp = np.outer(np.exp(-b * (np.arange(e.shape[0]) - ys.mean())),
                    np.exp(-a * (np.arange(e.shape[1]) - xs.mean()))).astype(np.float32)
    evened = e * ramp
    top = 1.0 if calibrated else float(np.percentile(evened[m], 99))
    return np.clip(evened / max(top, 1e-6), 0.0, 1.0).astype(np.float32) * m


def is_flat(e: np.ndarray, mask: np.ndarray, *, min_brightness: float = 0.02,
            calibrated: bool = False) -> bool:
    """Whether the object is a flat surface facing the camera: over its inside (the
    object less its outermost working pixels), with a planar light ramp taken out of E
    (:func:`even_light`; ``calibrated``: the albedo was given), the median slope eq. 1
    reads, ``sqrt(1/E^2 - 1)``, is under :data:`FLAT_SLOPE`.

    Seed 000's pipeline min-max normalises heights (eq. 7), so any rise, however small,
    becomes a full hill with its three contour lines: a card lit from one side, or
    merely with a camera's noise (E = 0.99 is a slope of 0.14), was played as a mound
    inside its outline, never as the outline a flat object gives
    (:func:`normalise_height`). A flat object keeps ``Z = 0`` and so its outline.

    The outermost working pixels are left out: they are the object's edge seen in part,
    or a figure mask's fringe of shadow and ground, which shape from shading reads as a
    cliff.
    """
    cv = cv2()
    m = np.asarray(mask, bool)
    inner = cv.erode(m.astype(np.uint8), _EIGHT).astype(bool)
    if inner.sum() < 12:
        inner = m
    if not inner.any():
        return False
    evened = even_light(e, inner, calibrated=calibrated)[inner]
    slope = np.sqrt(1.0 / np.square(np.clip(evened, min_brightness, 1.0)) - 1.0)
    return float(np.median(slope)) < FLAT_SLOPE


def normalise_height(height: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Min-max normalisation of the height matrix (seed 000 eq. 7).

    Eq. 7 is printed as ``(Hmax - H)/(H - Hmin)``; the min-max normalisation
    ``h = (H - Hmin)/(Hmax - Hmin)`` is what its text describes
    (docs/decisions.md). As in the paper, ``Hmin`` and ``Hmax`` are taken over
    the whole height matrix H, whose minimum is the background plane at 0 on
    which the object's silhouette stands; the object's lowest pixels are then
    a little above 0, as they are on the real surface.
    """
    m = np.asarray(mask, bool)
    h = np.zeros(height.shape, np.float32)
    if not m.any():
        return h
    lo = min(float(height.min()), 0.0)
    hi = float(height.max())
    if hi > lo:
        h[m] = (height[m] - lo) / (hi - lo)
    else:
        # A flat object (uniform shading: it faces the camera) stands as a whole above
        # the background; its one contour line is then its outline.
        h[m] = 1.0
    return h


def count_lines(h: np.ndarray, mask: np.ndarray,
                thresholds: tuple[float, float] = VARIANCE_THRESHOLDS) -> tuple[int, float]:
    """Number of contour lines by the variance rule (seed 000 eqs. 8-9, step 4).

    The mean and variance are taken over the object's pixels: over the whole
    image, the background's zeros would make the variance depend on how large
    the object is in the frame. ``Var < 0.02`` -> 1 line, ``0.02 <= Var < 0.06``
    -> 3 lines, ``Var >= 0.06`` -> 5 lines (the paper leaves ``Var = 0.02`` open;
    it is given to 3). Returns (number of lines, variance).
    """
    m = np.asarray(mask, bool)
    if not m.any():
        return 0, 0.0
    v = float(np.var(h[m], dtype=np.float64))
    lo, hi = thresholds
    return (1 if v < lo else 3 if v < hi else 5), v


def line_heights(n_lines: int, h_min: float = 0.0, h_max: float = 1.0,
                 rule: str = "interior") -> list[float]:
    """Heights of the contour lines (seed 000 eq. 10).

    ``paper``: eq. 10 as printed, ``tp_k = h_min + k (h_max - h_min)/N``,
    k = 1..N; its top line lies at ``h_max``, which is a single point on a
    smooth surface. ``outline``: k = 0..N-1, the lowest line is the object's
    outline. ``interior`` (default): ``tp_k = h_min + k (h_max - h_min)/(N+1)``,
    k = 1..N, evenly spaced in height strictly between the lowest and highest
    points, so every line is a closed ring. Equal height steps are what make
    the cone's rings evenly spaced and the ball's not (seed 000 Fig. 3).
    """
    if n_lines <= 0:
        return []
    span = h_max - h_min
    if rule == "paper":
        return [h_min + k * span / n_lines for k in range(1, n_lines + 1)]
    if rule == "outline":
        return [h_min + k * span / n_lines for k in range(n_lines)]
    if rule == "interior":
        return [h_min + k * span / (n_lines + 1) for k in range(1, n_lines + 1)]
    raise ValueError(f"unknown level rule {rule!r}")


_EIGHT = np.ones((3, 3), np.uint8)


def sharpen(h: np.ndarray, mask: np.ndarray, heights: list[float]) -> np.ndarray:
    """The contour map S: ``S = k`` on the k-th line, 0 elsewhere (seed 000 §2.2.1).

    For line k, pixels below ``tp_k`` are black and the others white; a pixel
    is on the line if its 8-neighbourhood holds both. Taking only the white
    pixels with a black 8-neighbour gives a line one pixel wide (taking both
    sides would give two). Where lines touch, the higher line wins.
    """
    cv = cv2()
    s = np.zeros(h.shape, np.int16)
    m = np.asarray(mask, bool)
    for k, tp in enumerate(heights, start=1):
        white = (m & (h >= tp)) if tp > 0 else m
        if not white.any():
            continue
        # A white pixel with a black pixel in its 8-neighbourhood: white minus its erosion.
        eroded = cv.erode(white.astype(np.uint8), _EIGHT, borderType=cv.BORDER_CONSTANT,
                          borderValue=0).astype(bool)
        s[white & ~eroded] = k
    return s


def lattice_shape(m: int, n: int, rows: int, cols: int) -> tuple[int, int]:
    """Size (rows, cols) of the lattice an ``m x n`` map occupies (seed 000 eq. 11).

    Eq. 11 for a square 20 x 20 array, ``w = ceil(m / max(m, n) * 20)``, keeps
    the aspect ratio; for an array of ``rows x cols`` the scale is the largest
    that fits both sides.
    """
    scale = min(rows / m, cols / n)
    return min(rows, math.ceil(m * scale - 1e-9)), min(cols, math.ceil(n * scale - 1e-9))


def map_to_array(s: np.ndarray, n_lines: int, rows: int, cols: int, *,
                 proportion: float = PROPORTION, align: str = "center") -> np.ndarray:
    """Map the contour map S onto the array: M (seed 000 §2.2.2, eq. 11, rules 1-3).

    S is divided into the regions of the eq. 11 lattice, one per motor. A
    region without line pixels is 0 (rule 1); otherwise the line with the most
    pixels in it (rule 3; the only one, rule 2) claims the motor if its pixels
    are more than ``proportion`` (0.01) of the region. The lattice is placed on
    the array centred (or at the top left, the paper's origin).
    """
    m, n = s.shape
    lr, lc = lattice_shape(m, n, rows, cols)
    out = np.zeros((rows, cols), np.int16)
    if n_lines <= 0:
        return out
    r_edges = np.linspace(0, m, lr + 1).round().astype(int)
    c_edges = np.linspace(0, n, lc + 1).round().astype(int)
    area = np.outer(np.diff(r_edges), np.diff(c_edges)).astype(np.float64)
    counts = np.zeros((n_lines + 1, lr, lc))
    equal_blocks = m % lr == 0 and n % lc == 0
    for k in range(1, n_lines + 1):
        if equal_blocks:                        # count by reshaping into the blocks
            counts[k] = (s.reshape(lr, m // lr, lc, n // lc) == k).sum(axis=(1, 3))
            continue
        on = (s == k).astype(np.float64)
        # Pixel counts per region by cumulative sums at the region edges.
        cs = np.zeros((m + 1, n + 1))
        cs[1:, 1:] = on.cumsum(0).cumsum(1)
        counts[k] = (cs[np.ix_(r_edges[1:], c_edges[1:])] - cs[np.ix_(r_edges[:-1], c_edges[1:])]
                     - cs[np.ix_(r_edges[1:], c_edges[:-1])] + cs[np.ix_(r_edges[:-1], c_edges[:-1])])
    best = counts[1:].argmax(axis=0) + 1
    share = counts[1:].max(axis=0) / np.maximum(area, 1)
    lattice = np.where((counts[1:].max(axis=0) > 0) & (share > proportion), best, 0)
    r0, c0 = ((rows - lr) // 2, (cols - lc) // 2) if align == "center" else (0, 0)
    out[r0:r0 + lr, c0:c0 + lc] = lattice
    return out


# --------------------------------------------------------------------------- pipeline

def height_contours(gray: np.ndarray, rows: int, cols: int, *, lines="variance",
                    levels: str = "interior", proportion: float = PROPORTION,
                    cells_per_motor: int = 4, align: str = "center",
                    min_brightness: float = 0.02, albedo: float | None = None,
                    ambient: float | None = None, mask: np.ndarray | None = None) -> Pattern:
    """Image -> contour lines of the object's height on the array (seed 000 §2).

    ``mask`` (uint8 0/1 of the image's height x width) is the object if given
    (:func:`masked_reflectance`); an all-zero mask gives an empty Pattern.

    Returns a Pattern whose points are the motors of M, each with ``line`` = k
    (1 = lowest). ``params`` records the number of lines, the variance, the line
    heights, the lattice size and where the image lies on the array
    (``to_array``, :mod:`vtexp.encoding.mapping`), for the session log.

    Examples
    --------
    >>> from vtexp.stimuli.surfaces import render_surface
    >>> pat = height_contours(render_surface(surface="ball"), 20, 20)
    >>> pat.params["n_lines"], pat.lines()
    (3, [1, 2, 3])
    """
    g = np.asarray(gray)
    if g.ndim != 2 or g.size == 0:
        raise ValueError("expected a 2-D grayscale image")
    m, n = g.shape
    if mask is not None:
        mask = given_mask(mask, g.shape, "height-contours")
    lr, lc = lattice_shape(m, n, rows, cols)
    # Working resolution: at least cells_per_motor pixels per motor of the lattice,
    # reached by an integer reduction factor f (area averaging over f x f blocks is
    # OpenCV's fast path; the last m % f rows and n % f columns are left out).
    f = max(1, min(n // max(lc * cells_per_motor, 1), m // max(lr * cells_per_motor, 1)))
    if f > 1:
        g = g[:m - m % f, :n - n % f]
        mask = None if mask is None else mask[:m - m % f, :n - n % f]
    wh = (g.shape[1] // f, g.shape[0] // f)
    e, mask = reflectance(g, size=wh, albedo=albedo, ambient=ambient, mask=mask)
    flat = is_flat(e, mask, min_brightness=min_brightness, calibrated=albedo is not None)
    z = (np.zeros(e.shape, np.float32) if flat
         else shape_from_shading(e, mask, min_brightness=min_brightness))
    return _contour_pattern(z, mask, rows, cols, f=f, wh=wh, lattice=(lr, lc), lines=lines,
                            levels=levels, proportion=proportion, align=align,
                            given={"lines": lines, "levels": levels, "proportion": proportion,
                                   "cells_per_motor": cells_per_motor, "align": align,
                                   "albedo": albedo, "ambient": ambient, "flat": flat})


def height_contours_of_heights(height: np.ndarray, mask: np.ndarray, rows: int, cols: int, *,
                               lines="variance", levels: str = "interior",
                               proportion: float = PROPORTION, cells_per_motor: int = 4,
                               align: str = "center", **_image_only) -> Pattern:
    """A height map (the image's size) -> contour lines on the array: steps 3-7 of
    :func:`height_contours` on heights that are known rather than inferred from shading.

    What a participant told that "the greater vibration intensity represents a greater
    height value" (seed 000 §3.4) expects a named surface to feel like: its true heights (e.g.
    :func:`vtexp.stimuli.surfaces.surface_height`) drawn by the same contour rules and
    array mapping as a camera image would be. The working resolution is reduced as
    :func:`height_contours` reduces the image (area averages of ``cells_per_motor``
    pixels per actuator). Parameters that only concern shading (``albedo``,
    ``ambient``, ``min_brightness``) are accepted and ignored.
    """
    cv = cv2()
    z = np.asarray(height, np.float32)
    if z.ndim != 2 or z.size == 0 or z.shape != np.shape(mask):
        raise ValueError("expected a 2-D height map and a mask of its size")
    m, n = z.shape
    lr, lc = lattice_shape(m, n, rows, cols)
    f = max(1, min(n // max(lc * cells_per_motor, 1), m // max(lr * cells_per_motor, 1)))
    zz = z[:m - m % f, :n - n % f]
    mm = np.asarray(mask, np.float32)[:m - m % f, :n - n % f]
    wh = (zz.shape[1] // f, zz.shape[0] // f)
    if f > 1:
        zz = cv.resize(zz, wh, interpolation=cv.INTER_AREA)
        mm = cv.resize(mm, wh, interpolation=cv.INTER_AREA)
    work_mask = mm > 0.5
    zz = np.where(work_mask, zz, 0.0)
    return _contour_pattern(zz, work_mask, rows, cols, f=f, wh=wh, lattice=(lr, lc),
                            lines=lines, levels=levels, proportion=proportion, align=align,
                            given={"lines": lines, "levels": levels, "proportion": proportion,
                                   "cells_per_motor": cells_per_motor, "align": align,
                                   "heights": "given"})


def _contour_pattern(z: np.ndarray, mask: np.ndarray, rows: int, cols: int, *, f: int,
                     wh: tuple[int, int], lattice: tuple[int, int], lines, levels: str,
                     proportion: float, align: str, given: dict) -> Pattern:
    """Steps 3-7 on a height map at the working resolution ``wh`` (reduced ``f`` times)."""
    lr, lc = lattice
    h = normalise_height(z, mask)
    if lines == "variance":
        n_lines, var = count_lines(h, mask)
    else:
        n_lines, var = int(lines), count_lines(h, mask)[1]
    tps = line_heights(n_lines, 0.0, 1.0, levels)
    s = sharpen(h, mask, tps)
    arr = map_to_array(s, n_lines, rows, cols, proportion=proportion, align=align)
    points = [{"row": int(r), "col": int(c), "line": int(arr[r, c])}
              for r, c in zip(*np.nonzero(arr), strict=True)]
    # Where the lattice put the image (eq. 11): motor centre = centre of its region.
    mh, mw = wh[1], wh[0]
    r0, c0 = ((rows - lr) // 2, (cols - lc) // 2) if align == "center" else (0, 0)
    rs, cs = lr / (f * mh), lc / (f * mw)
    to_array = {"row": [round(rs, 9), round(r0 + 0.5 * rs - 0.5, 9)],
                "col": [round(cs, 9), round(c0 + 0.5 * cs - 0.5, 9)]}
    return Pattern.model_validate({
        "rows": rows, "cols": cols, "points": points, "pipeline": "height-contours",
        "params": {**given, "n_lines": n_lines, "variance": round(var, 6),
                   "line_heights": [round(t, 6) for t in tps], "lattice": [lr, lc],
                   "to_array": to_array}})
