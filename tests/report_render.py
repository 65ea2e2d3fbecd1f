"""Render a report in headless Chromium and measure where its text lands.

Chromium (Debian's ``chromium``, installed by ``make system-packages``) loads a
copy of the report with a script appended that walks every text node, takes
the boxes the layout gave it (``Range.getClientRects``) and writes the pairs of
boxes from different text nodes that intersect into the page; ``--dump-dom``
prints the page after the script ran. A screenshot can be taken the same way.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import tempfile
from contextlib import contextmanager
from pathlib import Path

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--hide-scrollbars"]

SCRIPT = r"""
<script>
(function () {
  const boxes = [];
  const walker = document.createTreeWalker(document.body, NodeFilter.SHOW_TEXT);
  let node, id = 0;
  while ((node = walker.nextNode())) {
    if (!node.textContent.trim()) continue;
    const parent = node.parentElement;
    if (!parent || getComputedStyle(parent).visibility === 'hidden') continue;
    const range = document.createRange();
    range.selectNodeContents(node);
    for (const r of range.getClientRects()) {
      if (r.width > 0.5 && r.height > 0.5)
        boxes.push({id: id, text: node.textContent.trim().slice(0, 40),
                    x0: r.left, y0: r.top, x1: r.right, y1: r.bottom});
    }
    id++;
  }
  const hits = [];
  for (let i = 0; i < boxes.length; i++) for (let j = i + 1; j < boxes.length; j++) {
    const a = boxes[i], b = boxes[j];
    if (a.id === b.id) continue;
    const w = Math.min(a.x1, b.x1) - Math.max(a.x0, b.x0);
    const h = Math.min(a.y1, b.y1) - Math.max(a.y0, b.y0);
    if (w > 1 && h > 1) hits.push([a.text, b.text]);
  }
  const wide = document.documentElement.scrollWidth > window.innerWidth + 1;
  const pre = document.createElement('pre');
  pre.id = 'vtexp-layout';
  pre.textContent = JSON.stringify({boxes: boxes.length, overlaps: hits.slice(0, 50),
                                    n_overlaps: hits.length, too_wide: wide});
  document.body.appendChild(pre);
})();
</script>
"""


def layout(html: Path, width: int = 1280, height: int = 900) -> dict:
    """Text boxes and their overlaps in the report as Chromium lays it out."""
    with tempfile.TemporaryDirectory() as tmp:
        page = Path(tmp) / "page.html"
        text = html.read_text(encoding="utf-8")
        page.write_text(text.replace("</body>", SCRIPT + "</body>"), encoding="utf-8")
        r = subprocess.run([CHROMIUM, *FLAGS, f"--user-data-dir={tmp}/profile",
                            f"--window-size={width},{height}", "--virtual-time-budget=5000",
                            "--dump-dom", page.as_uri()],
                           capture_output=True, text=True, timeout=120)
    m = re.search(r'<pre id="vtexp-layout">(.*?)</pre>', r.stdout, re.S)
    if not m:
        raise RuntimeError(f"chromium did not lay the page out: {r.stderr[-2000:]}")
    import html as h
    return json.loads(h.unescape(m.group(1)))


def screenshot(html: Path, png: Path, width: int = 1280, height: int = 2400) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([CHROMIUM, *FLAGS, f"--user-data-dir={tmp}/profile",
                        f"--window-size={width},{height}", f"--screenshot={png}",
                        html.resolve().as_uri()], capture_output=True, timeout=120, check=True)


# --------------------------------------------------------------------------- figures

def _corners(t, renderer):
    """The four corners of a text's box as drawn: rotated text is a rotated rectangle,
    whose axis-aligned box (what ``get_window_extent`` gives) would cover its
    neighbours' without a glyph touching. The rectangle's centre is its
    axis-aligned box's centre; its sides are the text's extent unrotated."""
    import numpy as np
    bb = t.get_window_extent(renderer)
    angle = t.get_rotation()
    if angle % 180 == 0:
        w, h = bb.width, bb.height
    else:
        t.set_rotation(0)
        flat = t.get_window_extent(renderer)
        t.set_rotation(angle)
        w, h = flat.width, flat.height
    a = np.deg2rad(angle)
    u, v = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])
    c = np.array([(bb.x0 + bb.x1) / 2, (bb.y0 + bb.y1) / 2])
    w, h = 0.92 * w / 2, 0.92 * h / 2                 # anti-aliasing, not overlap
    return np.array([c - w * u - h * v, c + w * u - h * v, c + w * u + h * v,
                     c - w * u + h * v])


def _convex_overlap(p, q) -> bool:
    """Whether two convex polygons intersect (separating axis theorem)."""
    import numpy as np
    for poly in (p, q):
        for i in range(len(poly)):
            edge = poly[(i + 1) % len(poly)] - poly[i]
            axis = np.array([-edge[1], edge[0]])
            a, b = p @ axis, q @ axis
            if a.max() <= b.min() or b.max() <= a.min():
                return False
    return True


def text_overlaps(fig) -> list[tuple[str, str]]:
    """Pairs of visible, non-empty texts of ``fig`` that overlap (titles, axis and tick
    labels, legend entries, cell values: every matplotlib ``Text``), their boxes as
    the renderer draws them (rotated with the text), so as the PNG shows them.
    Written here, apart from vtexp, so that the tests measure vtexp's figures and not
    vtexp's measurement."""
    from matplotlib.text import Text
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    boxes = []
    for t in fig.findobj(Text):
        if not t.get_visible() or not t.get_text().strip() or t.get_alpha() == 0:
            continue
        bb = t.get_window_extent(r)
        if bb.width > 0 and bb.height > 0:
            boxes.append((t.get_text(), bb, _corners(t, r)))
    if not boxes:
        return []
    # the boxes' overlaps as matplotlib's Bbox.overlaps has them (edges touching count),
    # every pair at once; then the rotated outlines of the pairs whose boxes meet
    import numpy as np
    ext = np.array([bb.extents for _, bb, _ in boxes])
    x0, x1 = np.minimum(ext[:, 0], ext[:, 2]), np.maximum(ext[:, 0], ext[:, 2])
    y0, y1 = np.minimum(ext[:, 1], ext[:, 3]), np.maximum(ext[:, 1], ext[:, 3])
    meet = ((x0[:, None] <= x1[None, :]) & (x0[None, :] <= x1[:, None])
            & (y0[:, None] <= y1[None, :]) & (y0[None, :] <= y1[:, None]))
    pairs = zip(*np.nonzero(np.triu(meet, k=1)))
    return [(boxes[i][0], boxes[j][0]) for i, j in pairs
            if _convex_overlap(boxes[i][2], boxes[j][2])]


def measure_figure(fig, dpi: float | None) -> dict:
    """What a saved figure shows: its text overlaps, each axes' box in pixels of the
    PNG (at the dpi it was saved with), title, y label and lines, each legend's box."""
    overlaps = text_overlaps(fig)
    r = fig.canvas.get_renderer()
    scale = (dpi or fig.dpi) / fig.dpi
    axes = []
    for ax in fig.axes:
        bb = ax.get_window_extent(r)
        axes.append({"box": bb, "width_px": bb.width * scale, "height_px": bb.height * scale,
                     "title": ax.get_title(), "ylabel": ax.get_ylabel(),
                     "images": len(ax.images),
                     "lines": [(ln.get_label(), [float(v) for v in ln.get_ydata()])
                               for ln in ax.get_lines()]})
    legends = [lg.get_window_extent(r) for lg in fig.findobj(
        lambda a: type(a).__name__ == "Legend")]
    return {"overlaps": overlaps, "axes": axes, "legends": legends}


@contextmanager
def captured_figures():
    """Every matplotlib figure saved inside the block, measured as it was saved
    (:func:`measure_figure`): vtexp's figure functions return PNG bytes, so the
    figures are caught on their way into ``savefig``."""
    from matplotlib.figure import Figure
    got: list[dict] = []
    real = Figure.savefig

    def savefig(self, fname, *args, **kwargs):
        got.append(measure_figure(self, kwargs.get("dpi")))
        return real(self, fname, *args, **kwargs)

    Figure.savefig = savefig
    try:
        yield got
    finally:
        Figure.savefig = real
