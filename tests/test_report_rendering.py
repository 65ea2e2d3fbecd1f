"""Every report of the demo's studies laid out by headless Chromium: no text on text.

The figures are checked the same way inside matplotlib (the boxes of every
title, label, legend entry and cell value), since a PNG's text is not in the DOM.
"""

from __future__ import annotations

import pytest

from report_render import CHROMIUM, layout, screenshot

pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium "
                                "(make system-packages installs it)")


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    from conftest import run_cli
    root = tmp_path_factory.mktemp("demo")
    r = run_cli("demo", "--data", str(root / "demo"), "--participants", "3", cwd=root,
                timeout=600)
    assert r.returncode == 0, r.stderr
    return root / "demo" / "report"


STUDIES = ["six_mode_ball", "duration_interval_grid", "whirlpool", "circle_vs_rectangle"]


@pytest.mark.parametrize("study", STUDIES)
def test_no_text_overlaps_another_in_chromium(demo, study, tmp_path):
    html = demo / study / "report.html"
    got = layout(html)
    assert got["boxes"] > 50                                 # the page was laid out
    assert got["n_overlaps"] == 0, got["overlaps"][:10]
    assert not got["too_wide"]
    if study == "duration_interval_grid":
        out = tmp_path.parent / "report_screenshot.png"
        screenshot(html, out)
        assert out.stat().st_size > 10_000


def test_figures_have_no_overlapping_text():
    import numpy as np
    import pandas as pd

    from vtexp.analysis import figures
    letters = [chr(65 + i) for i in range(26)]
    rows = [{"timing": t, "stimulus": s, "response": r,
             "proportion": (0.8 if s == r else 0.2 / 25)}
            for t in ("200/100 ms, long condition name", "300/500 ms, another long name")
            for s in letters for r in letters]
    figures.confusion_heatmaps(pd.DataFrame(rows), ["timing"])
    assert figures.last_overlaps == []
    four = [{"timing": t, "stimulus": s, "response": r, "proportion": 0.25}
            for t in [f"{a}/{b}" for a in (200, 300) for b in (100, 200, 300, 400)]
            for s in ("triangle", "circle", "square", "rectangle")
            for r in ("triangle", "circle", "square", "rectangle")]
    figures.confusion_heatmaps(pd.DataFrame(four), ["timing"])
    assert figures.last_overlaps == []
    m = pd.DataFrame([{"participant": p, "corner": c, "shape": s,
                       "answer": (2 if s == "circle" else -2) + 0.1 * p}
                      for p in range(4) for c in ("with", "without") for s in ("circle", "rectangle")])
    m["corner"] = pd.Categorical(m["corner"])
    figures.per_participant_lines(m, "answer", "corner", "rating", trace="shape")
    assert figures.last_overlaps == []
    assert np.isfinite(m["answer"]).all()
