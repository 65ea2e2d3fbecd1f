"""The model participant (observer): percept, decision, population, and the Responder.

- :mod:`.params`: parameters with their literature defaults, and the population;
- :mod:`.percept`: what is felt of a played stimulus;
- :mod:`.model`: templates and decisions (:class:`ObserverModel`);
- :mod:`.responder`: :class:`ModelObserver`, the Responder a session asks;
- :mod:`.spec`: the experiment's ``observer:`` section.
"""

from __future__ import annotations

from importlib import import_module

_EXPORTS = {"ObserverModel": ".model", "ModelObserver": ".responder",
            "ObserverParams": ".params", "Participant": ".params",
            "draw_participant": ".params", "load_params": ".params", "ObserverSpec": ".spec"}

__all__ = ["ModelObserver", "ObserverModel", "ObserverParams", "ObserverSpec", "Participant",
           "draw_participant", "load_params"]


def __getattr__(name: str):
    # Lazy, because the experiment schema imports .spec before the rest can load.
    if name in _EXPORTS:
        return getattr(import_module(_EXPORTS[name], __name__), name)
    raise AttributeError(name)
