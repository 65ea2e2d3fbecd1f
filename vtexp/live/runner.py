"""A whole live run as ``vtexp live`` makes it: source, loop, device, record, preview.

:func:`run_live` opens nothing before it has checked what it can (the record folder
is created first, so an existing one stops the run before anything plays), runs the
loop (:class:`~vtexp.live.loop.LiveRun`) — in this thread, or, with the preview, in
a worker thread while this one draws the window (OpenGL wants the main thread) —
and always leaves every actuator off and the record closed with its status.
"""

from __future__ import annotations

import platform
import sys
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .. import __version__
from ..clock import iso
from ..devices.base import DeviceBase
from ..errors import SessionAborted
from .encoder import LiveEncoder, LiveSetup
from .loop import LiveRun, LiveStats, Snapshot
from .record import Recorder
from .sources import FrameSource


@dataclass
class LiveResult:
    stats: LiveStats
    record: Path | None
    preview_image: Any = None          # the last picture the preview showed (BGR), if any


def run_live(source: FrameSource, setup: LiveSetup, device: DeviceBase, *,
             preview: bool = False, record: str | Path | None = None,
             duration_s: float | None = None, stall_s: float = 2.0,
             command: list[str] | None = None, preview_options: dict | None = None,
             screenshot: str | Path | None = None, background=None) -> LiveResult:
    """Run ``source`` through ``setup`` to ``device`` until the source ends, ``duration_s``
    passes, the preview's Escape, Ctrl-C or an error (module docstring). ``background``
    (:class:`vtexp.encoding.figure.BackgroundModel`) tells the object from the scene; None
    leaves it to the pipeline's own threshold (a plain background)."""
    recorder = None
    if record is not None:
        recorder = Recorder(record, {
            "command": command or sys.argv, "source": source.label,
            "pipeline": setup.pipeline, "encoding_params": setup.encoding_params,
            "coding": setup.coding, "coding_params": setup.coding_params,
            "play": setup.play, "follow": setup.follow,
            "profile": setup.profile.model_dump(mode="json"),
            "started": iso(device.clock),
            "versions": {"vtexp": __version__, "python": platform.python_version()}},
            t0=device.clock.now())
    holder: dict[str, Snapshot] = {}
    run = LiveRun(source, LiveEncoder(setup, background), device, duration_s=duration_s,
                  stall_s=stall_s,
                  sinks=[recorder] if recorder else [],
                  on_snapshot=(lambda s: holder.__setitem__("s", s)) if preview else None)
    if recorder is not None:
        recorder.t0 = device.clock.now()
    status = "failed"
    image = None
    try:
        if preview:
            image = _run_with_preview(run, setup, holder, preview_options or {}, screenshot)
        else:
            run.run()
        status = "completed"
    except KeyboardInterrupt:
        status = "interrupted"
        raise
    except SessionAborted:
        status = "aborted"
        raise
    finally:
        if recorder is not None:
            info = device._info.model_dump(mode="json") if device._info is not None else None
            recorder.close(status, ended=iso(device.clock),
                           device=info, end=run.stats.end_reason,
                           warnings=setup.warnings)
    return LiveResult(run.stats, Path(record) if record else None, image)


def _run_with_preview(run: LiveRun, setup: LiveSetup, holder: dict, options: dict,
                      screenshot: str | Path | None):
    from .preview import PreviewWindow

    window = PreviewWindow(setup.profile, **options)
    failure: list[BaseException] = []

    def work() -> None:
        try:
            run.run()
        except BaseException as e:          # re-raised in this thread below
            failure.append(e)

    worker = threading.Thread(target=work, name="vtexp-live-loop", daemon=True)
    worker.start()
    after = 0.6 * run.duration_s if run.duration_s else 1.5
    try:
        window.run(lambda: holder.get("s"), worker.is_alive, run.stop,
                   screenshot=None if screenshot is None else str(screenshot),
                   screenshot_after_s=after)
    except KeyboardInterrupt:
        run.stop("interrupted (Ctrl-C)")
        worker.join(timeout=5)
        raise
    finally:
        run.stop(run.stats.end_reason or "preview closed")
        worker.join(timeout=10)
        image = window.last_image
        window.close()
    if failure:
        raise failure[0]
    return image
