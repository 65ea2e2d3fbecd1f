"""The ``observer:`` section of an experiment: how a model participant answers its questions."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, model_validator
from typing_extensions import Self

from ..model import Model


class TemplateSpec(Model):
    """What an answer option feels like: a stimulus of the experiment, or a new image.

    The template is encoded as the participant was told the display shows it
    (``answer_templates: told``, ``model.told_pattern``: a surface by its true
    heights) or else through the experiment's encoding, coded with the parameters of
    the trial's condition, and played on the simulated device, as the stimulus was. ``scramble: true`` keeps the pulses but plays
    them at shuffled positions: vibration without a coherent movement.
    """

    stimulus: str | None = Field(None, description="a stimulus of the experiment")
    generator: str | None = Field(None, description="a name from vtexp.stimuli.GENERATORS")
    params: dict[str, Any] = Field(default_factory=dict)
    scramble: bool = False

    @model_validator(mode="before")
    @classmethod
    def _name(cls, v: Any) -> Any:
        return {"stimulus": v} if isinstance(v, str) else v

    @model_validator(mode="after")
    def _one(self) -> Self:
        if (self.stimulus is None) == (self.generator is None):
            raise ValueError("give either 'stimulus' or 'generator'")
        if self.stimulus is not None and self.params:
            raise ValueError("'params' go with 'generator', not with 'stimulus'")
        return self


class RatingAnchors(Model):
    """The templates a rating scale runs between: its low end and its high end."""

    low: str = Field(description="template (or stimulus) at the scale's low end")
    high: str = Field(description="template (or stimulus) at the scale's high end")


class ObserverSpec(Model):
    """How the model participant answers this experiment's questions (``vtexp simulate``).

    Options named like a stimulus need no template. ``abstain`` names options
    that mean "I cannot tell". Rating questions need their anchors; number
    questions say what is counted.
    """

    body_site: str | None = Field(None, description="overrides the device profile's site")
    params: dict[str, Any] = Field(default_factory=dict,
                                   description="overrides of protocols/observers/default.yaml")
    templates: dict[str, TemplateSpec] = Field(default_factory=dict)
    abstain: list[str] = Field(default_factory=list)
    ratings: dict[str, RatingAnchors] = Field(default_factory=dict)
    counts: dict[str, Literal["turns"]] = Field(default_factory=dict)
