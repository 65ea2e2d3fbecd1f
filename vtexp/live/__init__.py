"""Live vision-to-touch: a camera felt at camera rate (``vtexp live``).

The three papers describe systems in which a camera sees an object and the array
renders its shape as it is seen (seed 000 §3: "acquire images in real time"; seed
001: a USB camera at 1 frame per second; seed 002: a web camera, the snake tracking
the object "even if the object moves"). This package is that path:

=================  ==============================================================
``sources``        camera, video file, folder of images, standard input; capture
                   in a thread into a one-frame mailbox (newest frame only)
``encoder``        frame -> Pattern -> one cycle of the paper's coding; the live
                   defaults of each pipeline; the snake carried between frames
``program``        a cycle as the outputs it asks for at each phase; a new cycle
                   goes on from where it changed (or from the same place)
``loop``           the loop: frame -> cycle -> ``device.stream`` (changes only,
                   limits across frames); latency, dropped frames, clock mapping
``record``         ``--record DIR``: every frame, cycle and output, to replay and
                   analyse; :func:`~vtexp.live.record.load_record`
``preview``        the experimenter's window: camera, contour, array, figures
``runner``         a whole run as ``vtexp live`` makes it
=================  ==============================================================

It uses encoding, coding, safety and the device layer, and nothing uses it but
the command line and the session's live trials.
"""

from .encoder import LIVE_DEFAULTS, LIVE_PIPELINES, LiveEncoder, LiveSetup
from .loop import LiveRun, LiveStats
from .runner import LiveResult, run_live
from .sources import open_source

__all__ = ["LIVE_DEFAULTS", "LIVE_PIPELINES", "LiveEncoder", "LiveResult", "LiveRun",
           "LiveSetup", "LiveStats", "open_source", "run_live"]
