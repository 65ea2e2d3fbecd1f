"""Every report of the demo's studies laid out by headless Chromium: no text on text.

A PNG's text is not in the DOM: the figures are measured inside matplotlib
(the boxes of every title, label, legend entry and cell value) by the tests in
tests/test_report_defects.py.
"""

from __future__ import annotations

import pytest

from report_render import CHROMIUM, layout, screenshot

pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium "
                                "(make system-packages installs it)")


@pytest.fixture(scope="module")
def demo(demo_run):
    return demo_run[0]


STUDIES = ["six_mode_ball", "duration_interval_grid", "whirlpool", "circle_vs_rectangle"]


@pytest.mark.parametrize("study", STUDIES)
def test_no_text_overlaps_another_in_chromium(demo, study, tmp_path):
    html = demo / study / "derivatives" / "vtexp" / study / "report.html"   # BIDS derivatives
    # a full-width window and half a laptop screen: before the tables scrolled inside
    # the page, every demo report was wider than an 800 px window
    for width in (1280, 800):
        got = layout(html, width=width)
        assert got["boxes"] > 50                             # the page was laid out
        assert got["n_overlaps"] == 0, (width, got["overlaps"][:10])
        assert not got["too_wide"], width
    figures = {"six_mode_ball": 3, "duration_interval_grid": 3, "whirlpool": 4,
               "circle_vs_rectangle": 2}
    assert html.read_text().count("data:image/png;base64,") == figures[study]
    if study == "duration_interval_grid":
        out = tmp_path.parent / "report_screenshot.png"
        screenshot(html, out)
        assert out.stat().st_size > 10_000

