"""The installation: OpenCV's contrib build wins over PsychoPy's opencv-python."""

from __future__ import annotations

import importlib.util

import pytest


def test_cv2_has_ximgproc_even_with_psychopy_installed():
    from vtexp._cv2 import cv2
    assert hasattr(cv2(), "ximgproc")
    assert cv2().ximgproc.thinning is not None


@pytest.mark.skipif(importlib.util.find_spec("psychopy") is None,
                    reason="the gui extra (PsychoPy) is not installed")
def test_psychopy_imports_beside_the_contrib_build():
    import psychopy
    import cv2
    assert psychopy.__version__
    assert hasattr(cv2, "ximgproc")


def test_a_broken_opencv_is_reported_with_the_repair(monkeypatch):
    import sys
    import types

    from vtexp import _cv2
    fake = types.ModuleType("cv2")
    monkeypatch.setitem(sys.modules, "cv2", fake)
    _cv2.cv2.cache_clear()
    try:
        with pytest.raises(_cv2.OpenCVError, match="not the contrib build.*force-reinstall"):
            _cv2.cv2()
    finally:
        monkeypatch.delitem(sys.modules, "cv2")
        _cv2.cv2.cache_clear()
