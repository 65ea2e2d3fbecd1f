"""bench/scenes.py on a few cases: its scenes, its projection of the truth and its counts.

Not a benchmark (no timing): the checks that would fail if the bench broke silently and
went on printing numbers. Its photographs are scikit-image's (installed by the test extra).
"""

from __future__ import annotations

import importlib.util
import os
import sys
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import skimage  # noqa: F401  (the photographs: installed by the test extra)

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def scenes():
    threads = {k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                              "MKL_NUM_THREADS")}
    spec = importlib.util.spec_from_file_location("bench_scenes", ROOT / "bench" / "scenes.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod                 # its dataclasses look their module up
    spec.loader.exec_module(mod)
    yield mod
    sys.modules.pop(spec.name, None)
    for k, v in threads.items():                 # the bench pins BLAS to one thread
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v


@pytest.fixture(scope="module")
def grounds(scenes):
    found, _ = scenes.load_grounds()
    assert found, "no photograph found in skimage.data"
    return found


@pytest.fixture(scope="module")
def edge_trace(scenes):
    study = scenes.prepare(scenes.STUDIES[0])
    yield study
    study.device.close()


@pytest.fixture(scope="module")
def circle(scenes, grounds):
    """Case 0, a circle (its reference is ten camera frames: made once)."""
    return scenes.make_case(0, grounds)


def test_a_case_is_made_again_from_its_seed_alone(scenes, grounds):
    a, b = scenes.make_case(3, grounds), scenes.make_case(3, grounds)
    assert a.seed == scenes.SEED + 3 and a.describe() == b.describe()
    for key, frame in a.frames.items():
        assert frame.shape == (scenes.HEIGHT, scenes.WIDTH, 3) and frame.dtype == np.uint8
        assert np.array_equal(frame, b.frames[key])
    assert np.array_equal(a.truth, b.truth) and 0.01 < a.truth.mean() < 0.5
    # The object is in the scene and not on the empty stage; the reference is the empty
    # stage again (the mean of ten captures), close to it but not the same picture.
    inside = a.truth
    obj, empty = (a.frames["plain", k].astype(float) for k in ("object", "empty"))
    assert obj[inside].mean() > empty[inside].mean() + 50
    ref = a.frames["plain", "reference"].astype(float)
    assert 0 < np.abs(ref - empty).mean() < 8


def test_the_true_mask_scores_one_against_itself_and_less_when_shifted(scenes, circle,
                                                                       edge_trace):
    case = circle
    clean = np.repeat((case.truth * 170 + 40).astype(np.uint8)[..., None], 3, axis=2)
    with scenes.FitRecorder() as recorder, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        played = scenes.play_frame(edge_trace, clean, "none", clean, recorder)
    assert played.outcome == "played" and played.fitted is not None
    on = scenes.played_and_true(edge_trace, played, case.truth)
    assert scenes.iou(on["played_line"], on["true_line"]) == 1.0
    assert scenes.iou(on["played_area"], on["true_area"]) == 1.0
    assert scenes.chamfer(on["played_line"], on["true_line"]) == 0.0
    shifted = np.roll(case.truth, (60, -80), axis=(0, 1))
    on = scenes.played_and_true(edge_trace, played, shifted)
    assert scenes.iou(on["played_line"], on["true_line"]) < 0.8
    assert scenes.chamfer(on["played_line"], on["true_line"]) > 0.3


def test_iou_and_chamfer_of_point_sets(scenes):
    square = np.array([[r, c] for r in range(4) for c in range(4) if r in (0, 3) or c in (0, 3)],
                      float)
    assert scenes.iou(square, square) == 1.0 and scenes.chamfer(square, square) == 0.0
    moved = square + [0, 1]
    assert 0 < scenes.iou(square, moved) < 1 and 0 < scenes.chamfer(square, moved) <= 1
    assert scenes.chamfer(square, np.zeros((0, 2))) == float("inf")
    assert scenes.iou(square, np.zeros((0, 2))) == 0.0


def test_an_empty_scene_that_plays_nothing_drives_nothing(scenes, grounds, edge_trace):
    case = scenes.make_case(1, grounds)
    grey = np.full((scenes.HEIGHT, scenes.WIDTH, 3), 90, np.uint8)
    blank = replace(case, frames={("real", "empty"): grey, ("real", "reference"): grey})
    with scenes.FitRecorder() as recorder, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = scenes.measure_empty(edge_trace, blank, "real", "none", recorder)
        real = scenes.measure_empty(edge_trace, case, "real", "none", recorder)
    assert rec["outcome"] == "nothing" and rec["driven"] == 0
    assert real["driven"] >= 0 and real["outcome"] in ("played", "nothing", "unsafe")
    summary = scenes.summarise_empty([rec, dict(rec, case=2, driven=5, outcome="played")])
    assert summary[0]["drive_any"] == 0.5 and summary[0]["driven_median"] == 2.5


def test_a_measured_case_and_its_summary(scenes, circle, edge_trace):
    case = circle                                             # a circle: it is named
    namer = scenes.Namer(edge_trace, case)
    with scenes.FitRecorder() as recorder, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        recs = [scenes.measure(edge_trace, case, g, "none", recorder, namer)
                for g in ("plain", "real")]
    for r in recs:
        assert 0 <= r["iou_line"] <= 1 and 0 <= r["iou_area"] <= 1 and r["ms"] > 0
        assert 0 <= r["named"] <= 1 and r["nearest"] in (True, False)
    rows = scenes.summarise(recs)
    assert {r["ground"] for r in rows} == {"plain", "real"}
    assert all(r["fps_ratio"] == 1.0 and r["cases"] == 1 for r in rows)


def test_the_truth_method_passes_the_exact_mask_and_refuses_an_empty_scene(scenes, circle,
                                                                           edge_trace):
    if scenes.Figure is None:
        pytest.skip("vtexp.encoding.figure is not in this tree")
    case = circle
    with scenes.FitRecorder() as recorder, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = scenes.measure(edge_trace, case, "real", "truth", recorder, None)
        empty = scenes.measure_empty(edge_trace, case, "real", "truth", recorder)
    assert rec["outcome"] == "played" and rec["figure_iou"] == 1.0
    assert rec["figure_method"] == "truth" and rec["iou_line"] > 0.9
    assert empty["outcome"] == "refused" and empty["driven"] == 0
