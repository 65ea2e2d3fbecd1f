from __future__ import annotations

import contextlib
import gc
import os
import subprocess
import sys
from pathlib import Path

import shutil
import time

import pytest
from hypothesis import HealthCheck, settings

import inprocess
from inprocess import run_in_process

# Hypothesis's deadline (200 ms an example) and its too-slow checks are timings: on two
# cores shared by five test processes an example or its generation can take longer
# without anything being wrong (test_model and test_wire failed so on a busy machine).
# The properties are what the tests check; how fast is for bench/.
settings.register_profile("vtexp", deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("vtexp")


def pytest_addoption(parser):
    parser.addoption("--fuzz-long", type=int, default=0, metavar="N",
                     help="tests/test_fuzz.py: N damaged inputs per family instead of the "
                          "few of every run (bench/fuzz.py prints the same as a table)")


#: The files that take longest (wall time in `make test`, measured with a per-test
#: timer), first: pytest-xdist hands whole files (`--dist loadfile`) to its processes in
#: the order collected, and a long file handed out last keeps the run waiting for it
#: alone. Alphabetical order put the participant window's 40 s near the end.
LONGEST_FIRST = ("test_firmware_study.py", "test_cli.py", "test_accessible_window.py",
                 "test_psychopy_builder.py",
                 "test_analysis_report.py", "test_resume_safety.py", "test_window.py",
                 "test_audio_sound_server.py", "test_live.py", "test_firmware_pins.py",
                 "test_live_preview.py", "test_conform.py", "test_camera_trials.py",
                 "test_observer.py", "test_portable.py", "test_coding_limits.py",
                 "test_session.py", "test_cluster.py", "test_report_defects.py",
                 "test_height_contours.py", "test_live_firmware.py")


def pytest_collection_finish(session):
    """Everything collection made (every module the suite imports: about 225,000 objects)
    is left out of garbage collections from here on (``gc.freeze``). A full collection
    looked at all of it in 0.16 s, longer on a busy machine, holding Python's lock: an
    emulated device served from the test process fell silent meanwhile, past the 120 ms
    after which its host counts it lost (a flaky 'lost contact' in tests whose subject is
    not the link)."""
    gc.collect()
    gc.freeze()
    inprocess.RUN_FROZEN = True


def pytest_collection_modifyitems(config, items):
    rank = {name: k for k, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))   # stable: files keep
                                                                       # their own order


ROOT = Path(__file__).resolve().parents[1]
GRID = ROOT / "experiments" / "duration_interval_grid.yaml"


@pytest.fixture
def grid_path() -> Path:
    return GRID


#: ``vtexp ARGS`` run in this process as a fresh ``python -m vtexp`` would run it (see
#: tests/inprocess.py); the result as ``subprocess.run`` gives it. Tests whose subject is
#: the process itself (signals, kills, locks, start-up, a terminal) start it with
#: ``subprocess`` and are marked ``process``.
run_cli = run_in_process


def run_printed(command: list[str], **kwargs) -> subprocess.CompletedProcess:
    """A command vtexp printed for the user to run (e.g. to continue a session), run with
    ``run_cli``: it must call vtexp as this test run does, ``python -m vtexp``."""
    assert command[:3] == [sys.executable, "-m", "vtexp"], command
    return run_cli(*command[3:], **kwargs)


@pytest.fixture
def cli():
    return run_cli


def write_experiment(tmp_path: Path, text: str, name: str = "exp.yaml") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


MINIMAL = """\
name: mini
title: A minimal experiment
device: vest_6x8
stimuli:
  square: {generator: shape, params: {shape: square}}
  circle: {generator: shape, params: {shape: circle}}
encoding:
  pipeline: edge-trace
coding:
  protocol: sequential-trace
  params: {duration_ms: 200, soa_ms: 200}
factors:
  shape:
    sets: stimulus
    levels: [square, circle]
design:
  repetitions: 2
  iti_ms: 0
question:
  prompt: Which shape?
  options: [square, circle]
  correct: "{shape}"
"""


@pytest.fixture
def minimal_yaml() -> str:
    return MINIMAL


def dies_with_us(command: list[str]) -> list[str]:
    """``command`` run so that the system kills it when this process ends, however it ends
    (``setpriv --pdeathsig KILL``, util-linux; unchanged where there is no setpriv): a test
    run killed in the middle leaves no X server or sound server behind. Start it from the
    main thread: the signal follows the thread that started it."""
    exe = shutil.which("setpriv")
    return [exe, "--pdeathsig", "KILL", *command] if exe else list(command)


@contextlib.contextmanager
def start_xvfb(first: int, size: str):
    """A virtual X server on the first free display number from ``first`` (40 tried),
    ``size`` as ``WxHxDEPTH``; yields ``":N"`` and stops it afterwards."""
    exe = shutil.which("Xvfb")
    if exe is None:
        pytest.fail("Xvfb is not installed: apt-get install xvfb libgl1-mesa-dri "
                    "(make test installs them)")
    n = next(n for n in range(first, first + 40)
             if not Path(f"/tmp/.X{n}-lock").exists()
             and not Path(f"/tmp/.X11-unix/X{n}").exists())
    proc = subprocess.Popen(dies_with_us([exe, f":{n}", "-screen", "0", size, "-nolisten",
                                          "tcp"]),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 20
    while not Path(f"/tmp/.X11-unix/X{n}").exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            pytest.fail(f"Xvfb :{n} did not start: {proc.stderr.read().decode()[-500:]}")
        time.sleep(0.05)
    try:
        yield f":{n}"
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)


def worker_number() -> int:
    """This pytest-xdist worker's number (gw0, gw1, ...; 0 without xdist)."""
    return int(os.environ.get("PYTEST_XDIST_WORKER", "gw0")[2:] or 0)


#: The participant window's frame rate on the virtual display. Xvfb's flip returns at once,
#: so the window draws at its own cap (vtexp.responders.window.MAX_FRAME_RATE, 240 a
#: second, for drivers with vsync off), and every window test would keep a core busy
#: drawing frames that do not change. The tests see the window as a 60 Hz lab monitor
#: shows it.
TEST_DISPLAY_HZ = 60.0


def _as_a_lab_display() -> None:
    """The participant window on the test display: refreshed at TEST_DISPLAY_HZ, and each
    PsychoPy window icon converted once (pyglet turns an icon into X11's pixel format
    pixel by pixel, with a regular expression: 0.2 s of CPU per icon, two icons for every
    window opened, about 70 windows a run)."""
    import vtexp.responders.window as window
    window.MAX_FRAME_RATE = TEST_DISPLAY_HZ
    import psychopy.visual  # noqa: F401  (sets pyglet's options before pyglet.window loads)
    from ctypes import c_ulong, sizeof
    from pyglet.image import ImageData
    from pyglet.window.xlib import XlibWindow
    if getattr(XlibWindow.set_icon, "converted_once", False):
        return
    fmt = {("little", 4): "BGRA", ("little", 8): "BGRAAAAA", ("big", 4): "ARGB",
           ("big", 8): "AAAAARGB"}[(sys.byteorder, sizeof(c_ulong))]     # as pyglet's
    set_icon, done = XlibWindow.set_icon, {}

    def converted_once(self, *images):
        ready = []
        for image in images:
            data = image.get_image_data()
            raw = data.get_data(data.format, data.pitch)
            key = (data.width, data.height, data.format, data.pitch, bytes(raw))
            pitch = -(data.width * len(fmt))
            if key not in done:
                done[key] = data.get_data(fmt, pitch)
            ready.append(ImageData(data.width, data.height, fmt, done[key], pitch))
        return set_icon(self, *ready)

    converted_once.converted_once = True
    XlibWindow.set_icon = converted_once


@pytest.fixture(scope="session")
def xvfb():
    """A virtual X server on a free display number, for the whole test session (one for
    every window test: pyglet stays connected to the first display it opens)."""
    # pytest-xdist's workers look in ranges of their own: no two pick one display
    with start_xvfb(90 + 40 * worker_number(), "1920x1200x24") as disp:
        old = os.environ.get("DISPLAY")
        os.environ["DISPLAY"] = disp
        _as_a_lab_display()
        yield disp
        if "psychopy.visual" in sys.modules:      # a failed test may leave its window open
            from psychopy.visual.window import openWindows
            for ref in list(openWindows):
                if ref() is not None:
                    ref().close()
    if old is None:
        os.environ.pop("DISPLAY", None)
    else:
        os.environ["DISPLAY"] = old


@pytest.fixture(scope="session")
def demo_run(tmp_path_factory):
    """``vtexp demo --participants 3`` run once for the whole test run, shared by every
    pytest-xdist worker (the first to ask makes it, under a lock): ``(root, stdout)``.
    Read only: a test that changes a demo dataset copies it first."""
    import fcntl
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent                      # the workers' common folder
    root, out = base / "shared-demo", base / "shared-demo.stdout"
    with open(base / "shared-demo.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not out.exists():
            shutil.rmtree(root, ignore_errors=True)
            r = run_cli("demo", "--data", str(root), "--participants", "3", cwd=base,
                        timeout=600)
            assert r.returncode == 0, r.stderr
            out.write_text(r.stdout)
    return root, out.read_text()



def record_plays(dev) -> list[tuple[float, float]]:
    """Wrap ``dev.play`` so that each play's start and end (``time.monotonic``) are added
    to the list returned, as the device is asked and as it answers."""
    plays: list[tuple[float, float]] = []
    play = dev.play

    def timed(schedule, **kw):
        t0 = time.monotonic()
        rep = play(schedule, **kw)
        plays.append((t0, time.monotonic()))
        return rep
    dev.play = timed
    return plays

def session_record(ses: Path) -> Path:
    """The session record of a BIDS session folder (``.../sub-P/ses-N`` or its ``beh/``):
    ``sourcedata/vtexp/sub-P/ses-N/*_session.json`` of the same dataset."""
    ses = Path(ses)
    ses = ses.parent if ses.name == "beh" else ses
    folder = ses.parents[1] / "sourcedata" / "vtexp" / ses.parent.name / ses.name
    found = sorted(folder.glob("*_session.json"))
    assert len(found) == 1, f"no session record in {folder}"
    return found[0]
