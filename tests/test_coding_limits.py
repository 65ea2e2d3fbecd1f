"""Every shipped coding within every shipped profile's limits by construction (issue 20).

For each shipped coding on each shipped profile whose drive it suits, with its defaults
and with every shipped experiment's coding parameters on that experiment's device, on
many Patterns (random outlines that wander and come back, every actuator in order, dense
patterns on a few actuators, scattered contour lines, and the Patterns the pipelines make
of real images): the coding returns a Schedule that ``vtexp.safety.check_schedule``
passes, or raises ``UnsafeStimulus`` naming the parameter to change, and the value it
names works. Fitting only takes time away. The papers' pipelines with their papers'
codings refuse no ordinary image.
"""

from __future__ import annotations

import re
import warnings
from collections import defaultdict
from functools import cache

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vtexp.adaptive.spec import parameter_value, value_list
from vtexp.coding import CODINGS
from vtexp.compile import enumerate_conditions
from vtexp.encoding import PIPELINES
from vtexp.errors import InputError, UnsafeStimulus
from vtexp.experiment import load_experiment
from vtexp.model import DeviceProfile, LevelDrive, Pattern, PatternPoint, available_profiles
from vtexp.resources import experiments_dir
from vtexp.safety import check_schedule
from vtexp.stimuli import read_image, render

PROFILES = {name: DeviceProfile.load(name) for name in available_profiles()}

#: The pipelines with the coding and device of their paper's studies: an ordinary image
#: through these is never refused.
PAPERS = [("height-contours", "pad_20x20", "contour-modes"),
          ("edge-trace", "vest_6x8", "sequential-trace"),
          ("snake-corners", "sma_5x5", "pulse-trains"),
          ("spiral-path", "sma_5x5", "pulse-trains")]

#: "KEY [and KEY] to at most|at least VALUE" in a refusal (not "every duration in KEY ...")
FIX = re.compile(r"(?<![a-z_])(?<!in )([a-z_]+(?: and [a-z_]+)*) to at (most|least) "
                 r"(\d+(?:\.\d+)?)")
#: other ways a refusal names what to change
NAMED = re.compile(r"set (?:every duration (?:and interval )?in )?([a-z_]+) ")


def suits(coding: str, profile: DeviceProfile) -> bool:
    return (coding != "pulse-trains") == isinstance(profile.drive, LevelDrive)


@cache
def shipped_params() -> dict[tuple[str, str], list[dict]]:
    """(profile, coding) -> its defaults and every parameter set a shipped experiment codes
    with on that device (an adaptive coding parameter at both ends of its range)."""
    out: dict[tuple[str, str], list[dict]] = defaultdict(lambda: [{}])
    for f in sorted(experiments_dir().glob("*.yaml")):
        lx = load_experiment(f)
        exp = lx.experiment
        for c in enumerate_conditions(lx):
            sets = [c.coding_params]
            ada = exp.adaptive
            if ada is not None and ada.sets != "stimulus":
                vals = value_list(ada.values)
                sets = [{**c.coding_params, ada.variable: parameter_value(v)}
                        for v in (vals[0], vals[-1])]
            key = (exp.device, exp.coding.protocol)
            for p in sets:
                if p not in out[key]:
                    out[key].append(p)
    return dict(out)


def params_for(profile: str, coding: str) -> list[dict]:
    return shipped_params().get((profile, coding), [{}])


def unbound(profile: DeviceProfile) -> DeviceProfile:
    """``profile`` with limits of time and budget nothing reaches (the settings' limits
    kept): what a coding plays when it has nothing to fit."""
    lim = profile.limits.model_copy(update={"max_on_ms": 1e12, "min_off_ms": 0.0,
                                            "max_simultaneous": 1_000_000})
    return profile.model_copy(update={"limits": lim})


def code(coding: str, pattern: Pattern, profile: DeviceProfile, params: dict):
    fn, model = CODINGS[coding]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)      # values not characterised
        return fn(pattern, profile, **model.model_validate(params).model_dump())


def only_shortened(fitted, free) -> bool:
    """Every pulse of ``fitted`` lies where its actuator is on in ``free``, at a setting it
    has there: fitting to the limits took time away and added none."""
    by_actuator = defaultdict(list)
    for q in sorted(free.pulses, key=lambda q: q.onset_ms):
        by_actuator[(q.row, q.col)].append(q)
    return all(covered(q, by_actuator[(q.row, q.col)]) for q in fitted.pulses)


def covered(pulse, mine) -> bool:
    """``pulse`` lies where ``mine`` (its actuator's pulses, by onset) are on, at a setting
    they have."""
    if not any((q.level, q.train) == (pulse.level, pulse.train) for q in mine):
        return False
    t = pulse.onset_ms
    for q in mine:
        if q.onset_ms <= t < q.offset_ms:
            t = max(t, q.offset_ms)
    return t >= pulse.offset_ms - 1e-9


def judge_any_lines(coding: str, pattern: Pattern, profile: DeviceProfile, params: dict
                    ) -> None:
    """:func:`judge`, for any pattern: an experiment's explicit levels, given for another
    number of lines than the pattern has, are refused as an input error instead."""
    try:
        judge(coding, pattern, profile, params)
    except InputError as e:
        assert "'levels' gives" in str(e), e


def judge(coding: str, pattern: Pattern, profile: DeviceProfile, params: dict, *,
          retry: bool = True) -> str | None:
    """Code ``pattern``; a Schedule must pass the safety check and take time only away;
    a refusal must name a parameter of the coding and what to set it to, and that value
    must not be refused for the same parameter again. Returns the refusal or None."""
    model = CODINGS[coding][1]
    try:
        schedule = code(coding, pattern, profile, params)
    except UnsafeStimulus as e:
        msg = str(e)
        assert msg.startswith(f"{coding} on {profile.name}: "), msg
        assert e.schedule is not None and e.schedule.device == profile.name, msg
        named = [k for keys, _, _ in FIX.findall(msg) for k in keys.split(" and ")] \
            + NAMED.findall(msg)
        known = set(model.model_fields)
        if pattern.pipeline in PIPELINES:         # a line too large: fewer motors on it
            known |= set(PIPELINES[pattern.pipeline][1].model_fields)
        assert named or "use the coding sequential-trace" in msg, msg
        assert all(k in known for k in named), msg
        fixes = {k: int(float(v)) if k.endswith("level") else float(v)
                 for keys, _, v in FIX.findall(msg) for k in keys.split(" and ")}
        if retry and fixes:
            again = judge(coding, pattern, profile, {**params, **fixes}, retry=False)
            assert again is None or not any(k in again.split(": set ")[-1]
                                            for k in fixes), (msg, again)
        return msg
    check_schedule(schedule, profile)
    free = code(coding, pattern, unbound(profile), params)
    assert only_shortened(schedule, free), "fitting lengthened"
    return None


# --------------------------------------------------------------------------- patterns

def grid_of(coding: str) -> int:
    """Grid points per pitch: pulse-trains also plays the phantom points between pins."""
    return 2 if coding == "pulse-trains" else 1


@st.composite
def outline(draw, profile: DeviceProfile, coding: str):
    """A walk of 8-neighbour steps (or jumps) that wanders and comes back, ordered, with
    vertices, corners and contour lines drawn at random."""
    g = grid_of(coding)
    rows, cols = (profile.rows - 1) * g, (profile.cols - 1) * g
    r, c = draw(st.integers(0, rows)), draw(st.integers(0, cols))
    steps = draw(st.lists(st.tuples(st.integers(-1, 1), st.integers(-1, 1))
                          | st.tuples(st.integers(-rows, rows), st.integers(-cols, cols)),
                          min_size=0, max_size=120))
    pts = [(r, c)]
    for dr, dc in steps:
        r, c = min(max(r + dr, 0), rows), min(max(c + dc, 0), cols)
        pts.append((r, c))
    n = len(pts)
    top = draw(st.integers(1, 5))                        # contour lines: often just one
    flags = draw(st.lists(st.tuples(st.booleans(), st.integers(1, top)), min_size=n,
                          max_size=n))
    return Pattern(rows=profile.rows, cols=profile.cols, closed=[0] if n > 2 else [],
                   points=[PatternPoint(row=a / g, col=b / g, order=k, vertex=v, corner=v,
                                        line=line)
                           for k, ((a, b), (v, line)) in enumerate(zip(pts, flags))])


@st.composite
def dense(draw, profile: DeviceProfile, coding: str):
    """Many points on a few actuators, in order: the same ones again and again, often
    many times in a row."""
    g = grid_of(coding)
    cells = draw(st.lists(st.tuples(st.integers(0, (profile.rows - 1) * g),
                                    st.integers(0, (profile.cols - 1) * g)),
                          min_size=1, max_size=3))
    runs = draw(st.lists(st.tuples(st.sampled_from(cells), st.integers(1, 40)),
                         min_size=1, max_size=6))
    order = [cell for cell, times in runs for _ in range(times)]
    corner = draw(st.booleans())
    lines = draw(st.integers(1, 3))
    return Pattern(rows=profile.rows, cols=profile.cols,
                   points=[PatternPoint(row=a / g, col=b / g, order=k, corner=corner,
                                        vertex=corner, line=1 + k % lines)
                           for k, (a, b) in enumerate(order)])


def every_actuator(profile: DeviceProfile, coding: str, *, phantom: bool = False) -> Pattern:
    """Every actuator (or, with phantom points, every grid point) in raster order."""
    g = 2 if phantom else 1
    pts = [(r / g, c / g) for r in range((profile.rows - 1) * g + 1)
           for c in range((profile.cols - 1) * g + 1)]
    return Pattern(rows=profile.rows, cols=profile.cols,
                   points=[PatternPoint(row=r, col=c, order=k, line=1 + k % 5)
                           for k, (r, c) in enumerate(pts)])


CASES = [(coding, name) for coding in sorted(CODINGS) for name, prof in PROFILES.items()
         if suits(coding, prof)]


@pytest.mark.parametrize("coding, profile", CASES)
@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_random_patterns_are_played_safely_or_refused_naming_a_parameter(coding, profile,
                                                                         data):
    prof = PROFILES[profile]
    pattern = data.draw(outline(prof, coding) | dense(prof, coding))
    params = data.draw(st.sampled_from(params_for(profile, coding)))
    judge_any_lines(coding, pattern, prof, params)


@pytest.mark.parametrize("coding, profile", CASES)
def test_every_actuator_in_order(coding, profile):
    prof = PROFILES[profile]
    patterns = [every_actuator(prof, coding)]
    if coding == "pulse-trains":
        patterns.append(every_actuator(prof, coding, phantom=True))
    for pattern in patterns:
        for params in params_for(profile, coding):
            judge_any_lines(coding, pattern, prof, params)


def test_a_coding_refuses_a_drive_it_does_not_suit():
    for coding, prof in ((c, p) for c in CODINGS for p in PROFILES.values()
                         if not suits(c, p)):
        pattern = every_actuator(prof, coding)
        with pytest.raises(InputError, match="driven by"):
            code(coding, pattern, prof, {})


# --------------------------------------------------------------------------- real images

@cache
def images() -> dict:
    """Ordinary images: matplotlib's photographs and vtexp's own stimuli (and
    scikit-image's horse silhouette where that is installed)."""
    import matplotlib.cbook as cbook
    import numpy as np

    out = {name: read_image(cbook.get_sample_data(name, asfileobj=False))
           for name in ("grace_hopper.jpg", "Minduka_Present_Blue_Pack.png", "logo2.png")}
    for s in ("triangle", "circle", "square", "rectangle"):
        out[s] = render("shape", {"shape": s})
    for letter in "AEMSW":
        out[letter] = render("letter", {"letter": letter})
    for s in ("ball", "cone", "uneven"):
        out[s] = render("surface", {"surface": s})
    for turns in (2, 4):
        out[f"whirlpool {turns}"] = render("whirlpool", {"turns": turns, "inner": 0.3})
    try:
        from skimage.data import horse
        out["horse"] = (~horse()).astype(np.uint8) * 255
    except ImportError:
        pass
    return out


#: a few of each kind, for every pipeline on every profile
FEW = ("grace_hopper.jpg", "Minduka_Present_Blue_Pack.png", "logo2.png", "circle", "A",
       "ball", "whirlpool 4", "horse")
#: what spiral-path (slow: it traces a drawn line) is given: the photographs and lines
LINES = ("grace_hopper.jpg", "Minduka_Present_Blue_Pack.png", "logo2.png", "S",
         "whirlpool 2", "whirlpool 4")


@cache
def encoded(pipeline: str, profile: str, few: bool = False) -> list[tuple[str, Pattern]]:
    prof = PROFILES[profile]
    out = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)           # "no line found"
        for name, img in images().items():
            if (few and name not in FEW) or (pipeline == "spiral-path" and name not in LINES):
                continue
            pattern = PIPELINES[pipeline][0](img, prof.rows, prof.cols)
            if pattern.points:
                out.append((name, pattern))
    return out


@pytest.mark.parametrize("pipeline, profile, coding", PAPERS)
def test_no_ordinary_image_is_refused(pipeline, profile, coding):
    """The papers' pipelines, codings and devices, with the coding's defaults and every
    shipped experiment's parameters: every image plays (issue 20: the horse and Grace
    Hopper on the SMA panel were refused, a pin on past max_on_ms)."""
    prof = PROFILES[profile]
    played = 0
    for name, pattern in encoded(pipeline, profile):
        for params in params_for(profile, coding):
            refusal = judge(coding, pattern, prof, params)
            assert refusal is None, (name, params, refusal)
            played += 1
    assert played >= 6


def test_every_pipeline_on_every_profile_plays_or_names_a_parameter():
    for pipeline in PIPELINES:
        for profile, prof in PROFILES.items():
            for coding in (c for c in CODINGS if suits(c, prof)):
                for _, pattern in encoded(pipeline, profile, few=True):
                    for params in params_for(profile, coding):
                        judge_any_lines(coding, pattern, prof, params)


def test_grace_hopper_on_the_panel_rests_a_pin_rather_than_refuse():
    """`vtexp encode grace_hopper.jpg --pipeline snake-corners --device sma_5x5` was refused
    (a pin on 1148.5 ms, above max_on_ms 1000). Now that pin rests min_off_ms before a
    point begins on it; unbound, it would still be on past max_on_ms."""
    prof = PROFILES["sma_5x5"]
    pattern = dict(encoded("snake-corners", "sma_5x5"))["grace_hopper.jpg"]
    free = code("pulse-trains", pattern, unbound(prof), {})
    with pytest.raises(UnsafeStimulus, match="above max_on_ms 1000"):
        check_schedule(free.model_copy(update={"device": "sma_5x5"}), prof)
    check_schedule(code("pulse-trains", pattern, prof, {}), prof)


# --------------------------------------------------------------------------- each coding's rule

def one_place(profile: DeviceProfile, n: int, **kw) -> Pattern:
    """``n`` points in order on one actuator (a trace that stays: a short loop played often)."""
    return Pattern(rows=profile.rows, cols=profile.cols,
                   points=[PatternPoint(row=1, col=1, order=k, **kw) for k in range(n)])


def rests(schedule, row: int, col: int) -> list[tuple[float, float]]:
    """(end, next onset) of each pause of one actuator between its activations."""
    mine = sorted((q for q in schedule.pulses if (q.row, q.col) == (row, col)),
                  key=lambda q: q.onset_ms)
    out, end = [], None
    for q in mine:
        if end is not None and q.onset_ms > end + 1e-6:
            out.append((end, q.onset_ms))
        end = q.offset_ms if end is None else max(end, q.offset_ms)
    return out


def test_sequential_trace_rests_a_tactor_that_stays_on_and_names_what_it_cannot_fit():
    vest = PROFILES["vest_6x8"]
    # 20 visits of one tactor, 300 ms each, 200 ms apart: on for 3900 ms unbound. It rests
    # a tenth of max_on_ms (the live loop's rest) just before an onset.
    s = code("sequential-trace", one_place(vest, 20), vest, {})
    check_schedule(s, vest)
    pauses = rests(s, 1, 1)
    assert pauses and all(b - a >= vest.limits.rest_ms for a, b in pauses)
    assert {b for _, b in pauses} <= {k * 200.0 for k in range(20)}      # before an onset
    with pytest.raises(UnsafeStimulus, match=r"level 9 exceeds max_level 2 of vest_6x8: "
                       r"set vertex_level to at most 2"):
        code("sequential-trace", one_place(vest, 2, vertex=True), vest, {"vertex_level": 9})
    with pytest.raises(UnsafeStimulus, match=r"on for 9000.0 ms without a pause.*set "
                       r"duration_ms to at most 2000$"):
        code("sequential-trace", one_place(vest, 1), vest, {"duration_ms": 9000})
    outline = every_actuator(vest, "sequential-trace")
    with pytest.raises(UnsafeStimulus, match=r"30 tactors would be on at once.*above "
                       r"max_simultaneous 12.*set duration_ms to at most 119, or soa_ms to "
                       r"at least 26"):
        code("sequential-trace", outline, vest, {"soa_ms": 10})
    check_schedule(code("sequential-trace", outline, vest, {"soa_ms": 26}), vest)


def test_contour_modes_rests_a_motor_that_stays_on_and_names_what_it_cannot_fit():
    pad, vest = PROFILES["pad_20x20"], PROFILES["vest_6x8"]
    # One line, twenty cycles of 900 ms every 600 ms: on for 12300 ms unbound.
    line = Pattern(rows=20, cols=20, points=[PatternPoint(row=r, col=3, line=1)
                                             for r in range(5)])
    s = code("contour-modes", line, pad, {"cycles": 20, "timing": "fixed"})
    check_schedule(s, pad)
    assert rests(s, 0, 3) and all(b - a >= pad.limits.rest_ms for a, b in rests(s, 0, 3))
    # seed 000's levels 1, 3, 5 are the pad's; the vest has levels 0-2
    three = Pattern(rows=8, cols=6, points=[PatternPoint(row=k, col=k % 6, line=1 + k % 3)
                                            for k in range(6)])
    with pytest.raises(UnsafeStimulus, match=r"level 5 of line 3 exceeds max_level 2 of "
                       r"vest_6x8 \(levels 1, 3, 5 from the lowest line up\): set high_level "
                       r"to at most 2 \(levels 1, 2, 2\), or give levels"):
        code("contour-modes", three, vest, {})
    check_schedule(code("contour-modes", three, vest, {"high_level": 2}), vest)
    with pytest.raises(UnsafeStimulus, match=r"on for 4000.0 ms.*set static_ms to at most 2000"):
        code("contour-modes", three, vest, {"high_level": 2, "display": "static"})
    # more motors on one line than the vest's budget: no contour-modes parameter helps
    block = Pattern(rows=8, cols=6, pipeline="covered-cells", params={"fill_threshold": 0.5},
                    points=[PatternPoint(row=r, col=c, line=1) for r in range(4)
                            for c in range(4)])
    with pytest.raises(UnsafeStimulus, match=r"16 motors would be on at once.*line 1 alone "
                       r"has 16 motors.*use the coding sequential-trace.*set fill_threshold "
                       r"above 0.5"):
        code("contour-modes", block, vest, {"levels": [2], "display": "static", "static_ms": 800})
