"""psychopy-vtexp: a vtexp tactile array as a PsychoPy Builder component.

PsychoPy finds :class:`~psychopy_vtexp.component.TactileStimulusComponent` through this
distribution's ``psychopy.experiment.components`` entry point; the script Builder
compiles runs it through :mod:`vtexp.builder`.
"""

from .component import TactileStimulusComponent

__all__ = ["TactileStimulusComponent"]
