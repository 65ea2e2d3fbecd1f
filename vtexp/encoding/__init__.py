"""Encoding core: images in, Patterns out. Pure functions on numpy arrays.

Pipelines are looked up by name in :data:`PIPELINES`; each entry holds the
function and the pydantic model of its parameters (what YAML may declare).
"""

from __future__ import annotations

from .covered_cells import CoveredCellsParams, covered_cells
from .edge_trace import EdgeTraceParams, edge_trace, follow_contour
from .height_contours import HeightContourParams, height_contours
from .snake import SnakeCornersParams, snake_corners
from .spiral_path import SpiralPathParams, spiral_path

PIPELINES = {
    "covered-cells": (covered_cells, CoveredCellsParams),
    "edge-trace": (edge_trace, EdgeTraceParams),
    "height-contours": (height_contours, HeightContourParams),
    "snake-corners": (snake_corners, SnakeCornersParams),
    "spiral-path": (spiral_path, SpiralPathParams),
}

__all__ = ["PIPELINES", "EdgeTraceParams", "HeightContourParams", "edge_trace", "follow_contour",
           "height_contours"]
