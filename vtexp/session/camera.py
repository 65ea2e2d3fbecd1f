"""What camera trials need from the session: its record folder (where the frames are kept)
and the experimenter's prompt. The work is :mod:`vtexp.live.trial`'s."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ..errors import SessionError
from ..experiment import LoadedExperiment
from ..design import Trial
from .files import has_camera


@dataclass
class CameraTrials:
    lx: LoadedExperiment
    dir: Path
    prompt: Callable[[str], None] | None

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
        try:
            got = camera.capture(self.lx, trial, self.dir, self.prompt, source, name)
            if self.lx.experiment.stimuli[trial.stimulus].live:
                folder = self.dir / (got.stim_file[:-len(".png")] + "-live")
                live = camera.LiveTrial(self.lx, trial.condition, device, source, folder)
                source = None                       # the live run reads it from here on
                return None, got.stim_file, live
            _, schedule = camera.coded(self.lx, trial.condition, got.image, device.profile)
            return schedule, got.stim_file, None
        finally:
            if source is not None:
                source.close()
