"""Adaptive procedures: the next level from the answers so far (pure, numpy).

- :mod:`.psychometric`: Weibull, logistic, cumulative normal, Gumbel (log-Weibull)
- :mod:`.staircase`: transformed (Levitt 1971) and weighted (Kaernbach 1991) up-down
- :mod:`.quest`: QUEST (Watson & Pelli 1983)
- :mod:`.questplus`: QUEST+ (Watson 2017) / psi (Kontsevich & Tyler 1999)
- :mod:`.fit`: maximum-likelihood fits with parametric-bootstrap intervals
- :mod:`.spec`: the experiment's ``adaptive:`` section (schema); :mod:`.check`: its
  load-time checks
- :mod:`.track`: an experiment's ``adaptive:`` section as tracks on the device's levels

Nothing here knows devices, sessions or files; :mod:`vtexp.session` asks a
:class:`~.track.AdaptiveRun` for each trial's level and tells it the answer.

Names are imported lazily, so that the experiment schema (:mod:`vtexp.experiment`) can
import :mod:`.spec` without the procedures (numpy, SciPy).
"""

from __future__ import annotations

from importlib import import_module

_EXPORTS = {"Fit": ".fit", "fit_psychometric": ".fit",
            "FUNCTIONS": ".psychometric", "psi": ".psychometric",
            "threshold_at": ".psychometric", "Quest": ".quest", "QuestRule": ".quest",
            "QuestPlus": ".questplus", "QuestPlusRule": ".questplus",
            "Staircase": ".staircase", "StaircaseRule": ".staircase",
            "target_probability": ".staircase", "weighted_up_steps": ".staircase"}

__all__ = ["FUNCTIONS", "Fit", "Quest", "QuestPlus", "QuestPlusRule", "QuestRule", "Staircase",
           "StaircaseRule", "fit_psychometric", "psi", "target_probability", "threshold_at",
           "weighted_up_steps"]


#: Submodules reachable as attributes (``vtexp.adaptive.quest``) without an import first.
_MODULES = ("fit", "psychometric", "quest", "questplus", "staircase")


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(import_module(_EXPORTS[name], __name__), name)
    if name in _MODULES:
        return import_module(f".{name}", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
