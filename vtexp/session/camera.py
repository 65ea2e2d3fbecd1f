"""What camera trials need from the session: its record folder (where the frames are kept)
and the experimenter's prompt. The work is :mod:`vtexp.live.trial`'s."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

from ..errors import SessionError
from ..experiment import LoadedExperiment
from ..design import Trial
from .files import has_camera


@dataclass
class CameraTrials:
    """A camera stimulus that asks the experimenter to place its object has the stage
    captured empty first (once per camera, and again when the experimenter asks at an
    object's prompt), kept as ``stim/empty-stage.png`` beside the trial frames; each
    trial's object is what differs from it (:mod:`vtexp.encoding.figure`). One taken
    after ``delay_s`` with nobody asked, or from a video standing in for the camera, is
    encoded as it is."""

    lx: LoadedExperiment
    dir: Path
    prompt: Callable[[str], str | None] | None
    empty: dict[str, object] = field(default_factory=dict)   # camera name -> the stage

    @classmethod
    def of(cls, lx: LoadedExperiment, folder: Path, prompt) -> CameraTrials | None:
        """None without camera stimuli; refused when one must ask the experimenter to
        place its object and no one can be asked."""
        if not has_camera(lx):
            return None
        from ..live.trial import needs_prompt

        asking = needs_prompt(lx)
        if asking and prompt is None:
            raise SessionError(f"stimulus {asking[0]!r} asks the experimenter to place the object "
                               "before the camera, but no one can be asked (no terminal); "
                               "declare delay_s for it, or run from a terminal")
        return cls(lx, folder, prompt)

    def take(self, trial: Trial, device):
        """The frame of this trial, saved: ``(schedule, stim_file, None)``, or for a live
        stimulus ``(None, stim_file, live)`` with the live run to start."""
        from ..live import trial as camera

        source, name = camera.camera_source(self.lx, trial.stimulus)
        spec = self.lx.experiment.stimuli[trial.stimulus]
        try:
            recapture = None
            if spec.delay_s is None and spec.camera is not None:
                recapture = partial(self._empty_stage, source, name, trial.stimulus)
                if name not in self.empty:
                    source.open()
                    recapture()
            got = camera.capture(self.lx, trial, self.dir, self.prompt, source, name,
                                 recapture=recapture)
            if self.lx.experiment.stimuli[trial.stimulus].live:
                folder = self.dir / (got.stim_file[:-len(".png")] + "-live")
                live = camera.LiveTrial(self.lx, trial.condition, device, source, folder,
                                        self.empty.get(name))
                source = None                       # the live run reads it from here on
                return None, got.stim_file, live
            _, schedule = camera.coded(self.lx, trial.condition, got.image, device.profile,
                                       self.empty.get(name))
            return schedule, got.stim_file, None
        finally:
            if source is not None:
                source.close()

    def _empty_stage(self, source, name: str, stimulus: str) -> None:
        from ..live import trial as camera

        stage = camera.capture_empty_stage(source, self.prompt, key=f"stimuli.{stimulus}")
        camera.save_frame(self.dir / "stim", "empty-stage", stage)
        self.empty[name] = stage
