"""What the participant feels, measured, on real scenes (issue 20).

Every shipped pipeline is run as its study runs it, on camera-like composites whose true
object is known to the pixel, and what it plays is compared with that object on the
array. This is the figure-ground problem the papers leave out: their objects stand on a
plain dark ground.

Scenes (:func:`make_case`; case ``i`` is drawn from seed ``SEED + i``, so every case can
be made again alone). An object with an exact mask at a random pose (position, size 0.3-0.6
of the frame's height, rotation within +-25 degrees) is pasted on a 640x480 photograph
shipped inside a PyPI package (scikit-image's ``skimage.data``: brick, grass, gravel, coffee,
astronaut, chelsea, rocket, camera; scikit-learn's ``load_sample_images``: china, flower;
read from the installed files only, never downloaded; a missing one is skipped and said)
and, beside it, on a plain dark ground: the same object at the same pose under the same
light. Objects: the four study shapes (``render_shape``), a capital letter
(``render_letter``) and the horse silhouette (``skimage.data.horse``) as flat cards; the
horse also textured with another photograph; and seed 000's shaded surfaces (ball, cone,
vase, uneven; ``render_surface``, mask = pixels the surface covers at least half, as it
renders them). Both scenes then get one draw of degradations: a soft shadow (the mask
offset 8-24 px, blurred, darkening the ground by 30-55 %), uneven light (a linear gain
ramp from 0.70-0.90 to 1.10-1.25 in a random direction), Gaussian blur (sigma 0.6-1.4 px),
sensor noise (sd 2-5 grey levels) and JPEG at quality 70 (``cv2.imencode``). The *empty*
scenes are the same grounds and light with no object and no shadow. The *reference* of a
scene is its empty stage as vtexp captures it before the object comes
(``vtexp.live.trial.capture_empty_stage``, camera trials and ``vtexp live --background
capture``): the mean of ``EMPTY_FRAMES`` (10) frames, rounded to 8 bits, each with the same
light, the exposure changed by up to +-3 %, its own sensor noise and its own JPEG.

Conditions: plain or real ground, each with no figure-ground (``none``: the pipelines as
they are, the baseline) or with the figure of ``vtexp.encoding.figure`` passed to the
pipeline as ``mask=``: ``truth`` (the exact mask itself: the ceiling, which separates what a
pipeline loses after the mask from what the figure-ground method loses; on an empty scene an
all-zero mask, refused), ``reference`` (``figure_from_reference(frame, reference)``) and
``still`` (``figure_from_still(frame)``). A Figure that is ``.empty`` plays nothing and is
counted as refused. If that module is missing, those columns are skipped and this is said.

Pipelines, as the shipped studies run them (:data:`STUDIES`: the experiment's device,
encoding and coding with the levels of one of its conditions; ``compile_stimulus``'s path:
encode, code, safety check): edge-trace on vest_6x8 (seed 001, duration_interval_grid at
300/200 ms), snake-corners on sma_5x5 (seed 002, circle_vs_rectangle with corner emphasis),
height-contours on pad_20x20 (seed 000, six_mode_ball, dynamic / varied / linear: the
paper's best mode).

Measures (:func:`measure`), the true mask projected onto the array by the mapping the
pipeline used for that frame (``Pattern.params["to_array"]`` when present, else the
pipeline's fit-to-object rule with the box it fitted, recorded as it ran):

- IoU. edge-trace: the cells the true mask covers (``cells_covered``'s canvas and
  coverage rule, at the box the pipeline fitted: the bounding box of its own Otsu mask),
  their outline (``boundary``), against the played cells. snake-corners: the true mask's
  outer contour fitted by the pipeline's rule (``phantom_grid.fit_to_array`` with the
  bounding box of the snake's outline) and put on the 9x9 grid of pins and phantom points
  (``grid_path``), against the played grid points. height-contours (a region): the true
  mask at the pipeline's working resolution (``reflectance``'s rule: a working pixel
  belongs to the object if covered at least half), its outline mapped by eq. 11's lattice
  and proportion rule (``map_to_array``, what the pipeline plays as a flat object's one
  line), holes filled; against the played cells with their holes filled.
- Chamfer: symmetric (mean of the two mean nearest distances), in actuator pitches,
  between the played points and the true outline above (for height-contours, the outlines
  of the two regions).
- Shape named (the four study shapes only): the model participant of ``vtexp simulate``
  (:class:`vtexp.observer.model.ObserverModel`, its typical participant, the shipped
  observer parameters) answers a 4-alternative question (circle, square, triangle,
  rectangle; chance 25 %) in an experiment that is the study's with the four shapes as
  stimuli, each drawn at the case's pose on a clean card. Each template goes through the
  same encoding, coding and sim device; the played report is the scene's. ``named`` is
  the share of ``TRIALS`` answers that are right (lapses and noise included), ``nearest``
  the share of cases whose noise-free nearest template (in the model's percept space) is
  the right one. Nothing played counts as wrong.
- fps: 1000 / median milliseconds of encode + code + safety check (+ the figure, when
  one is used) per frame, one thread (``cv2.setNumThreads(1)``, BLAS pools at 1).
- Empty scenes: actuators driven (distinct actuators in the Schedule), median, and the
  share of scenes that drive any.
- Outcomes: played; none (an empty Pattern: the pipeline found nothing); refused (an
  empty Figure); unsafe (the safety check refused the Schedule, as a session would: nothing
  is played). Anything not played scores IoU 0 and is not named; the Chamfer median is over
  the frames played.
- ``own`` (a diagnostic, fit-to-object pipelines): the IoU with the true mask fitted by its
  own bounding box instead of the pipeline's, i.e. against what the array would show had
  the pipeline found the object alone. On a plain ground the two agree; on a real one the
  pipeline's box is mostly the background's.

The baseline is ``none`` on the same scenes in the same run: the ratio columns are
IoU / baseline IoU and fps / baseline fps. Prints a table per pipeline and writes
``bench/results/scenes.json`` with every case's seed and numbers. Needs the ``bench``
extra (scikit-image; scikit-learn adds two grounds).

Usage: python bench/scenes.py [--cases N] [--quick] [--seed SEED] [--figures none,truth,...]
(default 72 cases and every method; ``--quick``: 12, under a minute)
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse
import importlib
import json
import platform
import statistics
import sys
import time
import warnings
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vtexp._cv2 import cv2  # noqa: E402
from vtexp.compile import (  # noqa: E402
    checked_encoding_params,
    compile_stimulus,
    enumerate_conditions,
)
from vtexp.devices.sim import SimDevice  # noqa: E402
from vtexp.encoding import PIPELINES  # noqa: E402
from vtexp.encoding.mapping import ImageToArray  # noqa: E402
from vtexp.errors import UnsafeStimulus  # noqa: E402
from vtexp.experiment import LoadedExperiment, load_experiment  # noqa: E402
from vtexp.live.trial import EMPTY_FRAMES, mean_frame  # noqa: E402
from vtexp.model import DeviceProfile, Pattern, Schedule  # noqa: E402
from vtexp.stimuli import render_letter, render_shape  # noqa: E402
from vtexp.stimuli.surfaces import render_surface, surface_height  # noqa: E402

WIDTH, HEIGHT = 640, 480
SEED = 20_000
SHAPES = ("circle", "square", "triangle", "rectangle")
#: object kinds, taken in turn (case i gets OBJECTS[i % len]): the shapes more often, as
#: only they are named
OBJECTS = ("circle", "square", "triangle", "rectangle", "letter", "horse", "surface",
           "circle", "square", "triangle", "rectangle", "textured horse")
SURFACE_KINDS = ("ball", "cone", "vase", "uneven")
JPEG_QUALITY = 70

# --------------------------------------------------------------------------- grounds

#: real grounds: (package, file inside it); read from the installed package, never fetched
GROUNDS = {
    "brick": ("skimage", "brick.png"), "grass": ("skimage", "grass.png"),
    "gravel": ("skimage", "gravel.png"), "coffee": ("skimage", "coffee.png"),
    "astronaut": ("skimage", "astronaut.png"), "chelsea": ("skimage", "chelsea.png"),
    "rocket": ("skimage", "rocket.jpg"), "camera": ("skimage", "camera.png"),
    "china": ("sklearn", "china.jpg"), "flower": ("sklearn", "flower.jpg"),
}


def _package_file(package: str, name: str) -> Path | None:
    """The file as installed with ``package`` (no download), or None."""
    try:
        if package == "skimage":
            import skimage.data as mod
            folder = Path(mod.__file__).parent
        else:
            import sklearn.datasets as mod
            folder = Path(mod.__file__).parent / "images"
    except ImportError:
        return None
    path = folder / name
    return path if path.is_file() else None


def load_grounds() -> tuple[dict[str, np.ndarray], list[str]]:
    """The real grounds found, as 640x480 BGR (centre crop to 4:3, area resize), and the
    names skipped."""
    cv = cv2()
    found, skipped = {}, []
    for name, (package, file) in GROUNDS.items():
        path = _package_file(package, file)
        img = None if path is None else cv.imread(str(path), cv.IMREAD_COLOR)
        if img is None:
            skipped.append(f"{name} ({package} {file})")
            continue
        found[name] = _fit_frame(img)
    return found, skipped


def _fit_frame(img: np.ndarray) -> np.ndarray:
    cv = cv2()
    h, w = img.shape[:2]
    if w * HEIGHT > h * WIDTH:                       # too wide: crop the sides
        cw = h * WIDTH // HEIGHT
        img = img[:, (w - cw) // 2:(w - cw) // 2 + cw]
    else:
        ch = w * HEIGHT // WIDTH
        img = img[(h - ch) // 2:(h - ch) // 2 + ch]
    interp = cv.INTER_AREA if img.shape[1] > WIDTH else cv.INTER_CUBIC
    return cv.resize(img, (WIDTH, HEIGHT), interpolation=interp)


# --------------------------------------------------------------------------- objects

#: half the diagonal of each object's box, per unit of its size (size = height / frame
#: height): keeps the whole object in the frame at any rotation
REACH = {"circle": 0.5, "square": 0.71, "triangle": 0.62, "rectangle": 0.91, "letter": 0.75,
         "horse": 0.8, "textured horse": 0.8, "surface": 0.5}


@dataclass
class Layer:
    """An object as the camera sees it: colour (BGR float), coverage (0-1) and the exact
    mask (the pixels it covers at least half)."""

    colour: np.ndarray
    alpha: np.ndarray
    truth: np.ndarray


def draw_pose(kind: str, rng: np.random.Generator) -> dict:
    """Where the object stands: size (its height over the frame's), centre (fractions of
    the frame), rotation (degrees), mirrored or not."""
    reach = REACH[kind]
    size = float(rng.uniform(0.3, min(0.6, (0.5 * HEIGHT - 12) / (reach * HEIGHT))))
    r = reach * size * HEIGHT + 8
    return {"size": round(size, 4),
            "center_x": round(float(rng.uniform(r, WIDTH - r)) / WIDTH, 4),
            "center_y": round(float(rng.uniform(r, HEIGHT - r)) / HEIGHT, 4),
            "rotation_deg": round(float(rng.uniform(-25, 25)), 2),
            "mirrored": bool(rng.random() < 0.5)}


def _card(coverage: np.ndarray, rng: np.random.Generator) -> Layer:
    """A flat light card (grey 170-235, slightly tinted) of the given coverage."""
    tone = rng.uniform(170, 235) + rng.uniform(-10, 10, 3)
    alpha = coverage.astype(np.float32)
    return Layer(np.broadcast_to(tone.astype(np.float32), (HEIGHT, WIDTH, 3)), alpha,
                 alpha >= 0.5)


def _horse_coverage(pose: dict) -> np.ndarray:
    from skimage.data import horse

    cv = cv2()
    ink = (~horse()).astype(np.float32)                  # the horse is False in the file
    if pose["mirrored"]:
        ink = ink[:, ::-1].copy()
    ys, xs = np.nonzero(ink)
    ink = ink[ys.min():ys.max() + 1, xs.min():xs.max() + 1]
    s = pose["size"] * HEIGHT / ink.shape[0]
    m = cv.getRotationMatrix2D((ink.shape[1] / 2, ink.shape[0] / 2), -pose["rotation_deg"], s)
    m[:, 2] += (pose["center_x"] * WIDTH - ink.shape[1] / 2,
                pose["center_y"] * HEIGHT - ink.shape[0] / 2)
    return cv.warpAffine(ink, m, (WIDTH, HEIGHT), flags=cv.INTER_LINEAR)


def _surface(kind: str, pose: dict, rng: np.random.Generator) -> Layer:
    """A shaded surface (seed 000's renderer, lit from the viewer), drawn on a canvas just
    larger than it and put at its place; its mask is the renderer's (covered at least
    half, a sharp silhouette)."""
    side = int(np.ceil(pose["size"] * HEIGHT)) + 6
    params = {"surface": kind, "width": side, "height": side, "size": pose["size"] * HEIGHT / side,
              "rotation_deg": pose["rotation_deg"], "background": 0, "albedo": 255,
              "seed": int(rng.integers(1 << 16))}
    shade = render_surface(**params).astype(np.float32) / 255.0
    _, inside = surface_height(_supersample=4, **params)
    cover = inside.reshape(side, 4, side, 4).mean(axis=(1, 3)) >= 0.5
    y0 = int(round(pose["center_y"] * HEIGHT - side / 2))
    x0 = int(round(pose["center_x"] * WIDTH - side / 2))
    truth = np.zeros((HEIGHT, WIDTH), bool)
    lit = np.zeros((HEIGHT, WIDTH), np.float32)
    truth[y0:y0 + side, x0:x0 + side] = cover
    lit[y0:y0 + side, x0:x0 + side] = shade
    albedo = rng.uniform(190, 240) + rng.uniform(-8, 8, 3)
    return Layer(lit[..., None] * albedo.astype(np.float32), truth.astype(np.float32), truth)


def object_layer(kind: str, pose: dict, rng: np.random.Generator,
                 grounds: dict[str, np.ndarray], ground: str) -> tuple[Layer, str]:
    """The object of ``kind`` at ``pose``, and what exactly it is (shape, letter, surface,
    the texture's photograph)."""
    place = {k: pose[k] for k in ("size", "center_x", "center_y", "rotation_deg")}
    flat = {"width": WIDTH, "height": HEIGHT, "background": 0, "foreground": 255, **place}
    if kind in SHAPES:
        return _card(render_shape(shape=kind, **flat) / 255.0, rng), kind
    if kind == "letter":
        letter = "ABCDEFGHIJKLMNOPQRSTUVWXYZ"[int(rng.integers(26))]
        return _card(render_letter(letter=letter, **flat) / 255.0, rng), letter
    if kind == "horse":
        return _card(_horse_coverage(pose), rng), "horse"
    if kind == "textured horse":
        others = sorted(g for g in grounds if g != ground)
        texture = others[int(rng.integers(len(others)))]
        layer = _card(_horse_coverage(pose), rng)
        layer.colour = 0.55 * grounds[texture].astype(np.float32) + 105.0
        return layer, f"horse textured with {texture}"
    surface = SURFACE_KINDS[int(rng.integers(len(SURFACE_KINDS)))]
    return _surface(surface, pose, rng), surface


# --------------------------------------------------------------------------- scenes


def draw_degradation(rng: np.random.Generator) -> dict:
    """One draw of what the camera and the room do to every scene of a case."""
    return {"shadow_dx": round(float(rng.uniform(8, 24) * rng.choice([-1, 1])), 2),
            "shadow_dy": round(float(rng.uniform(8, 24) * rng.choice([-1, 1])), 2),
            "shadow_blur_px": round(float(rng.uniform(5, 12)), 2),
            "shadow_darkness": round(float(rng.uniform(0.30, 0.55)), 3),
            "light_from": round(float(rng.uniform(0.70, 0.90)), 3),
            "light_to": round(float(rng.uniform(1.10, 1.25)), 3),
            "light_angle_deg": round(float(rng.uniform(0, 360)), 1),
            "blur_px": round(float(rng.uniform(0.6, 1.4)), 3),
            "noise_sd": round(float(rng.uniform(2, 5)), 3),
            "exposure": round(float(rng.uniform(0.97, 1.03)), 4),
            "jpeg_quality": JPEG_QUALITY}


def light_field(d: dict) -> np.ndarray:
    """The uneven light: a linear gain ramp across the frame, (H, W, 1)."""
    a = np.deg2rad(d["light_angle_deg"])
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float32)
    t = np.cos(a) * xx + np.sin(a) * yy
    t = (t - t.min()) / (t.max() - t.min())
    return (d["light_from"] + (d["light_to"] - d["light_from"]) * t)[..., None]


def shadow_of(alpha: np.ndarray, d: dict) -> np.ndarray:
    """How much light the ground keeps under the object's soft shadow, (H, W, 1)."""
    cv = cv2()
    m = np.float32([[1, 0, d["shadow_dx"]], [0, 1, d["shadow_dy"]]])
    moved = cv.warpAffine(alpha, m, (WIDTH, HEIGHT), flags=cv.INTER_LINEAR)
    soft = cv.GaussianBlur(moved, (0, 0), d["shadow_blur_px"])
    return (1.0 - d["shadow_darkness"] * soft)[..., None]


def camera(stage: np.ndarray, d: dict, noise_seed: int, gain: float = 1.0) -> np.ndarray:
    """The stage (BGR float, before the light) as the camera gives it: lit, blurred, noisy,
    JPEG-compressed; uint8 BGR."""
    cv = cv2()
    img = stage * light_field(d) * gain
    img = cv.GaussianBlur(img, (0, 0), d["blur_px"])
    img = img + np.random.default_rng(noise_seed).normal(0, d["noise_sd"], img.shape)
    img = np.clip(np.round(img), 0, 255).astype(np.uint8)
    ok, buf = cv.imencode(".jpg", img, [cv.IMWRITE_JPEG_QUALITY, d["jpeg_quality"]])
    return cv.imdecode(buf, cv.IMREAD_COLOR)


def reference(stage: np.ndarray, d: dict, noise_seed: int) -> np.ndarray:
    """The empty stage as vtexp captures it (``capture_empty_stage``): the mean of
    ``EMPTY_FRAMES`` camera frames at the reference's exposure, each with its own noise
    (seeds ``noise_seed``, ``noise_seed + 1``, ...), rounded to uint8 BGR."""
    return mean_frame(camera(stage, d, noise_seed + k, gain=d["exposure"])
                      for k in range(EMPTY_FRAMES))


@dataclass
class Case:
    """One composite: the same object, pose and degradations on a real ground and on a
    plain one; the empty stages; the empty stage as vtexp captured it before the object came."""

    index: int
    seed: int
    ground: str
    kind: str
    what: str
    pose: dict
    degradation: dict
    plain_tone: list
    truth: np.ndarray
    frames: dict            # (ground kind, "object" | "empty" | "reference") -> BGR uint8

    @cached_property
    def contour(self) -> np.ndarray:
        return outer_contour(self.truth)

    def describe(self) -> dict:
        return {"case": self.index, "seed": self.seed, "ground": self.ground,
                "object": self.kind, "what": self.what, "pose": self.pose,
                "degradation": self.degradation, "plain_tone": self.plain_tone,
                "object_share": round(float(self.truth.mean()), 4)}


def make_case(index: int, grounds: dict[str, np.ndarray], seed: int = SEED) -> Case:
    """Case ``index`` of the test set, drawn from ``seed + index`` alone."""
    rng = np.random.default_rng(seed + index)
    names = sorted(grounds)
    ground = names[(index + index // len(OBJECTS)) % len(names)]    # every object on every ground
    kind = OBJECTS[index % len(OBJECTS)]
    pose = draw_pose(kind, rng)
    layer, what = object_layer(kind, pose, rng, grounds, ground)
    d = draw_degradation(rng)
    tone = (rng.uniform(25, 70) + rng.uniform(-5, 5, 3)).astype(np.float32)
    plain = np.broadcast_to(tone, (HEIGHT, WIDTH, 3))
    noise = [int(s) for s in rng.integers(1 << 31, size=3)]
    alpha = layer.alpha[..., None]
    frames = {}
    for name, stage in (("real", grounds[ground].astype(np.float32)), ("plain", plain)):
        shaded = stage * shadow_of(layer.alpha, d)
        frames[name, "object"] = camera(shaded * (1 - alpha) + layer.colour * alpha, d, noise[0])
        frames[name, "empty"] = camera(stage, d, noise[1])
        frames[name, "reference"] = reference(stage, d, noise[2])
    return Case(index, seed + index, ground, kind, what, pose, d,
                [round(float(t), 1) for t in tone], layer.truth, frames)


# --------------------------------------------------------------------------- studies


@dataclass(frozen=True)
class StudySpec:
    """A pipeline as a shipped study runs it: the experiment file and the levels of the
    coding factors of the condition played."""

    pipeline: str
    experiment: str
    levels: dict
    seed: str


STUDIES = (
    StudySpec("edge-trace", "duration_interval_grid.yaml", {"timing": "300/200"}, "001"),
    StudySpec("snake-corners", "circle_vs_rectangle.yaml", {"corners": "emphasised"}, "002"),
    StudySpec("height-contours", "six_mode_ball.yaml",
              {"display": "dynamic", "timing": "varied", "intensity": "linear"}, "000"),
)


@dataclass
class Study:
    spec: StudySpec
    lx: LoadedExperiment
    profile: DeviceProfile
    encoding_params: dict
    protocol: str
    coding_params: dict
    device: SimDevice = field(repr=False, default=None)

    @property
    def label(self) -> str:
        return (f"{self.spec.pipeline} on {self.profile.name} (seed {self.spec.seed}, "
                f"{self.lx.experiment.name}: {', '.join(self.spec.levels.values())})")


def prepare(spec: StudySpec) -> Study:
    """The study's device, its encoding parameters, and the coding of the chosen condition,
    as ``compile_conditions`` takes them from the experiment file."""
    lx = load_experiment(ROOT / "experiments" / spec.experiment)
    exp = lx.experiment
    condition = next(c for c in enumerate_conditions(lx)
                     if all(c.levels.get(k) == v for k, v in spec.levels.items()))
    profile = DeviceProfile.load(exp.device)
    device = SimDevice(profile)
    device.open()
    return Study(spec, lx, profile,
                 checked_encoding_params(exp.encoding.pipeline, condition.encoding_params),
                 exp.coding.protocol, dict(condition.coding_params), device)


# --------------------------------------------------------------------------- playing


class FitRecorder:
    """Records what the fit-to-object rules are given while the pipelines run: the mask
    whose bounding box edge-trace fits (``edge_trace.cells_covered``) and the outline
    snake-corners fits (``phantom_grid.fit_to_array`` as the snake module calls it). The
    two functions are wrapped in their modules' namespaces and the call handed through
    unchanged; the truth is then mapped with the same box (:func:`measure`)."""

    TARGETS = (("vtexp.encoding.edge_trace", "cells_covered", "edge-trace"),
               ("vtexp.encoding.snake", "fit_to_array", "snake-corners"))

    def __init__(self):
        self.seen: dict[str, tuple] = {}
        self._saved: list[tuple] = []

    def __enter__(self) -> FitRecorder:
        for module, name, pipeline in self.TARGETS:
            mod = importlib.import_module(module)
            original = getattr(mod, name)
            self._saved.append((mod, name, original))
            setattr(mod, name, self._wrap(original, pipeline))
        return self

    def _wrap(self, original, pipeline: str):
        def recorded(first, *args, **kwargs):
            self.seen[pipeline] = (first, args, kwargs)
            return original(first, *args, **kwargs)
        return recorded

    def __exit__(self, *exc) -> None:
        for mod, name, original in reversed(self._saved):
            setattr(mod, name, original)
        self._saved.clear()


try:
    from vtexp.encoding.figure import Figure, figure_from_reference, figure_from_still
except ImportError:                       # the figure-ground module is not in this tree yet
    Figure = figure_from_reference = figure_from_still = None

#: ``truth`` passes the exact mask: the ceiling of a pipeline with a figure, which tells
#: what the pipeline loses after the mask from what the figure-ground method loses
METHODS = ("none", "truth", "reference", "still")


def available_methods() -> tuple[str, ...]:
    return METHODS if figure_from_reference is not None else ("none",)


@dataclass
class Played:
    """One frame through a study: what was played, and how long it took."""

    outcome: str                # played | nothing (empty Pattern) | refused (empty Figure) | unsafe
    ms: float
    pattern: Pattern | None = None
    schedule: Schedule | None = None
    fitted: tuple | None = None
    figure: object = None
    reason: str | None = None    # why the safety check refused it

    @property
    def driven(self) -> int:
        """Actuators the Schedule switches on."""
        if self.schedule is None:
            return 0
        return len({(p.row, p.col) for p in self.schedule.pulses})


def play_frame(study: Study, frame: np.ndarray, method: str, reference: np.ndarray,
               recorder: FitRecorder, truth: np.ndarray | None = None) -> Played:
    """``frame`` (BGR) encoded, coded and checked as the study does it, after the figure of
    ``method`` (``none``: the pipeline alone; ``truth``: ``truth``, the exact mask, as a
    Figure of confidence 1, all-zero on an empty scene). Timed from the colour frame to the
    checked Schedule, on this thread."""
    cv = cv2()
    p = study.profile
    recorder.seen.pop(study.spec.pipeline, None)
    t0 = time.perf_counter()
    kw = dict(study.encoding_params)
    figure = None
    if method != "none":
        if method == "truth":
            t = np.zeros(frame.shape[:2], np.uint8) if truth is None else truth
            figure = Figure(np.asarray(t, np.uint8), 1.0, "truth")
        elif method == "reference":
            figure = figure_from_reference(frame, reference)
        else:
            figure = figure_from_still(frame)
        if figure.empty:
            return Played("refused", (time.perf_counter() - t0) * 1e3, figure=figure)
        kw["mask"] = np.asarray(figure.mask, np.uint8)
    gray = cv.cvtColor(frame, cv.COLOR_BGR2GRAY)
    pattern = PIPELINES[study.spec.pipeline][0](gray, p.rows, p.cols, **kw)
    try:
        pattern, schedule = compile_stimulus(
            None, p, pipeline=study.spec.pipeline, encoding_params=study.encoding_params,
            protocol=study.protocol, coding_params=study.coding_params, pattern=pattern)
        outcome = "played" if schedule is not None else "nothing"
    except UnsafeStimulus as e:
        schedule, outcome, reason = None, "unsafe", str(e)
    else:
        reason = None
    ms = (time.perf_counter() - t0) * 1e3
    return Played(outcome, ms, pattern, schedule, recorder.seen.get(study.spec.pipeline),
                  figure, reason)


# --------------------------------------------------------------------------- the truth on the array


def _bbox(mask: np.ndarray) -> tuple[int, int, int, int] | None:
    rows, cols = np.nonzero(mask.any(axis=1))[0], np.nonzero(mask.any(axis=0))[0]
    if rows.size == 0:
        return None
    return int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1


def covered_in_box(truth: np.ndarray, box: tuple[int, int, int, int], rows: int, cols: int,
                   *, fill_threshold: float, margin_cells: float) -> np.ndarray:
    """The cells ``truth`` covers when the image is fitted onto the array by ``box``, exactly
    as ``edge_trace.cells_covered`` fits a mask by its own bounding box: a canvas of
    ``rows x cols`` cells with the box in its middle, area averaging, the fill threshold.
    Parts of ``truth`` outside the box land where they would on that canvas."""
    y0, y1, x0, x1 = box
    bh, bw = y1 - y0, x1 - x0
    px = max(bw / max(cols - 2 * margin_cells, 1e-9), bh / max(rows - 2 * margin_cells, 1e-9))
    ch, cw = max(int(round(rows * px)), bh), max(int(round(cols * px)), bw)
    oy, ox = y0 - (ch - bh) // 2, x0 - (cw - bw) // 2       # image pixel at canvas (0, 0)
    canvas = np.zeros((ch, cw), np.float32)
    ys, xs = max(oy, 0), max(ox, 0)
    ye, xe = min(oy + ch, truth.shape[0]), min(ox + cw, truth.shape[1])
    if ye > ys and xe > xs:
        canvas[ys - oy:ye - oy, xs - ox:xe - ox] = truth[ys:ye, xs:xe]
    cover = cv2().resize(canvas, (cols, rows), interpolation=cv2().INTER_AREA)
    return cover >= fill_threshold


def cells_by_mapping(truth: np.ndarray, to_array, rows: int, cols: int) -> np.ndarray:
    """Share of each cell that ``truth`` covers, the cells placed by an ``ImageToArray``
    (cell (r, c) spans array coordinates r +- 0.5; its edges rounded to whole pixels)."""
    integral = np.pad(truth.astype(np.float64), ((1, 0), (1, 0))).cumsum(0).cumsum(1)
    h, w = truth.shape

    def edges(n, scale, offset, size):
        e = ((np.arange(n + 1) - 0.5 - offset) / scale).round().astype(int)
        return np.clip(e, 0, size)
    r, c = edges(rows, to_array.row_scale, to_array.row0, h), \
        edges(cols, to_array.col_scale, to_array.col0, w)
    s = (integral[np.ix_(r[1:], c[1:])] - integral[np.ix_(r[:-1], c[1:])]
         - integral[np.ix_(r[1:], c[:-1])] + integral[np.ix_(r[:-1], c[:-1])])
    area = np.outer((r[1:] - r[:-1]) / 1.0, c[1:] - c[:-1])
    return s / np.maximum(area, 1)


def outer_contour(truth: np.ndarray) -> np.ndarray:
    """The longest outline of ``truth`` as (row, col): the iso-line at one half between
    pixel centres (marching squares), i.e. on the mask's pixel edges, not on the centres
    of its border pixels half a pixel inside."""
    from skimage.measure import find_contours

    lines = find_contours(np.pad(truth.astype(np.float32), 1), 0.5)
    return max(lines, key=len) - 1.0


def fit_with_box(points: np.ndarray, lo: np.ndarray, hi: np.ndarray, rows: int, cols: int,
                 margin: float) -> np.ndarray:
    """``phantom_grid.fit_to_array`` with the bounding box ``lo``-``hi`` of the outline the
    pipeline fitted instead of ``points``' own."""
    centre = np.array([(rows - 1) / 2.0, (cols - 1) / 2.0])
    span = hi - lo
    avail = np.maximum(np.array([rows - 1, cols - 1], dtype=np.float64) - 2 * margin, 0.0)
    scales = [avail[k] / span[k] for k in (0, 1) if span[k] > 1e-12]
    out = (points - (lo + hi) / 2.0) * (min(scales) if scales else 0.0) + centre
    return np.minimum(np.maximum(out, 0.0), [rows - 1, cols - 1])


def _edge_trace_truth(truth: np.ndarray, played: Played, params: dict) -> np.ndarray:
    """The true outline's cells as edge-trace would draw the true mask with the box it
    fitted (the bounding box of its own mask, or the whole frame with ``fit: frame``)."""
    from vtexp.encoding.edge_trace import boundary

    p = played.pattern
    rows, cols = p.rows, p.cols
    fill, margin = params["fill_threshold"], params["margin_cells"]
    if played.fitted is not None:
        mask, _, kw = played.fitted
        h, w = mask.shape
        blocks = not (h % rows or w % cols or h // rows != w // cols)
        box = (0, h, 0, w) if kw.get("whole") or blocks else _bbox(mask)
        cells = covered_in_box(truth, box, rows, cols, fill_threshold=fill, margin_cells=margin)
    else:
        to = ImageToArray.from_params(p.params)
        if to is None:
            raise RuntimeError("edge-trace fitted no mask and recorded no to_array: this "
                               "bench does not know how the frame was mapped (mode "
                               f"{params['mode']!r}?)")
        cells = cells_by_mapping(truth, to, rows, cols) >= fill
    return np.argwhere(boundary(cells)).astype(np.float64)


def _snake_truth(truth: np.ndarray, played: Played, params: dict,
                 contour: np.ndarray | None = None) -> np.ndarray:
    """The true outer contour put on the grid of pins and phantom points as snake-corners
    puts its outline: fitted by the box of the snake's outline (or ``to_array``)."""
    from vtexp.encoding.phantom_grid import grid_path

    p = played.pattern
    rows, cols = p.rows, p.cols
    contour = outer_contour(truth) if contour is None else contour
    if played.fitted is not None:
        outline = np.asarray(played.fitted[0], np.float64).reshape(-1, 2)
        arr = fit_with_box(contour, outline.min(axis=0), outline.max(axis=0), rows, cols,
                           params["margin"])
    else:
        to = ImageToArray.from_params(p.params)
        if to is None:
            raise RuntimeError("snake-corners fitted no outline and recorded no to_array")
        arr = np.minimum(np.maximum(to.to_array(contour), 0.0), [rows - 1, cols - 1])
    return grid_path(arr, sharp_turns(arr, 0.5 / params["subdivisions"]), rows, cols,
                     closed=True, subdivisions=params["subdivisions"])[0]


def sharp_turns(line: np.ndarray, reach: float, min_turn_deg: float = 50.0) -> np.ndarray:
    """Corners of a closed line: points where it turns by at least ``min_turn_deg`` between
    the chords to the points ``reach`` before and after it along the line, the sharpest of
    each run. ``grid_path`` keeps them, as it keeps the snake's corners (otherwise a
    polygon's apex is dropped as a staircase step)."""
    pts = np.asarray(line, np.float64).reshape(-1, 2)
    n = len(pts)
    if n < 5:
        return np.zeros(n, bool)
    seg = np.hypot(*np.diff(pts, axis=0, append=pts[:1]).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    total = s[-1]
    closed = np.concatenate([pts, pts[:1]])

    def at(t):
        t = np.mod(t, total)
        return np.stack([np.interp(t, s, closed[:, k]) for k in (0, 1)], axis=1)
    a, b = pts - at(s[:-1] - reach), at(s[:-1] + reach) - pts
    cos = (a * b).sum(axis=1) / np.maximum(np.hypot(*a.T) * np.hypot(*b.T), 1e-12)
    turn = np.degrees(np.arccos(np.clip(cos, -1, 1)))
    sharp = turn >= min_turn_deg
    best = turn >= np.maximum(np.roll(turn, 1), np.roll(turn, -1))
    return sharp & best


def _fill(cells: np.ndarray) -> np.ndarray:
    from scipy.ndimage import binary_fill_holes

    return binary_fill_holes(cells)


def _height_truth(truth: np.ndarray, played: Played, params: dict) -> np.ndarray:
    """The true region as height-contours would draw a flat object of the true mask: at its
    working resolution (covered at least half), its outline mapped by eq. 11's lattice and
    proportion rule, holes filled. Refuses if the pipeline's ``to_array`` says it mapped the
    frame otherwise."""
    from vtexp.encoding.height_contours import lattice_shape, map_to_array

    cv = cv2()
    p = played.pattern
    rows, cols = p.rows, p.cols
    m, n = truth.shape
    lr, lc = lattice_shape(m, n, rows, cols)
    k = params["cells_per_motor"]
    f = max(1, min(n // max(lc * k, 1), m // max(lr * k, 1)))
    t = truth[:m - m % f, :n - n % f].astype(np.uint8)
    wh = (t.shape[1] // f, t.shape[0] // f)
    work = cv.resize(t * np.uint8(255), wh, interpolation=cv.INTER_AREA) >= 128 if f > 1 \
        else t.astype(bool)
    r0, c0 = ((rows - lr) // 2, (cols - lc) // 2) if params["align"] == "center" else (0, 0)
    rs, cs = lr / (f * wh[1]), lc / (f * wh[0])
    expected = [[round(rs, 9), round(r0 + 0.5 * rs - 0.5, 9)],
                [round(cs, 9), round(c0 + 0.5 * cs - 0.5, 9)]]
    got = p.params.get("to_array")
    if got is not None and [got["row"], got["col"]] != expected:
        raise RuntimeError(f"height-contours mapped the frame by {got}, this bench by "
                           f"{expected}: update _height_truth")
    eroded = cv.erode(work.astype(np.uint8), np.ones((3, 3), np.uint8),
                      borderType=cv.BORDER_CONSTANT, borderValue=0).astype(bool)
    line = (work & ~eroded).astype(np.int16)
    return _fill(map_to_array(line, 1, rows, cols, proportion=params["proportion"],
                              align=params["align"]) > 0)


def _filled(points: np.ndarray, rows: int, cols: int, step: float) -> np.ndarray:
    """The grid positions (step ``step``) on or inside the closed lines ``points`` draw."""
    grid = np.zeros((int(round((rows - 1) / step)) + 1, int(round((cols - 1) / step)) + 1), bool)
    k = np.round(np.asarray(points).reshape(-1, 2) / step).astype(int)
    grid[k[:, 0], k[:, 1]] = True
    return np.argwhere(_fill(grid)) * step


def played_and_true(study: Study, played: Played, truth: np.ndarray,
                    contour: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The played and the true outline and area on the array, as (n, 2) array coordinates:
    ``played_line``, ``true_line``, ``played_area``, ``true_area`` (module docstring). An
    area is a line's grid positions with the holes filled (on the grid of pins and phantom
    points for snake-corners); for height-contours the areas come first and the lines are
    their outlines. ``contour``: ``truth``'s :func:`outer_contour`, if already known."""
    from vtexp.encoding.edge_trace import boundary

    pipeline, params = study.spec.pipeline, study.encoding_params
    rows, cols = played.pattern.rows, played.pattern.cols
    pts = np.array([[q.row, q.col] for q in played.pattern.points], np.float64)
    if pipeline in ("edge-trace", "snake-corners"):
        if pipeline == "edge-trace":
            true, step = _edge_trace_truth(truth, played, params), 1.0
        else:
            true, step = _snake_truth(truth, played, params, contour), 1.0 / params["subdivisions"]
        return {"played_line": pts, "true_line": true,
                "played_area": _filled(pts, rows, cols, step),
                "true_area": _filled(true, rows, cols, step)}
    if pipeline == "height-contours":
        out = {"played_area": _filled(pts, rows, cols, 1.0),
               "true_area": np.argwhere(_height_truth(truth, played, params)).astype(float)}
        for name in ("played", "true"):
            cells = np.zeros((rows, cols), bool)
            area = out[f"{name}_area"].astype(int)
            cells[area[:, 0], area[:, 1]] = True
            out[f"{name}_line"] = np.argwhere(boundary(cells)).astype(float)
        return out
    raise ValueError(f"no truth projection for pipeline {pipeline!r}")


def iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two sets of array positions (any grid of quarter steps)."""
    ka = {tuple(r) for r in np.round(np.asarray(a).reshape(-1, 2) * 4).astype(int).tolist()}
    kb = {tuple(r) for r in np.round(np.asarray(b).reshape(-1, 2) * 4).astype(int).tolist()}
    union = ka | kb
    return len(ka & kb) / len(union) if union else 1.0


def chamfer(a: np.ndarray, b: np.ndarray) -> float:
    """Symmetric Chamfer distance: the mean of the two mean nearest-point distances, in the
    unit of the coordinates (actuator pitches); infinite if either set is empty."""
    a, b = np.asarray(a).reshape(-1, 2), np.asarray(b).reshape(-1, 2)
    if not len(a) or not len(b):
        return float("inf")
    d = np.hypot(a[:, None, 0] - b[None, :, 0], a[:, None, 1] - b[None, :, 1])
    return float(0.5 * (d.min(axis=1).mean() + d.min(axis=0).mean()))


# --------------------------------------------------------------------------- the model participant

TRIALS = 40          # answers of the model participant per case (its noise and lapses)


def probe_experiment(study: Study, pose: dict) -> LoadedExperiment:
    """The study as a 4-alternative shape identification: its device, encoding, and the
    coding of the condition played, with the four shapes as stimuli drawn at ``pose`` (the
    generator's clean card, light on dark) and the question "which shape?". Its observer
    parameters are the study's."""
    from vtexp.experiment import load_experiment_text

    base = study.lx.source.data
    place = {k: pose[k] for k in ("size", "center_x", "center_y", "rotation_deg")}
    data = {k: base[k] for k in ("title", "description", "instructions", "device")
            if k in base}
    data.update({
        "name": f"{base['name']}_named_in_scenes",
        "stimuli": {s: {"generator": "shape",
                        "params": {"shape": s, "width": WIDTH, "height": HEIGHT, **place}}
                    for s in SHAPES},
        "encoding": {"pipeline": study.spec.pipeline, "params": study.encoding_params},
        "coding": {"protocol": study.protocol, "params": study.coding_params},
        "factors": {"shape": {"sets": "stimulus", "levels": list(SHAPES)}},
        "design": {"repetitions": 1, "order": "sequential", "iti_ms": 1000},
        "question": {"kind": "choice", "prompt": "Which shape did you feel?",
                     "options": list(SHAPES), "correct": "{shape}"},
    })
    if (base.get("observer") or {}).get("params"):
        data["observer"] = {"params": base["observer"]["params"]}
    return load_experiment_text(json.dumps(data), study.lx.path)


class Namer:
    """The model participant of ``vtexp simulate`` naming the shape of one case's scenes
    (module docstring): its typical participant, ``TRIALS`` answers per scene."""

    def __init__(self, study: Study, case: Case):
        from vtexp.observer.model import ObserverModel

        self.lx = probe_experiment(study, case.pose)
        self.model = ObserverModel.for_experiment(self.lx, study.profile)
        self.question = self.lx.experiment.asked()[0]
        self.condition = next(c for c in enumerate_conditions(self.lx)
                              if c.levels["shape"] == case.kind)
        self.who = self.model.participant(case.seed, "typical", typical=True)
        self.uniforms = self.model.uniforms(case.seed, f"case{case.index}", 1, TRIALS)
        self.truth = case.kind

    def name(self, report, key: tuple) -> tuple[float, bool]:
        """(share of answers naming the true shape, whether the nearest template is it)."""
        if report is None or not report.pulses:
            return 0.0, False                       # nothing felt, nothing named
        answers = self.model.answers(self.question, self.condition, report, self.who,
                                     self.uniforms, played_key=key)
        g = self.model.geometry(self.question, self.condition, report, self.who, key)
        nearest = SHAPES[int(np.argmin(g.half))]
        return float(np.mean([a == self.truth for a in answers])), nearest == self.truth


# --------------------------------------------------------------------------- measuring


def mask_refusal(study: Study) -> str | None:
    """Why the study's pipeline does not take ``mask=`` (None: it does), tried on a small
    card."""
    img = np.full((64, 64), 40, np.uint8)
    img[16:48, 16:48] = 200
    p = study.profile
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            PIPELINES[study.spec.pipeline][0](img, p.rows, p.cols, **study.encoding_params,
                                              mask=(img > 100).astype(np.uint8))
    except Exception as e:                      # noqa: BLE001 - any refusal is reported
        return f"{type(e).__name__}: {str(e).splitlines()[0][:120]}"
    return None


def measure(study: Study, case: Case, ground: str, method: str, recorder: FitRecorder,
            namer: Namer | None) -> dict:
    """One scene with the object through one study: the record of the module docstring."""
    frame = case.frames[ground, "object"]
    played = play_frame(study, frame, method, case.frames[ground, "reference"], recorder,
                        case.truth)
    rec = {"pipeline": study.spec.pipeline, "case": case.index, "seed": case.seed,
           "object": case.kind, "ground": ground, "figure": method, "outcome": played.outcome,
           "ms": round(played.ms, 3), "driven": played.driven}
    if played.reason:
        rec["unsafe"] = played.reason
    if played.figure is not None:
        fm = np.asarray(played.figure.mask, bool)
        union = max(int((fm | case.truth).sum()), 1)
        rec["figure_iou"] = round(float((fm & case.truth).sum()) / union, 4)
        rec["figure_method"] = str(getattr(played.figure, "method", ""))
    if played.outcome == "played":
        on = played_and_true(study, played, case.truth, case.contour)
        rec.update(iou_line=iou(on["played_line"], on["true_line"]),
                   iou_area=iou(on["played_area"], on["true_area"]),
                   chamfer=chamfer(on["played_line"], on["true_line"]),
                   points=len(played.pattern.points))
        if played.fitted is not None:           # diagnostic: the truth fitted by its own box
            own = (case.truth if study.spec.pipeline == "edge-trace" else case.contour, (), {})
            on = played_and_true(study, replace(played, fitted=own), case.truth, case.contour)
            key = PRIMARY[study.spec.pipeline]
            rec["iou_own_box"] = iou(on[f"played_{key[4:]}"], on[f"true_{key[4:]}"])
    else:
        rec.update(iou_line=0.0, iou_area=0.0, chamfer=float("inf"), points=0)
        if study.spec.pipeline in ("edge-trace", "snake-corners"):
            rec["iou_own_box"] = 0.0
    if namer is not None:
        report = study.device.play(played.schedule) if played.schedule is not None else None
        rec["named"], rec["nearest"] = namer.name(report, (ground, method))
    return rec


def measure_empty(study: Study, case: Case, ground: str, method: str,
                  recorder: FitRecorder) -> dict:
    """The case's empty stage through one study: what it drives."""
    played = play_frame(study, case.frames[ground, "empty"], method,
                        case.frames[ground, "reference"], recorder)
    return {"pipeline": study.spec.pipeline, "case": case.index, "seed": case.seed,
            "ground": ground, "figure": method, "outcome": played.outcome,
            "ms": round(played.ms, 3), "driven": played.driven}


def measure_case(study: Study, case: Case, methods: list[str], recorder: FitRecorder
                 ) -> tuple[list[dict], list[dict]]:
    """The case's scenes with and without the object through one study, on both grounds,
    by every figure-ground method: (records, empty-scene records)."""
    namer = Namer(study, case) if case.kind in SHAPES else None
    records, empties = [], []
    for ground in ("plain", "real"):
        for method in methods:
            try:
                records.append(measure(study, case, ground, method, recorder, namer))
                empties.append(measure_empty(study, case, ground, method, recorder))
            except Exception as e:
                e.add_note(f"in case {case.index} (seed {case.seed}, {case.what} on {ground} "
                           f"{case.ground}), {study.spec.pipeline}, figure {method}")
                raise
    return records, empties


def run(cases: int, seed: int = SEED, figures: tuple[str, ...] | None = None) -> dict:
    """Every case through every study, plain and real, by every figure-ground method (or
    those of ``figures``; ``none``, the baseline, always)."""
    cv = cv2()
    threads = cv.getNumThreads()
    cv.setNumThreads(1)
    grounds, skipped = load_grounds()
    if not grounds:
        raise SystemExit("no photograph found (" + ", ".join(skipped) + "): install the bench "
                         "extra, pip install -e '.[bench]'")
    studies = [prepare(s) for s in STUDIES]
    methods = {st.spec.pipeline: [m for m in available_methods()
                                  if m == "none" or (mask_refusal(st) is None and (
                                      figures is None or m in figures))]
               for st in studies}
    records, empties, described = [], [], []
    try:
        with FitRecorder() as recorder, warnings.catch_warnings():
            warnings.simplefilter("ignore")      # "no object found": counted, not printed
            for i in range(cases):
                case = make_case(i, grounds, seed)
                described.append(case.describe())
                for st in studies:
                    got, empty = measure_case(st, case, methods[st.spec.pipeline], recorder)
                    records += got
                    empties += empty
                if sys.stderr.isatty():
                    print(f"\rcase {i + 1}/{cases}", end="", file=sys.stderr, flush=True)
        if sys.stderr.isatty():
            print(file=sys.stderr)
    finally:
        cv.setNumThreads(threads)
        for st in studies:
            st.device.close()
    return {"benchmark": "scenes", "cases": cases, "seed": seed, "grounds": sorted(grounds),
            "skipped_grounds": skipped,
            "figure_module": figure_from_reference is not None,
            "mask_refused": {st.spec.pipeline: mask_refusal(st) for st in studies}
            if figure_from_reference is not None else {},
            "studies": [describe_study(st) for st in studies],
            "summary": summarise(records), "empty_summary": summarise_empty(empties),
            "scenes": described, "records": records, "empty_records": empties,
            "machine": machine()}


# --------------------------------------------------------------------------- summary

#: the IoU the issue asks for: against the outline for outline pipelines, the region else
PRIMARY = {"edge-trace": "iou_line", "snake-corners": "iou_line", "height-contours": "iou_area"}


def _groups(records: list[dict]) -> dict[tuple, list[dict]]:
    out: dict[tuple, list[dict]] = {}
    for r in records:
        out.setdefault((r["pipeline"], r["ground"], r["figure"]), []).append(r)
    return out


def _fps(rows: list[dict]) -> float:
    return 1000.0 / statistics.median(r["ms"] for r in rows)


def summarise(records: list[dict]) -> list[dict]:
    """One row per pipeline, ground and figure method; ratios to ``none`` on that ground."""
    groups = _groups(records)
    out = []
    for (pipeline, ground, method), rows in groups.items():
        named = [r for r in rows if "named" in r]
        played = [r for r in rows if r["outcome"] == "played"]
        row = {"pipeline": pipeline, "ground": ground, "figure": method, "cases": len(rows),
               "iou": statistics.fmean(r[PRIMARY[pipeline]] for r in rows),
               "iou_line": statistics.fmean(r["iou_line"] for r in rows),
               "iou_area": statistics.fmean(r["iou_area"] for r in rows),
               "chamfer_median": statistics.median(r["chamfer"] for r in played) if played
               else None,
               "named": statistics.fmean(r["named"] for r in named) if named else None,
               "nearest": statistics.fmean(r["nearest"] for r in named) if named else None,
               "shapes": len(named), "fps": _fps(rows),
               **{o: sum(r["outcome"] == o for r in rows)
                  for o in ("played", "nothing", "refused", "unsafe")}}
        if any("iou_own_box" in r for r in rows):
            row["iou_own_box"] = statistics.fmean(r.get("iou_own_box", 0.0) for r in rows)
        if any("figure_iou" in r for r in rows):
            row["figure_iou"] = statistics.fmean(r.get("figure_iou", 0.0) for r in rows)
        out.append(row)
    base = {(r["pipeline"], r["ground"]): r for r in out if r["figure"] == "none"}
    for r in out:
        b = base[r["pipeline"], r["ground"]]
        r["iou_ratio"] = r["iou"] / b["iou"] if b["iou"] else None
        r["fps_ratio"] = r["fps"] / b["fps"]
    return out


def summarise_empty(records: list[dict]) -> list[dict]:
    """Per pipeline, ground and method: scenes, share driving anything, median actuators."""
    out = []
    for (pipeline, ground, method), rows in _groups(records).items():
        driven = [r["driven"] for r in rows]
        out.append({"pipeline": pipeline, "ground": ground, "figure": method,
                    "scenes": len(rows), "drive_any": sum(d > 0 for d in driven) / len(rows),
                    "driven_median": statistics.median(driven), "driven_max": max(driven),
                    "refused": sum(r["outcome"] == "refused" for r in rows),
                    "unsafe": sum(r["outcome"] == "unsafe" for r in rows), "fps": _fps(rows)})
    return out


def describe_study(st: Study) -> dict:
    return {"pipeline": st.spec.pipeline, "label": st.label, "device": st.profile.name,
            "experiment": st.spec.experiment, "levels": st.spec.levels,
            "encoding_params": st.encoding_params, "protocol": st.protocol,
            "coding_params": st.coding_params}


def machine() -> dict:
    import skimage

    return {"python": platform.python_version(), "platform": platform.platform(),
            "opencv": cv2().__version__, "numpy": np.__version__,
            "scikit-image": skimage.__version__, "threads": 1}


def _num(v, fmt: str, width: int) -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return f"{'-':>{width}s}"
    return f"{format(v, fmt):>{width}s}"


def print_tables(result: dict) -> None:
    """The tables of a result of :func:`run`."""
    for st in result["studies"]:
        rows = [r for r in result["summary"] if r["pipeline"] == st["pipeline"]]
        n = rows[0]["cases"]
        key = "outline" if PRIMARY[st["pipeline"]] == "iou_line" else "area"
        print(f"\n{st['label']}: {n} composites per condition ({rows[0]['shapes']} of the four "
              f"shapes, named); IoU = {key}")
        head = (f"{'ground':7s}{'figure':10s}{'IoU':>6s}{'line':>6s}{'area':>6s}{'own':>6s}"
                f"{'Chamfer':>8s}"
                f"{'named':>7s}{'nearest':>8s}{'played':>7s}{'none':>5s}{'refused':>8s}"
                f"{'unsafe':>7s}{'fps':>7s}{'IoU x':>7s}{'fps x':>7s}{'fig IoU':>8s}")
        print(head)
        print("-" * len(head))
        for r in rows:
            print(f"{r['ground']:7s}{r['figure']:10s}{_num(r['iou'], '.2f', 6)}"
                  f"{_num(r['iou_line'], '.2f', 6)}{_num(r['iou_area'], '.2f', 6)}"
                  f"{_num(r.get('iou_own_box'), '.2f', 6)}{_num(r['chamfer_median'], '.2f', 8)}"
                  f"{_num(None if r['named'] is None else 100 * r['named'], '.0f', 6)}%"
                  f"{_num(None if r['nearest'] is None else 100 * r['nearest'], '.0f', 7)}%"
                  f"{r['played']:7d}{r['nothing']:5d}{r['refused']:8d}{r['unsafe']:7d}"
                  f"{r['fps']:7.0f}{_num(r['iou_ratio'], '.2f', 7)}{r['fps_ratio']:7.2f}"
                  f"{_num(r.get('figure_iou'), '.2f', 8)}")
        print("empty scenes (no object): actuators driven")
        head = (f"{'ground':7s}{'figure':10s}{'scenes':>7s}{'drive any':>10s}{'median':>7s}"
                f"{'max':>5s}{'refused':>8s}{'unsafe':>7s}{'fps':>7s}")
        print(head)
        print("-" * len(head))
        for r in (e for e in result["empty_summary"] if e["pipeline"] == st["pipeline"]):
            print(f"{r['ground']:7s}{r['figure']:10s}{r['scenes']:7d}"
                  f"{100 * r['drive_any']:9.0f}%{r['driven_median']:7.0f}{r['driven_max']:5d}"
                  f"{r['refused']:8d}{r['unsafe']:7d}{r['fps']:7.0f}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=72, help="composites per condition")
    ap.add_argument("--quick", action="store_true", help="12 cases (under a minute)")
    ap.add_argument("--seed", type=int, default=SEED, help="case i is drawn from SEED + i")
    ap.add_argument("--figures", default=",".join(METHODS),
                    help="figure-ground methods measured beside 'none' (comma-separated; "
                         f"default {','.join(METHODS)})")
    args = ap.parse_args(argv)
    figures = tuple(f.strip() for f in args.figures.split(",") if f.strip())
    unknown = sorted(set(figures) - set(METHODS))
    if unknown:
        ap.error(f"unknown figure method(s) {', '.join(unknown)}; known: {', '.join(METHODS)}")
    cases = 12 if args.quick else args.cases
    if figure_from_reference is None:
        print("vtexp.encoding.figure not found: the 'reference' and 'still' columns are "
              "skipped (only today's pipelines, 'none', are measured)")
    result = run(cases, args.seed, figures)
    for pipeline, why in result["mask_refused"].items():
        if why:
            print(f"{pipeline} does not take mask= ({why}): its figure columns are skipped")
    if result["skipped_grounds"]:
        print("grounds not installed, skipped: " + ", ".join(result["skipped_grounds"]))
    print(f"grounds: {', '.join(result['grounds'])}; seeds {args.seed}..{args.seed + cases - 1}")
    print_tables(result)
    out = ROOT / "bench" / "results" / "scenes.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1, default=_jsonable) + "\n", encoding="utf-8")
    print(f"written {out.relative_to(ROOT)}")
    return 0


def _jsonable(v):
    if isinstance(v, (np.integer, np.floating, np.bool_)):
        return v.item()
    raise TypeError(type(v).__name__)


if __name__ == "__main__":
    raise SystemExit(main())
