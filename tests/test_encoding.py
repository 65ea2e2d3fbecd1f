"""Edge trace (seed 001 §3): shapes become one ordered closed loop on the vest."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from vtexp.coding import sequential_trace
from vtexp.encoding import edge_trace, follow_contour
from vtexp.model import DeviceProfile
from vtexp.stimuli import SHAPES, read_image, render_shape

VEST = DeviceProfile.load("vest_6x8")


def test_follow_contour_on_a_ring_visits_every_cell_once_clockwise():
    ring = np.zeros((5, 6), bool)
    ring[1, 1:5] = ring[3, 1:5] = ring[1:4, 1] = ring[1:4, 4] = True
    [(path, vertex, closed)] = follow_contour(ring)
    assert closed and len(path) == ring.sum() == len(set(path))
    # Head: first non-zero cell in raster order; then east along the top (clockwise).
    assert path[:4] == [(1, 1), (1, 2), (1, 3), (1, 4)]
    assert path[4] == (2, 4)
    # Vertices where the chain code changes: the four corners.
    assert {p for p, v in zip(path, vertex) if v} == {(1, 1), (1, 4), (3, 4), (3, 1)}


def test_open_path_and_separate_pieces_are_all_kept():
    g = np.zeros((4, 8), bool)
    g[1, 0:3] = True          # an open path
    g[3, 5:8] = True          # another one
    res = follow_contour(g)
    assert [(len(p), c) for p, _, c in res] == [(3, False), (3, False)]
    assert sum(len(p) for p, _, _ in res) == g.sum()


@pytest.mark.parametrize("shape", SHAPES)
def test_each_study_shape_is_one_closed_loop_on_the_vest(shape):
    pat = edge_trace(render_shape(shape=shape), VEST.rows, VEST.cols)
    assert pat.closed == [0] and pat.lines() == [0]
    cells = [(int(p.row), int(p.col)) for p in pat.ordered()]
    assert len(cells) == len(set(cells)) >= 8
    assert [p.order for p in pat.ordered()] == list(range(len(cells)))
    steps = [max(abs(a[0] - b[0]), abs(a[1] - b[1])) for a, b in zip(cells, cells[1:] + cells[:1])]
    assert steps == [1] * len(cells)         # each step to an 8-neighbour, and back to the head


def test_square_vertices_are_its_corners():
    pat = edge_trace(render_shape(shape="square"), VEST.rows, VEST.cols)
    rows = [p.row for p in pat.points]
    cols = [p.col for p in pat.points]
    corners = {(min(rows), min(cols)), (min(rows), max(cols)), (max(rows), min(cols)),
               (max(rows), max(cols))}
    assert {(p.row, p.col) for p in pat.points if p.vertex} == corners


def test_rectangle_keeps_its_aspect_ratio_in_the_portrait_vest():
    pat = edge_trace(render_shape(shape="rectangle"), VEST.rows, VEST.cols)
    h = max(p.row for p in pat.points) - min(p.row for p in pat.points) + 1
    w = max(p.col for p in pat.points) - min(p.col for p in pat.points) + 1
    assert w > h            # wider than tall, as drawn, though the array is portrait


def test_uniform_image_gives_an_empty_pattern():
    assert edge_trace(np.full((240, 320), 128, np.uint8), 8, 6).points == []


def test_sequential_trace_uses_soa_onset_to_onset_and_vertex_levels():
    pat = edge_trace(render_shape(shape="square"), VEST.rows, VEST.cols)
    s = sequential_trace(pat, VEST, duration_ms=300, soa_ms=200, loops=2)
    n = len(pat.points)
    assert len(s.pulses) == 2 * n
    assert [p.onset_ms for p in s.pulses] == [200.0 * k for k in range(2 * n)]
    assert all(p.duration_ms == 300 for p in s.pulses)
    ordered = pat.ordered()
    assert [p.level for p in s.pulses[:n]] == [2 if q.vertex else 1 for q in ordered]
    assert s.duration_ms == 200 * (2 * n - 1) + 300


def test_image_files_of_any_depth_and_colour(tmp_path):
    from vtexp._cv2 import cv2
    cv = cv2()
    gray = render_shape(shape="circle")
    cv.imwrite(str(tmp_path / "g.png"), gray)
    cv.imwrite(str(tmp_path / "c.jpg"), cv.cvtColor(gray, cv.COLOR_GRAY2BGR))
    cv.imwrite(str(tmp_path / "w.png"), gray.astype(np.uint16) * 257)
    for f in ("g.png", "c.jpg", "w.png"):
        img = read_image(tmp_path / f)
        assert img.shape == gray.shape and img.dtype == np.uint8
        assert np.abs(img.astype(int) - gray).mean() < 3


def test_cv2_is_the_contrib_build():
    from vtexp._cv2 import cv2
    assert hasattr(cv2(), "ximgproc")


def test_rotated_and_scaled_shapes_mostly_give_one_closed_loop():
    # docs/decisions.md: starting the search one step counter-clockwise of the
    # inherited direction closes 213 of these 216 outlines (148 without it).
    from vtexp.encoding.edge_trace import boundary, cells_covered, object_mask
    good = 0
    for shape in SHAPES:
        for rot in range(0, 90, 5):
            for size in (0.5, 0.7, 0.9):
                img = render_shape(shape=shape, rotation_deg=rot, size=size)
                res = follow_contour(boundary(cells_covered(object_mask(img), 8, 6)))
                good += len(res) == 1 and res[0][2]
    assert good >= 213


@settings(max_examples=60, deadline=None)
@given(shape=st.sampled_from(SHAPES), rot=st.floats(0, 360), dx=st.floats(0.4, 0.6),
       dy=st.floats(0.4, 0.6), size=st.floats(0.5, 0.8), noise=st.floats(0, 8),
       contrast=st.integers(60, 190))
# found by hypothesis: noise pixels past Otsu's threshold stretched the object's box, and
# the triangle lost 7 of its 12 cells
@example(shape="triangle", rot=0.0, dx=0.5, dy=0.5, size=0.5, noise=7.5, contrast=60)
def test_outline_tolerates_rotation_offset_noise_and_low_contrast(shape, rot, dx, dy, size,
                                                                  noise, contrast):
    # Stated tolerance: any rotation, offsets of +-10 % of the frame, sizes 50-80 % of
    # the height, sensor noise up to 8 gray levels, contrast down to 60 levels. Every
    # edge cell is visited exactly once, and the longest list is a closed loop holding
    # at least 80 % of the cells (a stray corner cell may form its own list).
    img = render_shape(shape=shape, rotation_deg=rot, center_x=dx, center_y=dy, size=size,
                       noise_sd=noise, background=60, foreground=60 + contrast, seed=3)
    pat = edge_trace(img, VEST.rows, VEST.cols)
    cells = [(int(p.row), int(p.col)) for p in pat.points]
    assert len(cells) == len(set(cells)) >= 6
    sizes = {k: sum(p.line == k for p in pat.points) for k in pat.lines()}
    main = max(sizes, key=sizes.get)
    assert main in pat.closed and sizes[main] >= 0.8 * len(cells)


def test_shape_touching_the_border_and_huge_images():
    # Half the square outside the frame: still an outline, no error.
    cut = render_shape(shape="square", center_x=0.95, size=0.6)
    pat = edge_trace(cut, VEST.rows, VEST.cols)
    assert pat.points and len({(p.row, p.col) for p in pat.points}) == len(pat.points)
    huge = render_shape(shape="circle", width=6000, height=4500)
    pat = edge_trace(huge, VEST.rows, VEST.cols)
    assert pat.closed == [0]


def _render_shape_testing_every_sample(**params) -> np.ndarray:
    """render_shape as it was first written: all 4 x 4 samples of every pixel in the
    shape's box tested, the shares averaged, then the gray levels worked out per pixel."""
    from vtexp.stimuli.shapes import SUPERSAMPLE, ShapeParams, _shape_polygon
    p = ShapeParams(**params)
    ss = SUPERSAMPLE
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
    share = np.zeros((p.height, p.width), np.float32)
    if x1 > x0 and y1 > y0:
        x = ((np.arange(x0 * ss, x1 * ss) + 0.5) / ss)[None, :]
        y = ((np.arange(y0 * ss, y1 * ss) + 0.5) / ss)[:, None]
        if poly is None:
            inside = (x - cx) ** 2 + (y - cy) ** 2 <= r * r
        else:
            inside = np.ones((y.shape[0], x.shape[1]), bool)
            for (ax, ay), (bx, by) in zip(poly, np.roll(poly, -1, axis=0), strict=True):
                inside &= (bx - ax) * (y - ay) - (by - ay) * (x - ax) >= 0
        share[y0:y1, x0:x1] = inside.reshape(y1 - y0, ss, x1 - x0, ss).mean(axis=(1, 3))
    img = p.background + (p.foreground - p.background) * share
    if p.noise_sd > 0:
        img = img + np.random.default_rng(p.seed).normal(0, p.noise_sd, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("small_box_px", ["as set", 0])
def test_render_shape_gives_what_testing_every_sample_gives(monkeypatch, small_box_px):
    # render_shape tests sample by sample only the pixels on the outline; the image must
    # be the one testing all samples gives, byte for byte. Centres on 1/8 pixel and sizes
    # on 1/4 pixel put edges and the circle through samples, where >= and <= decide.
    # With SMALL_BOX_PX = 0 even a few pixels' box goes through the tiles.
    from vtexp.stimuli import shapes
    if small_box_px != "as set":
        monkeypatch.setattr(shapes, "SMALL_BOX_PX", small_box_px)
    rng = np.random.default_rng(20)
    for i in range(300):
        w, h = [(16, 16), (23, 17), (64, 48), (101, 77), (160, 120)][i % 5]
        on_grid = i // 4 % 2 == 0
        kw = dict(shape=SHAPES[i % 4], width=w, height=h,
                  size=(int(rng.integers(1, 4 * h + 1)) / (4 * h) if on_grid
                        else float(rng.uniform(0.001, 1))),
                  center_x=(int(rng.integers(0, 8 * w + 1)) / (8 * w) if on_grid
                            else float(rng.random())),
                  center_y=(int(rng.integers(0, 8 * h + 1)) / (8 * h) if on_grid
                            else float(rng.random())),
                  rotation_deg=float(rng.choice([0, 45, 90, 180, rng.uniform(-360, 360)])),
                  background=int(rng.integers(0, 256)), foreground=int(rng.integers(0, 256)),
                  noise_sd=float(rng.choice([0, 0, 0, 5.0])), seed=i)
        assert np.array_equal(render_shape(**kw), _render_shape_testing_every_sample(**kw)), kw
    for shape in SHAPES:    # the defaults, and a frame of a synthetic video
        assert np.array_equal(render_shape(shape=shape),
                              _render_shape_testing_every_sample(shape=shape))
        kw = dict(shape=shape, width=640, height=480, size=0.35, rotation_deg=33.0)
        assert np.array_equal(render_shape(**kw), _render_shape_testing_every_sample(**kw))


def test_paper_edge_modes_trace_the_study_shapes():
    # 'outline' (Sobel-Otsu-thinning, filled) closes the upright study shapes; the direct
    # 'edges' route is documented as fragile on 6x8 (docs/decisions.md): it still visits
    # each edge cell once.
    for shape in SHAPES:
        pat = edge_trace(render_shape(shape=shape), VEST.rows, VEST.cols, mode="outline")
        assert pat.closed == [0], shape
        pat = edge_trace(render_shape(shape=shape), VEST.rows, VEST.cols, mode="edges")
        cells = [(p.row, p.col) for p in pat.points]
        assert cells and len(cells) == len(set(cells)), shape


def test_skeleton_mode_traces_letters_as_paths():
    from vtexp.stimuli import render_letter
    for letter, closed in (("L", False), ("O", True)):
        pat = edge_trace(render_letter(letter=letter), VEST.rows, VEST.cols, mode="skeleton")
        assert pat.points and (0 in pat.closed) == closed, letter


@pytest.mark.parametrize("params", [
    dict(surface="ball"), dict(surface="vase", rotation_deg=55, size=1.0),
    dict(surface="uneven", center_x=0.02, center_y=0.97, size=0.9, noise_sd=3, seed=4),
    dict(surface="cone", center_x=1.0, center_y=0.0, width=37, height=300)])
def test_a_surface_shaded_in_its_window_is_the_surface_shaded_over_the_whole_image(params):
    """render_surface shades only the part of the image that holds the object; the pixels
    are those of shading every pixel (seed 000 eq. 1 at 4 x 4 sub-pixels)."""
    from vtexp.stimuli.surfaces import SUPERSAMPLE as ss, SurfaceParams, render_surface, \
        shade, surface_height

    p = SurfaceParams(**params)
    z, mask = surface_height(_supersample=ss, **params)
    e = shade(z, mask, 1.0 / ss)
    cover = mask.reshape(p.height, ss, p.width, ss).mean(axis=(1, 3))
    lit = e.reshape(p.height, ss, p.width, ss).sum(axis=(1, 3))
    e_pix = np.where(cover >= 0.5, lit / np.maximum(cover * ss * ss, 1), 0.0)
    img = p.background + (p.albedo - p.background) * e_pix
    if p.noise_sd > 0:
        img = img + np.random.default_rng(p.seed + 1).normal(0, p.noise_sd, img.shape)
    whole = np.clip(np.round(img), 0, 255).astype(np.uint8)
    assert (render_surface(**params) == whole).all()
    assert (whole != p.background).sum() > 20                 # an object was drawn
