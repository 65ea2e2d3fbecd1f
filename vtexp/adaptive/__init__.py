"""Adaptive procedures: the next level from the answers so far (pure, numpy).

- :mod:`.psychometric`: Weibull, logistic, cumulative normal, Gumbel (log-Weibull)
- :mod:`.staircase`: transformed (Levitt 1971) and weighted (Kaernbach 1991) up-down
- :mod:`.quest`: QUEST (Watson & Pelli 1983)
- :mod:`.questplus`: QUEST+ (Watson 2017) / psi (Kontsevich & Tyler 1999)
- :mod:`.fit`: maximum-likelihood fits with parametric-bootstrap intervals
- :mod:`.track`: an experiment's ``adaptive:`` section as tracks on the device's levels

Nothing here knows devices, sessions or files; :mod:`vtexp.session` asks a
:class:`~.track.AdaptiveRun` for each trial's level and tells it the answer.
"""

from .fit import Fit, fit_psychometric
from .psychometric import FUNCTIONS, psi, threshold_at
from .quest import Quest, QuestRule
from .questplus import QuestPlus, QuestPlusRule
from .staircase import Staircase, StaircaseRule, target_probability, weighted_up_steps

__all__ = ["FUNCTIONS", "Fit", "Quest", "QuestPlus", "QuestPlusRule", "QuestRule", "Staircase",
           "StaircaseRule", "fit_psychometric", "psi", "target_probability", "threshold_at",
           "weighted_up_steps"]
