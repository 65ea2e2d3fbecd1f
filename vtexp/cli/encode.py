"""``vtexp encode``: one image through a pipeline and a coding, written and drawn."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import yaml

from ..errors import InputError

# The coding each pipeline's paper uses, unless --coding says otherwise.
DEFAULT_CODING = {"height-contours": "contour-modes", "edge-trace": "sequential-trace",
                  "snake-corners": "pulse-trains", "spiral-path": "pulse-trains",
                  "covered-cells": "contour-modes"}


def _params(items: list[str] | None, flag: str) -> dict:
    out = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise InputError(f"expected KEY=VALUE, got {item!r}", key=flag)
        try:
            out[key] = yaml.safe_load(value)
        except yaml.YAMLError:
            out[key] = value
    return out


def load_image(spec: str, rows: int | None = None, cols: int | None = None, *,
               colour: bool = False):
    """IMAGE argument: a file, ``camera[:N]``, or ``GENERATOR:key=value,...`` (a generator
    that draws on the array's grid gets ``rows`` x ``cols``, the device's). ``colour``: a
    file or a camera frame as BGR (a generator's drawing stays gray)."""
    from ..stimuli import GENERATORS, read_camera, read_image, render

    head, sep, rest = spec.partition(":")
    if spec == "camera" or (head == "camera" and rest.isdigit()):
        return read_camera(int(rest or 0), colour=colour)
    if sep and head in GENERATORS and not Path(spec).exists():
        _, model = GENERATORS[head]
        kv = _params([x for x in rest.split(",") if x], "IMAGE")
        from pydantic import ValidationError
        try:
            model(**kv)
        except ValidationError as e:
            err = e.errors(include_url=False)[0]
            raise InputError(f"{'.'.join(map(str, err['loc']))}: {err['msg']}",
                             key=f"IMAGE ({head})") from None
        try:
            return render(head, kv, rows, cols)
        except ValueError as e:
            raise InputError(str(e), key=f"IMAGE ({head})") from None
    return read_image(spec, colour=colour)


def is_generated(spec: str) -> bool:
    """Whether IMAGE is drawn by one of vtexp's generators (a plain background by design)."""
    from ..stimuli import GENERATORS

    head, sep, _ = spec.partition(":")
    return bool(sep) and head in GENERATORS and not Path(spec).exists()


def find_figure(args, image):
    """The object in ``image`` as ``--background`` says (``auto``: a photograph or camera
    frame through the single-still figure-ground, a generator's drawing as it is; ``none``:
    as it is; a file: the empty stage, photographed from the same place). Returns the
    :class:`~vtexp.encoding.figure.Figure`, or None for "as it is" (the pipeline's own
    segmentation)."""
    from ..encoding.figure import figure_from_reference, figure_from_still
    from ..stimuli import read_image

    how = args.background
    if how == "none" or (how == "auto" and is_generated(args.image)):
        return None
    if how == "auto":
        return figure_from_still(image)
    reference = read_image(how, colour=image.ndim == 3)
    return figure_from_reference(image, reference)


def _checked(args, coding: str) -> tuple[dict, dict]:
    """--param and --coding-param, checked here too (compile_stimulus checks them as it
    goes), so that a mistake in either set is named before the slow encoding."""
    from pydantic import ValidationError

    from ..compile import checked_coding_params, checked_encoding_params

    enc = _params(args.param, "--param")
    try:
        checked_encoding_params(args.pipeline, enc)
    except ValidationError as e:
        err = e.errors(include_url=False)[0]
        raise InputError(f"{err['msg']}", key=f"--param {'.'.join(map(str, err['loc']))}") from None
    cod = _params(args.coding_param, "--coding-param")
    try:
        checked_coding_params(coding, cod)
    except ValidationError as e:
        err = e.errors(include_url=False)[0]
        raise InputError(f"{err['msg']}",
                         key=f"--coding-param {'.'.join(map(str, err['loc']))}") from None
    return enc, cod


def cmd_encode(args) -> int:
    from .._cv2 import cv2
    from ..coding import CODINGS
    from ..compile import compile_stimulus
    from ..draw import draw_figure, draw_pattern, write_png
    from ..encoding import PIPELINES
    from ..errors import UnsafeStimulus
    from ..model import DeviceProfile, Pattern

    if args.pipeline not in PIPELINES:
        raise InputError(f"unknown pipeline {args.pipeline!r}; available: "
                         f"{', '.join(sorted(PIPELINES))}", key="--pipeline")
    coding = args.coding or DEFAULT_CODING.get(args.pipeline)
    if coding not in CODINGS:
        raise InputError(f"unknown coding {coding!r}; available: {', '.join(sorted(CODINGS))}",
                         key="--coding")
    profile = DeviceProfile.load(args.device)
    image = load_image(args.image, profile.rows, profile.cols,
                       colour=args.background != "none")
    gray = image if image.ndim == 2 else cv2().cvtColor(image, cv2().COLOR_BGR2GRAY)
    enc, cod = _checked(args, coding)
    figure = find_figure(args, image)
    if figure is not None and figure.empty:
        # nothing plays: the experimenter sees why, and what vtexp looked at
        if args.png:
            write_png(draw_figure(image, None, draw_pattern(Pattern(
                rows=profile.rows, cols=profile.cols, points=[], pipeline=args.pipeline),
                title=f"{args.pipeline} on {profile.name}"), caption="no object"), args.png)
            print(f"  written: {args.png}")
        raise InputError(f"nothing to play: {figure.reason}", path=args.image)
    try:
        pattern, schedule = compile_stimulus(gray, profile, pipeline=args.pipeline,
                                             encoding_params=enc, protocol=coding,
                                             coding_params=cod,
                                             mask=None if figure is None else figure.mask)
    except UnsafeStimulus as e:
        raise InputError(f"unsafe stimulus: {e}", key="--coding-param") from None
    _report(args, coding, profile, image, figure, pattern, schedule)
    return 0


def _report(args, coding, profile, image, figure, pattern, schedule) -> None:
    """What ``vtexp encode`` found, said and written (--json, --png, --gif)."""
    from ..draw import draw_figure, draw_pattern, schedule_frames, write_gif, write_png

    if schedule is None:
        print(f"vtexp: warning: no shape found in {args.image}; the pattern is empty",
              file=sys.stderr)
    lines = pattern.lines()
    print(f"{args.image}: {image.shape[1]}x{image.shape[0]} -> {args.pipeline} on "
          f"{profile.name} ({profile.rows}x{profile.cols}): {len(pattern.points)} points on "
          f"{len(lines)} line(s), {len(pattern.closed)} closed, "
          f"{sum(p.vertex for p in pattern.points)} vertices, "
          f"{sum(p.corner for p in pattern.points)} corners")
    if figure is not None:
        print(f"  object: {figure.method} figure-ground, {int(figure.mask.sum())} pixels, "
              f"confidence {figure.confidence:.2f}")
        from ..live.trial import touches_edge
        if touches_edge(figure.mask):
            print(f"vtexp: warning: {args.image}: the object runs off the edge of the picture; "
                  "only the part in view is encoded", file=sys.stderr)
    if schedule is not None:
        print(f"  {coding}: {len(schedule.pulses)} pulses over {schedule.duration_ms:.0f} ms, "
              f"within {profile.name}'s safety limits")
    if args.json:
        Path(args.json).write_text(json.dumps({
            "image": args.image, "device": profile.name, "pipeline": args.pipeline,
            "coding": coding, "pattern": pattern.model_dump(mode="json"),
            "schedule": schedule.model_dump(mode="json") if schedule else None}, indent=2))
        print(f"  written: {args.json}")
    if args.png:
        drawing = draw_pattern(pattern, title=f"{args.pipeline} on {profile.name}")
        if figure is not None:        # beside the image, with the object's outline found
            drawing = draw_figure(image, figure.mask, drawing,
                                  caption=f"object: confidence {figure.confidence:.2f}")
        write_png(drawing, args.png)
        print(f"  written: {args.png}")
    if args.gif:
        if schedule is None:
            print("vtexp: warning: no schedule to animate; GIF not written", file=sys.stderr)
        else:
            write_gif(schedule_frames(schedule, profile, step_ms=args.gif_step_ms), args.gif,
                      frame_ms=args.gif_step_ms)
            print(f"  written: {args.gif}")


def register(sub) -> None:
    s = sub.add_parser("encode", help="turn one image into a pattern and a schedule, and draw them")
    s.add_argument("image", metavar="IMAGE",
                   help="image file, 'camera[:N]', or GENERATOR:key=value,... "
                        "(e.g. surface:surface=ball, shape:shape=square)")
    s.add_argument("--pipeline", required=True,
                   help="height-contours | edge-trace | snake-corners | spiral-path | "
                        "covered-cells")
    s.add_argument("--device", required=True, help="device profile name or YAML path")
    s.add_argument("--coding", help="coding protocol (default: the pipeline's paper's)")
    s.add_argument("--param", action="append", metavar="KEY=VALUE",
                   help="pipeline parameter (repeatable)")
    s.add_argument("--coding-param", action="append", metavar="KEY=VALUE",
                   help="coding parameter (repeatable)")
    s.add_argument("--json", metavar="OUT", help="write pattern and schedule as JSON")
    s.add_argument("--background", default="auto", metavar="auto|none|FILE",
                   help="how the object is told from its background: auto (default: a "
                        "photograph or camera frame through figure-ground separation, a "
                        "generator's drawing as it is), none (the pipeline's own "
                        "threshold, for a plain background), or FILE, a photograph of the "
                        "empty stage from the same place")
    s.add_argument("--png", metavar="OUT",
                   help="draw the pattern (and the image with the object's outline found)")
    s.add_argument("--gif", metavar="OUT", help="animate the schedule")
    s.add_argument("--gif-step-ms", type=float, default=50.0, help="time per GIF frame")
    s.set_defaults(func=cmd_encode)
