"""The participant window for people who cannot see it, or see it badly (issue 13).

- Every question of the five studies, in the visual and the audio mode, answered with
  real key presses sent to the X server (XTEST), in sessions on the simulator.
- The audio mode: what is played is captured (the espeak-ng files and their order):
  a spoken prompt precedes every answer, each answer is said back, and nothing is
  said while a stimulus plays (the masking noise covers each stimulus instead).
- The layout on screenshots: every question of the five studies at 1280x800 and
  1920x1080, scales 1 and 2, each label drawn alone and its pixels measured: inside
  its button, inside the screen, and apart from every other label.
"""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import threading
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import ROOT, record_plays
from xkeyboard import XKeyboard

if importlib.util.find_spec("psychopy") is None:
    pytest.skip("PsychoPy is not installed (the 'gui' extra)", allow_module_level=True)
if shutil.which("espeak-ng") is None:
    pytest.fail("espeak-ng is not installed: apt-get install espeak-ng (make test installs it)")

from vtexp.devices import open_device                    # noqa: E402
from vtexp.experiment import load_experiment            # noqa: E402
from vtexp.model import DeviceProfile                   # noqa: E402
from vtexp.session import SessionOptions, run_session   # noqa: E402

OUT = ROOT / "test-output"
STUDIES = ["duration_interval_grid", "letters", "six_mode_ball", "whirlpool",
           "circle_vs_rectangle"]

# A real PsychoPy window on Xvfb, answered with real key presses: real time is its subject.
pytestmark = pytest.mark.realtime


@pytest.fixture(scope="module", autouse=True)
def display(xvfb, tmp_path_factory):
    """The virtual X server of conftest.py (1920x1200), and a speech cache."""
    old = os.environ.get("VTEXP_SPEECH_CACHE")
    os.environ["VTEXP_SPEECH_CACHE"] = str(tmp_path_factory.mktemp("speech"))
    yield xvfb
    if old is None:
        os.environ.pop("VTEXP_SPEECH_CACHE", None)
    else:
        os.environ["VTEXP_SPEECH_CACHE"] = old


class CapturedAudio:
    """Stands in for the sound card: records what would be played, and when. A clip
    "plays" for its file's length divided by ``speed`` (the tests go faster)."""

    speed = 64.0

    def __init__(self):
        self.log: list[tuple[str, Path | None, float]] = []

    def duration(self, path: Path) -> float:
        from vtexp.responders.speech import wav_duration_s
        return wav_duration_s(path) / self.speed

    def play(self, path):
        self.log.append(("play", Path(path), time.monotonic()))

    def stop(self, path):
        self.log.append(("stop", Path(path), time.monotonic()))

    def loop(self, path):
        self.log.append(("loop", Path(path), time.monotonic()))

    def stop_loop(self):
        self.log.append(("stop_loop", None, time.monotonic()))




def quiet(r) -> bool:
    """Nothing is being said (read only: the session's thread plays the clips)."""
    sp = r.speech
    return sp is None or (sp.current is None and not sp.queue)


def wait_for(cond, timeout=30.0) -> bool:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


# What the participant answers in two trials of each study, as keys pressed, and what
# that must log (per trial, per question).
ANSWERS = {
    "duration_interval_grid": ([["1"], ["4"]], [["triangle"], ["rectangle"]]),
    "letters": ([["r"], ["z"]], [["R"], ["Z"]]),
    "six_mode_ball": ([["2"], ["5"]], [["ball"], ["uneven surface"]]),
    "whirlpool": ([["3", "1", "2", "Return"], ["0", "Up", "Up", "Up", "Down", "KP_Enter"]],   # up from nothing: 0, 1, 2; down: 1
                  [["3", "12"], ["0", "1"]]),
    "circle_vs_rectangle": ([["minus", "2"], ["1"]], [["-2"], ["1"]]),
}


def _session(study, audio, display, tmp_path):
    from vtexp.responders.window import WindowOptions, WindowResponder
    lx = load_experiment(ROOT / "experiments" / f"{study}.yaml")
    captured = CapturedAudio()
    r = WindowResponder(WindowOptions(fullscreen=False, size=(1280, 800), audio=audio),
                        lx=lx, audio=captured if audio else None)
    keys, expected = ANSWERS[study]
    questions = lx.experiment.asked()
    kb = XKeyboard(display)
    problems: list[str] = []
    ended = threading.Event()            # set when the session is over, however it ended

    def speaking(text):
        sp = r.speech
        return sp is None or (sp.current is not None and sp.current[0] == text) or any(
            p.text == text for p in sp.played[-3:])

    def participant():
        try:
            if not wait_for(lambda: r.win is not None and r.screen == "instructions"):
                problems.append("no instructions")
                return
            kb.focus(r.win)
            time.sleep(0.2)
            if audio:                    # the instructions have begun to be said: before
                first = r.speech.phrase("headphones")   # (their clips being made) it is
                if not wait_for(lambda: speaking(first) or any(   # quiet too
                        p.text == first for p in r.speech.played)):
                    problems.append("the instructions were not said")
                    return
            wait_for(lambda: quiet(r), timeout=60)   # heard it all
            kb.press("space")
            for n, trial_keys in enumerate(keys, start=1):
                qi, asked = 0, -1
                for k in trial_keys:
                    q = questions[qi]
                    if asked != qi:      # a question's first key: once it has been heard
                        if not wait_for(lambda q=q, n=n: r.entered.count("ready") >= n
                                        and r.screen == q.kind and speaking(q.prompt)):
                            problems.append(f"question {q.name} never asked (on {r.screen})")
                            return
                        wait_for(lambda: quiet(r))
                        asked = qi
                    time.sleep(0.05)
                    before = r.layout
                    kb.press(k)
                    if k in ("Return", "KP_Enter") or q.kind != "number" and k != "minus":
                        qi += 1
                        # The answer is taken: the screen shows it (and says it) and moves on.
                        wait_for(lambda: r.layout is not before)
                    time.sleep(0.05)
            if not wait_for(lambda: r.screen == "end" and quiet(r)):
                problems.append(f"no end screen (on {r.screen})")
                return
            # Space until the window closes: a press made just before the end screen
            # listened is forgotten by it, and the session would wait for ever.
            deadline = time.monotonic() + 30
            while not ended.is_set() and r.win is not None:
                if time.monotonic() > deadline:
                    problems.append("the end screen did not close on space")
                    return
                time.sleep(0.1)
                kb.press("space")
                wait_for(lambda: ended.is_set() or r.win is None, timeout=1.0)
        except Exception as e:           # a mistake in the script fails the test, no hang
            problems.append(repr(e))
        finally:
            kb.close()
            if problems:                 # end the session rather than hang the test: Escape
                from psychopy import event     # until it has ended (a screen clears the
                while not ended.wait(0.5):     # keys pressed before it listened)
                    event._keyBuffer.append(("escape", 0, 0.0))

    with open_device("sim", DeviceProfile.load(lx.experiment.device)) as dev:
        plays = record_plays(dev)
        thread = threading.Thread(target=participant, daemon=True)
        thread.start()
        try:
            res = run_session(lx, dev, r,
                              SessionOptions(participant="01", data_dir=tmp_path / "data",
                                             max_trials=2))
        finally:
            ended.set()
            thread.join(30)
            assert not problems, problems
    beh = pd.read_csv(res.paths.beh_tsv, sep="\t", dtype=str, keep_default_na=False)
    got = [list(beh[beh["trial"] == str(t)]["answer"]) for t in (1, 2)]
    assert got == expected, (study, audio, got)
    return r, captured, plays, lx, res


def test_a_clip_the_output_plays_late_holds_the_next_one_back():
    """A clip whose length has passed while its output still plays it (the output ran dry
    on a busy computer and plays late) is not over: the next one waits for the output, so
    that two are never heard at once; an output that never finishes holds it MAX_LATE_S."""
    from vtexp.clock import VirtualClock
    from vtexp.responders.speech import MAX_LATE_S, Speech
    clock = VirtualClock()

    class Voice:
        def clip(self, text):
            return Path(f"{text}.wav")

    class LateOutput:
        done_at = {"a": 1.5, "b": float("inf"), "c": 1.0}     # each clip lasts 1 s

        def __init__(self):
            self.started: dict[str, float] = {}

        def duration(self, path):
            return 1.0

        def play(self, path):
            self.started[path.stem] = clock.now()

        def playing(self, path):
            return clock.now() < self.started[path.stem] + self.done_at[path.stem] - 1e-9

    out = LateOutput()
    sp = Speech(Voice(), out, {}, clock=clock)
    sp.say("a", "b", "c")
    while sp.busy():
        clock.sleep(0.01)
    assert out.started["a"] == 0.0
    assert out.started["b"] == pytest.approx(1.5, abs=0.011)
    assert out.started["c"] == pytest.approx(1.5 + 1.0 + MAX_LATE_S, abs=0.011)
    assert [(p.text, round(p.end - p.start, 1)) for p in sp.played] == \
        [("a", 1.5), ("b", 1.0 + MAX_LATE_S), ("c", 1.0)]


@pytest.mark.parametrize("study", STUDIES)
def test_every_question_answered_with_real_keys_on_screen(study, display, tmp_path):
    r, _, _, _, res = _session(study, False, display, tmp_path)
    assert json.loads(res.paths.session_json.read_text())["status"] == "aborted"   # 2 trials


@pytest.mark.parametrize("study", STUDIES)
def test_every_question_answered_with_real_keys_by_ear(study, display, tmp_path):
    r, captured, plays, lx, res = _session(study, True, display, tmp_path)
    sp = r.speech
    said = [p.text for p in sp.played]
    # Every clip is a real espeak-ng recording of its sentence, from the experiment's cache.
    for p in sp.played:
        assert p.path.is_file() and p.path.stat().st_size > 4000
        assert p.path.parent.parts[-2:] == (lx.experiment.name, "en")
    files = [path for event, path, _ in captured.log if event == "play"]
    heard = [p.path for p in sp.played]
    # Played in the order said (the last may still be playing when the session ends).
    assert files[:len(heard)] == heard and len(files) - len(heard) <= 1, (files, heard)
    # How to take part comes first: headphones, the masking noise, the keys.
    assert said[0].startswith("Please put on the headphones") and "rushing noise" in said[1]
    # A spoken prompt precedes every answer, and every answer is said back.
    questions = lx.experiment.asked()
    beh = pd.read_csv(res.paths.beh_tsv, sep="\t", dtype=str, keep_default_na=False)
    pos = 0
    for _, row in beh.iterrows():
        q = next(q for q in questions if q.name == row["question"])
        asked = said.index(q.prompt, pos)
        taken = said.index(sp.phrase("answer_taken", answer=r.spoken_answer(q, row["answer"])),
                           asked)
        pos = taken
    # Nothing is said while a stimulus plays; the masking noise covers every stimulus.
    assert len(plays) == 2
    for t0, t1 in plays:
        for p in sp.played:
            assert p.end <= t0 or p.start >= t1, f"{p.text!r} overlaps a stimulus"
        assert any(a <= t0 and b >= t1 for a, b in sp.noise_on)
    if study == "duration_interval_grid":
        # The spoken prompts of trial 1, from its "ready" to the answer said back.
        start = said.index(sp.phrase("ready"))
        end = said.index(sp.phrase("answer_taken", answer="triangle"))
        listing = "\n".join(f"  {i + 1}. {t}" for i, t in enumerate(said[start:end + 1]))
        print(f"\nspoken in trial 1 of {study}:\n{listing}")
        (OUT / "spoken_trial1.txt").parent.mkdir(parents=True, exist_ok=True)
        (OUT / "spoken_trial1.txt").write_text(listing + "\n")


def _label_boxes(r, screen, name: str):
    """Each label of the screen on show drawn alone: its pixels' bounding box, in height
    units (x right, y up), with the box it must stay in."""
    w, h = r.win.size
    out = []
    for lb, box in screen.all_labels():
        lit = _lit_pixels(r, lb)
        cols, rows = np.flatnonzero(lit.any(axis=0)), np.flatnonzero(lit.any(axis=1))
        assert cols.size, f"{name}: label {lb.text!r} drew nothing"
        left, right = (cols[0] - w / 2) / h, (cols[-1] + 1 - w / 2) / h
        top, bottom = (h / 2 - rows[0]) / h, (h / 2 - rows[-1] - 1) / h
        out.append((lb, box, (left, right, bottom, top)))
    return out


def _lit_pixels(r, lb) -> np.ndarray:
    """The pixels a label lights when drawn alone into the back buffer (rows from the
    top): PIL's grey level ``L`` above 60, as on :meth:`WindowResponder.grab`'s picture,
    read straight from OpenGL (a whole picture per label took most of this test)."""
    import ctypes
    from pyglet import gl
    r._label(lb)
    w, h = r.win.size
    px = np.empty((h, w, 4), np.uint8)
    gl.glReadBuffer(gl.GL_COLOR_ATTACHMENT0 if r.win.useFBO else gl.GL_BACK)
    gl.glPixelStorei(gl.GL_PACK_ALIGNMENT, 1)
    gl.glReadPixels(0, 0, w, h, gl.GL_RGBA, gl.GL_UNSIGNED_BYTE,
                    px.ctypes.data_as(ctypes.POINTER(gl.GLubyte)))
    r.win.clearBuffer()
    px = px[::-1]
    # A pixel's grey level is at most its brightest channel: only where that is above 60
    # is the exact level worked out (the label's few rows and columns, not the screen).
    lit = np.zeros((h, w), bool)
    top = np.maximum(np.maximum(px[..., 0], px[..., 1]), px[..., 2]) > 60
    rows, cols = np.flatnonzero(top.any(axis=1)), np.flatnonzero(top.any(axis=0))
    if rows.size:
        y0, y1, x0, x1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
        rgb = px[y0:y1, x0:x1, :3].astype(np.uint32)
        lit[y0:y1, x0:x1] = (rgb[..., 0] * 19595 + rgb[..., 1] * 38470 + rgb[..., 2] * 7471
                             + 0x8000) >> 16 > 60
    return lit


@pytest.mark.parametrize("size", [(1280, 800), (1920, 1080)])
@pytest.mark.parametrize("scale", [1, 2])
def test_the_layout_never_overlaps_or_cuts_on_screenshots(size, scale, display):
    from vtexp.responders.layout import MIN_TEXT, check
    from vtexp.responders.window import WindowOptions, WindowResponder
    shots = OUT / "layout"
    shots.mkdir(parents=True, exist_ok=True)
    r = WindowResponder(WindowOptions(fullscreen=False, size=size, scale=scale))
    r.open()
    assert tuple(r.win.size) == size
    tol = 2.0 / size[1]                      # two pixels of anti-aliasing
    seen = 0
    try:
        for study in STUDIES:
            lx = load_experiment(ROOT / "experiments" / f"{study}.yaml")
            for q in lx.experiment.asked():
                for practice, answered in ((True, None), (False, q.options[0])):
                    screen = r.question_screen(q, practice=practice, replays_left=q.replays,
                                               answered=answered)
                    assert check(screen, r.aspect) == []
                    r._enter(q.kind, screen, chosen=answered)
                    name = (f"{study}-{q.name}-{size[0]}x{size[1]}-scale{scale}"
                            + ("-practice" if practice else "-answered"))
                    r.capture(shots / f"{name}.png")
                    boxes = _label_boxes(r, screen, name)
                    half = r.aspect / 2
                    for lb, box, (left, right, bottom, top) in boxes:
                        assert lb.height >= MIN_TEXT * scale - 1e-9
                        where = box or lb.box
                        assert left >= max(where.left, -half) - tol and \
                            right <= min(where.right, half) + tol and \
                            bottom >= max(where.bottom, -0.5) - tol and \
                            top <= min(where.top, 0.5) + tol, \
                            f"{name}: {lb.text!r} leaves its box"
                    for i, (a, _, ba) in enumerate(boxes):
                        for b, _, bb in boxes[i + 1:]:
                            apart = (ba[1] <= bb[0] + tol or bb[1] <= ba[0] + tol or
                                     ba[3] <= bb[2] + tol or bb[3] <= ba[2] + tol)
                            assert apart, f"{name}: {a.text!r} overlaps {b.text!r}"
                    seen += 1
    finally:
        r.close()
    assert seen == 2 * 6


def test_a_scale_too_large_for_the_screen_is_said_before_the_first_trial(display):
    from vtexp.errors import SessionError
    from vtexp.responders.window import WindowOptions, WindowResponder
    lx = load_experiment(ROOT / "experiments" / "whirlpool.yaml")
    r = WindowResponder(WindowOptions(fullscreen=False, size=(1280, 800), scale=2.5), lx=lx)
    with pytest.raises(SessionError, match="does not fit a 1280x800 window at scale 2.5"):
        r.open()
    r.close()


def test_the_pause_screen_during_a_device_fault(display, tmp_path):
    from vtexp.errors import DeviceError
    from vtexp.responders.window import WindowOptions, WindowResponder
    lx = load_experiment(ROOT / "experiments" / "duration_interval_grid.yaml")
    r = WindowResponder(WindowOptions(fullscreen=False, size=(1280, 800)), lx=lx)
    shown = []

    def experimenter(error, trial):          # the terminal asks; the window shows the pause
        shown.append(r.screen)
        r.capture(OUT / "screens-issue13" / "paused.png")
        raise DeviceError("stop here")
    calls = [0]

    def failing(self, schedule):
        calls[0] += 1
        raise DeviceError("lost contact with the tactile device (test)")
    r.instructions = lambda text: None
    with open_device("sim", DeviceProfile.load("vest_6x8")) as dev:
        dev._play = lambda schedule: failing(dev, schedule)
        with pytest.raises(DeviceError):
            run_session(lx, dev, r,
                        SessionOptions(participant="01", data_dir=tmp_path / "d",
                                       on_device_error=experimenter))
    assert shown == ["paused"]
    px = np.asarray(__import__("PIL.Image", fromlist=["Image"]).open(
        OUT / "screens-issue13" / "paused.png").convert("L"))
    assert (px > 200).mean() > 0.002
