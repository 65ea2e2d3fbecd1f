"""The load-time checks of an experiment's ``adaptive:`` section (what the schema needs of
the adaptive procedures; :mod:`.track` is what runs them).

:func:`check_adaptive` runs when the experiment is loaded: the variable is a parameter
of the coding (or, ``sets: stimulus``, of every presented stimulus's generator); every
level is one the device can take (whole milliseconds for a ``*_ms`` parameter, whole
actuator pitches for a ``*_pitches`` one, whole levels from 0 to the profile's
``max_level`` for a level) and valid for the coding or generator; a staircase's start
and every level its steps can reach are among the levels. One message, before the
first trial. (Each level is then coded and checked against the device's safety limits
by :func:`vtexp.compile.compile_conditions`.)
"""

from __future__ import annotations

from collections import Counter

import numpy as np
from pydantic import ValidationError

from ..stimuli import GENERATORS
from .spec import TOL, AdaptiveSpec, StaircaseSpec, parameter_value, procedure_spec, value_list


def device_levels(variable: str, values: list[float], profile) -> str | None:
    """Why a level cannot be played by the device (None if every level can)."""
    if variable.endswith("_ms"):
        off = [v for v in values if abs(v - round(v)) > TOL or v < 0]
        if off:
            return (f"{variable} is played in whole milliseconds (0 or more); {off[0]:g} is not "
                    f"one")
    if variable.endswith("_pitches"):
        off = [v for v in values if abs(v - round(v)) > TOL or v < 0]
        if off:
            return (f"{variable} is a distance on the array in whole actuator pitches (0 or "
                    f"more); {off[0]:g} is not one")
    if variable == "level" or variable.endswith("_level"):
        top = profile.limits.max_level
        off = [v for v in values if abs(v - round(v)) > TOL or not 0 <= v <= top]
        if off:
            return (f"{profile.name} plays whole levels from 0 to {top}; {off[0]:g} is not one")
    return None


def staircase_levels(p: StaircaseSpec, values: list[float]) -> tuple[set[float], str | None]:
    """Every level the staircase can reach from its start; why one is not a level, if so."""
    lo = p.minimum if p.minimum is not None else values[0]
    hi = p.maximum if p.maximum is not None else values[-1]
    known = np.asarray(values)

    def on(v: float) -> bool:
        return bool(np.any(np.abs(known - v) <= TOL * max(1.0, abs(v))))

    for name, v in (("minimum", lo), ("maximum", hi), ("start", p.start)):
        if not on(v):
            return set(), (f"{name} {v:g} is not one of the levels the device can play "
                           f"({_describe(values)})")
    if not lo <= p.start <= hi:
        return set(), f"start {p.start:g} is outside minimum..maximum ({lo:g}..{hi:g})"
    steps = sorted(set(p.steps) | set(p.up()))
    seen, todo = {p.start}, [p.start]
    while todo:
        v = todo.pop()
        for s in steps:
            for w in (v - s, v + s):
                w = round(min(max(w, lo), hi), 9)
                if w in seen:
                    continue
                if not on(w):
                    return seen, (f"a step of {s:g} from {v:g} reaches {w:g}, which is not one "
                                  f"of the levels the device can play ({_describe(values)}); "
                                  "make the start and steps multiples of the levels' step")
                seen.add(w)
                todo.append(w)
                if len(seen) > 100000:
                    return seen, "the steps reach more than 100000 levels"
    return seen, None


def _describe(values: list[float]) -> str:
    if len(values) > 2:
        d = np.diff(values)
        if np.allclose(d, d[0]):
            return f"{values[0]:g} to {values[-1]:g} in steps of {d[0]:g}"
    return ", ".join(f"{v:g}" for v in values[:12]) + (" ..." if len(values) > 12 else "")


def check_adaptive(lx, profile, coding_model) -> None:
    """The load-time checks of the module's docstring; raise ``lx.error`` (an InputError
    naming file, line and key) on the first problem."""
    exp = lx.experiment
    spec: AdaptiveSpec = exp.adaptive
    at = ("adaptive",)
    if spec.sets == "stimulus":
        _check_stimulus_variable(lx, profile)
    else:
        fields = coding_model.model_fields
        if spec.variable not in fields:
            raise lx.error(f"{spec.variable!r} is not a parameter of coding "
                           f"{exp.coding.protocol!r} (its parameters: {', '.join(fields)}; a "
                           "stimulus generator's parameter needs 'sets: stimulus')",
                           at + ("variable",))
        for fname, f in exp.factors.items():
            if f.sets == "coding" and any(spec.variable in f.params_of(lv)
                                          for lv in f.level_names):
                raise lx.error(f"factor {fname!r} sets {spec.variable!r}, which the adaptive "
                               "procedure sets", ("factors", fname))
    values = value_list(spec.values)
    if not values:
        raise lx.error("no levels to play", at + ("values",))
    why = device_levels(spec.variable, values, profile)
    if why:
        raise lx.error(why, at + ("values",))
    if spec.sets == "stimulus":
        _check_stimulus_levels(lx, profile, values)
    else:
        for v in (values[0], values[-1]):
            try:
                coding_model.model_validate({**exp.coding.params, spec.variable: parameter_value(v)})
            except ValidationError as e:
                msg = e.errors(include_url=False)[0]["msg"]
                raise lx.error(f"{spec.variable} = {v:g} is not valid for coding "
                               f"{exp.coding.protocol!r}: {msg}", at + ("values",)) from None
    q = spec.response.question
    asked = {qq.name: qq for qq in exp.asked()}
    if q is not None and q not in asked:
        raise lx.error(f"no question {q!r} (questions: {', '.join(asked)})",
                       at + ("response", "question"))
    question = asked[q] if q is not None else exp.asked()[0]
    if spec.response.yes_answers is None:
        if question.correct is None:
            raise lx.error(f"question {question.name!r} has no correct answer: say which "
                           "answers count as yes (response: {yes_answers: [...]})", at + ("response",))
    else:
        bad = [a for a in spec.response.yes_answers if a not in question.options]
        if bad:
            raise lx.error(f"{bad[0]!r} is not one of the options {question.options}",
                           at + ("response", "yes_answers"))
    if spec.tracks is not None:
        for i, name in enumerate(spec.tracks):
            if name not in exp.factors:
                raise lx.error(f"{name!r} is not a factor (factors: {', '.join(exp.factors)})",
                               at + ("tracks", i))
        loose = [n for n, f in exp.factors.items() if f.sets == "adaptive"
                 and n not in spec.tracks]
        if loose:
            raise lx.error(f"factor {loose[0]!r} sets the procedure's settings, so its levels "
                           "are separate tracks: add it to 'tracks'", at + ("tracks",))
    levels = {n: f for n, f in exp.factors.items() if f.sets == "adaptive"}
    cases = [((), None)] + [(("factors", n, "levels", lv), f.params_of(lv))
                            for n, f in levels.items() for lv in f.level_names]
    for where, overrides in cases:
        try:
            p = procedure_spec(spec, overrides)
        except ValidationError as e:
            err = e.errors(include_url=False)[0]
            raise lx.error(f"{'.'.join(map(str, err['loc']))}: {err['msg']}",
                           where or at + ("procedure",)) from None
        key = where or at + ("procedure",)
        stop = p.stop.trials
        budget = exp.design.repetitions * _conditions_per_track(lx)
        if stop is not None and stop > budget:
            raise lx.error(f"stop.trials {stop} is more than the {budget} trials a track has "
                           f"(design.repetitions x the conditions of a track)",
                           key + (("stop", "trials") if not where else ()))
        if isinstance(p, StaircaseSpec):
            _, why = staircase_levels(p, values)
            if why:
                field = "start" if why.startswith("start") else "steps"
                raise lx.error(f"the staircase's {why}",
                               key + ((field,) if not where or field in (overrides or {})
                                      else ()))


def _adaptive_stimuli(lx) -> list[str]:
    """The stimuli the conditions present (those the adaptive level applies to)."""
    exp = lx.experiment
    f = exp.stimulus_factor()
    if f is None:
        return [next(iter(exp.stimuli))]
    if exp.design.conditions is not None:
        return list(dict.fromkeys(c[f] for c in exp.design.conditions))
    return exp.factors[f].level_names


def _check_stimulus_variable(lx, profile) -> None:
    """``sets: stimulus``: the variable is a parameter of every presented stimulus's
    generator, and no stimulus fixes it."""
    exp = lx.experiment
    var = exp.adaptive.variable
    for name in _adaptive_stimuli(lx):
        st = exp.stimuli[name]
        if st.generator is None:
            raise lx.error(f"stimulus {name!r} is not drawn by a generator, so its "
                           f"{var!r} cannot be set trial by trial", ("adaptive", "sets"))
        fields = GENERATORS[st.generator][1].model_fields
        if var not in fields:
            raise lx.error(f"{var!r} is not a parameter of generator {st.generator!r} "
                           f"(stimulus {name!r}; its parameters: {', '.join(fields)})",
                           ("adaptive", "variable"))
        if var in st.params:
            raise lx.error(f"stimulus {name!r} sets {var!r}, which the adaptive procedure "
                           "sets: remove it here", ("stimuli", name, "params", var))


def _check_stimulus_levels(lx, profile, values: list[float]) -> None:
    """Every level is a valid parameter of each stimulus's generator and, for a generator
    that draws on the array's grid, fits on the device's array."""
    exp = lx.experiment
    var = exp.adaptive.variable
    for name in _adaptive_stimuli(lx):
        st = exp.stimuli[name]
        model = GENERATORS[st.generator][1]
        base = dict(st.params)
        if "array_rows" in model.model_fields:
            base.setdefault("array_rows", profile.rows)
            base.setdefault("array_cols", profile.cols)
        for v in values:
            try:
                p = model.model_validate({**base, var: parameter_value(v)})
            except ValidationError as e:
                msg = e.errors(include_url=False)[0]["msg"]
                raise lx.error(f"{var} = {v:g} is not valid for generator {st.generator!r} "
                               f"(stimulus {name!r}): {msg}", ("adaptive", "values")) from None
            fits = getattr(p, "array_problem", None)
            why = fits(profile.rows, profile.cols) if fits is not None else None
            if why:
                raise lx.error(f"{var} = {v:g} does not fit on {profile.name} (stimulus "
                               f"{name!r}): {why}; keep the values within the array",
                               ("adaptive", "values"))


def _conditions_per_track(lx) -> int:
    exp = lx.experiment
    tracks = exp.adaptive.tracks
    if tracks is None:
        return 1
    n = 1
    for name, f in exp.factors.items():
        if name not in tracks:
            n *= len(f.level_names)
    if exp.design.conditions is not None:       # a declared list: the largest track
        counts = Counter(tuple(c[t] for t in tracks) for c in exp.design.conditions)
        n = max(counts.values())
    return n
