"""The data objects that flow between the layers.

Each is a pydantic model: plain data, validated on construction, written to
JSON with ``.to_json()`` and read back with ``Cls.from_json(text)``; a
:class:`Condition` is a plain dataclass that compiling fills in.

- :class:`DeviceProfile`: what an array is and what it may safely do.
- :class:`Pattern`: where on the array, in which order (encoding output).
- :class:`Schedule`: timed pulses on physical actuators (coding output).
- :class:`PlayReport`: what a device actually played, with its onsets.
- :class:`Condition`: one combination of an experiment's factor levels, with its
  stimulus, its parameters and, compiled (:mod:`vtexp.compile`), its Pattern and
  Schedule.
- :class:`TrialRecord`: one logged trial.

Positions: ``row`` counts from the top, ``col`` from the left, both from 0,
as seen by the participant (the profile's ``orientation`` says how that maps
onto the body). Times are in milliseconds and carry ``_ms`` in their names.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

from typing_extensions import Self

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from .errors import InputError
from .resources import devices_dir


#: A time of a stimulus's coding (a vibration, an SOA, a pulse width, a display time), in
#: milliseconds: positive and at most a minute, since an element of a tactile stimulus in
#: a human study lasts seconds (10^9 ms passed as "within the device's limits").
Ms = Annotated[float, Field(gt=0, le=60_000)]


class Model(BaseModel):
    """Base: unknown keys are errors; JSON round trip helpers."""

    model_config = ConfigDict(extra="forbid")

    def to_json(self, **kw: Any) -> str:
        return self.model_dump_json(indent=kw.pop("indent", 2), **kw)

    @classmethod
    def from_json(cls, text: str | bytes) -> Self:
        return cls.model_validate_json(text)


# --------------------------------------------------------------------------- device profile

class Orientation(Model):
    """Where row 0 and column 0 are on the body, both stated (seed 001 writes W = 6,
    H = 8 while its camera image is landscape: orientation is not to be guessed)."""

    row_0: Annotated[str, Field(min_length=1)] = Field(
        description="where the first row is, e.g. 'uppermost' or 'farthest from the "
                    "participant'")
    col_0: Annotated[str, Field(min_length=1)] = Field(
        description="where the first column is, e.g. \"at the participant's left\"")
    source: str = Field("", description="where this comes from (paper, section)")


class Geometry(Model):
    """Actuators in ``rows`` x ``cols``; on the wire, actuator ``row * cols + col``."""

    rows: Annotated[int, Field(ge=1, le=256)]
    cols: Annotated[int, Field(ge=1, le=256)]
    pitch_mm: Annotated[float, Field(gt=0)] = Field(description="centre-to-centre distance")
    body_site: Annotated[str, Field(min_length=1)] = Field(
        description="where the array touches the body")
    orientation: Orientation

    @property
    def n_actuators(self) -> int:
        return self.rows * self.cols

    def index(self, row: int, col: int) -> int:
        """The actuator's number on the wire (row-major), ``docs/protocol.md``."""
        return row * self.cols + col


class IntensityLevel(Model):
    level: Annotated[int, Field(ge=0)]
    duty: Annotated[float, Field(ge=0, le=1)] | None = None
    volts: Annotated[float, Field(ge=0)]


class LevelDrive(Model):
    """Vibration motors driven at discrete intensity levels (seed 000 Table 1, seed 001)."""

    kind: Literal["levels"] = "levels"
    carrier_hz: Annotated[float, Field(gt=0)] | None = Field(
        None, description="PWM carrier frequency, if the levels are PWM duty cycles")
    levels: list[IntensityLevel]

    @model_validator(mode="after")
    def _levels_contiguous(self) -> Self:
        got = [lv.level for lv in self.levels]
        if got != list(range(len(got))):
            raise ValueError(f"levels must be listed as 0, 1, 2, ... in order (got {got})")
        return self

    def volts(self, level: int) -> float:
        return self.levels[level].volts


class PulseTrainDrive(Model):
    """Pins driven by trains of short voltage pulses (seed 002, SMA wires)."""

    kind: Literal["pulse_train"] = "pulse_train"
    amplitude_v: Annotated[float, Field(gt=0)]
    frequencies_hz: list[Annotated[float, Field(gt=0)]] = Field(
        description="frequencies the device is characterised for")
    pulse_width_ms: list[Annotated[float, Field(gt=0)]] = Field(
        description="pulse widths the device is characterised for")


Drive = Annotated[LevelDrive | PulseTrainDrive, Field(discriminator="kind")]


class SafetyLimits(Model):
    """Limits that no Schedule may exceed (checked in vtexp.safety)."""

    max_level: Annotated[int, Field(ge=0)] | None = None
    max_amplitude_v: Annotated[float, Field(gt=0)] | None = None
    max_frequency_hz: Annotated[float, Field(gt=0)] | None = None
    max_pulse_width_ms: Annotated[float, Field(gt=0)] | None = None
    max_on_ms: Annotated[float, Field(gt=0)] = Field(
        description="longest continuous on-time of one actuator")
    min_off_ms: Annotated[float, Field(ge=0)] = Field(
        0.0, description="shortest pause between two activations of one actuator")
    max_simultaneous: Annotated[int, Field(ge=1)] = Field(
        description="most actuators on at the same moment (power budget)")

    @property
    def rest_ms(self) -> float:
        """The pause that splits an activation longer than ``max_on_ms``: ``min_off_ms``,
        or, for a profile without a cooling time, a tenth of ``max_on_ms``, so that it is
        a real pause (at most 91 % on). The live loop rests that long after it cuts a train
        (:class:`vtexp.safety.StreamGuard`); the codings split with it (issue 20)."""
        return self.min_off_ms if self.min_off_ms > 0 else 0.1 * self.max_on_ms


class DeviceProfile(Model):
    name: Annotated[str, Field(pattern=r"^[A-Za-z0-9_\-]+$")]
    description: str
    source: str = Field("", description="where the values come from (paper, section, table)")
    actuator: Literal["erm_motor", "coin_tactor", "sma_pin"]
    geometry: Geometry
    drive: Drive
    limits: SafetyLimits

    @model_validator(mode="after")
    def _limits_match_drive(self) -> Self:
        if isinstance(self.drive, LevelDrive):
            top = len(self.drive.levels) - 1
            if self.limits.max_level is None:
                raise ValueError("limits.max_level is required for a 'levels' drive")
            if self.limits.max_level > top:
                raise ValueError(f"limits.max_level {self.limits.max_level} is above the "
                                 f"highest declared level {top}")
        return self

    @property
    def rows(self) -> int:
        return self.geometry.rows

    @property
    def cols(self) -> int:
        return self.geometry.cols

    @classmethod
    def load(cls, name_or_path: str | Path) -> DeviceProfile:
        """Load a profile by name (``protocols/devices/NAME.yaml``) or from a path."""
        # Here: the data model itself needs pydantic alone, not YAML.
        from .yamlio import format_validation_error, load_yaml

        p = Path(name_or_path)
        if p.suffix not in (".yaml", ".yml"):
            p = devices_dir() / f"{name_or_path}.yaml"
            if not p.is_file():
                known = ", ".join(available_profiles()) or "none"
                raise InputError(f"unknown device profile {str(name_or_path)!r}; "
                                 f"known profiles: {known}")
        loaded = load_yaml(p)
        try:
            return cls.model_validate(loaded.data)
        except ValidationError as exc:
            raise format_validation_error(exc, loaded) from None


def available_profiles() -> list[str]:
    d = devices_dir()
    return sorted(p.stem for p in d.glob("*.yaml")) if d.is_dir() else []


# --------------------------------------------------------------------------- pattern

class PatternPoint(Model):
    """One point of a pattern, in actuator coordinates.

    ``row``/``col`` may be fractional: a phantom point half-way between two
    pins sits at ``col = 0.5`` (seed 002, §3.2).
    """

    row: float
    col: float
    line: Annotated[int, Field(ge=0)] = Field(
        0, description="contour line (seed 000) or loop/path index (seed 001/002)")
    order: Annotated[int, Field(ge=0)] | None = Field(
        None, description="position in the activation sequence; None if unordered")
    vertex: bool = False
    corner: bool = False


class Pattern(Model):
    """Where on the array a stimulus is, and in what order (encoding output)."""

    rows: Annotated[int, Field(ge=1)]
    cols: Annotated[int, Field(ge=1)]
    points: list[PatternPoint] = Field(default_factory=list)
    closed: list[int] = Field(default_factory=list, description="indices of closed lines")
    pipeline: str = ""
    params: dict[str, Any] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _inside(self) -> Self:
        for i, p in enumerate(self.points):
            if not (0 <= p.row <= self.rows - 1 and 0 <= p.col <= self.cols - 1):
                raise ValueError(f"point {i} at (row {p.row}, col {p.col}) is outside the "
                                 f"{self.rows}x{self.cols} array")
        return self

    def ordered(self) -> list[PatternPoint]:
        """Points in activation order (unordered points last, by line then position)."""
        return sorted(self.points, key=lambda p: (p.order is None, p.order or 0,
                                                  p.line, p.row, p.col))

    def lines(self) -> list[int]:
        return sorted({p.line for p in self.points})


# --------------------------------------------------------------------------- schedule

class PulseTrain(Model):
    """Drive parameters of an SMA pulse train (seed 002, Tables 2-4)."""

    amplitude_v: Annotated[float, Field(gt=0)]
    frequency_hz: Annotated[float, Field(gt=0)]
    pulse_width_ms: Annotated[float, Field(gt=0)]


class Pulse(Model):
    """One actuator switched on at ``onset_ms`` for ``duration_ms``.

    A vibration motor is driven at an intensity ``level``; an SMA pin by a
    pulse ``train``. Exactly one of the two is given.
    """

    row: Annotated[int, Field(ge=0)]
    col: Annotated[int, Field(ge=0)]
    onset_ms: Annotated[float, Field(ge=0)]
    duration_ms: Annotated[float, Field(gt=0)]
    level: Annotated[int, Field(ge=0)] | None = None
    train: PulseTrain | None = None

    @model_validator(mode="after")
    def _one_drive(self) -> Self:
        if (self.level is None) == (self.train is None):
            raise ValueError("a pulse has either a level or a train, not both or neither")
        return self

    @property
    def offset_ms(self) -> float:
        return self.onset_ms + self.duration_ms


class Schedule(Model):
    """Timed pulses on physical actuators, for one device profile."""

    device: str = Field(description="name of the device profile it was coded for")
    pulses: list[Pulse] = Field(default_factory=list)
    coding: str = ""
    params: dict[str, Any] = Field(default_factory=dict)

    @property
    def duration_ms(self) -> float:
        return max((p.offset_ms for p in self.pulses), default=0.0)

    def sorted(self) -> list[Pulse]:
        return sorted(self.pulses, key=lambda p: (p.onset_ms, p.row, p.col))


class PlayedPulse(Model):
    """A pulse as the device reports having played it."""

    row: int
    col: int
    scheduled_onset_ms: float
    onset_ms: float = Field(description="device-reported onset, from the start of the play")
    duration_ms: float
    level: int | None = None
    train: PulseTrain | None = None


class PlayReport(Model):
    """What a device actually played for one Schedule."""

    device: str
    started_at_ms: float = Field(description="device clock at the start of the play")
    duration_ms: float
    pulses: list[PlayedPulse]
    completed: bool = True
    started_at_host_ms: float | None = Field(
        None, description="the play's start on this computer's time.monotonic clock (ms), "
                          "mapped from the device's clock; None if the device cannot say")
    host_clock_error_ms: float | None = Field(
        None, description="bound on the error of started_at_host_ms (half the round trip "
                          "of the exchange it was mapped from)")


class DeviceInfo(Model):
    backend: str
    profile: str
    rows: int
    cols: int
    firmware: str = ""
    protocol: str = ""
    port: str = ""
    details: dict[str, Any] = Field(default_factory=dict)


# --------------------------------------------------------------------------- condition

@dataclass
class Condition:
    """One combination of factor levels; :func:`vtexp.compile.compile_conditions` fills in
    its pattern and schedule (or a schedule per level an adaptive procedure may play)."""

    index: int                               # 0-based, in declaration order
    levels: dict[str, str]                   # factor -> level
    stimulus: str
    encoding_params: dict[str, Any]
    coding_params: dict[str, Any]
    pattern: Pattern | None = field(default=None, repr=False)
    schedule: Schedule | None = field(default=None, repr=False)
    camera: bool = False                     # the stimulus is taken at each trial
    adaptive_params: dict[str, Any] = field(default_factory=dict)   # sets: adaptive
    #: with an adaptive procedure: the schedule at each level it may play
    schedules: dict[float, Schedule] | None = field(default=None, repr=False)
    #: with an adaptive stimulus parameter: the pattern at each level
    patterns: dict[float, Pattern] | None = field(default=None, repr=False)
    #: generator parameters that override the stimulus's (an adaptive level, at a trial)
    stimulus_params: dict[str, Any] = field(default_factory=dict)

    @property
    def label(self) -> str:
        return ", ".join(f"{k}={v}" for k, v in self.levels.items())


# --------------------------------------------------------------------------- trial record

class TrialRecord(Model):
    """One row of a session's trial log."""

    trial: Annotated[int, Field(ge=1)]
    practice: bool = False
    repetition: Annotated[int, Field(ge=0)] = Field(description="0 for a practice trial")
    block: Annotated[int, Field(ge=0)] = Field(0, description="block number, 0 if not blocked")
    stimulus: str
    stim_file: str | None = Field(
        None, description="camera stimuli: the frame taken, relative to the session folder")
    condition: dict[str, str] = Field(description="factor name -> level label")
    question: str = "response"
    answer: str | None
    correct_answer: str | None = None
    correct: bool | None = None
    rt_s: float | None = Field(None, description="from the end of the stimulus")
    replays: Annotated[int, Field(ge=0)] = 0
    stimulus_onset_ms: float | None = Field(None, description="device clock")
    stimulus_duration_ms: float | None = None
    n_pulses: int = 0
    status: Literal["ok", "skipped", "device_error", "stopped"] = "ok"
    started_at: str = Field(description="wall clock, ISO 8601 with time zone")
