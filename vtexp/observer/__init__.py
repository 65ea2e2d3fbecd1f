"""The model participant (observer): percept, decision, population, and the Responder."""

from .model import ObserverModel
from .params import ObserverParams, Participant, draw_participant, load_params
from .responder import ModelObserver
from .spec import ObserverSpec

__all__ = ["ModelObserver", "ObserverModel", "ObserverParams", "ObserverSpec", "Participant",
           "draw_participant", "load_params"]
