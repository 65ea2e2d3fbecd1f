"""Encoding core: images in, Patterns out. Pure functions on numpy arrays.

Pipelines are looked up by name in :data:`PIPELINES`; each entry holds the
function and the pydantic model of its parameters (what YAML may declare).
"""

from __future__ import annotations

from .edge_trace import EdgeTraceParams, edge_trace, follow_contour

PIPELINES = {
    "edge-trace": (edge_trace, EdgeTraceParams),
}

__all__ = ["PIPELINES", "edge_trace", "follow_contour", "EdgeTraceParams"]
