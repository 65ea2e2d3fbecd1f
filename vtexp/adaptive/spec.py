"""The ``adaptive:`` section of an experiment file (schema only).

::

    adaptive:
      variable: soa_ms                 # a parameter of the experiment's coding
      # sets: stimulus                 # or of the stimuli's generator (separation_pitches)
      values: {min: 10, max: 300, step: 1}     # the levels to play (or a list)
      response: {question: percept, yes_answers: [separate]}   # default: a correct answer
      procedure:
        kind: staircase                # staircase | quest | questplus
        ...

Each condition (combination of factor levels) runs its own track of the procedure,
``design.repetitions`` trials long, unless ``tracks`` names the factors that separate
tracks (the conditions that differ in the other factors share one, e.g. a staircase
over shapes presented at random); a factor with ``sets: adaptive`` gives each of its
levels other procedure settings (interleaved staircases from two starts). What the
device can play, and that every start and step lands on it, is checked when the
experiment is loaded (:func:`vtexp.adaptive.check.check_adaptive`).

Besides the schema, the few helpers on levels that the load-time checks, compiling and
the session share: :func:`value_list` (the levels), :func:`parameter_value` (a level as
the value of the parameter it sets) and :func:`procedure_spec` (a track's settings).
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Discriminator, Field, TypeAdapter, model_validator
from typing_extensions import Self

from ..model import Model

Function = Literal["weibull", "logistic", "normal", "gumbel"]
Prob = Annotated[float, Field(ge=0.0, lt=1.0)]


class ValueRange(Model):
    """Evenly spaced levels from ``min`` to ``max`` (both included) in steps of ``step``."""

    min: float
    max: float
    step: Annotated[float, Field(gt=0)]

    @model_validator(mode="after")
    def _order(self) -> Self:
        if self.max < self.min:
            raise ValueError("max is below min")
        if (self.max - self.min) / self.step > 100000:
            raise ValueError("more than 100000 levels; take a larger step")
        return self


class GridSpec(Model):
    """``n`` values evenly spaced from ``min`` to ``max`` (or ``log: true``: evenly in log)."""

    min: float
    max: float
    n: Annotated[int, Field(ge=1, le=1000)]
    log: bool = False

    @model_validator(mode="after")
    def _order(self) -> Self:
        if self.max < self.min or (self.log and self.min <= 0):
            raise ValueError("needs min <= max (and min > 0 with log)")
        return self


class ResponseSpec(Model):
    """Which answer counts as a "yes" (a detection, the correct option) for the procedure."""

    question: str | None = Field(None, description="the question read (default: the first)")
    yes_answers: list[str] | None = Field(
        None, description="answers that count as yes; default: the question's correct answer")


class StopSpec(Model):
    trials: Annotated[int, Field(ge=1)] | None = Field(
        None, description="stop a track after this many trials (at most design.repetitions)")
    reversals: Annotated[int, Field(ge=1)] | None = Field(
        None, description="stop a staircase after this many reversals")


class StaircaseSpec(Model):
    """Transformed (Levitt 1971) or weighted (Kaernbach 1991) up-down staircase."""

    kind: Literal["staircase"]
    start: float = Field(description="the first level (one of the values)")
    steps: list[Annotated[float, Field(gt=0)]] = Field(
        min_length=1, description="the step down after 0, 1, 2... reversals (the last repeats)")
    up_steps: list[Annotated[float, Field(gt=0)]] | None = Field(
        None, description="the step up likewise (default: as 'steps', or from 'target')")
    n_up: Annotated[int, Field(ge=1, le=10)] = 1
    n_down: Annotated[int, Field(ge=1, le=10)] = 1
    target: Annotated[float, Field(gt=0, lt=1)] | None = Field(
        None, description="weighted up-down (Kaernbach 1991): up steps = steps x p/(1-p); "
                          "with n_up = n_down = 1")
    initial_one_down: bool = Field(False, description="1-up-1-down until the first reversal")
    harder: Literal["down", "up"] = Field(
        "down", description="'down': a yes lowers the level (intensity); 'up': raises it")
    minimum: float | None = Field(None, description="lowest level (default: the values' lowest)")
    maximum: float | None = Field(None, description="highest level (default: the highest)")
    stop: StopSpec = Field(default_factory=StopSpec)
    estimate_reversals: Annotated[int, Field(ge=1)] | None = Field(
        None, description="the estimate averages the last N reversals (default: all but the "
                          "first, to an even number)")
    function: Function = Field("weibull", description="the function vtexp analyze fits")
    guess: Prob = Field(0.0, description="the task's guess rate (1/m for m alternatives)")

    @model_validator(mode="after")
    def _weighted(self) -> Self:
        if self.target is not None:
            if self.up_steps is not None:
                raise ValueError("give 'target' (weighted up-down) or 'up_steps', not both")
            if self.n_up != 1 or self.n_down != 1:
                raise ValueError("a weighted staircase ('target') takes n_up = n_down = 1")
        return self

    def up(self) -> list[float]:
        if self.up_steps is not None:
            return list(self.up_steps)
        if self.target is not None:
            return [s * self.target / (1.0 - self.target) for s in self.steps]
        return list(self.steps)


class QuestSpec(Model):
    """QUEST (Watson & Pelli 1983): the threshold's posterior, slope and lapse fixed."""

    kind: Literal["quest"]
    function: Function = "weibull"
    slope: Annotated[float, Field(gt=0)] = 3.5
    guess: Prob = 0.0
    lapse: Prob = 0.01
    thresholds: GridSpec | None = Field(
        None, description="the threshold grid (default: the values)")
    prior_mean: float | None = Field(None, description="normal prior (default: flat)")
    prior_sd: Annotated[float, Field(gt=0)] | None = None
    method: Literal["mode", "mean", "median"] = "mean"
    target: Annotated[float, Field(gt=0, lt=1)] | None = Field(
        None, description="place trials where psi reaches this (default: at the threshold)")
    stop: StopSpec = Field(default_factory=StopSpec)

    @model_validator(mode="after")
    def _prior(self) -> Self:
        if (self.prior_mean is None) != (self.prior_sd is None):
            raise ValueError("give both prior_mean and prior_sd, or neither (a flat prior)")
        return self


class QuestPlusSpec(Model):
    """QUEST+ (Watson 2017) / psi (Kontsevich & Tyler 1999): threshold, slope and lapse."""

    kind: Literal["questplus"]
    function: Function = "weibull"
    thresholds: GridSpec | list[float] = Field(description="the threshold grid")
    slopes: GridSpec | list[Annotated[float, Field(gt=0)]] = Field(description="the slope grid")
    lapses: list[Prob] = Field(default_factory=lambda: [0.0, 0.02, 0.04])
    guess: Prob = 0.0
    select_among: Annotated[int, Field(ge=1, le=100)] = Field(
        1, description="1: the level of least expected entropy; N: one of the N least, drawn "
                       "from the session's keyed random stream")
    stop: StopSpec = Field(default_factory=StopSpec)


Procedure = Annotated[StaircaseSpec | QuestSpec | QuestPlusSpec, Discriminator("kind")]


class AdaptiveSpec(Model):
    """Levels chosen trial by trial from the answers so far."""

    variable: str = Field(description="the parameter the procedure sets: of the coding "
                                      "(soa_ms) or, with sets: stimulus, of the stimuli's "
                                      "generator (separation_pitches)")
    sets: Literal["coding", "stimulus"] = Field(
        "coding", description="what the variable is a parameter of: the coding (default) or "
                              "the generator of every stimulus")
    values: ValueRange | list[float] = Field(
        description="the levels that may be played: {min, max, step} or a list")
    response: ResponseSpec = Field(default_factory=ResponseSpec)
    tracks: list[str] | None = Field(
        None, description="the factors whose levels make separate tracks (interleaved "
                          "staircases); conditions that differ only in the other factors share "
                          "a track. Default: every condition its own track")
    procedure: Procedure


#: Levels closer than this are the same level (:func:`value_list` rounds to 9 decimals).
TOL = 1e-9

_PROCEDURE = TypeAdapter(Procedure)


def procedure_spec(spec: AdaptiveSpec, overrides: dict[str, Any] | None = None):
    """The procedure with a condition's ``sets: adaptive`` settings merged in."""
    if not overrides:
        return spec.procedure
    return _PROCEDURE.validate_python({**spec.procedure.model_dump(exclude_unset=True),
                                       **overrides})


def grid(g: GridSpec | list[float]) -> list[float]:
    import numpy as np      # here: the schema (vtexp.experiment) imports without numpy

    if isinstance(g, list):
        return [float(v) for v in g]
    if g.log:
        return [float(v) for v in np.geomspace(g.min, g.max, g.n)]
    return [float(v) for v in np.linspace(g.min, g.max, g.n)]


def value_list(v: ValueRange | list[float]) -> list[float]:
    """The levels, ascending, without repeats."""
    if isinstance(v, list):
        return sorted(set(float(x) for x in v))
    n = int(round((v.max - v.min) / v.step))
    out = [v.min + i * v.step for i in range(n + 1)]
    out = [round(x, 9) for x in out if x <= v.max + 1e-9]
    return out


def parameter_value(level: float) -> int | float:
    """A level as the value of the parameter it sets: a whole number as an ``int`` (within
    :data:`TOL`), so that an integer parameter of a coding or generator takes it; any
    other level as it is."""
    return int(round(level)) if abs(level - round(level)) <= TOL else level
