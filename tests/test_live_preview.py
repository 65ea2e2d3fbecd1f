"""The experimenter's live preview in a real PsychoPy window on a virtual X server (Xvfb):
``vtexp live --preview`` for each pipeline, a screenshot of each under
``test-output/live/``, the safety guard's degradations on screen, and a real Escape key
press (XTEST) that ends the run with every actuator off."""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT, start_xvfb, worker_number

if importlib.util.find_spec("psychopy") is None:
    pytest.skip("PsychoPy is not installed (the 'gui' extra; make test installs it)",
                allow_module_level=True)

from vtexp.live.synthetic import write_video  # noqa: E402

SHOTS = ROOT / "test-output" / "live"


@pytest.fixture(scope="module")
def display():
    # a display range above the window tests' (tests/conftest.py)
    with start_xvfb(200 + 40 * worker_number(), "1400x900x24") as disp:
        shutil.rmtree(SHOTS, ignore_errors=True)
        SHOTS.mkdir(parents=True)
        yield disp


@pytest.fixture(scope="module")
def videos(tmp_path_factory):
    d = tmp_path_factory.mktemp("videos")
    out = {}
    for kind, size in [("rectangle", 0.5), ("ball", 0.6), ("horse", 0.55)]:
        out[kind] = d / f"{kind}.avi"
        write_video(out[kind], kind, seconds=4.0, size=size)
    return out


def live(display, *args, timeout=120):
    env = dict(os.environ, PYTHONPATH=str(ROOT), DISPLAY=display)
    return subprocess.run([sys.executable, "-m", "vtexp", "live", *args], capture_output=True,
                          text=True, env=env, timeout=timeout, cwd=ROOT)


def assert_not_blank(png: Path):
    from PIL import Image

    px = np.asarray(Image.open(png).convert("L"), dtype=float)
    assert px.std() > 10, f"{png} looks blank (pixel sd {px.std():.1f})"
    return px


@pytest.mark.parametrize("pipeline, video, play", [
    ("edge-trace", "rectangle", "cycle"), ("snake-corners", "rectangle", "cycle"),
    ("height-contours", "ball", "cycle"), ("snake-corners", "horse", "hold")])
def test_the_preview_shows_camera_contour_array_and_figures(display, videos, pipeline, video,
                                                            play):
    shot = SHOTS / f"preview-{pipeline}-{video}-{play}.png"
    r = live(display, str(videos[video]), "--pipeline", pipeline, "--play", play,
             "--preview", "--duration", "3", "--screenshot", str(shot))
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    assert "every actuator is off" in r.stdout
    px = assert_not_blank(shot)
    assert px.shape[1] >= 1000               # three panels side by side


def test_escape_in_the_preview_ends_the_run_with_everything_off(display, videos):
    """A real key press (XTEST) into the preview window, as the experimenter's keyboard."""
    pytest.importorskip("Xlib", reason="python-xlib (installed with PsychoPy on Linux)")
    from Xlib import X, XK
    from Xlib import display as xdisplay
    from Xlib.ext import xtest

    env = dict(os.environ, PYTHONPATH=str(ROOT), DISPLAY=display)
    rec = SHOTS.parent / "live-escape-record"
    shutil.rmtree(rec, ignore_errors=True)
    p = subprocess.Popen([sys.executable, "-m", "vtexp", "live", str(videos["rectangle"]),
                          "--pipeline", "edge-trace", "--device", "emulator", "--preview",
                          "--record", str(rec)], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT)
    try:
        deadline = time.monotonic() + 60
        while not (rec / "outputs.tsv").exists() or \
                len((rec / "outputs.tsv").read_text().splitlines()) < 3:
            assert p.poll() is None and time.monotonic() < deadline, p.stderr.read()
            time.sleep(0.05)
        d = xdisplay.Display(display)
        w, h = d.screen().width_in_pixels, d.screen().height_in_pixels
        xtest.fake_input(d, X.MotionNotify, x=w // 2, y=h // 2)    # over the window
        code = d.keysym_to_keycode(XK.string_to_keysym("Escape"))
        xtest.fake_input(d, X.KeyPress, code)
        xtest.fake_input(d, X.KeyRelease, code)
        d.sync()
        d.close()
        out, err = p.communicate(timeout=30)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 0, err
    assert "ended: preview closed by the experimenter (Escape); every actuator is off" in out
    from vtexp.live.record import load_record

    lr = load_record(rec)
    assert lr.meta["end"].startswith("preview closed") and lr.states()[-1][1] == {}


def test_the_guards_degradations_are_on_the_picture():
    """compose() writes what the safety guard left out under the figures, in orange."""
    from vtexp.live.loop import LiveStats, Snapshot
    from vtexp.live.preview import WARN, compose, status_lines
    from vtexp.model import DeviceProfile

    prof = DeviceProfile.load("sma_5x5")
    st = LiveStats(started=time.monotonic() - 2)
    st.latencies_ms = [3.0, 4.0, 5.0]
    snap = Snapshot(None, None, {}, st, ["power budget: 3 of 11 skipped (max_simultaneous 8)"])
    lines = status_lines(snap, prof)
    assert ("safety: power budget: 3 of 11 skipped (max_simultaneous 8)", WARN) in lines
    assert "latency p50 4.0 ms  p95 4.9 ms" in lines[0][0]
    img = compose(snap, prof)
    assert img.ndim == 3 and img.shape[2] == 3
    orange = (np.abs(img.astype(int) - np.array(WARN)).sum(axis=2) < 60)
    assert orange[-40:].any()                 # the warning line is drawn at the bottom
