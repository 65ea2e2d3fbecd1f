"""Height contours (seed 000 §2) on rendered Lambertian surfaces."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vtexp.coding import contour_modes
from vtexp._cv2 import cv2
from vtexp.encoding.height_contours import (count_lines, height_contours, is_flat,
                                            lattice_shape, line_heights, map_to_array,
                                            normalise_height, reflectance,
                                            shape_from_shading, sharpen, u8_quantile)
from vtexp.model import DeviceProfile
from vtexp.safety import check_schedule
from vtexp.stimuli import render_shape
from vtexp.stimuli.surfaces import SURFACES, render_surface, surface_height

PAD = DeviceProfile.load("pad_20x20")
# A cone has no surface facing the camera: its albedo must be given (reflectance docstring).
ALBEDO = {"cone": 235.0}


def recovered(surface, w=320, h=240, work=(80, 60), **kw):
    img = render_surface(surface=surface, width=w, height=h, **kw)
    e, m = reflectance(img, size=work, albedo=ALBEDO.get(surface))
    z_true, m_true = surface_height(surface=surface, width=work[0], height=work[1], **kw)
    return shape_from_shading(e, m), m, z_true, m_true


@pytest.mark.parametrize("surface", ["ball", "cone", "vase"])
@pytest.mark.parametrize("size", [(80, 60), (160, 120), (320, 240)])
def test_sfs_recovers_the_true_height(surface, size):
    z, m, zt, mt = recovered(surface, work=size)
    both = m & mt
    assert both.sum() > 0.9 * mt.sum()                 # the mask finds the object
    assert np.corrcoef(z[both], zt[both])[0, 1] >= 0.95


def test_a_bowl_is_seen_as_a_ball():
    # Under a light at the viewer a concave bowl shades exactly like a ball; the
    # scheme picks the convex surface (shape_from_shading docstring).
    z, m, zt, _ = recovered("bowl")
    assert np.corrcoef(z[m], zt[m])[0, 1] < -0.9


@pytest.mark.parametrize("surface", ["ball", "cone", "vase"])
@pytest.mark.parametrize("frame", [(320, 240), (640, 480)])
def test_variance_rule_gives_three_lines_as_the_paper_reports(surface, frame):
    pat = height_contours(render_surface(surface=surface, width=frame[0], height=frame[1]),
                          20, 20, albedo=ALBEDO.get(surface))
    assert pat.params["n_lines"] == 3 and pat.lines() == [1, 2, 3]
    assert 0.02 <= pat.params["variance"] < 0.06


def test_variance_rule_thresholds():
    m = np.ones((10, 10), bool)
    flat = np.full((10, 10), 0.5)
    assert count_lines(flat, m) == (1, 0.0)
    half = np.zeros((10, 10))
    half[:, 5:] = 1.0                                   # variance 0.25
    assert count_lines(half, m)[0] == 5
    ramp = np.tile(np.linspace(0.2, 0.8, 10), (10, 1))  # variance ~0.037
    assert count_lines(ramp, m)[0] == 3


def ring_radii(pattern):
    pts = np.array([[p.row, p.col, p.line] for p in pattern.points])
    centre = pts[:, :2].mean(axis=0)
    return [float(np.median(np.hypot(*(pts[pts[:, 2] == k, :2] - centre).T)))
            for k in (1, 2, 3)]


def test_cone_rings_even_ball_rings_not_on_the_mapped_array():
    # Seed 000 Fig. 3: equal height steps give evenly spaced rings on a cone (height
    # linear in radius) and unevenly spaced ones on a ball, measured on the pad.
    gaps = {}
    for surface in ("ball", "cone"):
        pat = height_contours(render_surface(surface=surface, size=0.95), 20, 20,
                              albedo=ALBEDO.get(surface))
        r = ring_radii(pat)
        assert r[0] > r[1] > r[2]                       # line 1 (lowest) outermost
        gaps[surface] = (r[1] - r[2]) / (r[0] - r[1])   # inner gap / outer gap
    assert abs(gaps["cone"] - 1) <= 0.2, gaps
    assert gaps["ball"] >= 1.25, gaps


def test_line_heights_rules():
    assert line_heights(3, 0, 1, "interior") == [0.25, 0.5, 0.75]
    assert line_heights(3, 0, 1, "paper") == pytest.approx([1 / 3, 2 / 3, 1.0])   # eq. 10
    assert line_heights(3, 0, 1, "outline") == pytest.approx([0, 1 / 3, 2 / 3])


def test_sharpened_lines_are_one_pixel_wide_closed_rings():
    z, m, _, _ = recovered("cone", work=(160, 120))
    s = sharpen(normalise_height(z, m), m, line_heights(3))
    import cv2
    for k in (1, 2, 3):
        line = (s == k).astype(np.uint8)
        n, _ = cv2.connectedComponents(line, connectivity=8)
        assert n - 1 == 1                               # one piece per line
        # One pixel wide: no 2x2 block entirely on the line.
        blocks = line[:-1, :-1] & line[1:, :-1] & line[:-1, 1:] & line[1:, 1:]
        assert blocks.sum() == 0


def test_eq_11_lattice_keeps_the_aspect_ratio():
    assert lattice_shape(240, 320, 20, 20) == (15, 20)      # ceil(240/320*20) = 15
    assert lattice_shape(480, 640, 20, 20) == (15, 20)
    assert lattice_shape(300, 300, 20, 20) == (20, 20)
    assert lattice_shape(240, 320, 8, 6) == (5, 6)


def test_mapping_rules_proportion_and_majority():
    s = np.zeros((40, 40), np.int16)         # 2x2 lattice of 20x20-pixel regions
    s[0:20, 0:20][0, 0:3] = 1                 # 3 px of 400 = 0.75 % -> below 1 %: empty
    s[0:20, 20:40][0, 0:10] = 1               # 2.5 % of line 1 ...
    s[0:20, 20:40][5, 0:14] = 2               # ... against 3.5 % of line 2: line 2 wins
    s[20:40, 0:20][3, 0:5] = 3                # 1.25 %: line 3
    m = map_to_array(s, 3, 2, 2)
    assert m.tolist() == [[0, 2], [3, 0]]


def test_contour_modes_follow_table_2_as_decided():
    pat = height_contours(render_surface(surface="ball"), 20, 20)
    n = {k: sum(p.line == k for p in pat.points) for k in (1, 2, 3)}
    static = contour_modes(pat, PAD, display="static", intensity="linear")
    assert {p.duration_ms for p in static.pulses} == {4000}
    assert {p.onset_ms for p in static.pulses} == {0}
    levels = {(p.row, p.col): p.level for p in static.pulses}
    assert {levels[(int(p.row), int(p.col))] for p in pat.points if p.line == 1} == {1}
    assert {levels[(int(p.row), int(p.col))] for p in pat.points if p.line == 3} == {5}

    fixed = contour_modes(pat, PAD, display="dynamic", timing="fixed", intensity="nonlinear")
    onsets = sorted({p.onset_ms for p in fixed.pulses})
    assert onsets == [0, 600, 1200, 1800, 2400, 3000]           # 3 lines x 2 cycles, SOA 600
    assert {p.duration_ms for p in fixed.pulses} == {900}
    assert sorted({p.level for p in fixed.pulses}) == [1, 4, 5]
    assert len(fixed.pulses) == 2 * sum(n.values())

    varied = contour_modes(pat, PAD, display="dynamic", timing="varied")
    first_cycle = sorted({(p.onset_ms, p.duration_ms, p.level) for p in varied.pulses})[:3]
    # Lowest line first: 800/600 at level 1, then 1200/1000 at 3, then 1600/1400 at 5.
    assert first_cycle == [(0, 800, 1), (600, 1200, 3), (1600, 1600, 5)]
    for s in (static, fixed, varied):
        check_schedule(s, PAD)


@pytest.mark.parametrize("surface", SURFACES)
def test_every_surface_encodes_safely(surface):
    pat = height_contours(render_surface(surface=surface), 20, 20)
    assert pat.points and pat.params["n_lines"] in (1, 3, 5)
    check_schedule(contour_modes(pat, PAD), PAD)


def test_uniform_image_gives_an_empty_pattern():
    pat = height_contours(np.full((240, 320), 90, np.uint8), 20, 20)
    assert pat.points == [] and pat.params["n_lines"] == 0


@settings(max_examples=25, deadline=None)
@given(dx=st.floats(0.4, 0.6), dy=st.floats(0.4, 0.6), rot=st.floats(0, 360),
       noise=st.floats(0, 4), albedo=st.integers(120, 255), size=st.floats(0.6, 0.9))
def test_ball_keeps_three_lines_under_offsets_rotation_noise_contrast(dx, dy, rot, noise,
                                                                       albedo, size):
    # Tolerance: offsets of +-10 % of the frame, any rotation, sensor noise up to 4 gray
    # levels, albedo down to 120 over a background of 20, sizes 60-90 % of the height.
    img = render_surface(surface="ball", center_x=dx, center_y=dy, rotation_deg=rot,
                         noise_sd=noise, albedo=albedo, size=size, seed=1)
    pat = height_contours(img, 20, 20)
    assert pat.params["n_lines"] == 3


def test_a_flat_object_is_shown_by_its_outline():
    # Uniform shading: a flat object facing the camera; one line, its outline.
    img = np.full((240, 320), 30, np.uint8)
    img[60:180, 100:220] = 200
    pat = height_contours(img, 20, 20)
    assert pat.params["n_lines"] == 1
    rows = sorted({int(p.row) for p in pat.points})
    cols = sorted({int(p.col) for p in pat.points})
    inner = [p for p in pat.points if rows[0] < p.row < rows[-1] and cols[0] < p.col < cols[-1]]
    assert pat.points and not inner                     # a ring, nothing inside


def _lit_from_one_side(img, gain_from, gain_to, noise, seed):
    """``img`` under a lamp to its left (a linear gain across the frame), blurred, with
    sensor noise and JPEG at quality 70, as a camera gives it."""
    cv = cv2()
    ramp = np.linspace(gain_from, gain_to, img.shape[1], dtype=np.float32)[None, :]
    lit = cv.GaussianBlur(img.astype(np.float32) * ramp, (0, 0), 1.0)
    lit += np.random.default_rng(seed).normal(0, noise, lit.shape)
    ok, buf = cv.imencode(".jpg", np.clip(np.round(lit), 0, 255).astype(np.uint8),
                          [cv.IMWRITE_JPEG_QUALITY, 70])
    return cv.imdecode(buf, cv.IMREAD_GRAYSCALE)


@pytest.mark.parametrize("shape", ["circle", "square", "triangle", "rectangle"])
def test_a_card_under_a_lamp_to_one_side_is_flat_and_played_by_its_outline(shape):
    # A card brighter towards the lamp (0.8 -> 1.2 across the frame), with noise and JPEG:
    # shape from shading alone reads the ramp and the noise as relief, and eq. 7's min-max
    # normalisation makes any relief a full hill of three lines inside the outline.
    clean = render_shape(shape=shape, width=640, height=480, size=0.5, background=40,
                         foreground=170, rotation_deg=10)
    lit = _lit_from_one_side(clean, 0.8, 1.2, 3.0, seed=4)
    want = height_contours(clean, 20, 20)
    got = height_contours(lit, 20, 20)
    assert want.params["n_lines"] == 1 and want.params["flat"]
    assert got.params["n_lines"] == 1 and got.params["flat"]
    cells = lambda p: {(int(q.row), int(q.col)) for q in p.points}   # noqa: E731
    a, b = cells(want), cells(got)
    assert len(a & b) / len(a | b) >= 0.8                 # the clean card's outline


@pytest.mark.parametrize("surface", ["ball", "vase"])
def test_a_surface_under_a_lamp_to_one_side_keeps_its_relief(surface):
    # Taking the light's ramp out is only a test of flatness: a shaded surface is still
    # read from its own shading, ramp and all.
    img = _lit_from_one_side(render_surface(surface=surface, width=640, height=480),
                             0.8, 1.2, 3.0, seed=5)
    pat = height_contours(img, 20, 20)
    assert not pat.params["flat"] and pat.params["n_lines"] == 3


def test_flat_is_a_median_tilt_under_22_degrees_once_the_light_ramp_is_out():
    m = np.zeros((60, 80), bool)
    m[10:50, 10:70] = True
    x = np.linspace(0, 1, 80, dtype=np.float32)[None, :]
    lamp = np.where(m, 0.7 + 0.3 * x, 0).astype(np.float32)      # E 0.7 -> 1 across it
    assert is_flat(lamp, m)
    assert not is_flat(np.where(m, 0.9, 0).astype(np.float32), m, calibrated=True)
    assert is_flat(np.where(m, 0.9, 0).astype(np.float32), m)   # the albedo estimated
    e, ball = reflectance(render_surface(surface="ball"), size=(80, 60))
    assert not is_flat(e, ball)


@given(st.lists(st.integers(0, 255), min_size=1, max_size=600),
       st.sampled_from([0.0, 0.01, 0.5, 0.99, 1.0]))
def test_a_quantile_from_the_gray_levels_counts_is_numpys_to_the_last_bit(values, q):
    """masked_reflectance counts a frame's gray levels instead of sorting them."""
    v = np.array(values, np.uint8)
    assert u8_quantile(np.bincount(v, minlength=256), q) == np.percentile(v, 100 * q)
