"""The ``analysis:`` section of an experiment file: the questions its paper asked.

Each study declares the analyses of its report, so that ``vtexp analyze``
answers the questions the study's paper asked (seed 001 §4.1: a two-way
repeated-measures ANOVA of shape × timing on the recognition rate, Table 1,
confusions). Everything is optional; an experiment without the section gets
the default analysis (:func:`default_spec`). Unknown keys are errors, and
factor names are checked against the experiment's factors when the file is
loaded.

Measures (``dv``), one value per participant and cell, averaged over trials:
``rate`` (share of correct answers among scored trials), ``rt_s`` (reaction
time), ``replays`` (times the stimulus was felt again) and ``answer`` (the
answer read as a number, for rating scales).
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, ValidationInfo, model_validator
from typing_extensions import Self

from ..model import Model

Measure = Literal["rate", "rt_s", "replays", "answer"]


def _where():
    """The ``where:`` of the ANOVA family: the trials analysed, by level."""
    return Field(default_factory=dict, description="only the trials at these levels, e.g. "
                 "{display: dynamic} (seed 000's 2 x 2 of the dynamic modes)")


def _between():
    """The ``between:`` of the ANOVA family: factors from the participants table."""
    return Field(default_factory=list, description="between-participant factors: columns of "
                 "the participants table (participants.tsv), e.g. group")


class AnovaSpec(Model):
    """A repeated-measures ANOVA of a measure on within-participant factors."""

    dv: Measure = "rate"
    within: list[str] | None = Field(None, description="factors (default: all of them)")
    correction: Literal["auto", "none", "GG", "HF"] = Field(
        "auto", description="which p the report's sentences give; auto = Greenhouse–Geisser "
                            "when Mauchly's test rejects sphericity (p < .05)")
    note: str = Field("", description="what the paper reported, shown beside the result")
    where: dict[str, str | list[str]] = _where()
    between: list[str] = _between()
    observed: list[str] = Field(default_factory=list, description="factors measured, not "
                                                                  "manipulated (η²G only)")


class SimpleEffectsSpec(Model):
    """Simple effects of ``effect`` at each level of ``by`` (seed 000 Table 3)."""

    effect: str
    by: str
    dv: Measure = "rate"
    within: list[str] | None = None
    method: Literal["separate", "pooled", "both"] = "both"
    between: list[str] = _between()
    where: dict[str, str | list[str]] = _where()


#: The family-wise corrections of post-hoc comparisons (R's ``p.adjust`` names, and Šidák).
PADJUST_METHODS = ("holm", "bonferroni", "BH", "fdr", "sidak", "none")


class PosthocSpec(Model):
    """Paired comparisons between the levels of ``factor`` (within each level of ``by``)."""

    factor: str
    by: str | None = None
    dv: Measure = "rate"
    within: list[str] | None = None
    padjust: Literal[PADJUST_METHODS] = "holm"
    error: Literal["paired", "pooled"] = Field(
        "paired", description="paired: per-participant tests; pooled: the ANOVA model's "
                              "error (emmeans)")
    where: dict[str, str | list[str]] = _where()
    between: list[str] = _between()


class TableSpec(Model):
    """Rate by two factors in the paper's layout (seed 001 Table 1: rows timing, columns shape)."""

    rows: str
    columns: str
    pooled: bool = Field(True, description="pool trials over participants (the paper's "
                                           "percentages) or average participants' rates")


class ConfusionSpec(Model):
    """Confusion matrices, information transfer and kappa per level (combination) of ``by``."""

    by: list[str] = Field(default_factory=list)


class OrdinalSpec(Model):
    """Friedman's test and Wilcoxon signed-rank comparisons on a rating."""

    factor: str
    dv: Measure = "answer"
    padjust: Literal["holm", "bonferroni"] = "holm"
    where: dict[str, str | list[str]] = Field(
        default_factory=dict, description="only these rows, e.g. {question: whirlpool}")


class MixedModelSpec(Model):
    """Mixed logistic regression of correct on the factors, random intercept per participant."""

    factors: list[str] | None = None
    interactions: bool = False
    items: str | None = Field(None, description="a factor whose levels are the stimulus items "
                                                "(e.g. the letter), for a crossed random "
                                                "intercept per item")
    n_quad: int = Field(1, ge=1, le=50, description="1 = Laplace (glmer's default); more = "
                                                    "adaptive Gauss–Hermite quadrature nodes "
                                                    "(only without items)")


class FigureSpec(Model):
    """A measure per condition (x axis ``x``, one line per level of ``trace``): the mean
    of the participants ± SE, and one line per participant (one panel per ``trace``)."""

    x: str
    trace: str | None = None
    dv: Measure = "rate"
    where: dict[str, str | list[str]] = Field(
        default_factory=dict, description="only these rows, e.g. {question: turns} for one "
                                          "question of several")


class PsychometricSpec(Model):
    """A psychometric function fitted per participant to an adaptive experiment's
    answers at the levels played (maximum likelihood, parametric-bootstrap interval)."""

    function: Literal["weibull", "logistic", "normal", "gumbel"] | None = Field(
        None, description="default: the adaptive procedure's")
    guess: float | None = Field(None, ge=0, lt=1, description="default: the procedure's")
    lapse: float | Literal["free"] = Field(
        "free", description="a fixed lapse rate, or 'free' (fitted within [0, max_lapse])")
    max_lapse: float = Field(0.1, ge=0, lt=0.5)
    bootstrap: int = Field(200, ge=0, le=10000, description="parametric bootstrap samples")
    by: list[str] = Field(default_factory=list,
                          description="factors fitted separately (e.g. the staircase track)")


class AnalysisSpec(Model):
    """The analyses of an experiment's report."""

    anova: list[AnovaSpec] = Field(default_factory=list)
    simple_effects: list[SimpleEffectsSpec] = Field(default_factory=list)
    posthoc: list[PosthocSpec] = Field(default_factory=list)
    table: TableSpec | None = None
    confusion: ConfusionSpec | None = None
    ordinal: list[OrdinalSpec] = Field(default_factory=list)
    mixed_model: MixedModelSpec | None = None
    figure: FigureSpec | list[FigureSpec] | None = Field(
        None, description="a figure, or a list of them (e.g. one per question)")
    psychometric: PsychometricSpec | None = Field(
        None, description="adaptive experiments: the psychometric function per participant "
                          "(fitted by default when the experiment is adaptive)")

    def figures(self) -> list[FigureSpec]:
        """The declared figures as a list (``figure:`` may be one or a list)."""
        if self.figure is None:
            return []
        return list(self.figure) if isinstance(self.figure, list) else [self.figure]

    @model_validator(mode="after")
    def _distinct(self) -> Self:
        for i, s in enumerate(self.simple_effects):
            if s.effect == s.by:
                raise ValueError(f"simple_effects[{i}]: effect and by are both {s.effect!r}")
        for i, p in enumerate(self.posthoc):
            if p.by == p.factor:
                raise ValueError(f"posthoc[{i}]: factor and by are both {p.factor!r}")
        if self.table and self.table.rows == self.table.columns:
            raise ValueError("table: rows and columns are the same factor")
        return self

    def references(self) -> list[tuple[str, str]]:
        """(where, factor name) for every factor the analyses name."""
        refs: list[tuple[str, str]] = []
        for i, a in enumerate(self.anova):
            refs += [(f"anova[{i}].within", f) for f in a.within or []]
            refs += [(f"anova[{i}].where", f) for f in a.where]
        for i, s in enumerate(self.simple_effects):
            refs += [(f"simple_effects[{i}].effect", s.effect), (f"simple_effects[{i}].by", s.by)]
            refs += [(f"simple_effects[{i}].within", f) for f in s.within or []]
            refs += [(f"simple_effects[{i}].where", f) for f in s.where]
        for i, p in enumerate(self.posthoc):
            refs += [(f"posthoc[{i}].factor", p.factor)]
            refs += [(f"posthoc[{i}].by", p.by)] if p.by else []
            refs += [(f"posthoc[{i}].within", f) for f in p.within or []]
            refs += [(f"posthoc[{i}].where", f) for f in p.where]
        if self.table:
            refs += [("table.rows", self.table.rows), ("table.columns", self.table.columns)]
        if self.confusion:
            refs += [("confusion.by", f) for f in self.confusion.by]
        for i, o in enumerate(self.ordinal):
            refs += [(f"ordinal[{i}].factor", o.factor)]
            refs += [(f"ordinal[{i}].where", f) for f in o.where]
        if self.mixed_model:
            refs += [("mixed_model.factors", f) for f in self.mixed_model.factors or []]
            refs += [("mixed_model.items", self.mixed_model.items)] if self.mixed_model.items \
                else []
        if self.psychometric:
            refs += [("psychometric.by", f) for f in self.psychometric.by]
        many = isinstance(self.figure, list)
        for i, f in enumerate(self.figures()):
            at = f"figure[{i}]" if many else "figure"
            refs += [(f"{at}.x", f.x)]
            refs += [(f"{at}.trace", f.trace)] if f.trace else []
            refs += [(f"{at}.where", k) for k in f.where]
        return refs

    def between_factors(self) -> list[str]:
        """Every between-participant factor the analyses name (participants' properties)."""
        out: list[str] = []
        for a in [*self.anova, *self.simple_effects, *self.posthoc]:
            out += [f for f in a.between if f not in out]
        return out

    def unknown_factors(self, factors: list[str]) -> list[str]:
        """Messages for every factor name that is not one of ``factors``."""
        # 'question' is a column too: where: {question: NAME} picks one question's rows;
        # between factors are participants' properties, checked against participants.tsv.
        between = self.between_factors()
        for i, a in enumerate(self.anova):
            for f in a.observed:
                if f not in a.between and f not in (a.within or factors):
                    return [f"analysis.anova[{i}].observed: {f!r} is not one of its factors"]
        return [f"analysis.{where}: {name!r} is not a factor of this experiment (factors: "
                f"{', '.join(factors)})" for where, name in self.references()
                if name not in factors and name not in between
                and not (where.endswith(".where") and name == "question")]


def check_factor_references(spec: AnalysisSpec | None, info: ValidationInfo) -> Any:
    """Pydantic after-validator for ``Experiment.analysis``: names must be factors."""
    factors = (info.data or {}).get("factors")
    if spec is not None and factors:
        problems = spec.unknown_factors(list(factors))
        if problems:
            raise ValueError(problems[0])
    return spec


def default_spec(factors: list[str], stimulus_factor: str | None, scored: bool) -> AnalysisSpec:
    """What an experiment without an ``analysis:`` section gets.

    With scored answers: an ANOVA of the rate on every factor, the rate figure
    (x: the first factor that is not the stimulus, lines: the stimulus), the
    rate table (rows: that factor, columns: the stimulus), confusion matrices
    per level of the other factors, and the mixed logistic model. Without
    scored answers: only what needs no scoring (none of the above).
    """
    if not scored:
        return AnalysisSpec()
    others = [f for f in factors if f != stimulus_factor]
    x = others[0] if others else factors[0]
    trace = stimulus_factor if stimulus_factor and stimulus_factor != x else None
    return AnalysisSpec(
        anova=[AnovaSpec(within=list(factors))],
        table=TableSpec(rows=x, columns=trace) if trace else None,
        confusion=ConfusionSpec(by=others if stimulus_factor else []),
        mixed_model=MixedModelSpec(factors=list(factors)),
        figure=FigureSpec(x=x, trace=trace))
