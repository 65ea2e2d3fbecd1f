"""What the snake-corners pipeline costs per camera frame, against scikit-image's snake.

- vtexp: ``snake_corners(gray, 5, 5)`` on a 640x480 frame, image to Pattern
  (working resolution, Otsu initial contour, Shi-Tomasi corners, greedy snake
  of Williams & Shah, sub-pixel edges, mapping to the 9x9 grid of pins and
  phantom points).
- baseline: ``skimage.segmentation.active_contour`` on the same frame as
  scikit-image's own example runs it (Gaussian sigma 3, alpha 0.015, beta 10,
  gamma 0.001, 400 points), started on a circle 10 % larger than the object's
  enclosing circle from the same Otsu segmentation; its time includes the
  smoothing and that initialisation.

Single thread: OpenCV with ``cv2.setNumThreads(1)``, BLAS/OpenMP pools at one
thread (set before numpy loads). Accuracy on the same frames: IoU of each
outline with the rendered shape (pixel centres inside the polygon against
pixels more than half covered), and for polygons the largest distance from a
true vertex to the nearest corner found.

Prints a table and writes JSON to bench/results/encoding_snake.json. Ratios are
baseline time over vtexp time in the same run. Usage:
``python bench/encoding_snake.py [REPEATS]`` (needs the ``bench`` extra:
scikit-image). :func:`run` returns the same numbers for other scripts.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import json
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vtexp._cv2 import cv2
from vtexp.encoding.snake import find_outline, outline_mask, snake_corners
from vtexp.stimuli import render_shape
from vtexp.stimuli.shapes import ShapeParams, _shape_polygon

WIDTH, HEIGHT = 640, 480
SHAPES = ("circle", "square", "triangle")


def _timed(fn, repeats: int) -> tuple[list[float], list[float], object]:
    """Wall-clock and this thread's CPU times (ms) of ``repeats`` calls after a warm-up.
    On a shared machine the CPU time shows the cost apart from waiting for a core."""
    out = fn()                                   # warm-up (imports, caches)
    wall, cpu = [], []
    for _ in range(repeats):
        c = time.thread_time_ns()
        t = time.perf_counter()
        out = fn()
        wall.append((time.perf_counter() - t) * 1000.0)
        cpu.append((time.thread_time_ns() - c) / 1e6)
    return wall, cpu, out


def _iou(points: np.ndarray, truth: np.ndarray) -> float:
    m = outline_mask(points, truth.shape)
    return float((m & truth).sum() / max((m | truth).sum(), 1))


def _corner_error(points: np.ndarray, params: dict) -> float | None:
    poly = _shape_polygon(ShapeParams(**params))
    if poly is None:
        return None
    if len(points) == 0:
        return float("inf")
    d = np.hypot(poly[:, None, 1] - points[None, :, 0], poly[:, None, 0] - points[None, :, 1])
    return float(d.min(axis=1).max())


def skimage_snake(gray: np.ndarray) -> np.ndarray:
    """The baseline: scikit-image's active contour as its gallery example runs it."""
    from skimage.filters import gaussian
    from skimage.segmentation import active_contour

    cv = cv2()
    _, mask = cv.threshold(gray, 0, 1, cv.THRESH_BINARY + cv.THRESH_OTSU)
    contours, _ = cv.findContours(mask, cv.RETR_EXTERNAL, cv.CHAIN_APPROX_NONE)
    (x, y), radius = cv.minEnclosingCircle(max(contours, key=cv.contourArea))
    s = np.linspace(0, 2 * np.pi, 400)
    init = np.c_[y + 1.1 * radius * np.sin(s), x + 1.1 * radius * np.cos(s)]
    return active_contour(gaussian(gray, sigma=3, preserve_range=False), init,
                          alpha=0.015, beta=10, gamma=0.001)


def run(repeats: int = 200, baseline_repeats: int = 5, shapes=SHAPES) -> dict:
    cv = cv2()
    threads = cv.getNumThreads()
    cv.setNumThreads(1)
    rows = []
    try:
        for shape in shapes:
            params = {"shape": shape, "width": WIDTH, "height": HEIGHT}
            gray = render_shape(**params)
            truth = render_shape(**params, background=0, foreground=255) > 127
            t_ours, c_ours, pattern = _timed(lambda g=gray: snake_corners(g, 5, 5), repeats)
            outline = find_outline(gray)
            t_base, c_base, base = _timed(lambda g=gray: skimage_snake(g), baseline_repeats)
            ours_ms, base_ms = statistics.median(t_ours), statistics.median(t_base)
            rows.append({
                "shape": shape, "image": f"{WIDTH}x{HEIGHT}",
                "vtexp_ms": ours_ms, "vtexp_p90_ms": float(np.percentile(t_ours, 90)),
                "vtexp_cpu_ms": statistics.median(c_ours),
                "baseline_ms": base_ms, "baseline_cpu_ms": statistics.median(c_base),
                "ratio": base_ms / ours_ms,
                "vtexp_iou": _iou(outline.points, truth), "baseline_iou": _iou(base, truth),
                "vtexp_corner_error_px": _corner_error(outline.points[outline.corner], params),
                "vtexp_corners": int(outline.corner.sum()),
                "pattern_points": len(pattern.points),
                "repeats": repeats, "baseline_repeats": baseline_repeats,
            })
    finally:
        cv.setNumThreads(threads)
    import skimage

    return {"benchmark": "encoding_snake", "rows": rows,
            "machine": {"python": platform.python_version(), "platform": platform.platform(),
                        "opencv": cv.__version__, "numpy": np.__version__,
                        "scikit-image": skimage.__version__, "threads": 1}}


def main(argv: list[str]) -> int:
    repeats = int(argv[1]) if len(argv) > 1 else 200
    result = run(repeats)
    head = (f"{'shape':9s} {'vtexp ms':>9s} {'p90':>6s} {'cpu':>6s} {'skimage ms':>11s} "
            f"{'ratio':>7s} {'IoU vtexp':>9s} {'IoU skimage':>11s} {'corner err px':>13s}")
    print(f"snake on a {WIDTH}x{HEIGHT} frame, median of {repeats} (vtexp) / "
          f"{result['rows'][0]['baseline_repeats']} (skimage) runs, single thread; "
          "ms = wall clock, cpu = this thread's CPU time")
    print(head)
    print("-" * len(head))
    for r in result["rows"]:
        ce = r["vtexp_corner_error_px"]
        print(f"{r['shape']:9s} {r['vtexp_ms']:9.2f} {r['vtexp_p90_ms']:6.2f} "
              f"{r['vtexp_cpu_ms']:6.2f} {r['baseline_ms']:11.1f} {r['ratio']:6.0f}x {r['vtexp_iou']:9.4f} "
              f"{r['baseline_iou']:11.4f} {('-' if ce is None else f'{ce:.2f}'):>13s}")
    out = ROOT / "bench" / "results" / "encoding_snake.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    print(f"written {out.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv))
