"""The experimenter's live preview in a real PsychoPy window on a virtual X server (Xvfb):
``vtexp live --preview`` for each pipeline, a screenshot of each under
``test-output/live/``, the safety guard's degradations on screen, and a real Escape key
press (XTEST) that ends the run with every actuator off.

The command runs in the test process (``run_cli``), on the X server the window tests of
this process share (``tests/conftest.py``'s ``xvfb``): pyglet stays connected to the
first display a process opens."""

from __future__ import annotations

import importlib.util
import shutil
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT, run_cli

if importlib.util.find_spec("psychopy") is None:
    pytest.skip("PsychoPy is not installed (the 'gui' extra; make test installs it)",
                allow_module_level=True)

from vtexp.live.synthetic import write_video  # noqa: E402

SHOTS = ROOT / "test-output" / "live"

# The experimenter's preview, a real PsychoPy window on Xvfb: real time is its subject.
pytestmark = pytest.mark.realtime


@pytest.fixture(scope="module")
def display(xvfb):
    shutil.rmtree(SHOTS, ignore_errors=True)
    SHOTS.mkdir(parents=True)
    return xvfb


@pytest.fixture(scope="module")
def videos(tmp_path_factory):
    d = tmp_path_factory.mktemp("videos")
    out = {}
    for kind, size in [("rectangle", 0.5), ("ball", 0.6), ("horse", 0.55)]:
        out[kind] = d / f"{kind}.avi"
        write_video(out[kind], kind, seconds=4.0, size=size)
    return out


def live(display, *args, timeout=120):
    return run_cli("live", *args, timeout=timeout)       # DISPLAY: the xvfb fixture's


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


def test_the_preview_outlines_the_object_over_a_photograph(display, tmp_path):
    """A card moving over a photograph (matplotlib's sample, dimmed), the empty stage given:
    the object found is outlined in magenta over the camera image."""
    import matplotlib

    from vtexp._cv2 import cv2
    from vtexp.stimuli import read_image

    photo = read_image(Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg")
    stage = (cv2().resize(photo, (640, 480)) * 0.6).astype(np.uint8)
    cv2().imwrite(str(tmp_path / "stage.png"), stage)
    video = tmp_path / "card.avi"
    write_video(video, "rectangle", seconds=3.0, size=0.45, backdrop=stage)
    shot = SHOTS / "preview-edge-trace-over-a-photograph.png"
    r = live(display, str(video), "--pipeline", "edge-trace", "--background",
             str(tmp_path / "stage.png"), "--preview", "--duration", "2", "--screenshot",
             str(shot))
    assert r.returncode == 0, r.stderr
    from PIL import Image
    px = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    magenta = (px[..., 0] > 200) & (px[..., 1] < 80) & (px[..., 2] > 200)
    assert magenta.sum() > 200, magenta.sum()


def test_escape_in_the_preview_ends_the_run_with_everything_off(display, videos):
    """A real key press (XTEST) into the preview window, as the experimenter's keyboard."""
    pytest.importorskip("Xlib", reason="python-xlib (installed with PsychoPy on Linux)")
    from Xlib import X, XK
    from Xlib import display as xdisplay
    from Xlib.ext import xtest

    rec = SHOTS.parent / "live-escape-record"
    shutil.rmtree(rec, ignore_errors=True)
    pressed = threading.Event()
    done = threading.Event()

    def experimenter():                     # the run holds this thread: keys from another
        deadline = time.monotonic() + 60
        while not (rec / "outputs.tsv").exists() or \
                len((rec / "outputs.tsv").read_text().splitlines()) < 3:
            if done.is_set() or time.monotonic() > deadline:
                return
            time.sleep(0.05)
        d = xdisplay.Display(display)
        w, h = d.screen().width_in_pixels, d.screen().height_in_pixels
        xtest.fake_input(d, X.MotionNotify, x=w // 2, y=h // 2)    # over the window
        code = d.keysym_to_keycode(XK.string_to_keysym("Escape"))
        xtest.fake_input(d, X.KeyPress, code)
        xtest.fake_input(d, X.KeyRelease, code)
        d.sync()
        d.close()
        pressed.set()

    keys = threading.Thread(target=experimenter, daemon=True)
    keys.start()
    try:
        r = run_cli("live", str(videos["rectangle"]), "--pipeline", "edge-trace", "--device",
                    "emulator", "--preview", "--record", str(rec), timeout=90)
    finally:
        done.set()
        keys.join(10)
    assert pressed.is_set(), r.stderr
    out, err = r.stdout, r.stderr
    assert r.returncode == 0, err
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
