"""Camera trials: a real object in front of the camera is the stimulus (seed 001 §4.1, seed
002 §4: the objects were "presented in front of the camera").

A stimulus ``{camera: N}`` (or ``{video: FILE}``, a video standing in for the camera in
tests) has no image until its trial runs. At each such trial :func:`run_camera_trial`:

1. opens the camera and asks the experimenter, at the terminal, to place the named
   object (``object:``, default the stimulus's name) and press Enter — or, with
   ``delay_s``, takes the frame that long after the trial starts, asking nobody;
2. takes the newest frame, saves it in the session folder as
   ``stim/trial-NNN.png`` (created exclusively; a trial played again after a fault or
   a resume gets ``trial-NNN-2.png``, ...) and returns that path for the trial's
   ``stim_file`` column, so the analysis knows exactly what was felt;
3. encodes and codes the frame with the condition's parameters and plays it like any
   other stimulus (``device.play``: the safety check, the cooling wait, the onsets,
   replays); or, for a ``live: true`` stimulus, plays the camera continuously
   (:class:`~vtexp.live.loop.LiveRun`, recorded in ``stim/trial-NNN-live/``) while the
   participant answers, and stops it, every actuator off, when the answer is given.

The session engine calls it for camera conditions and otherwise runs the trial as
usual (``vtexp.session``); the experimenter's prompt is the command line's
(``vtexp.cli.prompts.place_object``), handed in by the caller.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._cv2 import cv2
from ..compile import Condition, code, encode
from ..errors import InputError, SessionError
from ..model import DeviceProfile, Pattern, Schedule
from .sources import Capture, CameraSource, FrameSource, LatestFrame, SourceEnded, VideoSource

#: Called with the text to show; returns when the experimenter pressed Enter, with what
#: they typed before it (or None).
CapturePrompt = Callable[[str], "str | None"]

#: Frames averaged into a capture of the empty stage (less sensor noise than one).
EMPTY_FRAMES = 10
#: What the experimenter types, at an object's prompt, to capture the empty stage again.
RECAPTURE = "e"


@dataclass
class Captured:
    image: object             # 8-bit gray frame
    stim_file: str            # relative to the session folder
    t_capture: float


def camera_source(lx, stimulus: str) -> tuple[FrameSource, str]:
    """The source of a camera stimulus, and how to name it to the experimenter."""
    spec = lx.experiment.stimuli[stimulus]
    if spec.camera is not None:
        return CameraSource(spec.camera), f"camera {spec.camera}"
    return VideoSource(lx.resolve(spec.video)), "the camera"


def needs_prompt(lx) -> list[str]:
    """Camera stimuli that ask the experimenter (no ``delay_s``)."""
    return [n for n, s in lx.experiment.stimuli.items() if s.is_camera and s.delay_s is None]


def _new_file(folder: Path, stem: str, suffix: str = ".png") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    k = 1
    while True:
        name = f"{stem}{'' if k == 1 else f'-{k}'}"
        p = folder / f"{name}{suffix}"
        if not p.exists() and not (folder / f"{name}-live").exists():
            return p
        k += 1


def capture(lx, trial, session_dir: Path, prompt: CapturePrompt | None,
            source: FrameSource, camera_name: str, *, stall_s: float = 5.0,
            recapture: Callable[[], None] | None = None) -> Captured:
    """Steps 1-2 of the module docstring: the frame, saved. ``source`` stays open.
    ``recapture``: what to call when the experimenter asks to capture the empty stage
    again at the object's prompt (it reads the source itself, so the frames read for the
    prompt stop meanwhile)."""
    spec = lx.experiment.stimuli[trial.stimulus]
    if spec.delay_s is None and prompt is None:
        raise SessionError(f"trial {trial.number}: stimulus {trial.stimulus!r} asks the "
                           "experimenter to place the object, but nobody is at a "
                           "terminal; declare delay_s, or run from a terminal")
    source.open()
    while True:
        box = LatestFrame()
        cap = Capture(source, box)        # reading while the experimenter places it: the
        cap.start()                       # newest frame is there when Enter is pressed
        try:
            if spec.delay_s is not None:
                time.sleep(spec.delay_s)
            else:
                said = prompt(f"Trial {trial.number}: place {spec.object or trial.stimulus} "
                              f"in front of {camera_name}, then press Enter"
                              + (f" ('{RECAPTURE}' and Enter: capture the empty stage again "
                                 "first) " if recapture is not None else " "))
                if recapture is not None and (said or "").strip().lower() == RECAPTURE:
                    cap.stop(close=False)
                    recapture()
                    continue
            frame = _newest(box, source, trial, stall_s)
        finally:
            cap.stop(close=False)
        break
    path = save_frame(session_dir / "stim", f"trial-{trial.number:03d}", frame.image)
    return Captured(frame.image, str(path.relative_to(session_dir)), frame.t_capture)


def _newest(box: LatestFrame, source: FrameSource, trial, stall_s: float):
    deadline = time.monotonic() + stall_s
    while True:
        try:
            frame = box.take()
        except SourceEnded:
            raise InputError(f"{source.label} ended before a frame could be taken for "
                             f"trial {trial.number}", key=f"stimuli.{trial.stimulus}") from None
        if frame is not None:
            return frame
        if time.monotonic() > deadline:
            raise InputError(f"{source.label} gave no frame for {stall_s:g} s (trial "
                             f"{trial.number})", key=f"stimuli.{trial.stimulus}")
        box.wait(0.05)


def capture_empty_stage(source: FrameSource, prompt: CapturePrompt | None, *,
                        frames: int = EMPTY_FRAMES, stall_s: float = 5.0,
                        key: str = "--background") -> np.ndarray:
    """The empty stage, for telling each trial's object from it
    (:func:`vtexp.encoding.figure.figure_from_reference`): the experimenter is asked to
    clear the stage and press Enter, then the mean of the next ``frames`` frames of
    ``source`` (open) is taken. ``key``: what an error names (the option, or the
    stimulus)."""
    if prompt is None:
        raise InputError("capturing the empty stage asks the experimenter to clear it, but "
                         "no one is at a terminal; give a photograph of the empty stage "
                         "(--background FILE) or learn it (--background auto)",
                         key="--background")
    box = LatestFrame()
    cap = Capture(source, box)
    cap.start()
    got: list[np.ndarray] = []
    try:
        prompt(f"Clear the stage in front of {source.label}: nothing but the background, "
               "then press Enter ")
        deadline = time.monotonic() + stall_s
        while len(got) < frames:
            try:
                frame = box.take()
            except SourceEnded:
                break
            if frame is None:
                if time.monotonic() > deadline:
                    break
                box.wait(0.05)
                continue
            got.append(frame.image)
    finally:
        cap.stop(close=False)
    if not got:
        raise InputError(f"{source.label} gave no frame of the empty stage for {stall_s:g} s",
                         key=key)
    return mean_frame(got)


def mean_frame(frames) -> np.ndarray:
    """The mean of ``frames`` (of one shape), rounded to uint8: the empty stage as
    :func:`capture_empty_stage` keeps it (less sensor noise than one frame)."""
    return np.clip(np.rint(np.mean([np.asarray(f, np.float32) for f in frames], axis=0)),
                   0, 255).astype(np.uint8)


def touches_edge(mask: np.ndarray) -> bool:
    """Whether the object (uint8 0/1) reaches the frame's edge: the camera saw only part
    of it."""
    return bool(mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any())


def save_frame(folder: Path, stem: str, image) -> Path:
    """``image`` as ``folder/stem.png`` (``stem-2.png``, ... if taken), created exclusively."""
    path = _new_file(folder, stem)
    ok, data = cv2().imencode(".png", image)
    if not ok:
        raise SessionError(f"cannot encode {stem} as PNG")
    try:
        with open(path, "xb") as f:
            f.write(data.tobytes())
    except OSError as e:
        raise SessionError(f"cannot save {stem} to {path}: {e.strerror or e}") from None
    return path


def coded(lx, condition: Condition, image, profile: DeviceProfile, empty_stage=None
          ) -> tuple[Pattern, Schedule]:
    """The captured frame through the condition's pipeline and coding; with the
    ``empty_stage`` captured, the object is what differs from it."""
    mask = None
    if empty_stage is not None:
        from ..encoding.figure import figure_from_reference

        figure = figure_from_reference(image, empty_stage)
        if figure.empty:
            raise InputError(f"no object was found in the frame taken for stimulus "
                             f"{condition.stimulus!r}: {figure.reason}",
                             key=f"stimuli.{condition.stimulus}")
        if touches_edge(figure.mask):
            raise InputError(f"the object of stimulus {condition.stimulus!r} runs off the "
                             "edge of the frame, so only part of its shape would be felt: "
                             "move it (or the camera) so that all of it is in view",
                             key=f"stimuli.{condition.stimulus}")
        mask = figure.mask
    pattern = encode(lx, image, profile, condition.encoding_params, mask=mask)
    if not pattern.points:
        raise InputError(f"no object was found in the frame taken for stimulus "
                         f"{condition.stimulus!r}; is it in front of the camera, against a "
                         "plain background?", key=f"stimuli.{condition.stimulus}")
    return pattern, code(lx, pattern, profile, condition.coding_params)


class LiveTrial:
    """Step 3 for a ``live: true`` stimulus: the camera felt continuously, in a thread,
    until :meth:`stop` (the participant answered)."""

    def __init__(self, lx, condition: Condition, device, source: FrameSource,
                 record_dir: Path, empty_stage=None):
        from .encoder import LiveEncoder, LiveSetup
        from .loop import LiveRun
        from .record import Recorder

        exp = lx.experiment
        setup = LiveSetup.make(exp.encoding.pipeline, profile=device.profile,
                               coding=exp.coding.protocol,
                               encoding_params={"fit": "object", **condition.encoding_params}
                               if "fit" in _fields(exp.encoding.pipeline) else
                               condition.encoding_params,
                               coding_params=condition.coding_params)
        self.recorder = Recorder(record_dir, {
            "source": source.label, "pipeline": setup.pipeline,
            "encoding_params": setup.encoding_params, "coding": setup.coding,
            "coding_params": setup.coding_params,
            "play": setup.play, "follow": setup.follow,
            "profile": setup.profile.model_dump(mode="json")}, t0=device.clock.now())
        background = None
        if empty_stage is not None:            # the object is what differs from it
            from ..encoding.figure import BackgroundModel
            background = BackgroundModel.from_reference(empty_stage)
        self.run = LiveRun(source, LiveEncoder(setup, background), device,
                           sinks=[self.recorder],
                           stall_s=5.0)
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._work, daemon=True,
                                        name="vtexp-live-trial")

    def _work(self) -> None:
        try:
            self.run.run()
        except BaseException as e:           # raised in the session's thread by stop()
            self.error = e

    def start(self) -> None:
        self.recorder.t0 = self.run.clock.now()
        self._thread.start()

    def stop(self, reason: str = "answered") -> float:
        """Stop (every actuator off), close the record; return how long it played, ms."""
        self.run.stop(reason)
        self._thread.join(timeout=10)
        status = "completed" if self.error is None else "failed"
        self.recorder.close(status, end=self.run.stats.end_reason)
        if self.error is not None and not isinstance(self.error, (SourceEnded,)):
            raise self.error
        return self.run.stats.elapsed_s * 1000.0


def _fields(pipeline: str) -> set[str]:
    from ..encoding import PIPELINES

    return set(PIPELINES[pipeline][1].model_fields)
