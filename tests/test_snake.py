"""Snake and corners (seed 002 §3.1-3.2): accuracy on rendered shapes, the grid mapping,
and the greedy algorithm checked against a plain sequential transcription of it."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from vtexp.encoding import PIPELINES
from vtexp.encoding.phantom_grid import fit_to_array, grid_path
from vtexp.encoding.snake import (
    SnakeCornersParams,
    contour_corners,
    edge_strength,
    find_outline,
    greedy_snake,
    initial_contour,
    outline_mask,
    snake_corners,
)
from vtexp.errors import InputError
from vtexp.stimuli import SHAPES, render_shape
from vtexp.stimuli.shapes import ShapeParams, _shape_polygon

VERTICES = {"triangle": 3, "square": 4, "rectangle": 4, "circle": 0}


def iou(points: np.ndarray, params: dict) -> float:
    """IoU of an outline with the rendered shape (pixels more than half covered)."""
    truth = render_shape(**{**params, "background": 0, "foreground": 255, "noise_sd": 0}) > 127
    m = outline_mask(points, truth.shape)
    return float((m & truth).sum() / (m | truth).sum())


def corner_errors(res, params: dict) -> np.ndarray:
    """Distance from each true vertex to the nearest corner found (pixels)."""
    # (x, y) in image coordinates (0 at the frame's edge); the snake's points are in
    # pixel-centre coordinates (pixel i centred at i): half a pixel apart.
    poly = _shape_polygon(ShapeParams(**params)) - 0.5
    found = res.points[res.corner]                          # (row, col)
    d = np.hypot(poly[:, None, 1] - found[None, :, 0], poly[:, None, 0] - found[None, :, 1])
    return d.min(axis=1)


# --------------------------------------------------------------------------- accuracy

@pytest.mark.parametrize("shape", SHAPES)
def test_study_shapes_outline_and_corners_at_320x240(shape):
    """Issue 3: IoU >= 0.9 and corners within 2 px at 320x240. Measured: IoU 0.992-1.000,
    corner error <= 0.8 px; the bound below is tighter than the issue's so a
    regression shows."""
    params = {"shape": shape}
    res = find_outline(render_shape(**params))
    assert iou(res.points, params) >= 0.97
    assert int(res.corner.sum()) == VERTICES[shape]
    if VERTICES[shape]:
        assert corner_errors(res, params).max() <= 2.0


def test_working_resolution_does_not_cost_accuracy_at_640x480():
    for shape in ("circle", "square", "triangle"):
        params = {"shape": shape, "width": 640, "height": 480}
        res = find_outline(render_shape(**params))
        assert res.factor == 4
        assert iou(res.points, params) >= 0.98
        if VERTICES[shape]:
            # Half a working pixel at f = 4 is 2 px; measured 2.02 px on the triangle's apex
            # against the exactly rendered shape (render_shape integrates the pixel area).
            assert corner_errors(res, params).max() <= 2.5


def _inside(params: dict, margin: float = 10.0) -> bool:
    p = ShapeParams(**params)
    poly = _shape_polygon(p)
    if poly is None:
        r = p.size * p.height / 2
        cx, cy = p.center_x * p.width, p.center_y * p.height
        return margin <= cx - r and cx + r <= p.width - margin and margin <= cy - r \
            and cy + r <= p.height - margin
    return bool(poly[:, 0].min() >= margin and poly[:, 0].max() <= p.width - margin
                and poly[:, 1].min() >= margin and poly[:, 1].max() <= p.height - margin)


shape_params = st.fixed_dictionaries({
    "shape": st.sampled_from(SHAPES),
    "rotation_deg": st.floats(0, 360),
    "center_x": st.floats(0.3, 0.7),
    "center_y": st.floats(0.3, 0.7),
    "size": st.floats(0.3, 0.7),
})


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(params=shape_params, background=st.integers(0, 200), contrast=st.integers(15, 215))
def test_rotation_offset_size_and_low_contrast_without_noise(params, background, contrast):
    """Any rotation, offset and size that keeps the shape 10 px inside the frame, contrast
    down to 15 grey levels: IoU >= 0.95, every vertex found within 2 px, no extra corner.

    IoU counts whole pixels: when an edge runs along a pixel row, an error of 0.15 px can
    move the whole row in or out (about 1.6 % of a small square's area), so the bound
    leaves room for that and still catches an outline that is a pixel off."""
    assume(_inside(params))
    assume(background + contrast <= 255)
    params = {**params, "background": background, "foreground": background + contrast}
    res = find_outline(render_shape(**params))
    assert iou(res.points, params) >= 0.95
    assert int(res.corner.sum()) == VERTICES[params["shape"]]
    if VERTICES[params["shape"]]:
        assert corner_errors(res, params).max() <= 2.0


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(params=shape_params, contrast=st.integers(30, 170), snr=st.floats(6, 40),
       seed=st.integers(0, 2**16))
def test_noise_tolerance(params, contrast, snr, seed):
    """Gaussian noise up to a sixth of the contrast (sd <= contrast / 6): IoU >= 0.95,
    the right number of corners, each within 2.5 px. (Measured over 400 random cases:
    IoU >= 0.986, corner error <= 1.8 px; below contrast / 4 corners start to be
    missed or invented.)"""
    assume(_inside(params))
    params = {**params, "background": 60, "foreground": 60 + contrast,
              "noise_sd": contrast / snr, "seed": seed}
    res = find_outline(render_shape(**params))
    assert iou(res.points, params) >= 0.95
    assert int(res.corner.sum()) == VERTICES[params["shape"]]
    if VERTICES[params["shape"]]:
        assert corner_errors(res, params).max() <= 2.5


def test_corners_only_where_the_outline_turns():
    gray = render_shape(shape="circle", size=0.8)
    work = gray[::2, ::2]
    smooth, gx, gy, _ = edge_strength(work)
    init = initial_contour(smooth, spacing_px=4, min_area=0.001)
    assert len(contour_corners(smooth, gx, gy, init)) == 0
    # ... while a plain goodFeaturesToTrack, whose threshold is relative, finds "corners"
    # along the circle: the isotropy test is what rejects them.
    assert len(contour_corners(smooth, gx, gy, init, isotropy=0.0)) > 0


def test_corners_can_be_switched_off_and_the_outline_stays():
    params = {"shape": "square"}
    res = find_outline(render_shape(**params), corners=False)
    assert not res.corner.any()
    assert iou(res.points, params) >= 0.95


# --------------------------------------------------------------------------- the greedy algorithm

def reference_sweep(edge, pts, betas, *, alpha, gamma, window, order, corner_curvature,
                    corner_edge):
    """One sweep of Williams & Shah's greedy algorithm, point after point, as written in
    their paper (and cvSnakeImage), visiting the points in ``order``."""
    h_img, w_img = edge.shape
    n = len(pts)
    half = window // 2
    pts = [complex(c, r) for r, c in pts]
    d_mean = sum(abs(pts[i] - pts[i - 1]) for i in range(n)) / n
    offs = [(0, 0)] + [(dr, dc) for dr in range(-half, half + 1)
                       for dc in range(-half, half + 1) if (dr, dc) != (0, 0)]
    moved = 0
    for i in order:
        prev, nxt, cur = pts[i - 1], pts[(i + 1) % n], pts[i]
        cands = [cur + complex(dc, dr) for dr, dc in offs]
        cont = [abs(d_mean - abs(v - prev)) for v in cands]
        curv = [abs((prev + nxt - 2 * cur) - 2 * complex(dc, dr)) ** 2 for dr, dc in offs]
        mags = [float(edge[int(v.imag), int(v.real)]) for v in cands]
        mx_cont, mx_curv = max(max(cont), 1e-12), max(max(curv), 1e-12)
        g_max = max(mags)
        g_min = min(min(mags), g_max - 5.0)
        energies = []
        for k, v in enumerate(cands):
            inside = half <= v.imag <= h_img - 1 - half and half <= v.real <= w_img - 1 - half
            e_img = (g_min - mags[k]) * (gamma / (g_max - g_min)) if inside else math.inf
            energies.append(cont[k] * (alpha / mx_cont) + curv[k] * (betas[i] / mx_curv)
                            + e_img)
        best = int(np.argmin(energies))
        if best:
            moved += 1
        pts[i] = cands[best]
    betas = list(betas)
    u = [pts[i] - pts[i - 1] for i in range(n)]
    u = [x / abs(x) if abs(x) > 0 else 0j for x in u]
    c = [abs(u[i] - u[(i + 1) % n]) ** 2 for i in range(n)]
    for i in range(n):
        r, col = int(pts[i].imag), int(pts[i].real)
        if (c[i] > c[i - 1] and c[i] > c[(i + 1) % n] and c[i] > corner_curvature
                and edge[r, col] > corner_edge):
            betas[i] = 0.0
    return np.array([[int(z.imag), int(z.real)] for z in pts]), betas, moved


@pytest.mark.parametrize("n", [24, 25])
def test_vectorised_sweeps_equal_the_sequential_algorithm(n):
    """Every point makes exactly the move of Williams & Shah's sequential sweep that visits
    even indices, then odd ones (and the last point of an odd count on its own)."""
    rng = np.random.default_rng(n)
    yy, xx = np.mgrid[:80, :90]
    ring = np.exp(-((np.hypot(yy - 40, xx - 45) - 25) ** 2) / 8)
    edge = (60 * ring + rng.uniform(0, 6, ring.shape)).astype(np.float32)
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    pts = np.c_[40 + 31 * np.sin(t), 45 + 31 * np.cos(t)].round().astype(np.int64)
    pts += rng.integers(-2, 3, pts.shape)
    order = list(range(0, n - (n % 2), 2)) + list(range(1, n, 2)) + ([n - 1] if n % 2 else [])
    kw = {"alpha": 1.0, "gamma": 1.2, "window": 3, "corner_curvature": 0.25,
          "corner_edge": 10.0}
    ref, betas = pts.copy(), [1.0] * n
    for sweeps in range(1, 6):
        ref, betas, _ = reference_sweep(edge, ref, betas, order=order, **kw)
        got, got_betas, its = greedy_snake(edge, pts, beta=1.0, max_iterations=sweeps,
                                           stop_fraction=0.0, **kw)
        assert its == sweeps
        np.testing.assert_array_equal(got, ref)
        np.testing.assert_array_equal(got_betas, betas)


def test_greedy_snake_settles_on_the_edge_and_stops():
    yy, xx = np.mgrid[:64, :64]
    edge = (50 * np.exp(-((np.hypot(yy - 32, xx - 32) - 20) ** 2) / 4)).astype(np.float32)
    t = np.linspace(0, 2 * np.pi, 32, endpoint=False)
    init = np.c_[32 + 26 * np.sin(t), 32 + 26 * np.cos(t)].round().astype(int)
    pts, _, its = greedy_snake(edge, init, max_iterations=500, stop_fraction=0.05)
    assert its < 500
    assert np.abs(np.hypot(pts[:, 0] - 32, pts[:, 1] - 32) - 20).max() <= 1.5


def test_fixed_points_do_not_move():
    edge = np.zeros((40, 40), np.float32)
    edge[10:30, 10] = edge[10:30, 29] = edge[10, 10:30] = edge[29, 10:30] = 40
    init = np.array([[5, 5], [5, 20], [5, 34], [20, 34], [34, 34], [34, 20], [34, 5], [20, 5]])
    fixed = np.zeros(8, bool)
    fixed[[0, 3]] = True
    pts, _, _ = greedy_snake(edge, init, fixed=fixed, max_iterations=50)
    np.testing.assert_array_equal(pts[fixed], init[fixed])
    assert (pts[~fixed] != init[~fixed]).any()


# --------------------------------------------------------------------------- the pattern

def _cheb(a, b):
    return max(abs(a[0] - b[0]), abs(a[1] - b[1]))


@pytest.mark.parametrize("shape", SHAPES)
def test_pattern_is_one_clockwise_loop_on_the_9x9_grid(shape):
    pat = snake_corners(render_shape(shape=shape), 5, 5)
    pts = [(p.row, p.col) for p in pat.ordered()]
    assert pat.pipeline == "snake-corners" and pat.closed == [0] and pat.lines() == [0]
    assert [p.order for p in pat.ordered()] == list(range(len(pts)))
    assert all((2 * r).is_integer() and (2 * c).is_integer() for r, c in pts)   # half pins
    assert len(set(pts)) == len(pts) >= 8
    steps = [_cheb(a, b) for a, b in zip(pts, pts[1:] + pts[:1])]
    assert max(steps) == 0.5                     # 8-neighbours on the 9x9 grid, loop closed
    assert pts[0] == min(pts)                    # starts at its first point in raster order
    x, y = np.array([c for _, c in pts]), np.array([r for r, _ in pts])
    assert np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) > 0         # clockwise as felt
    assert sum(p.corner for p in pat.points) == VERTICES[shape]


def test_square_corners_fall_on_the_corner_pins():
    pat = snake_corners(render_shape(shape="square", rotation_deg=0), 5, 5)
    assert {(p.row, p.col) for p in pat.points if p.corner} == {(0, 0), (0, 4), (4, 0), (4, 4)}


def test_rectangle_keeps_its_aspect_ratio_and_the_triangle_is_not_a_rectangle():
    pat = snake_corners(render_shape(shape="rectangle"), 5, 5)
    rows = [p.row for p in pat.points]
    cols = [p.col for p in pat.points]
    assert (max(cols) - min(cols)) == 4 and (max(rows) - min(rows)) == pytest.approx(4 / 1.5,
                                                                                  abs=0.5)
    # Seed 002 Fig. 8-9: on the pins alone a triangle turns into a rectangle; with the
    # phantom points its slanted sides are kept.
    tri = snake_corners(render_shape(shape="triangle"), 5, 5)
    slanted = [(a, b) for a, b in zip(tri.ordered(), tri.ordered()[1:])
               if a.row != b.row and a.col != b.col]
    assert len(slanted) >= 4


def test_pins_only_grid_without_phantom_points():
    pat = snake_corners(render_shape(shape="circle"), 5, 5, subdivisions=1)
    pts = [(p.row, p.col) for p in pat.ordered()]
    assert all(r.is_integer() and c.is_integer() for r, c in pts)
    assert max(_cheb(a, b) for a, b in zip(pts, pts[1:] + pts[:1])) == 1


def test_grid_path_keeps_a_sharp_apex_as_a_spike():
    """Two sides of an apex narrower than the grid step meet the same grid point: the
    path goes out to the apex and back rather than jumping."""
    pts = np.array([[0.0, 2.0], [4.0, 2.2], [4.0, 1.8]])
    grid, corner, _, _ = grid_path(pts, np.array([True, False, False]), 5, 5,
                                                closed=True, subdivisions=2)
    g = [tuple(x) for x in grid]
    assert max(_cheb(a, b) for a, b in zip(g, g[1:] + g[:1])) <= 0.5
    assert g[0] == (0.0, 2.0) and corner[0]


def test_fit_keeps_aspect_ratio_and_centres():
    pts = np.array([[10, 0], [10, 300], [110, 300], [110, 0]], float)   # 3:1, wide
    out = fit_to_array(pts, 5, 5)
    assert out[:, 1].min() == 0 and out[:, 1].max() == 4
    assert out[:, 0].min() == pytest.approx(2 - 2 / 3) and out[:, 0].max() == pytest.approx(2 + 2 / 3)


# --------------------------------------------------------------------------- bad input

@pytest.mark.parametrize("image", [
    np.zeros((240, 320), np.uint8),
    np.full((240, 320), 255, np.uint8),
    np.full((480, 640), 128, np.uint8),
    np.full((16, 16), 7, np.uint8),
])
def test_uniform_image_gives_an_empty_pattern_and_a_warning(image):
    with pytest.warns(UserWarning, match="no object found"):
        pat = snake_corners(image, 5, 5)
    assert pat.points == [] and pat.closed == []
    assert "no object found" in pat.params["warnings"][0]


def test_bad_arrays_are_refused_with_a_message():
    with pytest.raises(InputError, match="2-D grayscale"):
        snake_corners(np.zeros((240, 320, 3), np.uint8), 5, 5)
    with pytest.raises(InputError, match="at least 16x16"):
        snake_corners(np.zeros((8, 8), np.uint8), 5, 5)


def test_awkward_but_valid_images():
    # a shape cut by the border, float input with NaN, a huge frame, a tiny object
    cut = render_shape(shape="square", center_x=0.95)
    assert snake_corners(cut, 5, 5).closed == [0]
    f = render_shape(shape="circle").astype(np.float64)
    f[0, 0] = np.nan
    assert snake_corners(f, 5, 5).closed == [0]
    big = render_shape(shape="triangle", width=4000, height=3000)
    res = find_outline(big)
    assert res.factor == 25 and int(res.corner.sum()) == 3
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        tiny = render_shape(shape="circle", size=0.05)
        assert snake_corners(tiny, 5, 5).points


def test_parameters_are_checked_and_registered():
    fn, model = PIPELINES["snake-corners"]
    assert fn is snake_corners and model is SnakeCornersParams
    with pytest.raises(ValueError):
        SnakeCornersParams(window=4)
    with pytest.raises(ValueError):
        SnakeCornersParams(unknown=1)
