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

from .._cv2 import cv2
from ..compile import Condition, code, encode
from ..errors import InputError, SessionError
from ..model import DeviceProfile, Pattern, Schedule
from .sources import Capture, CameraSource, FrameSource, LatestFrame, SourceEnded, VideoSource

#: Called with the text to show; returns when the experimenter pressed Enter.
CapturePrompt = Callable[[str], None]


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
            source: FrameSource, camera_name: str, *, stall_s: float = 5.0) -> Captured:
    """Steps 1-2 of the module docstring: the frame, saved. ``source`` stays open."""
    spec = lx.experiment.stimuli[trial.stimulus]
    box = LatestFrame()
    cap = Capture(source, box)
    source.open()
    cap.start()
    try:
        if spec.delay_s is not None:
            time.sleep(spec.delay_s)
        else:
            if prompt is None:
                raise SessionError(f"trial {trial.number}: stimulus {trial.stimulus!r} asks the "
                                   "experimenter to place the object, but nobody is at a "
                                   "terminal; declare delay_s, or run from a terminal")
            prompt(f"Trial {trial.number}: place {spec.object or trial.stimulus} in front of "
                   f"{camera_name}, then press Enter ")
        deadline = time.monotonic() + stall_s
        frame = None
        while frame is None:
            try:
                frame = box.take()
            except SourceEnded:
                raise InputError(f"{source.label} ended before a frame could be taken for "
                                 f"trial {trial.number}", key=f"stimuli.{trial.stimulus}") from None
            if frame is None:
                if time.monotonic() > deadline:
                    raise InputError(f"{source.label} gave no frame for {stall_s:g} s (trial "
                                     f"{trial.number})", key=f"stimuli.{trial.stimulus}")
                box.wait(0.05)
    finally:
        cap.stop(close=False)
    path = _new_file(session_dir / "stim", f"trial-{trial.number:03d}")
    ok, data = cv2().imencode(".png", frame.image)
    if not ok:
        raise SessionError(f"cannot encode the frame of trial {trial.number} as PNG")
    try:
        with open(path, "xb") as f:
            f.write(data.tobytes())
    except OSError as e:
        raise SessionError(f"cannot save the frame of trial {trial.number} to {path}: "
                           f"{e.strerror or e}") from None
    return Captured(frame.image, str(path.relative_to(session_dir)), frame.t_capture)


def coded(lx, condition: Condition, image, profile: DeviceProfile
          ) -> tuple[Pattern, Schedule]:
    """The captured frame through the condition's pipeline and coding."""
    pattern = encode(lx, image, profile, condition.encoding_params)
    if not pattern.points:
        raise InputError(f"no object was found in the frame taken for stimulus "
                         f"{condition.stimulus!r}; is it in front of the camera, against a "
                         "plain background?", key=f"stimuli.{condition.stimulus}")
    return pattern, code(lx, pattern, profile, condition.coding_params)


class LiveTrial:
    """Step 3 for a ``live: true`` stimulus: the camera felt continuously, in a thread,
    until :meth:`stop` (the participant answered)."""

    def __init__(self, lx, condition: Condition, device, source: FrameSource,
                 record_dir: Path):
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
        self.run = LiveRun(source, LiveEncoder(setup), device, sinks=[self.recorder],
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
