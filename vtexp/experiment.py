"""Experiment declarations: the YAML schema, loading and validation.

:func:`load_experiment` reads a YAML file safely, validates it against
:class:`Experiment` (unknown keys are errors), then checks what a schema
cannot: that names refer to things that exist, that every condition's
parameters are valid for its pipeline and coding, and that every condition's
stimulus is safe on the declared device. Errors name the file, the line and
the key.

The coding may be given inline (``protocol`` + ``params``) or by reference to
a coding file (``ref``: ``protocols/codings/NAME.yaml`` or a path relative to
the experiment file), whose parameters the inline ``params`` override; either
way the loaded :class:`CodingSpec` holds the protocol and the merged parameters.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (AfterValidator, ConfigDict, Discriminator, Field, PrivateAttr, Tag,
                      ValidationError, ValidationInfo, computed_field, field_validator,
                      model_validator)
from typing_extensions import Self

from .adaptive.spec import AdaptiveSpec
from .analysis.spec import AnalysisSpec, check_factor_references
from .errors import InputError
from .model import DeviceProfile, Model
from .observer.spec import ObserverSpec
from .resources import codings_dir
from .yamlio import KeyPath, LoadedYaml, format_validation_error, load_yaml, load_yaml_text

# The registries of generators, pipelines and codings (OpenCV, SciPy), the adaptive
# checks (numpy) and the live path are imported by the functions that check against
# them, when an experiment is loaded: importing the schema stays light (vtexp.analysis,
# vtexp.adaptive and vtexp.observer load lazily for the same reason).

NAME = r"^[a-z][a-z0-9_]*$"
LABEL = r"^[A-Za-z0-9][A-Za-z0-9_.\-/ ]*$"


def _registered(kind: str, name: str | None, registry: dict) -> str | None:
    if name is not None and name not in registry:
        raise ValueError(f"unknown {kind} {name!r}; available: {', '.join(sorted(registry))}")
    return name


class StimulusSpec(Model):
    """A stimulus image: from a generator (``generator`` + ``params``), a ``file``, or a
    camera (``camera: N``; ``video: FILE`` stands in for one in tests), whose frame is
    taken at each trial (``vtexp.live.trial``)."""

    generator: str | None = Field(None, description="a name from vtexp.stimuli.GENERATORS")
    file: Annotated[str, Field(min_length=1)] | None = Field(
        None, description="image path, relative to the YAML file")
    params: dict[str, Any] = Field(default_factory=dict)
    camera: Annotated[int, Field(ge=0)] | None = Field(
        None, description="a camera (OpenCV index): the object placed before it is the stimulus")
    video: Annotated[str, Field(min_length=1)] | None = Field(
        None, description="a video file standing in for a camera, relative to the YAML file")
    object: str | None = Field(
        None, description="camera: what the experimenter is asked to place (default: the "
                          "stimulus's name)")
    delay_s: Annotated[float, Field(ge=0, le=600)] | None = Field(
        None, description="camera: take the frame this long after the trial starts, instead "
                          "of asking the experimenter to press Enter")
    live: bool = Field(False, description="camera: play the camera continuously until the "
                                          "participant answers")

    @field_validator("generator")
    @classmethod
    def _known(cls, v: str | None) -> str | None:
        from .stimuli import GENERATORS
        return _registered("generator", v, GENERATORS)

    @model_validator(mode="after")
    def _one_source(self) -> Self:
        given = [k for k in ("generator", "file", "camera", "video")
                 if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError("give one of 'generator', 'file', 'camera' or 'video'")
        if self.generator is None and self.params:
            raise ValueError("'params' apply to generators only")
        if not self.is_camera and (self.object is not None or self.delay_s is not None
                                   or self.live):
            raise ValueError("'object', 'delay_s' and 'live' apply to 'camera' and 'video' only")
        return self

    @property
    def is_camera(self) -> bool:
        """Taken from a camera (or a video standing in for one) at each trial."""
        return self.camera is not None or self.video is not None


class EncodingSpec(Model):
    pipeline: str = Field(description="a name from vtexp.encoding.PIPELINES")

    params: dict[str, Any] = Field(default_factory=dict)

    @field_validator("pipeline")
    @classmethod
    def _known(cls, v: str) -> str:
        from .encoding import PIPELINES
        return _registered("pipeline", v, PIPELINES)


def _no_default(schema: dict) -> None:
    # Absent is not null: an editor should not offer 'protocol: null'.
    schema.pop("default", None)


def _ref_schema(schema: dict) -> None:
    _no_default(schema)
    schema["examples"] = available_codings()


class CodingFile(Model):
    """A coding protocol in a file of its own: ``protocols/codings/NAME.yaml``.

    It names a registered protocol and its parameters, with the paper they come
    from; experiments refer to it by ``coding: {ref: NAME}``.
    """

    name: Annotated[str, Field(pattern=NAME)] = Field(
        description="the file's name without .yaml (what 'ref:' gives)")
    description: str = ""
    reference: str = Field(description="where the values come from: paper, section, table")
    protocol: str = Field(description="a name from vtexp.coding.CODINGS")
    params: dict[str, Any] = Field(default_factory=dict)

    @field_validator("protocol")
    @classmethod
    def _known(cls, v: str) -> str:
        from .coding import CODINGS
        return _registered("coding protocol", v, CODINGS)


class CodingSource(Model):
    """The coding file an experiment's coding came from (recorded in session.json)."""

    ref: str = Field(description="the reference as the experiment file gives it")
    file: str = Field(description="the file it resolved to")
    sha256: str = Field(description="SHA-256 of the file's text")


class CodingSpec(Model):
    """How patterns become pulses: a ``protocol`` with its ``params``, or ``ref`` to a
    coding file (a name in protocols/codings/, or a path relative to the experiment
    file) whose parameters ``params`` override. Loaded, both forms have ``protocol``
    and the merged ``params``; with ``ref``, ``source`` names the file and its SHA-256.
    """

    model_config = ConfigDict(json_schema_extra={
        "oneOf": [{"required": ["protocol"]}, {"required": ["ref"]}]})

    protocol: str | None = Field(None, description="a name from vtexp.coding.CODINGS",
                                 json_schema_extra=_no_default)
    ref: str | None = Field(
        None, description="a coding file instead of 'protocol': NAME for "
                          "protocols/codings/NAME.yaml, or a path to a .yaml file relative "
                          "to the experiment file",
        json_schema_extra=_ref_schema)
    params: dict[str, Any] = Field(
        default_factory=dict, description="the protocol's parameters; with 'ref', they "
                                          "override the file's")
    _source: CodingSource | None = PrivateAttr(None)

    @field_validator("protocol")
    @classmethod
    def _known(cls, v: str | None) -> str | None:
        from .coding import CODINGS
        return _registered("coding protocol", v, CODINGS)

    @field_validator("ref")
    @classmethod
    def _findable(cls, v: str | None, info: ValidationInfo) -> str | None:
        if v is None:
            return v
        if info.data.get("protocol") is not None:
            raise ValueError("give either 'protocol' (with its 'params') or 'ref' to a "
                             "coding file, not both")
        coding_path(v, _base_dir(info))             # raises if there is no such file
        return v

    @model_validator(mode="after")
    def _resolve(self, info: ValidationInfo) -> Self:
        if self.ref is None:
            if self.protocol is None:
                raise ValueError("give 'protocol' (a coding protocol, with its 'params') "
                                 "or 'ref' (a coding file in protocols/codings/)")
            return self
        path = coding_path(self.ref, _base_dir(info))
        cf, sha = load_coding_file(path, referenced_at=_referenced_at(info))
        self.protocol = cf.protocol
        self.params = {**cf.params, **self.params}
        self._source = CodingSource(ref=self.ref, file=str(path.resolve()), sha256=sha)
        return self

    @computed_field(description="the coding file used, with 'ref' (filled in on loading)")
    @property
    def source(self) -> CodingSource | None:
        return self._source


def available_codings() -> list[str]:
    """Names of the coding files in protocols/codings/."""
    d = codings_dir()
    return sorted(p.stem for p in d.glob("*.yaml")) if d.is_dir() else []


def coding_path(ref: str, base: Path | None = None) -> Path:
    """The file ``coding: {ref: ...}`` names; ``ValueError`` if there is none.

    A bare name is ``protocols/codings/NAME.yaml``; anything with a ``/`` or a
    ``.yaml``/``.yml`` suffix is a path, relative to ``base`` (the experiment
    file's folder) unless absolute.
    """
    if "/" in ref or "\\" in ref or ref.endswith((".yaml", ".yml")):
        p = Path(ref)
        if not p.is_absolute() and base is not None:
            p = base / p
        if not p.is_file():
            raise ValueError(f"coding file {str(p)!r} " + ("is a directory" if p.is_dir()
                                                           else "not found"))
        return p
    p = codings_dir() / f"{ref}.yaml"
    if not p.is_file():
        raise ValueError(f"unknown coding {ref!r}; known codings: "
                         f"{', '.join(available_codings()) or 'none'} (or a path to a "
                         ".yaml file, relative to the experiment file)")
    return p


def load_coding_file(path: str | Path, *, referenced_at: str = "") -> tuple[CodingFile, str]:
    """Read and check a coding file; return it and the SHA-256 of its text.

    Errors name the coding file, its line and key (and, given ``referenced_at``,
    the experiment that refers to it).
    """
    from .coding import CODINGS

    path = Path(path)
    suffix = f" (coding file of {referenced_at})" if referenced_at else ""
    try:
        loaded = load_yaml(path)
        if not isinstance(loaded.data, dict):
            raise InputError("expected a mapping of keys (name:, reference:, protocol:, "
                             "params:) at the top level", path=loaded.path, line=1)
        try:
            cf = CodingFile.model_validate(loaded.data)
        except ValidationError as exc:
            raise format_validation_error(exc, loaded) from None
        if cf.name != path.stem:
            raise InputError(f"{cf.name!r} differs from the file's name {path.stem!r}; "
                             "make them the same", path=loaded.path,
                             line=loaded.line_of(("name",)), key="name")
        _, params_model = CODINGS[cf.protocol]
        try:
            params_model.model_validate(cf.params)
        except ValidationError as exc:
            raise format_validation_error(exc, loaded, root=("params",)) from None
    except InputError as e:
        if not suffix:
            raise
        raise InputError(e.message + suffix, path=e.path, line=e.line, key=e.key) from None
    return cf, hashlib.sha256(loaded.text.encode("utf-8")).hexdigest()


def _base_dir(info: ValidationInfo) -> Path | None:
    """The experiment file's folder, from the validation context ``{"experiment": LoadedYaml}``."""
    src = (info.context or {}).get("experiment")
    return Path(src.path).parent if src is not None else None


def _referenced_at(info: ValidationInfo) -> str:
    src = (info.context or {}).get("experiment")
    if src is None:
        return ""
    line = src.line_of(("coding", "ref"))
    return f"{src.path}:{line}" if line else str(src.path)


class FactorSpec(Model):
    """A within-participant factor.

    ``levels`` is a list of level names, or a mapping from level name to the
    parameters that level sets. ``sets`` says what the factor changes:
    ``stimulus`` (level names are stimulus names), ``coding`` or ``encoding``
    (each level's mapping overrides those parameters), ``adaptive`` (each level's
    mapping overrides the adaptive procedure's settings: interleaved tracks), or
    ``none``.
    """

    levels: list[Annotated[str, Field(pattern=LABEL)]] | dict[
        Annotated[str, Field(pattern=LABEL)], dict[str, Any]]
    sets: Literal["stimulus", "coding", "encoding", "adaptive", "none"] = "none"
    description: str = ""

    @model_validator(mode="after")
    def _shape(self) -> Self:
        names = self.level_names
        if len(names) < 1:
            raise ValueError("a factor needs at least one level")
        if len(set(names)) != len(names):
            raise ValueError("level names must be unique")
        if self.sets in ("coding", "encoding", "adaptive") and not isinstance(self.levels, dict):
            raise ValueError(f"a factor that sets {self.sets} parameters needs levels as a "
                             "mapping: level name -> parameters")
        if self.sets in ("stimulus", "none") and isinstance(self.levels, dict):
            raise ValueError(f"a factor that sets {self.sets} lists its level names; "
                             "parameters per level need 'sets: coding' or 'sets: encoding'")
        return self

    @property
    def level_names(self) -> list[str]:
        return list(self.levels) if isinstance(self.levels, dict) else list(self.levels)

    def params_of(self, level: str) -> dict[str, Any]:
        return dict(self.levels[level]) if isinstance(self.levels, dict) else {}


class DesignSpec(Model):
    repetitions: Annotated[int, Field(ge=1, le=10000)] = Field(
        description="times each condition is presented")
    order: Literal["random", "sequential", "blocked"] = "random"
    block_by: str | None = Field(
        None, description="with order: blocked, the factor whose levels form the blocks")
    block_order: Literal["latin_square", "random", "declared"] = Field(
        "latin_square", description="order of the blocks: a balanced Latin square row "
                                    "per participant (counterbalanced), random, or as declared")
    practice: Annotated[int, Field(ge=0, le=1000)] = Field(
        0, description="practice trials before the main trials (logged, not analysed)")
    break_every: Annotated[int, Field(ge=1)] | None = Field(
        None, description="a break screen after every N main trials")
    seed: int | None = Field(
        None, description="fixed shuffle seed; by default derived from (experiment, "
                          "participant, session)")
    iti_ms: Annotated[float, Field(ge=0, le=600000)] = Field(
        1000, description="pause between trials, after the answer")
    conditions: list[dict[str, str]] | None = Field(
        None, description="the conditions to run, each naming a level of every factor; "
                          "default: every combination of levels (full factorial)")


class ChoiceQuestion(Model):
    kind: Literal["choice"] = "choice"
    name: Annotated[str, Field(pattern=NAME)] = "response"
    prompt: str
    options: list[Annotated[str, Field(pattern=LABEL)]] = Field(min_length=2)
    correct: str | None = Field(
        None, description="the correct option: a literal option, or '{factor}' for the "
                          "trial's level of that factor, or '{stimulus}'; none if unscored")
    replays: Annotated[int, Field(ge=0)] = Field(
        0, description="how many times the participant may feel the stimulus again")

    @model_validator(mode="after")
    def _unique(self) -> Self:
        if len(set(self.options)) != len(self.options):
            raise ValueError("options must be unique")
        return self


class RatingQuestion(Model):
    """A rating on a scale of whole numbers from ``low`` to ``high`` (seed 002: 0..4, -2..+2)."""

    kind: Literal["rating"]
    name: Annotated[str, Field(pattern=NAME)] = "rating"
    prompt: str
    low: int
    high: int
    labels: dict[int, str] = Field(
        default_factory=dict, description="words shown under scale points, e.g. the ends")
    correct: str | None = Field(
        None, description="the correct rating, literal or '{factor}'; none if unscored")
    replays: Annotated[int, Field(ge=0)] = 0

    @model_validator(mode="after")
    def _scale(self) -> Self:
        if not self.low < self.high or self.high - self.low > 20:
            raise ValueError("a rating scale needs low < high and at most 21 points")
        outside = [k for k in self.labels if not self.low <= k <= self.high]
        if outside:
            raise ValueError(f"label for {outside[0]} is outside the scale {self.low}..{self.high}")
        return self

    @property
    def scale(self) -> list[int]:
        return list(range(self.low, self.high + 1))

    @property
    def options(self) -> list[str]:
        return [str(v) for v in self.scale]


class NumberQuestion(Model):
    """A whole number the participant types in (seed 002: the turns of a whirlpool)."""

    kind: Literal["number"]
    name: Annotated[str, Field(pattern=NAME)] = "count"
    prompt: str
    minimum: int = 0
    maximum: int = 99
    correct: str | None = Field(
        None, description="the correct number, literal or '{factor}'; none if unscored")
    replays: Annotated[int, Field(ge=0)] = 0

    @model_validator(mode="after")
    def _range(self) -> Self:
        if not self.minimum <= self.maximum or self.maximum - self.minimum > 10000:
            raise ValueError("a number question needs minimum <= maximum (at most 10000 apart)")
        return self

    @property
    def options(self) -> list[str]:
        return [str(v) for v in range(self.minimum, self.maximum + 1)]


class PresentationSpec(Model):
    """How the participant is told and asked (the participant window, ``--responder
    window``); ``--responder window:audio,scale=2,lang=de,noise=off`` overrides it."""

    audio: bool = Field(
        False, description="speak every instruction, question, option, confirmation and "
                           "break (espeak-ng), for participants who cannot see the screen; "
                           "answers by keys that match what is heard")
    language: Annotated[str, Field(pattern=r"^[A-Za-z]{2,3}([-_][A-Za-z0-9]{1,8})*$")] = Field(
        "en", description="espeak-ng's language of the spoken clips (espeak-ng --voices)")
    scale: Annotated[float, Field(ge=1.0, le=2.5)] = Field(
        1.0, description="every text at least scale x 3 % of the screen height (checked to "
                         "fit the screen before the first trial)")
    masking_noise: bool = Field(
        True, description="with audio: a rushing noise in the headphones while each stimulus "
                          "plays, so that the device's sound gives nothing away (seed 001)")
    phrases: dict[str, str] = Field(
        default_factory=dict, description="the spoken phrases to replace (see "
                                          "vtexp/responders/speech.py PHRASES), e.g. for a "
                                          "language vtexp has no phrase book for")


class ParticipantField(Model):
    """A property of each participant (a column of the dataset's ``participants.tsv``),
    asked of the experimenter at the participant's first session and kept."""

    description: str = Field(description="what the value means, for participants.json")
    levels: list[Annotated[str, Field(pattern=r"^[A-Za-z0-9][A-Za-z0-9_.\-]*$")]] | None = Field(
        None, description="the values allowed (e.g. [blind, sighted]); any single word if "
                          "not given")
    type: Literal["text", "number"] = Field("text", description="text or number")
    units: str | None = Field(None, description="units of a number, e.g. years")
    minimum: float | None = Field(None, description="smallest number allowed")
    maximum: float | None = Field(None, description="largest number allowed")

    @model_validator(mode="after")
    def _consistent(self) -> Self:
        if self.type == "number" and self.levels:
            raise ValueError("a number field has no 'levels' (give minimum/maximum)")
        if self.type == "text" and (self.units or self.minimum is not None
                                    or self.maximum is not None):
            raise ValueError("'units', 'minimum' and 'maximum' are for type: number")
        return self


def _participant_fields(value: dict) -> dict:
    for name in value:
        if name in ("participant_id", "participant", "experiment", "session", "dataset"):
            raise ValueError(f"{name!r} is not a participant field vtexp can ask (it names "
                             "the participant or the data); choose another name")
    return value


QUESTION_KINDS = ("choice", "rating", "number")


def _question_kind(value: Any) -> str:
    if isinstance(value, dict):
        kind = value.get("kind", "choice")
        return kind if kind in QUESTION_KINDS else "choice"
    return getattr(value, "kind", "choice")


Question = Annotated[
    Annotated[ChoiceQuestion, Tag("choice")] | Annotated[RatingQuestion, Tag("rating")]
    | Annotated[NumberQuestion, Tag("number")],
    Discriminator(_question_kind)]


class Experiment(Model):
    name: Annotated[str, Field(pattern=NAME, max_length=64)] = Field(
        description="lower-case identifier; names the data folder")
    title: str
    reference: str = Field("", description="the paper and section this reproduces")
    description: str = ""
    instructions: str = ""
    device: Annotated[str, Field(pattern=r"^[A-Za-z0-9_\-]+$")] = Field(
        description="device profile name (protocols/devices/NAME.yaml)")
    stimuli: dict[Annotated[str, Field(pattern=LABEL)], StimulusSpec] = Field(min_length=1)
    encoding: EncodingSpec
    coding: CodingSpec
    factors: dict[Annotated[str, Field(pattern=NAME)], FactorSpec] = Field(min_length=1)
    design: DesignSpec
    question: Question | None = Field(
        None, description="the question asked after each stimulus (or 'questions')")
    questions: list[Question] | None = Field(
        None, description="several questions asked in turn about one stimulus")
    analysis: Annotated[AnalysisSpec | None, AfterValidator(check_factor_references)] = Field(
        None, description="the analyses of the report (vtexp/analysis/spec.py)")
    observer: ObserverSpec | None = Field(
        None, description="how a model participant answers (vtexp simulate, vtexp/observer)")
    presentation: PresentationSpec | None = Field(
        None, description="how the participant is told and asked: spoken (audio), text size")
    adaptive: AdaptiveSpec | None = Field(
        None, description="a coding parameter chosen trial by trial from the answers so far: "
                          "staircase, QUEST or QUEST+ (vtexp/adaptive/spec.py)")
    participants: Annotated[dict[Annotated[str, Field(pattern=NAME)], ParticipantField],
                            AfterValidator(_participant_fields)] = Field(
        default_factory=dict,
        description="properties of each participant asked at their first session and kept in "
                    "the dataset's participants.tsv, besides group, age, handedness and vision "
                    "(which a field of the same name redefines, e.g. group with its levels)")

    @model_validator(mode="after")
    def _one_question_key(self) -> Self:
        if (self.question is None) == (self.questions is None):
            raise ValueError("give 'question' (one question) or 'questions' (a list), "
                             "not both or neither")
        names = [q.name for q in self.asked()]
        if not names:
            raise ValueError("'questions' is empty")
        if len(set(names)) != len(names):
            raise ValueError(f"question names must differ (got {names}); set 'name:'")
        return self

    def asked(self) -> list:
        """The questions asked after each stimulus, in order."""
        return [self.question] if self.question is not None else list(self.questions or [])

    @property
    def task_label(self) -> str:
        """BIDS task label (letters and digits only): ``six_mode_ball`` -> ``sixModeBall``."""
        head, *rest = self.name.split("_")
        return head + "".join(w[:1].upper() + w[1:] for w in rest)

    def stimulus_factor(self) -> str | None:
        for name, f in self.factors.items():
            if f.sets == "stimulus":
                return name
        return None


RESERVED_COLUMNS = frozenset(
    "trial practice repetition block stimulus stim_file question answer correct_answer correct rt_s "
    "replays stimulus_onset_ms stimulus_duration_ms n_pulses status started_at proposed presented "
    "experiment participant session".split())


class LoadedExperiment:
    """An experiment with where it came from (for messages and the session record)."""

    def __init__(self, experiment: Experiment, source: LoadedYaml):
        self.experiment = experiment
        self.source = source
        self.path = Path(source.path)
        self.sha256 = hashlib.sha256(source.text.encode("utf-8")).hexdigest()
        #: what the checks accepted but the experimenter should hear (printed by validate
        #: and run): stimulus files outside the experiment's folder
        self.notes: list[str] = []

    def error(self, message: str, keypath: KeyPath) -> InputError:
        return InputError(message, path=self.source.path, line=self.source.line_of(keypath),
                          key=".".join(str(k) for k in keypath))

    def resolve(self, file: str) -> Path:
        p = Path(file)
        return p if p.is_absolute() else self.path.parent / p


def load_experiment(path: str | Path) -> LoadedExperiment:
    """Load, validate and check an experiment file; raise :class:`InputError` if wrong.

    Checks the schema and every reference (device, stimulus files, generators,
    pipelines, codings and their parameters). Encoding the stimuli and checking
    their safety is :func:`vtexp.compile.load_and_compile`'s.
    """
    return _loaded(load_yaml(path))


def load_experiment_text(text: str, path: str | Path) -> LoadedExperiment:
    """:func:`load_experiment` of an experiment's ``text`` (a copy sent to another
    machine); ``path`` names it in messages, and files it refers to (stimulus images,
    coding files by path) are looked for beside it."""
    return _loaded(load_yaml_text(text, str(path)))


def _loaded(loaded: LoadedYaml) -> LoadedExperiment:
    if not isinstance(loaded.data, dict):
        raise InputError("expected a mapping of keys (name:, title:, ...) at the top level",
                         path=loaded.path, line=1)
    try:
        exp = Experiment.model_validate(loaded.data, context={"experiment": loaded})
    except ValidationError as exc:
        raise format_validation_error(exc, loaded) from None
    lx = LoadedExperiment(exp, loaded)
    _check(lx)
    return lx


def _check(lx: LoadedExperiment) -> None:
    from .coding import CODINGS
    from .encoding import PIPELINES
    from .stimuli import GENERATORS

    exp = lx.experiment
    try:
        profile = DeviceProfile.load(exp.device)
    except InputError as e:
        if e.path is None:                      # unknown name: point at the key
            raise lx.error(e.message, ("device",)) from None
        raise

    for sname, spec in exp.stimuli.items():
        if spec.file is not None or spec.video is not None:
            key = "file" if spec.file is not None else "video"
            f = lx.resolve(spec.file or spec.video)
            if not f.is_file():
                raise lx.error(f"stimulus {key} {str(f)!r} not found", ("stimuli", sname, key))
            home = lx.path.parent.resolve()
            if not f.resolve().is_relative_to(home):
                lx.notes.append(
                    f"{lx.path}:{lx.source.line_of(('stimuli', sname, key)) or '?'}: stimulus "
                    f"{sname!r}: {spec.file or spec.video!r} is outside the experiment's folder "
                    f"({f.resolve()}); a copy of the folder will not carry it (each session "
                    "records its path and checksum)")
        elif spec.is_camera:
            pass                                # a camera is looked for when the trial runs
        else:
            _, params_model = GENERATORS[spec.generator]
            _validate_params(lx, params_model, spec.params, ("stimuli", sname, "params"))

    stim_factors = [n for n, f in exp.factors.items() if f.sets == "stimulus"]
    if len(stim_factors) > 1:
        raise lx.error("only one factor may set the stimulus", ("factors", stim_factors[1], "sets"))
    if stim_factors:
        fname = stim_factors[0]
        for i, level in enumerate(exp.factors[fname].level_names):
            if level not in exp.stimuli:
                raise lx.error(f"level {level!r} is not a stimulus; declared stimuli: "
                               f"{', '.join(exp.stimuli)}", ("factors", fname, "levels", i))
    elif len(exp.stimuli) != 1:
        raise lx.error("several stimuli are declared but no factor chooses among them "
                       "(add a factor with 'sets: stimulus')", ("factors",))

    d = exp.design
    if d.order == "blocked" and (d.block_by is None or d.block_by not in exp.factors):
        raise lx.error("order: blocked needs 'block_by: FACTOR' naming one of the factors "
                       f"({', '.join(exp.factors)})", ("design", "block_by") if d.block_by
                       else ("design", "order"))
    if d.block_by is not None and d.order != "blocked":
        raise lx.error("block_by only applies with order: blocked", ("design", "block_by"))
    if exp.design.conditions is not None:
        seen: set[tuple] = set()
        if not exp.design.conditions:
            raise lx.error("the list of conditions is empty", ("design", "conditions"))
        for i, cond in enumerate(exp.design.conditions):
            kp = ("design", "conditions", i)
            missing = [f for f in exp.factors if f not in cond]
            extra = [k for k in cond if k not in exp.factors]
            if extra:
                raise lx.error(f"{extra[0]!r} is not a factor; factors: "
                               f"{', '.join(exp.factors)}", kp + (extra[0],))
            if missing:
                raise lx.error(f"the condition names no level of factor {missing[0]!r}", kp)
            for f, level in cond.items():
                if level not in exp.factors[f].level_names:
                    raise lx.error(f"{level!r} is not a level of {f!r}; levels: "
                                   f"{', '.join(exp.factors[f].level_names)}", kp + (f,))
            key = tuple(cond[f] for f in exp.factors)
            if key in seen:
                raise lx.error("the same condition is listed twice", kp)
            seen.add(key)

    for fname in exp.factors:
        if fname in RESERVED_COLUMNS:
            raise lx.error(f"{fname!r} is a reserved column name of the trial log; "
                           "choose another factor name", ("factors", fname))

    _, enc_model = PIPELINES[exp.encoding.pipeline]
    _, cod_model = CODINGS[exp.coding.protocol]
    _validate_params(lx, enc_model, exp.encoding.params, ("encoding", "params"))
    _validate_params(lx, cod_model, exp.coding.params, ("coding", "params"))
    for fname, f in exp.factors.items():
        if f.sets not in ("coding", "encoding"):
            continue
        base = exp.coding.params if f.sets == "coding" else exp.encoding.params
        model = cod_model if f.sets == "coding" else enc_model
        for level in f.level_names:
            kp = ("factors", fname, "levels", level)
            _validate_params(lx, model, {**base, **f.params_of(level)}, kp,
                             only=set(f.params_of(level)), fallback=(f.sets, "params"))

    for qi, q in enumerate(exp.asked()):
        _check_correct(lx, q, ("question",) if exp.question is not None else ("questions", qi))
    _check_camera(lx)
    adaptive_factors = [n for n, f in exp.factors.items() if f.sets == "adaptive"]
    if exp.adaptive is None and adaptive_factors:
        raise lx.error("a factor sets the adaptive procedure's settings, but there is no "
                       "'adaptive:' section", ("factors", adaptive_factors[0], "sets"))
    if exp.adaptive is not None:
        from .adaptive.check import check_adaptive

        if any(s.is_camera for s in exp.stimuli.values()):
            raise lx.error("an adaptive procedure needs stimuli that can be coded before the "
                           "session (not camera stimuli)", ("adaptive",))
        check_adaptive(lx, profile, cod_model)


def _check_camera(lx: LoadedExperiment) -> None:
    """Live camera stimuli need a pipeline that runs live, and no replays (they play
    until the answer)."""
    exp = lx.experiment
    live = [n for n, s in exp.stimuli.items() if s.live]
    if not live:
        return
    from .live.encoder import LIVE_PIPELINES

    if exp.encoding.pipeline not in LIVE_PIPELINES:
        raise lx.error(f"stimulus {live[0]!r} is live, but pipeline "
                       f"{exp.encoding.pipeline!r} does not run live (one of "
                       f"{', '.join(LIVE_PIPELINES)})", ("stimuli", live[0], "live"))
    for qi, q in enumerate(exp.asked()):
        if q.replays:
            where = ("question",) if exp.question is not None else ("questions", qi)
            raise lx.error(f"a live stimulus ({live[0]!r}) plays until the answer; it cannot "
                           "be felt again (replays: 0)", where + ("replays",))


def _check_correct(lx: LoadedExperiment, q, where: KeyPath) -> None:
    exp = lx.experiment
    if q.correct is not None:
        c = q.correct
        if c.startswith("{") and c.endswith("}"):
            ref = c[1:-1]
            if ref == "stimulus":
                values = list(exp.stimuli)
            elif ref in exp.factors:
                values = exp.factors[ref].level_names
            else:
                raise lx.error(f"{c!r} names no factor; use '{{factor}}' with one of "
                               f"{', '.join(exp.factors)}, or '{{stimulus}}'",
                               where + ("correct",))
            missing = [v for v in values if v not in q.options]
            if missing:
                raise lx.error(f"the correct answers {missing} are not among the options "
                               f"{q.options}", where + ("correct",))
        elif c not in q.options:
            raise lx.error(f"{c!r} is not one of the options {q.options}", where + ("correct",))


def _validate_params(lx: LoadedExperiment, model, params: dict, keypath: KeyPath,
                     only: set[str] | None = None, fallback: KeyPath = ()) -> Any:
    """Validate ``params`` against ``model``; errors point at ``keypath``.

    For a factor level (``only`` = the keys the level overrides), an error in a
    key the level does not set points at ``fallback``, where that key came from.
    """
    try:
        return model.model_validate(params)
    except ValidationError as exc:
        loc = tuple(exc.errors(include_url=False)[0]["loc"])
        if only is not None and loc and loc[0] not in only:
            keypath = fallback
        fake = LoadedYaml(data=None, path=lx.source.path, text="", lines=lx.source.lines)
        raise format_validation_error(exc, fake, root=keypath) from None
