"""From a declared experiment to its conditions, each with a safe Schedule.

A *condition* is one combination of factor levels (full factorial, in the
order the factors and levels are declared). Compiling a condition renders its
stimulus, runs the encoding pipeline, codes the Pattern into a Schedule for
the experiment's device, and checks that Schedule against the device's
safety limits, so an unsafe declaration is refused before any session.
:func:`compile_stimulus` is that path for one stimulus; ``vtexp encode`` takes it too.
"""

from __future__ import annotations

import itertools
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from .adaptive.spec import parameter_value, value_list
from .coding import CODINGS
from .encoding import PIPELINES
from .errors import InputError, UnsafeStimulus
from .experiment import LoadedExperiment, load_experiment
from .model import Condition, DeviceProfile, Pattern, Schedule
from .safety import check_schedule
from .stimuli import read_image, render

# Condition lives in the data model (vtexp.model); code that imports it from here keeps
# working.


def enumerate_conditions(lx: LoadedExperiment) -> list[Condition]:
    """The conditions, without encoding them: ``design.conditions`` in the order listed,
    or else every combination of factor levels (full factorial, in declaration order)."""
    exp = lx.experiment
    names = list(exp.factors)
    stim_factor = exp.stimulus_factor()
    if exp.design.conditions is not None:
        combos = [tuple(c[n] for n in names) for c in exp.design.conditions]
    else:
        combos = list(itertools.product(*(exp.factors[n].level_names for n in names)))
    out = []
    for i, combo in enumerate(combos):
        levels = dict(zip(names, combo, strict=True))
        enc = dict(exp.encoding.params)
        cod = dict(exp.coding.params)
        ada: dict[str, Any] = {}
        for n, lvl in levels.items():
            f = exp.factors[n]
            if f.sets == "coding":
                cod.update(f.params_of(lvl))
            elif f.sets == "encoding":
                enc.update(f.params_of(lvl))
            elif f.sets == "adaptive":
                ada.update(f.params_of(lvl))
        stimulus = levels[stim_factor] if stim_factor else next(iter(exp.stimuli))
        out.append(Condition(i, levels, stimulus, enc, cod,
                             camera=exp.stimuli[stimulus].is_camera, adaptive_params=ada))
    return out


def stimulus_image(lx: LoadedExperiment, name: str, profile: DeviceProfile | None = None,
                   overrides: dict[str, Any] | None = None) -> np.ndarray:
    """Stimulus ``name``'s image; a generator's parameters with ``overrides`` (an adaptive
    level) on top, and the device's grid for a generator that draws on it."""
    spec = lx.experiment.stimuli[name]
    if spec.file is not None:
        try:
            return read_image(lx.resolve(spec.file))
        except InputError as e:
            raise lx.error(e.message + f" ({e.path})", ("stimuli", name, "file")) from None
    profile = profile or DeviceProfile.load(lx.experiment.device)
    return render(spec.generator, {**spec.params, **(overrides or {})}, profile.rows,
                  profile.cols)


def checked_encoding_params(pipeline: str, params: dict[str, Any]) -> dict[str, Any]:
    """``params`` checked against ``pipeline``'s parameter model, with its defaults filled
    in; pydantic's ``ValidationError`` if they do not fit it."""
    return PIPELINES[pipeline][1].model_validate(params).model_dump()


def checked_coding_params(protocol: str, params: dict[str, Any]) -> dict[str, Any]:
    """``params`` checked against coding ``protocol``'s parameter model, with its defaults
    filled in; pydantic's ``ValidationError`` if they do not fit it."""
    return CODINGS[protocol][1].model_validate(params).model_dump()


def compile_stimulus(image: np.ndarray | None, profile: DeviceProfile, *, pipeline: str,
                     encoding_params: dict[str, Any], protocol: str,
                     coding_params: dict[str, Any], pattern: Pattern | None = None,
                     mask: np.ndarray | None = None) -> tuple[Pattern, Schedule | None]:
    """One stimulus on a device: ``image`` (a gray image, from a file, a camera or a
    generator) through the encoding ``pipeline`` into a Pattern (where, in what order),
    the Pattern through the coding ``protocol`` into a Schedule (when, how strong, how
    long), and the Schedule checked against ``profile``'s safety limits.

    Parameters
    ----------
    image
        The stimulus image; not used when ``pattern`` is given.
    profile
        The device: its grid for the encoding, its drive for the coding, its limits.
    pipeline, encoding_params
        A name from :data:`vtexp.encoding.PIPELINES` and its parameters (checked, the
        defaults filled in: :func:`checked_encoding_params`).
    protocol, coding_params
        A name from :data:`vtexp.coding.CODINGS` and its parameters (likewise,
        :func:`checked_coding_params`).
    pattern
        The image's Pattern with these encoding parameters, if it was encoded before
        (conditions that differ only in their coding share it): it is not encoded again.
    mask
        The object in the image (uint8 0/1, the image's size; :mod:`vtexp.encoding.figure`):
        the pipeline encodes it instead of finding the object itself. None: the
        pipeline's own segmentation (right for images on a plain background).

    Returns
    -------
    pattern, schedule
        The Pattern, and its checked Schedule; ``None`` for the Schedule when the
        pipeline finds no shape in the image (an empty Pattern, which is not coded).

    Raises
    ------
    UnsafeStimulus
        The Schedule breaks the device's safety limits.
    pydantic.ValidationError
        Parameters that do not fit the pipeline's or the protocol's model.
    """
    if pattern is None:
        fn = PIPELINES[pipeline][0]
        extra = {} if mask is None else {"mask": mask}
        pattern = fn(image, profile.rows, profile.cols,
                     **checked_encoding_params(pipeline, encoding_params), **extra)
    if not pattern.points:
        return pattern, None
    fn = CODINGS[protocol][0]
    schedule = fn(pattern, profile, **checked_coding_params(protocol, coding_params))
    check_schedule(schedule, profile)
    return pattern, schedule


def encoding_params(lx: LoadedExperiment, params: dict[str, Any]) -> dict[str, Any]:
    """``params`` checked against the experiment's pipeline, with its defaults filled in."""
    return checked_encoding_params(lx.experiment.encoding.pipeline, params)


def encode(lx: LoadedExperiment, image: np.ndarray, profile: DeviceProfile,
           params: dict[str, Any], *, mask: np.ndarray | None = None) -> Pattern:
    """``image`` through the experiment's encoding pipeline with ``params`` (``mask``: the
    object, if told from its background already; :func:`compile_stimulus`)."""
    fn, _ = PIPELINES[lx.experiment.encoding.pipeline]
    extra = {} if mask is None else {"mask": mask}
    return fn(image, profile.rows, profile.cols, **encoding_params(lx, params), **extra)


def code(lx: LoadedExperiment, pattern: Pattern, profile: DeviceProfile,
         params: dict[str, Any]) -> Schedule:
    """``pattern`` through the experiment's coding protocol with ``params`` (no safety check)."""
    fn, _ = CODINGS[lx.experiment.coding.protocol]
    return fn(pattern, profile, **checked_coding_params(lx.experiment.coding.protocol, params))


def compile_conditions(lx: LoadedExperiment, profile: DeviceProfile | None = None
                       ) -> list[Condition]:
    """Encode and code every condition; raise InputError naming an unsafe one."""
    exp = lx.experiment
    profile = profile or DeviceProfile.load(exp.device)
    images: dict[str, np.ndarray] = {}
    patterns: dict[tuple, Pattern] = {}
    conditions = enumerate_conditions(lx)
    _check_session_length(lx, len(conditions))
    for c in conditions:
        if c.camera:
            _check_camera_condition(lx, c, profile)
            continue
        if c.stimulus not in images:
            images[c.stimulus] = stimulus_image(lx, c.stimulus, profile)
        key = (c.stimulus, tuple(sorted(encoding_params(lx, c.encoding_params).items())))
        if exp.adaptive is not None:            # coded at each level, not at these params
            if key not in patterns:
                patterns[key] = encode(lx, images[c.stimulus], profile, c.encoding_params)
            c.pattern = patterns[key]
            if not c.pattern.points:
                raise _empty_pattern(lx, c, profile)
            _compile_levels(lx, c, profile)
            continue
        try:
            c.pattern, c.schedule = compile_stimulus(
                images[c.stimulus], profile, pipeline=exp.encoding.pipeline,
                encoding_params=c.encoding_params, protocol=exp.coding.protocol,
                coding_params=c.coding_params, pattern=patterns.get(key))
        except UnsafeStimulus as e:
            where = _condition_keypath(lx, c)
            raise lx.error(f"condition {c.label}: unsafe stimulus: {e}", where) from None
        patterns[key] = c.pattern
        if c.schedule is None:
            raise _empty_pattern(lx, c, profile)
    return conditions


def _empty_pattern(lx: LoadedExperiment, c: Condition, profile: DeviceProfile) -> InputError:
    return lx.error(f"stimulus {c.stimulus!r} gives an empty pattern on {profile.name} "
                    "(no shape found in the image)", ("stimuli", c.stimulus))


def _compile_levels(lx: LoadedExperiment, c: Condition, profile: DeviceProfile) -> None:
    """Code the condition at every level the adaptive procedure may play, each checked
    against the device's safety limits before the session: a procedure can only
    propose what was checked. ``c.schedule`` is the schedule at the first level."""
    exp = lx.experiment
    spec = exp.adaptive
    c.schedules = {}
    on_stimulus = spec.sets == "stimulus"
    if on_stimulus:
        c.patterns = {}
    for v in value_list(spec.values):
        value = parameter_value(v)
        try:
            if on_stimulus:
                image = stimulus_image(lx, c.stimulus, profile, {spec.variable: value})
                pattern, s = compile_stimulus(
                    image, profile, pipeline=exp.encoding.pipeline,
                    encoding_params=c.encoding_params, protocol=exp.coding.protocol,
                    coding_params=c.coding_params)
                if s is None:
                    raise InputError("the stimulus gives an empty pattern")
                c.patterns[v] = pattern
            else:
                _, s = compile_stimulus(
                    None, profile, pipeline=exp.encoding.pipeline,
                    encoding_params=c.encoding_params, protocol=exp.coding.protocol,
                    coding_params={**c.coding_params, spec.variable: value}, pattern=c.pattern)
        except (UnsafeStimulus, InputError, ValueError) as e:
            raise lx.error(f"condition {c.label} at {spec.variable} = {v:g}: unsafe or "
                           f"impossible on {profile.name}: {getattr(e, 'message', e)}",
                           ("adaptive", "values")) from None
        c.schedules[v] = s
    c.schedule = next(iter(c.schedules.values()))
    if on_stimulus:
        c.pattern = next(iter(c.patterns.values()))


def _check_camera_condition(lx: LoadedExperiment, c: Condition, profile: DeviceProfile) -> None:
    """A camera condition's coding on this device, tried on a one-point pattern (its image
    is taken when the trial runs)."""
    encoding_params(lx, c.encoding_params)
    probe = Pattern(rows=profile.rows, cols=profile.cols,
                    points=[{"row": 0, "col": 0, "line": 1, "order": 0}])
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            check_schedule(code(lx, probe, profile, c.coding_params), profile)
    except (InputError, UnsafeStimulus) as e:
        raise lx.error(f"condition {c.label}: {e}", _condition_keypath(lx, c)) from None


def _condition_keypath(lx: LoadedExperiment, c: Condition) -> tuple:
    for n, lvl in c.levels.items():
        if lx.experiment.factors[n].sets == "coding":
            return ("factors", n, "levels", lvl)
    return ("coding", "params")


#: the most trials one session of a person may plan, and the longest its pauses between
#: trials alone may last: a day's testing, far beyond any study of the papers (hundreds of
#: trials, an hour or two); more is a slip of a key, said before anything runs
MAX_SESSION_TRIALS = 20_000
MAX_SESSION_PAUSES_H = 12.0


def _check_session_length(lx: LoadedExperiment, n_conditions: int) -> None:
    d = lx.experiment.design
    if lx.experiment.adaptive is not None:      # a track's trials are capped by its stop rule
        return
    trials = n_conditions * d.repetitions + d.practice
    if trials > MAX_SESSION_TRIALS:
        raise lx.error(f"{n_conditions} conditions x {d.repetitions} repetitions"
                       + (f" + {d.practice} practice" if d.practice else "")
                       + f" = {trials:,} trials in one session, more than a person can give "
                       f"(at most {MAX_SESSION_TRIALS:,}); spread them over sessions",
                       ("design", "repetitions"))
    hours = trials * d.iti_ms / 3.6e6
    if hours > MAX_SESSION_PAUSES_H:
        raise lx.error(f"{trials:,} trials with iti_ms {d.iti_ms:g} pause {hours:,.1f} hours in "
                       f"one session (at most {MAX_SESSION_PAUSES_H:g}); shorten the pause or "
                       "spread the trials over sessions", ("design", "iti_ms"))


def load_and_compile(path: str | Path, profile: DeviceProfile | None = None
                     ) -> tuple[LoadedExperiment, list[Condition]]:
    """An experiment as a session needs it: loaded and checked
    (:func:`~vtexp.experiment.load_experiment`), then every condition encoded, coded
    and checked against the device's safety limits (:func:`compile_conditions`)."""
    lx = load_experiment(path)
    return lx, compile_conditions(lx, profile)
