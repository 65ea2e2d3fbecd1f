"""Two points a whole number of actuator pitches apart: the two-point threshold.

The classic measure of tactile spatial acuity (Weinstein 1968) asks whether one point
or two is felt as their distance changes. On an array the distance can only be a whole
number of actuator pitches, so this generator draws on the array's own grid: an image
of ``array_rows x array_cols`` cells of ``cell_px`` pixels, a square dot in the cell of
each point. Encoded with ``fit: frame`` (the ``covered-cells`` pipeline), each dot lands
on exactly one actuator, and ``separation_pitches`` is the distance on the skin in
units of the profile's ``pitch_mm``.

The grid defaults to the experiment's device (vtexp fills in ``array_rows`` and
``array_cols`` from the profile, :func:`vtexp.stimuli.render`); :meth:`TwoPointParams.array_problem`
says when the points do not fit on it.

References
----------
Weinstein, S. (1968). Intensive and extensive aspects of tactile sensitivity as a
function of body part, sex, and laterality. In D. R. Kenshalo (Ed.), The Skin Senses
(pp. 195-222). Springfield, IL: Thomas.
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import Field

from ..model import Model


class TwoPointParams(Model):
    """Parameters of :func:`render_two_point` (the keys allowed under ``params:``)."""

    separation_pitches: Annotated[int, Field(ge=0, le=255)] = Field(
        2, description="distance between the two points in actuator pitches (0: one point)",
        json_schema_extra={"unit": "pitches"})
    axis: Literal["vertical", "horizontal"] = Field(
        "vertical", description="the points one above the other (along the rows) or side by "
                                "side (along the columns)")
    row: Annotated[int, Field(ge=0)] | None = Field(
        None, description="the first (upper or left) point's row; default: the pair centred")
    col: Annotated[int, Field(ge=0)] | None = Field(
        None, description="the first point's column; default: the pair centred")
    array_rows: Annotated[int, Field(ge=1, le=256)] | None = Field(
        None, description="rows of the grid drawn on (default: the device's array)")
    array_cols: Annotated[int, Field(ge=1, le=256)] | None = Field(
        None, description="columns of the grid drawn on (default: the device's array)")
    cell_px: Annotated[int, Field(ge=4, le=64)] = Field(16, description="pixels per cell")
    dot: Annotated[float, Field(gt=0, le=1)] = Field(
        0.8, description="side of each square dot, as a share of a cell")
    background: Annotated[int, Field(ge=0, le=255)] = 40
    foreground: Annotated[int, Field(ge=0, le=255)] = 210

    def points(self, rows: int, cols: int) -> list[tuple[int, int]]:
        """The cells (row, col) of the points on a ``rows x cols`` grid (one if the
        separation is 0)."""
        s = self.separation_pitches
        if self.axis == "vertical":
            r = self.row if self.row is not None else (rows - 1 - s) // 2
            c = self.col if self.col is not None else (cols - 1) // 2
            cells = [(r, c), (r + s, c)]
        else:
            r = self.row if self.row is not None else (rows - 1) // 2
            c = self.col if self.col is not None else (cols - 1 - s) // 2
            cells = [(r, c), (r, c + s)]
        return cells[:1] if s == 0 else cells

    def array_problem(self, rows: int, cols: int) -> str | None:
        """Why the points do not fit on a ``rows x cols`` array (None if they do)."""
        n = rows if self.axis == "vertical" else cols
        along = "rows" if self.axis == "vertical" else "columns"
        if self.separation_pitches > n - 1:
            return (f"two points {self.separation_pitches} pitches apart along the {along} do "
                    f"not fit on an array of {n} {along} (at most {n - 1})")
        for r, c in self.points(rows, cols):
            if not (0 <= r < rows and 0 <= c < cols):
                return (f"the point at row {r}, column {c} is off the array of {rows} rows x "
                        f"{cols} columns (move 'row'/'col')")
        return None


def render_two_point(**params) -> np.ndarray:
    """Two square dots ``separation_pitches`` cells apart on the array's grid.

    Examples
    --------
    >>> img = render_two_point(separation_pitches=3, array_rows=8, array_cols=6, cell_px=4)
    >>> img.shape, [int(r) // 4 for r in np.nonzero(img[:, 2 * 4 + 2] > 100)[0][::3]]
    ((32, 24), [2, 5])
    """
    p = TwoPointParams(**params)
    if p.array_rows is None or p.array_cols is None:
        raise ValueError("two_point draws on the array's grid: give array_rows and array_cols "
                         "(an experiment fills them in from its device)")
    why = p.array_problem(p.array_rows, p.array_cols)
    if why:
        raise ValueError(why)
    k = p.cell_px
    img = np.full((p.array_rows * k, p.array_cols * k), p.background, np.uint8)
    side = max(1, int(round(p.dot * k)))
    lo = (k - side) // 2
    for r, c in p.points(p.array_rows, p.array_cols):
        img[r * k + lo:r * k + lo + side, c * k + lo:c * k + lo + side] = p.foreground
    return img
