"""Covered cells: every actuator the object covers, all at once (a tactile image).

The simplest rendering of a shape on an array: a cell is on if the object (Otsu's
threshold, :func:`~vtexp.encoding.segment.object_mask`) covers at least
``fill_threshold`` of it. With ``fit: frame`` (the default) the whole image is mapped
onto the array (aspect ratio kept, centred; :mod:`vtexp.encoding.mapping`), so an
image drawn on the array's grid (``two_point``) lands cell for cell and distances keep
their size in actuator pitches; ``fit: object`` scales the object's bounding box to
fill the array, as ``edge-trace`` does. Every point is on line 1 and unordered: a
coding plays them together (``contour-modes`` with ``display: static``).
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import Field

from ..model import Model, Pattern, PatternPoint
from .edge_trace import cells_covered
from .mapping import ImageToArray
from .segment import given_mask, object_mask


class CoveredCellsParams(Model):
    fill_threshold: Annotated[float, Field(gt=0, le=1)] = Field(
        0.5, description="share of a cell the object must cover")
    fit: Literal["frame", "object"] = Field(
        "frame", description="map the whole image onto the array (distances kept in cells), "
                             "or fit the object's bounding box into it")
    margin_cells: Annotated[float, Field(ge=0, le=10)] = Field(
        0.0, description="empty cells kept around the image (frame) or the object")


def covered_cells(gray: np.ndarray, rows: int, cols: int, *, fill_threshold: float = 0.5,
                  fit: str = "frame", margin_cells: float = 0.0,
                  mask: np.ndarray | None = None) -> Pattern:
    """Image -> the cells it covers on a ``rows x cols`` array, all on line 1.

    ``mask`` (uint8 0/1, the image's height x width) is the object if given; an
    all-zero mask gives an empty Pattern.

    Examples
    --------
    >>> from vtexp.stimuli import render_two_point
    >>> img = render_two_point(separation_pitches=3, array_rows=8, array_cols=6)
    >>> [(p.row, p.col) for p in covered_cells(img, 8, 6).points]
    [(2, 2), (5, 2)]
    """
    g = np.asarray(gray)
    obj = object_mask(g) if mask is None else given_mask(mask, g.shape, "covered-cells")
    cells = cells_covered(obj, rows, cols, fill_threshold=fill_threshold,
                          margin_cells=margin_cells, whole=fit == "frame")
    points = [PatternPoint(row=int(r), col=int(c), line=1) for r, c in np.argwhere(cells)]
    params: dict = {"fill_threshold": fill_threshold, "fit": fit, "margin_cells": margin_cells}
    if fit == "frame":
        h, w = g.shape[:2]
        params["to_array"] = ImageToArray.fit_frame(h, w, rows, cols,
                                                    margin=margin_cells).as_params()
    return Pattern(rows=rows, cols=cols, points=points, pipeline="covered-cells", params=params)
