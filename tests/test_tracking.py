"""An object moving before a camera: the frame fitted onto the array (fit: frame, the image
to array mapping each pipeline records) and seed 002's snake carried from frame to frame."""

from __future__ import annotations

import numpy as np
import pytest

from vtexp.encoding import PIPELINES
from vtexp.encoding.mapping import ImageToArray
from vtexp.encoding.snake import SnakeTracker, find_outline, rigid_shift
from vtexp.stimuli import render_shape
from vtexp.stimuli.surfaces import render_surface

W, H = 640, 480


def square(cx, cy, size=0.4, rotation=0.0, shape="square"):
    return render_shape(shape=shape, width=W, height=H, size=size, center_x=cx, center_y=cy,
                        rotation_deg=rotation)


def centroid(pattern):
    return np.array([[p.row, p.col] for p in pattern.points]).mean(axis=0)


@pytest.mark.parametrize("pipeline, rows, cols, tolerance", [
    ("edge-trace", 8, 6, 0.5), ("edge-trace", 20, 20, 0.5), ("snake-corners", 5, 5, 0.3)])
@pytest.mark.parametrize("cx, cy", [(0.3, 0.35), (0.5, 0.5), (0.68, 0.62)])
def test_with_fit_frame_the_object_is_where_the_camera_sees_it(pipeline, rows, cols, tolerance,
                                                                cx, cy):
    fn, _ = PIPELINES[pipeline]
    pat = fn(square(cx, cy), rows, cols, fit="frame")
    m = ImageToArray.from_params(pat.params)
    truth = m.to_array([[cy * H - 0.5, cx * W - 0.5]])[0]
    assert np.hypot(*(centroid(pat) - truth)) <= tolerance
    # With the default fit (the object's box), the same square is centred wherever it is.
    centred = fn(square(cx, cy), rows, cols)
    assert "to_array" not in centred.params
    assert np.allclose(centroid(centred), [(rows - 1) / 2, (cols - 1) / 2], atol=0.6)


def test_height_contours_record_where_the_lattice_put_the_image():
    img = render_surface(surface="ball", width=W, height=H)
    pat = PIPELINES["height-contours"][0](img, 20, 20)
    m = ImageToArray.from_params(pat.params)
    assert np.allclose(m.to_array([[H / 2 - 0.5, W / 2 - 0.5]])[0], centroid(pat), atol=0.3)
    # eq. 11 lattice: 640 px over 20 motors, 480 px over 15 rows placed from row 2.
    assert m.row_scale == m.col_scale == 1 / 32
    assert np.allclose(m.to_image(m.to_array([[10.0, 600.0]])), [[10.0, 600.0]])


def test_a_square_moving_and_turning_is_tracked_by_the_carried_snake():
    tracker = SnakeTracker(fit="frame")
    errors, inits = [], []
    for k in range(30):
        cx = 0.25 + 0.012 * k                  # 7.7 px per frame, turning 3 degrees
        res = tracker.outline(square(cx, 0.4, size=0.25, rotation=3 * k))
        inits.append(res.init)
        errors.append(np.hypot(*(res.points.mean(axis=0) - [0.4 * H - 0.5, cx * W - 0.5])))
    assert inits[0] == "otsu" and set(inits[1:]) == {"carried"}
    assert tracker.restarts == 0
    assert max(errors) < 2.0                    # pixels, at 640 x 480


def test_the_carried_snake_stays_on_its_object_when_a_larger_one_comes_into_view():
    """Otsu's outline is the largest object's; the carried snake keeps following the object
    it was on (seed 002: the snake tracks the object)."""
    tracker = SnakeTracker(fit="frame")
    for k in range(12):
        cx = 0.25 + 0.012 * k
        img = square(cx, 0.4, size=0.25, rotation=3 * k)
        if k >= 6:
            img = np.maximum(img, square(0.8, 0.75, size=0.4, shape="circle"))
        res = tracker.outline(img)
    truth = [0.4 * H - 0.5, cx * W - 0.5]
    assert np.hypot(*(res.points.mean(axis=0) - truth)) < 2.0
    fresh = find_outline(img)
    assert np.hypot(*(fresh.points.mean(axis=0) - [0.75 * H - 0.5, 0.8 * W - 0.5])) < 3.0


def test_a_snake_that_lost_its_object_starts_again_from_otsu():
    tracker = SnakeTracker(fit="frame")
    tracker.outline(square(0.25, 0.3, size=0.2))
    res = tracker.outline(square(0.75, 0.7, size=0.2))     # jumped far beyond track_px
    assert tracker.restarts == 1 and res.init == "otsu"
    assert np.hypot(*(res.points.mean(axis=0) - [0.7 * H - 0.5, 0.75 * W - 0.5])) < 2.0
    empty = tracker.outline(np.full((H, W), 40, np.uint8))
    assert empty.empty and tracker.previous is None


def test_rigid_shift_finds_the_displacement_of_an_outline():
    edge = np.zeros((60, 80), np.float32)
    edge[20, 10:40] = edge[40, 10:40] = edge[20:41, 10] = edge[20:41, 39] = 50.0
    pts = np.array([[20, c] for c in range(10, 40, 3)] + [[40, c] for c in range(10, 40, 3)]
                   + [[r, 10] for r in range(23, 40, 3)] + [[r, 39] for r in range(23, 40, 3)])
    moved = rigid_shift(edge, pts - [2, -3], radius=4)
    assert np.array_equal(moved, pts)
    assert np.array_equal(rigid_shift(edge, pts - [2, -3], radius=0), pts - [2, -3])
