"""``vtexp live``: a camera (or a video standing in for one) felt at camera rate;
``vtexp live-replay``: a recorded live run played again."""

from __future__ import annotations

import argparse
import sys

from ..errors import InputError
from ._io import err, out
from .encode import _params


def _size(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    w, _, h = text.lower().partition("x")
    if not (w.isdigit() and h.isdigit() and int(w) >= 16 and int(h) >= 16):
        raise InputError(f"{text!r} is not WIDTHxHEIGHT in pixels (e.g. 640x480)",
                         key="--frame-size")
    return int(w), int(h)


def summary_lines(stats, setup) -> list[str]:
    s = stats.summary()
    lat = s["latency_ms"]
    proc = s["process_ms"]
    lines = [
        f"live: {s['frames_processed']} frames in {s['elapsed_s']:.1f} s = {s['fps']:.1f} fps; "
        f"captured {s['frames_captured']}, dropped {s['frames_dropped']}; "
        f"{s['frames_unchanged']} changed nothing"
        + (f"; {s['changes_left_out']} changes left out by the safety guard (power "
           f"budget)" if s["changes_left_out"] else "")
        + (f"; {s['changes_in_place']} already so on the array" if s["changes_in_place"]
           else ""),
        f"  glass-to-skin latency over {lat['n']} changes: p50 {lat['p50']:.1f} ms, "
        f"p95 {lat['p95']:.1f} ms, p99 {lat['p99']:.1f} ms" if lat["n"] else
        "  glass-to-skin latency: no change was felt",
        f"  processing per frame: p50 {proc['p50']:.1f} ms, p95 {proc['p95']:.1f} ms"
        if proc["p50"] is not None else "  no frame was processed",
        f"  {s['outputs_sent']} frames of outputs sent, {s['changes_sent']} output changes",
    ]
    if s["degradations"]:
        lines.append("  safety held the limits of " + setup.profile.name + ": " + ", ".join(
            f"{k} x{v}" for k, v in sorted(s["degradations"].items())))
    lines.append(f"  ended: {s['end']}; every actuator is off")
    return lines


def _background(args, source):
    """The scene model ``--background`` asks for (None: the pipeline's own threshold)."""
    from ..encoding.figure import BackgroundModel

    how = args.background
    if how == "none":
        return None
    if how == "auto":
        out(f"live: learning the background from the first {LEARN_FRAMES} frames: keep the "
            "stage empty until the object is asked for")
        return BackgroundModel(learn_frames=LEARN_FRAMES)
    if how == "capture":
        from ..live.trial import capture_empty_stage
        from .prompts import place_object

        reference = capture_empty_stage(source, place_object if sys.stdin.isatty() else None,
                                        stall_s=args.stall_s)
        return BackgroundModel.from_reference(reference)
    from ..stimuli import read_image

    return _StageFromFile(how, read_image(how))


class _StageFromFile:
    """``--background FILE``: the photograph of the empty stage, which must be of the
    camera's frames' size (a model learned from it would otherwise learn again from the
    first frame, the object and all)."""

    def __init__(self, path: str, image):
        from ..encoding.figure import BackgroundModel

        self.path, self.shape = path, image.shape[:2]
        self.model = BackgroundModel.from_reference(image)

    def update(self, frame):
        if frame.shape[:2] != self.shape:
            raise InputError(f"the empty stage is {self.shape[1]}x{self.shape[0]} pixels, the "
                             f"frames {frame.shape[1]}x{frame.shape[0]}: photograph it with "
                             "the same camera (or use --background capture)", path=self.path)
        return self.model.update(frame)


#: Frames ``--background auto`` learns the empty stage from (a second at 30 fps).
LEARN_FRAMES = 30


def cmd_live(args) -> int:
    from ..devices import open_device
    from ..live import LiveSetup, open_source, run_live

    setup = LiveSetup.make(args.pipeline, profile=args.profile, coding=args.coding,
                           encoding_params=_params(args.param, "--param"),
                           coding_params=_params(args.coding_param, "--coding-param"),
                           play=args.play, follow=args.follow)
    if args.duration is not None and args.duration <= 0:
        raise InputError("must be a number of seconds above 0", key="--duration")
    source = open_source(args.source, pace=not args.no_pace, fps=args.fps,
                         frame_size=_size(args.frame_size), pixel_format=args.pixel_format,
                         stall_s=args.stall_s)
    source.open()              # no camera, an unreadable video: said before anything else
    background = _background(args, source)
    device = open_device(args.device, setup.profile)
    how = setup.play if setup.play == "hold" else f"{setup.play}, follow {setup.follow}"
    out(f"live: {source.label} -> {setup.pipeline} -> {setup.coding} ({how}) on "
        f"{setup.profile.name} via {args.device}"
        + (f"; recording to {args.record}" if args.record else "")
        + ("; Escape in the preview or Ctrl-C stops" if args.preview else "; Ctrl-C stops"))
    for w in setup.warnings:
        print(f"vtexp: warning: {w}", file=sys.stderr, flush=True)
    try:
        result = run_live(source, setup, device, preview=args.preview, record=args.record,
                          duration_s=args.duration, stall_s=args.stall_s,
                          command=["vtexp", *sys.argv[1:]],
                          preview_options={"fullscreen": False},
                          screenshot=args.screenshot, background=background)
    except KeyboardInterrupt:
        err("interrupted (Ctrl-C); every actuator is off"
            + (f"; the record in {args.record} is complete up to here" if args.record else ""))
        return 130
    finally:
        device.close()
    for line in summary_lines(result.stats, setup):
        out(line)
    if args.record:
        out(f"  record: {args.record} (frames.tsv, outputs.tsv, programs.jsonl, live.json)")
    return 0


def cmd_live_replay(args) -> int:
    from ..devices import open_device
    from ..live.record import load_record
    from ..model import DeviceProfile

    rec = load_record(args.record)
    profile = DeviceProfile.model_validate(rec.meta["profile"])
    states = rec.states()
    if not states:
        raise InputError("the record has no outputs to replay", path=str(args.record))
    if args.speed <= 0:
        raise InputError("must be above 0", key="--speed")
    device = open_device(args.device, profile)
    out(f"replay: {len(states)} frames of outputs from {args.record} "
        f"({rec.meta.get('pipeline')}, {rec.meta.get('source')}) on {profile.name} via "
        f"{args.device}; Ctrl-C stops")
    kinds: dict[str, int] = {}
    state_now: dict = {}
    try:
        with device:
            clock = device.clock
            t0 = clock.now() - states[0][0] / 1000.0 / args.speed
            for t_ms, state in states:
                due = t0 + t_ms / 1000.0 / args.speed
                while (delay := due - clock.now()) > 0:
                    # Check in with the device as a live loop does; the guard may need
                    # frames between the recorded ones (a train to cut, a rest that ends).
                    deadline = device.stream_deadline_s()
                    clock.sleep(min(delay, device.stream_checkin_ms / 2000.0,
                                    deadline if deadline is not None else delay))
                    deadline = device.stream_deadline_s()
                    if deadline is not None and deadline <= 0:
                        device.stream(state_now)
                    elif state_now:
                        device.stream_alive()
                rep = device.stream(state)
                state_now = state
                for d in rep.degradations:
                    kinds[d.kind] = kinds.get(d.kind, 0) + 1
            device.all_off()
    except KeyboardInterrupt:
        err("interrupted (Ctrl-C); every actuator is off")
        return 130
    out("  replayed; every actuator is off"
        + (f"; safety held the limits: {kinds}" if kinds else ""))
    return 0


def register(sub) -> None:
    s = sub.add_parser(
        "live", help="feel a camera (or a video, a folder of images, frames on stdin) live",
        description="Each frame of SOURCE through a pipeline and a coding to the device, "
                    "only the outputs that change sent, frames the loop has no time for "
                    "dropped (never queued), held to the device profile's limits across "
                    "frames.")
    s.add_argument("source", metavar="SOURCE",
                   help="camera:N, a video file, a folder of images, or - (raw frames on "
                        "standard input: --frame-size, --pixel-format)")
    s.add_argument("--pipeline", required=True,
                   help="height-contours | edge-trace | snake-corners")
    s.add_argument("--device", default="sim",
                   help="sim (default), emulator, or serial:PORT")
    s.add_argument("--profile", help="device profile (default: the pipeline's paper's: "
                                     "pad_20x20, vest_6x8, sma_5x5)")
    s.add_argument("--coding", help="coding protocol (default: the pipeline's live coding)")
    s.add_argument("--play", choices=("cycle", "hold"), default="cycle",
                   help="play each frame's cycle in time (a trace, apparent movement), or "
                        "hold everything it drives at once (default: cycle)")
    s.add_argument("--follow", choices=("change", "place"), default="change",
                   help="when a frame changes a cycle played in time: go on from the first "
                        "place ahead where it changed, felt at once (default), or from the "
                        "same place, the change felt when the trace gets there")
    s.add_argument("--param", action="append", metavar="KEY=VALUE",
                   help="pipeline parameter (repeatable), e.g. fit=object")
    s.add_argument("--coding-param", action="append", metavar="KEY=VALUE",
                   help="coding parameter (repeatable), e.g. soa_ms=150")
    s.add_argument("--background", default="none", metavar="none|auto|capture|FILE",
                   help="how the object is told from the scene: none (default: the "
                        "pipeline's own threshold, for a plain background), auto (learn the "
                        "empty stage from the first 30 frames, then hold it), capture (ask "
                        "to clear the stage and capture it first), or FILE, a photograph of "
                        "the empty stage from the camera's place")
    s.add_argument("--preview", action="store_true",
                   help="show the experimenter's preview window (camera, contour, array, "
                        "frame rate, latency); Escape in it stops")
    s.add_argument("--record", metavar="DIR",
                   help="record every frame, cycle and output in a new folder DIR")
    s.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    s.add_argument("--fps", type=float,
                   help="frame rate of a folder of images (default 30) or to override a "
                        "video's")
    s.add_argument("--no-pace", action="store_true",
                   help="video or folder: deliver frames as fast as the loop takes them, "
                        "instead of at their frame rate")
    s.add_argument("--frame-size", metavar="WxH", help="size of the frames on standard input")
    s.add_argument("--pixel-format", default="gray8", choices=("gray8", "bgr24"),
                   help="pixels of the frames on standard input (default gray8)")
    s.add_argument("--stall-s", type=float, default=2.0,
                   help="stop with an error when the source gives no frame for this long "
                        "(the first frame may take 10 s at least)")
    s.add_argument("--screenshot", metavar="PNG", help=argparse.SUPPRESS)
    s.set_defaults(func=cmd_live)

    r = sub.add_parser("live-replay", help="play a recorded live run again on a device")
    r.add_argument("record", metavar="DIR", help="a folder written by vtexp live --record")
    r.add_argument("--device", default="sim", help="sim (default), emulator, or serial:PORT")
    r.add_argument("--speed", type=float, default=1.0, help="time scale (default 1)")
    r.set_defaults(func=cmd_live_replay)
