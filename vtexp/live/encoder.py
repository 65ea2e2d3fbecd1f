"""Each live frame through a pipeline and a coding, into one cycle (:class:`Program`).

The three pipelines of the papers, each with the coding that makes sense for a live
camera unless ``--coding`` says otherwise (:data:`LIVE_DEFAULTS`):

============== =========== ===================================================
pipeline       profile     live coding
============== =========== ===================================================
height-contours pad_20x20  ``contour-modes`` static: every contour motor on at its
                           line's level, refreshed as the frame changes (seed 000
                           §3.1's static display); ``display=dynamic`` replays the
                           lines one after another instead
edge-trace     vest_6x8    ``sequential-trace`` at seed 001 Table 1's best pair
                           (300 ms, 200 ms onset to onset), the outline traced again
                           and again, carried on from the same place along the new
                           outline as the frame changes
snake-corners  sma_5x5     ``pulse-trains`` (seed 002 Table 3, corners Table 4),
                           apparent movement along the outline replayed; the snake of
                           each frame starts from the previous frame's
                           (:class:`~vtexp.encoding.snake.SnakeTracker`)
============== =========== ===================================================

Live, the pipelines fit the camera's whole frame onto the array (``fit: frame``) so
that an object moving before the camera moves across the array; ``--param
fit=object`` puts back the studies' fit (the object fills the array wherever it is).
A cycle is one pass (``loops``/``cycles`` 1): it is the live loop that repeats it,
in time (``play="cycle"``; a new frame's cycle goes on from the first place where
it changed, ``follow="change"``, or from the same place, ``follow="place"``), or
holds everything it drives at once (``play="hold"``: a static pattern refreshed,
whatever the coding; :mod:`vtexp.live.program`).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pydantic import ValidationError

from ..coding import CODINGS
from ..coding.pulses import tactile_brush_soa_ms
from ..encoding import PIPELINES
from ..encoding.snake import SnakeTracker
from ..errors import InputError, UnsafeStimulus
from ..model import DeviceProfile, Pattern, Schedule
from .program import FOLLOWS, Program

LIVE_PIPELINES = ("height-contours", "edge-trace", "snake-corners")

LIVE_DEFAULTS: dict[str, dict[str, Any]] = {
    "height-contours": {"profile": "pad_20x20", "coding": "contour-modes",
                        "encoding": {}, "coding_params": {"display": "static"}},
    "edge-trace": {"profile": "vest_6x8", "coding": "sequential-trace",
                   "encoding": {"fit": "frame"},
                   "coding_params": {"duration_ms": 300, "soa_ms": 200}},
    "snake-corners": {"profile": "sma_5x5", "coding": "pulse-trains",
                      "encoding": {"fit": "frame"}, "coding_params": {}},
}

# A coding's own repetition: live, the loop repeats the cycle.
_REPEATS = {"sequential-trace": "loops", "pulse-trains": "loops", "contour-modes": "cycles"}


@dataclass
class LiveSetup:
    """What a live run encodes and codes with, checked (:meth:`make`)."""

    pipeline: str
    profile: DeviceProfile
    coding: str
    encoding_params: dict[str, Any]
    coding_params: dict[str, Any]
    play: str = "cycle"
    follow: str = "change"
    warnings: list[str] = field(default_factory=list)

    @classmethod
    def make(cls, pipeline: str, *, profile: DeviceProfile | str | None = None,
             coding: str | None = None, encoding_params: dict | None = None,
             coding_params: dict | None = None, play: str = "cycle",
             follow: str = "change") -> LiveSetup:
        if pipeline not in LIVE_PIPELINES:
            raise InputError(f"unknown live pipeline {pipeline!r}; available: "
                             f"{', '.join(LIVE_PIPELINES)}", key="--pipeline")
        d = LIVE_DEFAULTS[pipeline]
        prof = profile if isinstance(profile, DeviceProfile) else \
            DeviceProfile.load(profile or d["profile"])
        cod = coding or d["coding"]
        if cod not in CODINGS:
            raise InputError(f"unknown coding {cod!r}; available: {', '.join(sorted(CODINGS))}",
                             key="--coding")
        _, enc_model = PIPELINES[pipeline]
        _, cod_model = CODINGS[cod]
        enc_kw = {**d["encoding"], **(encoding_params or {})}
        cod_kw = {**(d["coding_params"] if cod == d["coding"] else {}), **(coding_params or {})}
        repeat = _REPEATS.get(cod)
        if repeat and cod_kw.get(repeat, 1) != 1:
            raise InputError(f"live, one cycle is coded and the loop plays it again and again; "
                             f"leave out {repeat}", key=f"--coding-param {repeat}")
        if repeat:
            cod_kw[repeat] = 1
        try:
            enc = enc_model(**enc_kw).model_dump()
        except ValidationError as e:
            er = e.errors(include_url=False)[0]
            raise InputError(er["msg"], key=f"--param {'.'.join(map(str, er['loc']))}") from None
        try:
            codp = cod_model(**cod_kw).model_dump()
        except ValidationError as e:
            er = e.errors(include_url=False)[0]
            raise InputError(er["msg"],
                             key=f"--coding-param {'.'.join(map(str, er['loc']))}") from None
        if play not in ("cycle", "hold"):
            raise InputError(f"play must be 'cycle' or 'hold' (got {play!r})", key="--play")
        if follow not in FOLLOWS:
            raise InputError(f"follow must be 'change' or 'place' (got {follow!r})",
                             key="--follow")
        setup = cls(pipeline, prof, cod, enc, codp, play, follow)
        setup._check_coding()
        return setup

    def _check_coding(self) -> None:
        """Code a one-point pattern once: a coding that does not suit the profile fails
        here, before anything plays, and its warnings are said once, not every frame."""
        fn, _ = CODINGS[self.coding]
        probe = Pattern(rows=self.profile.rows, cols=self.profile.cols, pipeline=self.pipeline,
                        points=[{"row": 0, "col": 0, "line": 1, "order": 0}])
        refused = []
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                fn(probe, self.profile, **self.coding_params)
            except UnsafeStimulus as e:         # live, the guard leaves that out (code_frame)
                if e.schedule is None:
                    raise
                refused.append(f"{e}; live, what breaks a limit is left out")
        self.warnings = sorted({str(w.message) for w in caught} | set(refused))


@dataclass
class Encoded:
    """One frame encoded and coded: its cycle (None if nothing was found to feel)."""

    pattern: Pattern
    program: Program | None
    encode_ms: float
    code_ms: float
    #: what was taken for the object (:class:`vtexp.encoding.figure.Figure`), with a
    #: background model; None without one
    figure: object = None


class LiveEncoder:
    """Frame -> Pattern -> Schedule -> :class:`Program`, with what the pipeline carries
    from one frame to the next (the snake)."""

    def __init__(self, setup: LiveSetup, background=None):
        self.setup = setup
        self._encode, _ = PIPELINES[setup.pipeline]
        self._code, _ = CODINGS[setup.coding]
        self.tracker = SnakeTracker(**setup.encoding_params) \
            if setup.pipeline == "snake-corners" else None
        #: tells the object from the scene (``update(frame) -> Figure``,
        #: :class:`vtexp.encoding.figure.BackgroundModel`); None: the pipeline's own threshold
        self.background = background

    def process(self, gray: np.ndarray, *, frame: int = 0, t_capture: float = 0.0) -> Encoded:
        import time

        s = self.setup
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)   # said once (LiveSetup.warnings)
            extra, figure = {}, None
            if self.background is not None:
                figure = self.background.update(gray)
                if figure.empty:        # an empty stage, or still learning: nothing
                    empty = Pattern(rows=s.profile.rows, cols=s.profile.cols,
                                    pipeline=s.pipeline, points=[])
                    return Encoded(empty, None, (time.perf_counter() - t0) * 1000.0, 0.0,
                                   figure)
                extra = {"mask": figure.mask}
            if self.tracker is not None:
                pattern = self.tracker.pattern(gray, s.profile.rows, s.profile.cols, **extra)
            else:
                pattern = self._encode(gray, s.profile.rows, s.profile.cols,
                                       **s.encoding_params, **extra)
            t1 = time.perf_counter()
            if not pattern.points:
                return Encoded(pattern, None, (t1 - t0) * 1000.0, 0.0, figure)
            schedule = code_frame(self._code, pattern, s.profile, s.coding_params)
        t2 = time.perf_counter()
        program = Program.build(schedule, pattern, cycle_ms(s.coding, pattern, schedule),
                                frame=frame, t_capture=t_capture, hold=s.play == "hold")
        return Encoded(pattern, program, (t1 - t0) * 1000.0, (t2 - t1) * 1000.0, figure)


def code_frame(code, pattern: Pattern, profile: DeviceProfile,
               params: dict[str, Any]) -> Schedule:
    """A live frame's Schedule: the coding's, fitted to the profile's limits; where the
    coding refuses what it cannot fit, the schedule as coded, which the live loop's
    :class:`~vtexp.safety.StreamGuard` holds to the limits as it plays (leaving out what
    breaks one, and saying so) rather than stopping the stream."""
    try:
        return code(pattern, profile, **params)
    except UnsafeStimulus as e:
        if e.schedule is None:
            raise
        return e.schedule


def cycle_ms(coding: str, pattern: Pattern, schedule: Schedule) -> float:
    """Length of one cycle of ``schedule``: when the same coding with one more loop would
    start it again (a trace's last point overlaps the next cycle's first)."""
    p = schedule.params
    n = len(pattern.points)
    if coding == "sequential-trace":
        return n * float(p["soa_ms"])
    if coding == "pulse-trains":
        if p.get("soa_ms") is not None:
            return n * float(p["soa_ms"])
        total = 0.0
        for pt in pattern.ordered():
            corner = p["corner_emphasis"] and pt.corner
            total += tactile_brush_soa_ms(p["corner_vibration_ms"] if corner
                                          else p["vibration_ms"])
        return total
    if coding == "contour-modes":
        if p["display"] == "static":
            return float(p["static_ms"])
        return sum(float(interval) for _, interval in p["line_timing_ms"])
    return max(schedule.duration_ms, 1.0)
