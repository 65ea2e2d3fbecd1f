"""Coding: a Pattern becomes a Schedule of timed pulses for one device profile.

One module per paper's coding scheme; protocols are looked up by name in
:data:`CODINGS`, each entry holding the function
``f(pattern, profile, **params) -> Schedule`` and the pydantic model of its
parameters (what an experiment's YAML may declare).

A coding returns a Schedule within the profile's limits (``vtexp.safety.check_schedule``
passes it) or raises :class:`~vtexp.errors.UnsafeStimulus` naming the parameter to
change and a value that works: where its definition allows, an activation that would
outlast ``max_on_ms`` or come back before ``min_off_ms`` rests before an onset,
:mod:`vtexp.coding.limits` (issue 20).
"""

from __future__ import annotations

from .contours import ContourModeParams, contour_modes
from .pulses import PulseTrainParams, pulse_trains
from .trace import SequentialTraceParams, sequential_trace

CODINGS = {
    "sequential-trace": (sequential_trace, SequentialTraceParams),
    "contour-modes": (contour_modes, ContourModeParams),
    "pulse-trains": (pulse_trains, PulseTrainParams),
}

__all__ = ["CODINGS", "ContourModeParams", "SequentialTraceParams", "contour_modes",
           "sequential_trace"]
