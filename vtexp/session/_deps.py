"""Names the session takes from modules being reorganised (the data model, ``design``,
``compile``, ``adaptive``), imported here only, so that a move changes one file."""

from __future__ import annotations

from ..adaptive.track import AdaptiveRun
from ..adaptive.track import _number as level_number
from ..compile import Condition, compile_conditions
from ..design import Trial, trial_list

__all__ = ["AdaptiveRun", "Condition", "Trial", "compile_conditions", "level_number",
           "trial_list"]
