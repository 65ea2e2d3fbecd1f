"""Import OpenCV and make sure it is the contrib build.

PsychoPy depends on ``opencv-python``, which installs the same ``cv2`` module
as ``opencv-contrib-python-headless``. Whichever was installed last wins, and
only the contrib build has ``cv2.ximgproc`` (thinning, used by the edge-trace
pipeline). :func:`cv2` returns the module or raises a message that says how
to repair the environment.
"""

from __future__ import annotations

from functools import lru_cache

from .errors import VtexpError

REPAIR = ("pip uninstall -y opencv-python opencv-python-headless opencv-contrib-python "
          "&& pip install --force-reinstall --no-deps opencv-contrib-python-headless")


class OpenCVError(VtexpError):
    exit_code = 4


@lru_cache(maxsize=1)
def cv2():
    try:
        import cv2 as _cv2
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise OpenCVError(
            f"OpenCV is not importable ({exc}). Install the contrib build: {REPAIR}") from None
    if not hasattr(_cv2, "ximgproc"):
        raise OpenCVError(
            "the installed OpenCV is not the contrib build (cv2.ximgproc is missing); "
            "PsychoPy's opencv-python probably replaced it. Repair with: " + REPAIR)
    return _cv2
