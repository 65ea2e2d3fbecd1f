"""Per-frame latency of the encoding pipelines on 640x480 frames, single thread.

Each pipeline is timed against a baseline measured in the same run:

- height-contours (seed 000) against the same pipeline at the camera's
  resolution (shape from shading on every pixel; ``cells_per_motor`` set so the
  working image is the full frame);
- edge-trace (seed 001) against the straightforward full-resolution OpenCV
  chain: Sobel, Otsu and thinning on the 640x480 frame, the thinned edge
  resampled to the 8x6 vest by area, contour following.
- snake-corners (seed 002) is measured by bench/encoding_snake.py against
  scikit-image's active_contour.

Accuracy is reported beside speed: for height contours, the Pearson r of the
recovered height with the true one and the number of lines; for the edge
trace, whether the outline is one closed loop, over the four study shapes.
Prints a table and writes bench/results/encoding.json.
Usage: python bench/encoding.py [REPEATS]
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vtexp._cv2 import cv2  # noqa: E402
from vtexp.encoding.edge_trace import edge_trace, follow_contour  # noqa: E402
from vtexp.encoding.height_contours import (height_contours, reflectance,  # noqa: E402
                                            shape_from_shading)
from vtexp.stimuli import render_shape  # noqa: E402
from vtexp.stimuli.surfaces import render_surface, surface_height  # noqa: E402

W, H = 640, 480


def median_ms(fn, repeats: int) -> float:
    # Warm up for a quarter of a second: caches, allocator and the CPU's clock settle
    # (a single warm-up call left the first pipeline measured ~50 % slow).
    end = time.perf_counter() + 0.25
    while time.perf_counter() < end:
        fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times) * 1e3


def baseline_edge_chain(gray: np.ndarray, rows: int = 8, cols: int = 6):
    cv = cv2()
    gx = cv.Sobel(gray, cv.CV_32F, 1, 0)
    gy = cv.Sobel(gray, cv.CV_32F, 0, 1)
    mag = cv.magnitude(gx, gy)
    m8 = cv.normalize(mag, None, 0, 255, cv.NORM_MINMAX).astype(np.uint8)
    _, e = cv.threshold(m8, 0, 255, cv.THRESH_BINARY + cv.THRESH_OTSU)
    t = cv.ximgproc.thinning(e)
    cells = cv.resize(t, (cols, rows), interpolation=cv.INTER_AREA) > 0
    return follow_contour(cells)


def sfs_r(surface: str, cells_per_motor: int | None) -> float:
    img = render_surface(surface=surface, width=W, height=H)
    size = None if cells_per_motor is None else (20 * cells_per_motor, 15 * cells_per_motor)
    e, m = reflectance(img, size=size, albedo=235.0 if surface == "cone" else None)
    z = shape_from_shading(e, m)
    zt, mt = surface_height(surface=surface, width=m.shape[1], height=m.shape[0])
    both = m & mt
    return float(np.corrcoef(z[both], zt[both])[0, 1])


def main() -> None:
    repeats = int(sys.argv[1]) if len(sys.argv) > 1 else 30
    cv2().setNumThreads(1)
    rows = []
    # Height contours: ball, cone, vase at the default working resolution vs full frame.
    for surface in ("ball", "cone", "vase"):
        img = render_surface(surface=surface, width=W, height=H)
        alb = 235.0 if surface == "cone" else None
        ours = median_ms(lambda: height_contours(img, 20, 20, albedo=alb), repeats)
        base = median_ms(lambda: height_contours(img, 20, 20, albedo=alb, cells_per_motor=32),
                         max(3, repeats // 10))
        n_ours = height_contours(img, 20, 20, albedo=alb).params["n_lines"]
        n_base = height_contours(img, 20, 20, albedo=alb, cells_per_motor=32).params["n_lines"]
        rows.append({"pipeline": "height-contours", "input": surface, "ours_ms": ours,
                     "baseline": "full-resolution SFS", "baseline_ms": base,
                     "speedup": base / ours,
                     "accuracy": f"r={sfs_r(surface, 4):.3f}, {n_ours} lines",
                     "baseline_accuracy": f"r={sfs_r(surface, None):.3f}, {n_base} lines"})
    # Edge trace: the four study shapes.
    for shape in ("triangle", "circle", "square", "rectangle"):
        img = render_shape(shape=shape, width=W, height=H)
        ours = median_ms(lambda: edge_trace(img, 8, 6), repeats)
        base = median_ms(lambda: baseline_edge_chain(img), repeats)
        pat = edge_trace(img, 8, 6)
        b = baseline_edge_chain(img)
        rows.append({"pipeline": "edge-trace", "input": shape, "ours_ms": ours,
                     "baseline": "full-res OpenCV chain", "baseline_ms": base,
                     "speedup": base / ours,
                     "accuracy": "1 closed loop" if pat.closed == [0] and len(pat.lines()) == 1
                     else f"{len(pat.lines())} lines, {len(pat.closed)} closed",
                     "baseline_accuracy": "1 closed loop" if len(b) == 1 and b[0][2]
                     else f"{len(b)} lines, {sum(x[2] for x in b)} closed"})
    print(f"encoding latency per {W}x{H} frame, single thread, median of {repeats}")
    print(f"{'pipeline':<16}{'input':<10}{'ours ms':>9}{'base ms':>9}{'speedup':>9}  "
          f"{'accuracy':<24}{'baseline':<24}baseline accuracy")
    for r in rows:
        print(f"{r['pipeline']:<16}{r['input']:<10}{r['ours_ms']:>9.2f}{r['baseline_ms']:>9.2f}"
              f"{r['speedup']:>9.1f}  {r['accuracy']:<24}{r['baseline']:<24}"
              f"{r['baseline_accuracy']}")
    goal = all(r["ours_ms"] <= 2.0 for r in rows)
    print(f"\ngoal: every pipeline <= 2 ms per frame: {'met' if goal else 'NOT met'} "
          f"(worst {max(r['ours_ms'] for r in rows):.2f} ms)")
    out = ROOT / "bench" / "results"
    out.mkdir(exist_ok=True)
    (out / "encoding.json").write_text(json.dumps({"frame": [W, H], "repeats": repeats,
                                                    "rows": rows, "goal_met": goal}, indent=2))
    print(f"written: {out / 'encoding.json'}")


if __name__ == "__main__":
    main()
