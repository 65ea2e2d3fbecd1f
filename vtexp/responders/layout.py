"""The participant window's layout, computed: no text overlaps another or leaves its box.

Everything is in PsychoPy's ``height`` units (the screen is 1 high and ``aspect``
wide, centred on 0). Text is measured with the window's own font (DejaVu Sans,
the copy matplotlib ships, through Pillow), wrapped at word boundaries by this
module (so the window draws the lines it was given), and sized to the largest
height that fits its box, never below the smallest height the ``scale`` setting
asks for: ``MIN_TEXT * scale`` screen heights. A screen that cannot be laid out
at that size raises :class:`LayoutError`, before the session starts.

The layout is checked on screenshots by the window tests: each label drawn alone,
its pixels' bounding box inside its box and disjoint from every other label's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

#: The smallest text at scale 1, in screen heights (the font size, em): 3 % (24 px on an
#: 800-pixel-high screen; on a screen 30 cm high seen from 57 cm, 0.9 degrees of visual
#: angle). At scale S every text is at least S times that.
MIN_TEXT = 0.03
LINE = 1.2                  # line spacing, in text heights (DejaVu Sans: 1.164)
PAD = 0.15                  # padding inside a box, in text heights
GAP = 0.02                  # between buttons


class LayoutError(Exception):
    """A screen cannot be laid out at the text size asked for."""


@lru_cache(maxsize=1)
def _font():
    import matplotlib           # only to find its copy of DejaVu Sans, when text is
    from PIL import ImageFont   # first measured (a second to import, on a slow machine)
    path = Path(matplotlib.get_data_path()) / "fonts" / "ttf" / "DejaVuSans.ttf"
    return ImageFont.truetype(str(path), 200)


@lru_cache(maxsize=4096)
def _width_em(line: str) -> float:
    """Width of one line of text in ems (text heights)."""
    if not line:
        return 0.0
    return _font().getlength(line) / 200.0


def text_width(line: str, height: float) -> float:
    return _width_em(line) * height


def wrap(text: str, width: float, height: float) -> list[str] | None:
    """Lines of ``text`` no wider than ``width`` at ``height``, broken between words
    (a line break in ``text`` is kept); None if a word alone is too wide."""
    lines: list[str] = []
    for para in text.split("\n"):
        words = para.split()
        line = ""
        for w in words:
            cand = f"{line} {w}" if line else w
            if text_width(cand, height) <= width:
                line = cand
                continue
            if not line or text_width(w, height) > width:
                return None
            lines.append(line)
            line = w
        lines.append(line)
    return lines


def fit(text: str, w: float, h: float, smallest: float, largest: float) -> tuple[str, float] | None:
    """The largest text height in [smallest, largest] at which ``text`` fits a box of
    ``w`` x ``h`` (padding included), with its lines; None if not even ``smallest``."""
    def fits(height):
        pad = PAD * height
        lines = wrap(text, w - 2 * pad, height)
        if lines is None or len(lines) * LINE * height + 2 * pad > h:
            return None
        return lines
    if fits(smallest) is None:
        return None
    lo, hi = smallest, max(smallest, largest)
    if fits(hi) is not None:
        return "\n".join(fits(hi)), hi
    for _ in range(18):
        mid = (lo + hi) / 2
        if fits(mid) is None:
            hi = mid
        else:
            lo = mid
    return "\n".join(fits(lo)), lo


@dataclass(frozen=True)
class Box:
    x: float
    y: float
    w: float
    h: float

    @property
    def left(self) -> float:
        return self.x - self.w / 2

    @property
    def right(self) -> float:
        return self.x + self.w / 2

    @property
    def top(self) -> float:
        return self.y + self.h / 2

    @property
    def bottom(self) -> float:
        return self.y - self.h / 2

    def contains(self, pos) -> bool:
        return abs(pos[0] - self.x) <= self.w / 2 and abs(pos[1] - self.y) <= self.h / 2

    def inside(self, other: Box, tol: float = 1e-9) -> bool:
        return (self.left >= other.left - tol and self.right <= other.right + tol
                and self.bottom >= other.bottom - tol and self.top <= other.top + tol)

    def overlaps(self, other: Box) -> bool:
        return not (self.right <= other.left or other.right <= self.left
                    or self.top <= other.bottom or other.top <= self.bottom)


@dataclass
class Label:
    """A text drawn centred in ``box`` (its lines already broken) at ``height``."""

    text: str
    box: Box
    height: float
    role: str = "text"            # text | button | key | hint | prompt | banner ...

    @property
    def extent(self) -> Box:
        """The box the text itself takes (its lines' width, its lines' height)."""
        lines = self.text.split("\n")
        w = max(text_width(ln, self.height) for ln in lines)
        return Box(self.box.x, self.box.y, w, len(lines) * LINE * self.height)


@dataclass
class Cell:
    """A button's place: its box, and its label (and key hint) inside it."""

    box: Box
    label: Label
    key: Label | None = None


@dataclass
class Screen:
    """What a screen shows: labels outside buttons, and the buttons' cells."""

    name: str
    labels: list[Label] = field(default_factory=list)
    cells: list[Cell] = field(default_factory=list)

    def all_labels(self) -> list[tuple[Label, Box | None]]:
        """Every label with the button box it must stay in (None: the screen)."""
        out = [(lb, None) for lb in self.labels]
        for c in self.cells:
            out.append((c.label, c.box))
            if c.key is not None:
                out.append((c.key, c.box))
        return out


def text_block(text: str, area: Box, smallest: float, largest: float, role: str = "text"
               ) -> Label:
    got = fit(text, area.w, area.h, smallest, largest)
    if got is None:
        raise LayoutError(f"the text {text[:40]!r} does not fit its place at a text height of "
                          f"{smallest:.3f} screen heights")
    lines, h = got
    return Label(lines, area, h, role)


def button_cell(label: str, key: str | None, box: Box, smallest: float, largest: float
                ) -> Cell | None:
    """A button's label (and key hint in a strip at its top), fitted; None if it does not
    fit at ``smallest``."""
    inner = box
    key_label = None
    if key:
        strip = smallest * (LINE + 2 * PAD)
        if strip * 2 > box.h:
            return None
        kb = Box(box.x, box.top - strip / 2, box.w, strip)
        kfit = fit(key, kb.w, kb.h, smallest, smallest)
        if kfit is None:
            return None
        key_label = Label(kfit[0], kb, kfit[1], "key")
        inner = Box(box.x, box.y - strip / 2, box.w, box.h - strip)
    got = fit(label, inner.w, inner.h, smallest, largest)
    if got is None:
        return None
    return Cell(box, Label(got[0], inner, got[1], "button"), key_label)


def needed_height(text: str, width: float, height: float) -> float | None:
    """The height a box of ``width`` needs for ``text`` at ``height`` (None: a word is
    too wide)."""
    lines = wrap(text, width - 2 * PAD * height, height)
    return None if lines is None else len(lines) * LINE * height + 2 * PAD * height


def grid(items: list[tuple[str, str | None]], area: Box, smallest: float, largest: float,
         prefer_rows: int | None = None, rows_only: tuple[int, ...] | None = None
         ) -> list[Cell]:
    """Buttons for ``items`` (label, key hint) in the grid of ``area`` that gives their
    smallest label the largest text (rows filled left to right, top to bottom)."""
    n = len(items)
    best: tuple[float, int, list[Cell]] | None = None
    for rows in rows_only or range(1, n + 1):
        cols = math.ceil(n / rows)
        if (rows - 1) * cols >= n:
            continue
        w = (area.w - (cols - 1) * GAP) / cols
        h = (area.h - (rows - 1) * GAP) / rows
        if w <= 0 or h <= 0:
            continue
        h = min(h, max(0.16, largest * 3.5))     # buttons no taller than they need be
        cells = []
        for i, (label, key) in enumerate(items):
            r, c = divmod(i, cols)
            in_row = min(cols, n - r * cols)
            x = area.x + (c - (in_row - 1) / 2) * (w + GAP)
            total_h = rows * h + (rows - 1) * GAP
            y = area.y + total_h / 2 - h / 2 - r * (h + GAP)
            cell = button_cell(label, key, Box(x, y, w, h), smallest, largest)
            if cell is None:
                break
            cells.append(cell)
        if len(cells) < n:
            continue
        size = min(c.label.height for c in cells)
        score = size + (1e-3 if rows == prefer_rows else 0.0)
        if best is None or score > best[0] + 1e-9:
            best = (score, rows, cells)
    if best is None:
        raise LayoutError(f"{n} buttons do not fit a {area.w:.2f} x {area.h:.2f} area with "
                          f"text {smallest:.3f} screen heights high")
    return best[2]


def check(screen: Screen, aspect: float) -> list[str]:
    """What is wrong with a computed screen: a label outside its box or the screen, two
    labels that overlap, two buttons that overlap. Empty when all is well."""
    problems = []
    whole = Box(0, 0, aspect, 1.0)
    labels = screen.all_labels()
    for lb, box in labels:
        ext = lb.extent
        if not ext.inside(lb.box, 1e-6):
            problems.append(f"{lb.text[:30]!r} is larger than its place")
        if box is not None and not ext.inside(box, 1e-6):
            problems.append(f"{lb.text[:30]!r} leaves its button")
        if not ext.inside(whole, 1e-6):
            problems.append(f"{lb.text[:30]!r} leaves the screen")
    for i, (a, _) in enumerate(labels):
        for b, _ in labels[i + 1:]:
            if a.extent.overlaps(b.extent):
                problems.append(f"{a.text[:30]!r} overlaps {b.text[:30]!r}")
    for i, a in enumerate(screen.cells):
        for b in screen.cells[i + 1:]:
            if a.box.overlaps(b.box):
                problems.append(f"buttons {a.label.text[:20]!r} and {b.label.text[:20]!r} overlap")
    return problems
