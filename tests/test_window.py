"""The participant's PsychoPy window, in a real window on a virtual X server (Xvfb).

A scripted participant stands in for the person: PsychoPy's ``event.getKeys`` and
``Mouse.getPressed``/``getPos`` are replaced by its script, so every frame still goes
through the responder's real drawing, flips, hit-testing and clock. Clicks aim at the
centre of the button the responder has on screen. Each screen type is saved once to
``test-output/screens/<screen>.png`` and checked to be non-blank.
"""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import MINIMAL, ROOT, write_experiment, session_record
from xkeyboard import XKeyboard

if importlib.util.find_spec("psychopy") is None:
    pytest.skip("PsychoPy is not installed (the 'gui' extra: pip install -e '.[gui]'; "
                "make test installs it)", allow_module_level=True)

from vtexp.devices import open_device                    # noqa: E402
from vtexp.errors import InputError, SessionAborted     # noqa: E402
from vtexp.experiment import load_experiment            # noqa: E402
from vtexp.model import DeviceProfile                   # noqa: E402
from vtexp.session import SessionOptions, run_session   # noqa: E402

SCREENS = ROOT / "test-output" / "screens"

# A real PsychoPy window on Xvfb, answered with real key presses and clicks: real time is
# its subject.
pytestmark = pytest.mark.realtime


@pytest.fixture(scope="module", autouse=True)
def _display(xvfb):
    """The virtual X server of conftest.py, for every test here."""
    return xvfb


class Participant:
    """Plays a script of (screen, action) steps into the window's input.

    Actions: ``("key", name)``, ``("click", value)`` (the button with that value),
    ``("click_anywhere",)``. A step waits for its screen; the "ready" screen passes by
    itself; any other screen than the step's fails the test.
    """

    def __init__(self, steps, shots=SCREENS):
        self.steps = list(steps)
        self.shots = shots
        self.responder = None
        self.seen: list[str] = []
        self.pressed = False
        self.pos = (0.9, 0.9)
        self.polls = 0

    def install(self, monkeypatch, responder):
        from psychopy import event
        self.responder = responder
        monkeypatch.setattr(event, "getKeys", self.get_keys)
        monkeypatch.setattr(event.Mouse, "getPressed", lambda m, getTime=False: [
            int(self.pressed), 0, 0])
        monkeypatch.setattr(event.Mouse, "getPos", lambda m: np.array(self.pos))
        return self

    def get_keys(self, keyList=None, modifiers=False, timeStamped=False):
        r = self.responder
        self.polls += 1
        assert self.polls < 5000, f"the script is stuck at {self.steps[:1]} on {r.screen}"
        if not self.seen or self.seen[-1] != r.screen:
            self.seen.append(r.screen)
        again = next((b for b in r.buttons if b.value == "again"), None)
        name = r.screen if r.screen != "choice" or again is None or again.enabled \
            else "choice_no_replays_left"
        if self.shots and not (self.shots / f"{name}.png").exists():
            r.capture(self.shots / f"{name}.png")
        if self.pressed:                    # release the button for a frame
            self.pressed = False
            return []
        if not self.steps or r.screen == "ready" and self.steps[0][0] != "ready":
            return []
        if keyList is not None and (self.steps[0][1] != "key" or self.steps[0][2] not in keyList):
            return []               # a poll for some keys only (the abort key, by the device)
        screen, action, *arg = self.steps[0]
        assert screen == r.screen, f"expected the {screen} screen, the window shows {r.screen}"
        self.steps.pop(0)
        t = timeStamped.getTime() if timeStamped else None
        if action == "key":
            return [(arg[0], t)] if timeStamped else [arg[0]]
        if action == "click":
            b = next(b for b in r.buttons if b.value == arg[0])
            self.pos, self.pressed = (b.x, b.y), True
        elif action == "click_anywhere":
            self.pos, self.pressed = (0.3, -0.2), True
        return []


@pytest.fixture(scope="module", autouse=True)
def fresh_screens():
    shutil.rmtree(SCREENS, ignore_errors=True)
    SCREENS.mkdir(parents=True)


def assert_not_blank(png: Path):
    from PIL import Image
    px = np.asarray(Image.open(png).convert("L"), dtype=float)
    assert px.std() > 10, f"{png} looks blank (pixel sd {px.std():.1f})"
    assert (px > 200).mean() > 0.002, f"{png} has almost no bright (text) pixels"


def responder(**opts):
    from vtexp.responders.window import WindowOptions, WindowResponder
    return WindowResponder(WindowOptions(fullscreen=False, size=(1024, 768), **opts))


def experiment(tmp_path, replays=0, break_every=None):
    text = MINIMAL + (f"  replays: {replays}\n" if replays else "")
    if break_every:
        text = text.replace("  iti_ms: 0\n", f"  iti_ms: 0\n  break_every: {break_every}\n")
    return load_experiment(write_experiment(tmp_path, text))


def run(lx, tmp_path, resp):
    with open_device("sim", DeviceProfile.load(lx.experiment.device)) as dev:
        res = run_session(lx, dev, resp,
                          SessionOptions(participant="01", data_dir=tmp_path / "data"))
    return res, dev


def logged(res):
    beh = next(res.paths.dir.glob("*_beh.tsv"))
    return (pd.read_csv(beh, sep="\t", dtype=str, keep_default_na=False),
            json.loads(res.paths.session_json.read_text()))


def test_a_session_answered_with_keys_and_clicks_is_logged(tmp_path, monkeypatch):
    lx = experiment(tmp_path, break_every=2)
    r = responder()
    p = Participant([("instructions", "key", "space"),
                     ("choice", "key", "1"), ("choice", "click", "circle"),
                     ("break", "click_anywhere"),
                     ("choice", "key", "num_2"), ("choice", "click", "square"),
                     ("end", "key", "space")]).install(monkeypatch, r)
    res, dev = run(lx, tmp_path, r)
    beh, meta = logged(res)
    assert meta["status"] == "completed" and meta["responder"].startswith("window")
    assert list(beh["answer"]) == ["square", "circle", "circle", "square"]
    rts = beh["rt_s"].astype(float)
    assert (rts >= 0).all() and beh["replays"].eq("0").all()
    assert p.seen == ["instructions", "ready", "choice", "ready", "choice", "break",
                      "ready", "choice", "ready", "choice", "end"]
    assert r.win is None                     # the end screen closed the window
    for png in SCREENS.glob("*.png"):
        assert_not_blank(png)


def test_replays_are_played_counted_and_stop_when_none_are_left(tmp_path, monkeypatch):
    lx = experiment(tmp_path, replays=2)
    r = responder()
    Participant([("instructions", "click_anywhere"),
                 ("choice", "click", "again"), ("choice", "key", "r"),
                 ("choice", "click", "again"),       # greyed out now: nothing happens
                 ("choice", "key", "r"),             # neither does its key
                 ("choice", "key", "2"),
                 ("choice", "click", "again"), ("choice", "key", "1"),
                 ("choice", "key", "1"), ("choice", "key", "2"),
                 ("end", "click_anywhere")]).install(monkeypatch, r)
    res, dev = run(lx, tmp_path, r)
    beh, _ = logged(res)
    assert list(beh["replays"]) == ["2", "1", "0", "0"]
    assert list(beh["answer"]) == ["circle", "square", "square", "circle"]
    assert len(dev.plays) == 4 + 3          # every replay was felt
    events = pd.read_csv(next(res.paths.dir.glob("*_events.tsv")), sep="\t")
    assert sorted(events[events["trial"] == 1]["play"].unique()) == [0, 1, 2]


def test_escape_aborts_at_once_and_keeps_the_completed_trials(tmp_path, monkeypatch):
    lx = experiment(tmp_path)
    r = responder()
    Participant([("instructions", "key", "space"), ("choice", "key", "1"),
                 ("choice", "key", "escape"), ("choice", "key", "2")]).install(monkeypatch, r)
    with pytest.raises(SessionAborted, match="escape"):
        run(lx, tmp_path, r)
    d = tmp_path / "data" / "mini" / "sub-01" / "ses-1"
    meta = json.loads(session_record(d).read_text())
    beh = pd.read_csv(next(d.glob("beh/*_beh.tsv")), sep="\t", dtype=str)
    assert meta["status"] == "aborted" and "escape" in meta["reason"]
    assert list(beh["answer"]) == ["square"]
    assert r.win is None                     # the window is gone with the session


def test_escape_pressed_between_two_trials_aborts_at_the_next_screen(tmp_path, monkeypatch):
    """An abort key pressed during the inter-trial interval is not forgotten with the other
    pending input when the next screen comes up: it aborts there, before the stimulus."""
    from psychopy import event

    from vtexp.devices.sim import SimDevice
    lx = experiment(tmp_path)
    r = responder()
    script = Participant([("instructions", "key", "space"), ("choice", "key", "1")])
    script.install(monkeypatch, r)
    pending: list[str] = []                  # keys pressed while no screen was reading
    scripted = script.get_keys

    def get_keys(keyList=None, modifiers=False, timeStamped=False):
        hit = [k for k in pending if keyList is None or k in keyList]
        if hit:
            pending[:] = [k for k in pending if k not in hit]
            return [(k, 0.0) for k in hit] if timeStamped else hit
        return scripted(keyList=keyList, modifiers=modifiers, timeStamped=timeStamped)
    monkeypatch.setattr(event, "getKeys", get_keys)
    monkeypatch.setattr(event, "clearEvents", lambda *a, **k: pending.clear())
    wait = SimDevice.wait_ms

    def iti(self, ms):                       # the participant presses escape in the pause
        pending.extend(["x", "escape"])
        wait(self, ms)
    monkeypatch.setattr(SimDevice, "wait_ms", iti)
    with pytest.raises(SessionAborted, match="escape"):
        run(lx, tmp_path, r)
    d = tmp_path / "data" / "mini" / "sub-01" / "ses-1"
    meta = json.loads(session_record(d).read_text())
    events = pd.read_csv(next(d.glob("beh/*_events.tsv")), sep="\t", dtype=str)
    assert meta["status"] == "aborted" and meta["n_trials_logged"] == 1
    assert set(events["trial"]) == {"1"}         # trial 2's stimulus never played
    assert r.win is None


def wait_for(cond, timeout=20.0) -> bool:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.005)
    return True


@pytest.mark.parametrize("device", ["sim:realtime", "emulator"])
def test_escape_during_a_stimulus_stops_it_with_all_off_at_once(tmp_path, xvfb, device):
    """A real Escape key press, 0.3 s into the second of two stimuli of about 1 s."""
    import threading

    from vtexp.devices import wire
    lx = load_experiment(write_experiment(tmp_path, MINIMAL.replace(
        "{duration_ms: 200, soa_ms: 200}", "{duration_ms: 60, soa_ms: 60}")))
    profile = DeviceProfile.load(lx.experiment.device)
    seen: dict[str, float] = {}

    def trace(direction, item):             # the emulated device receiving ALL_OFF
        if direction == "to_device" and isinstance(item, wire.AllOff) and "key" in seen:
            seen.setdefault("all_off", time.perf_counter())

    # (the emulator answers from a thread of this process, beside the window's drawing: a
    # longer heartbeat than the default keeps a loaded machine from looking like a pulled
    # cable; what is tested is the key, not the link)
    dev = open_device(device, profile, **({"emulator_options": {"trace": trace},
                                           "heartbeat_ms": 500}
                                          if device == "emulator" else {}))
    plays: list[tuple[float, float]] = []        # (perf_counter at start, duration_ms)
    play = dev.play

    def timed_play(schedule, **kw):
        plays.append((time.perf_counter(), schedule.duration_ms))
        return play(schedule, **kw)
    dev.play = timed_play
    if device.startswith("sim"):
        all_off = dev._all_off

        def timed_all_off():                    # the sim turning every actuator off
            if "key" in seen:
                seen.setdefault("all_off", time.perf_counter())
            all_off()
        dev._all_off = timed_all_off

    r = responder()
    kb = XKeyboard(xvfb)

    def on_at_key() -> bool:
        if device.startswith("sim"):
            return bool(dev.state.max() > 0)
        return not dev.emulator.all_outputs_off()

    def participant():
        try:
            steps = [(lambda: r.win is not None and r.screen == "instructions", "space"),
                     (lambda: r.screen == "choice", "1"),           # trial 1: square
                     (lambda: len(plays) == 2, "Escape")]           # during trial 2's stimulus
            for i, (ready, key) in enumerate(steps):
                if not wait_for(ready):
                    # The keys do not arrive: end the session rather than hang the test.
                    from psychopy import event
                    seen["stuck"] = i
                    event._keyBuffer.append(("escape", 0, 0.0))
                    return
                if i == 0:
                    kb.focus(r.win)
                if key == "Escape":
                    time.sleep(0.3)             # well inside the second stimulus
                    seen["on"] = on_at_key()
                    seen["key"] = kb.press(key)
                else:
                    time.sleep(0.1)             # after the screen has forgotten older input
                    kb.press(key)
        finally:
            kb.close()

    thread = threading.Thread(target=participant, daemon=True)
    thread.start()
    with dev:
        with pytest.raises(SessionAborted) as aborted:
            run_session(lx, dev, r, SessionOptions(participant="01", data_dir=tmp_path / "data"))
        ended = time.perf_counter()
        off = (float(dev.state.max()) == 0.0 if device.startswith("sim")
               else dev.emulator.all_outputs_off())
        by_all_off = device.startswith("sim") or any(
            a.cause == "all_off" for a in dev.emulator.actuations())
    thread.join(5)
    assert "stuck" not in seen, f"key press {seen.get('stuck')} never reached the window"
    assert "escape key was pressed" in str(aborted.value) and \
        "during the stimulus" in str(aborted.value)
    assert len(plays) == 2 and seen["on"], "Escape was not pressed while a stimulus played"
    started, duration_ms = plays[1]
    assert ended - started < duration_ms / 1000.0      # stopped, not played to its end
    assert off and by_all_off
    assert seen["key"] < seen["all_off"]
    print(f"\n{device}: Escape -> ALL_OFF at the device "
          f"{(seen['all_off'] - seen['key']) * 1000:.1f} ms")
    if device.startswith("sim"):
        kinds = [e.kind for e in dev.history]
        assert kinds[kinds.index("stopped") + 1] == "all_off" and kinds.count("play") == 1
    d = tmp_path / "data" / "mini" / "sub-01" / "ses-1"
    meta = json.loads(session_record(d).read_text())
    beh = pd.read_csv(next(d.glob("beh/*_beh.tsv")), sep="\t", dtype=str)
    events = pd.read_csv(next(d.glob("beh/*_events.tsv")), sep="\t")
    assert meta["status"] == "aborted" and "during the stimulus" in meta["reason"]
    assert list(beh["trial"]) == ["1"] and list(beh["answer"]) == ["square"]
    assert set(events["trial"]) == {1}          # the stopped stimulus left no trace
    assert r.win is None                        # the window is gone with the session


def test_the_experimenter_can_choose_the_abort_key(tmp_path, monkeypatch):
    r = responder(abort_key="q")
    Participant([("instructions", "key", "escape"),      # not the abort key now
                 ("instructions", "key", "q")], shots=None).install(monkeypatch, r)
    with pytest.raises(SessionAborted, match="q key"):
        r.instructions("Page one")
    r.close()


def test_instruction_pages_and_the_break_screen(monkeypatch):
    r = responder()
    p = Participant([("instructions", "key", "space"), ("instructions", "click_anywhere"),
                     ("break", "key", "return")]).install(monkeypatch, r)
    r.instructions("You will feel a shape on your back.\n---\nThen choose what it was.")
    r.pause("Take a break. Have some water.")
    assert p.seen == ["instructions", "break"] and not p.steps
    r.close()
    assert_not_blank(SCREENS / "break.png")


def test_rating_scale_with_the_papers_labels(monkeypatch):
    r = responder()
    Participant([("rating", "key", "5"),                  # not on the scale: ignored
                 ("rating", "key", "3"), ("rating", "click", "4")]).install(monkeypatch, r)
    labels = {0: "no whirlpool felt", 4: "a clear whirlpool"}
    first = r.ask_rating("How clearly did you feel a whirlpool?", range(0, 5), labels)
    second = r.ask_rating("How clearly did you feel a whirlpool?", range(0, 5), labels)
    assert (first.answer, second.answer) == ("3", "4") and first.rt_s >= 0
    r.close()


def test_rating_from_minus_two_to_plus_two_takes_the_number_pressed(monkeypatch, tmp_path):
    """The key is the number said and shown: 1 is +1, minus then 1 is -1 (not the first
    button from the left, as before issue 13)."""
    r = responder()
    Participant([("rating", "key", "1"), ("rating", "key", "minus"), ("rating", "key", "1"),
                 ("rating", "key", "num_subtract"), ("rating", "key", "num_2"),
                 ("rating", "click", "2")], shots=tmp_path).install(monkeypatch, r)
    labels = {-2: "surely a circle", 2: "surely a rectangle"}
    got = [r.ask_rating("Circle or rectangle?", range(-2, 3), labels).answer for _ in range(4)]
    assert got == ["1", "-1", "-2", "2"]
    shutil.copy(tmp_path / "rating.png", SCREENS / "rating_pm2.png")
    r.close()


def test_number_entry_by_typing_and_by_buttons(monkeypatch):
    r = responder()
    Participant([("number", "key", "return"),            # nothing typed: not an answer
                 ("number", "key", "1"), ("number", "key", "2"), ("number", "key", "backspace"),
                 ("number", "key", "3"), ("number", "key", "return"),
                 ("number", "click", "plus"), ("number", "click", "plus"),
                 ("number", "click", "plus"), ("number", "click", "minus"),
                 ("number", "click", "ok"),
                 ("number", "key", "9"), ("number", "key", "9"),   # 99 > 20: the 2nd 9 is refused
                 ("number", "key", "num_enter")]).install(monkeypatch, r)
    turns = [r.ask_number("How many turns did the whirlpool make?", 0, 20).answer
             for _ in range(3)]
    assert turns == ["13", "1", "9"]
    r.close()


def test_questions_are_dispatched_by_kind(monkeypatch):
    from types import SimpleNamespace
    r = responder()
    Participant([("rating", "key", "2"), ("number", "key", "4"), ("number", "key", "return")],
                shots=None).install(monkeypatch, r)
    rating = SimpleNamespace(kind="rating", prompt="How strong?", scale=[0, 1, 2, 3, 4],
                             labels={0: "none", 4: "strong"}, replays=0)
    number = SimpleNamespace(kind="number", prompt="How many?", minimum=0, maximum=20)
    assert r.ask(rating, None, None).answer == "2"
    assert r.ask(number, None, None).answer == "4"
    with pytest.raises(Exception, match="cannot ask a sketch question"):
        r.ask(SimpleNamespace(kind="sketch"), None, None)
    r.close()


def test_window_specs_on_the_command_line():
    from vtexp.responders import make_responder
    from vtexp.responders.window import WindowOptions
    assert WindowOptions.parse("") == WindowOptions()
    o = WindowOptions.parse("windowed,screen=1,size=1024x768,abort=q")
    assert (o.fullscreen, o.screen, o.size, o.abort_key) == (False, 1, (1024, 768), "q")
    for bad in ("windowd", "size=10x10", "screen=one"):
        with pytest.raises(InputError, match="window"):
            make_responder(f"window:{bad}", "01", 1)


def run_python(code: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, timeout=120, cwd=ROOT)


@pytest.mark.process
def test_vtexp_imports_without_psychopy_and_says_how_to_install_it():
    hide = "import sys; sys.modules['psychopy'] = None\n"
    r = run_python(hide + "import vtexp, vtexp.cli, vtexp.session, vtexp.responders\n"
                          "print('ok')")
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr
    r = run_python(hide + "from vtexp.cli import main\n"
                          f"sys.exit(main(['run', {str(ROOT / 'experiments' / 'duration_interval_grid.yaml')!r}, "
                          "'-p', '01', '--responder', 'window', '--data', 'unused']))")
    assert r.returncode == 2, r.stderr
    assert "pip install -e '.[gui]'" in r.stderr and "opencv-contrib-python-headless" in r.stderr
    assert "Traceback" not in r.stderr and not (ROOT / "unused").exists()


@pytest.mark.process
def test_importing_psychopy_leaves_home_and_the_environment_alone(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT), HOME=str(tmp_path))
    env.pop("PYTHONUSERBASE", None)
    env.pop("PSYCHOPYNOPACKAGES", None)
    code = ("import os, json; from vtexp.responders.window import import_psychopy\n"
            "import_psychopy()\n"
            "print(json.dumps({k: os.environ.get(k) for k in ('HOME', 'PYTHONUSERBASE')}))")
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                       timeout=120, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    seen = json.loads(r.stdout.strip().splitlines()[-1])
    assert seen == {"HOME": str(tmp_path), "PYTHONUSERBASE": None}
    assert not (tmp_path / ".psychopy3").exists()


@pytest.mark.process
def test_without_a_display_the_window_says_so_in_one_message(tmp_path):
    # a process of its own: pyglet connects to a display once per process, and this
    # process has the window tests' one
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    env.pop("DISPLAY", None)
    r = subprocess.run([sys.executable, "-m", "vtexp", "run", str(write_experiment(
        tmp_path, MINIMAL)), "-p", "01", "--responder", "window", "--data", str(tmp_path / "d")],
        env=env, capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert r.returncode == 2 and "DISPLAY" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "d").exists()


def test_every_screen_type_was_saved_and_none_is_blank():
    """Runs last: the tests above saved each screen the first time it was shown."""
    expected = {"instructions", "ready", "choice", "choice_no_replays_left", "break", "end",
                "rating", "rating_pm2", "number"}
    saved = {p.stem for p in SCREENS.glob("*.png")}
    assert expected <= saved, f"screens never shown: {sorted(expected - saved)}"
    for png in sorted(SCREENS.glob("*.png")):
        assert_not_blank(png)


def test_the_schemas_rating_and_number_questions_reach_their_screens(monkeypatch):
    from vtexp.experiment import NumberQuestion, RatingQuestion
    r = responder()
    Participant([("rating", "key", "minus"), ("rating", "key", "2"), ("number", "key", "7"),
                 ("number", "key", "return")]).install(monkeypatch, r)
    rating = RatingQuestion(kind="rating", prompt="Circle or rectangle?", low=-2, high=2,
                            labels={-2: "rectangle", 2: "circle"})
    number = NumberQuestion(kind="number", prompt="How many turns?", maximum=20)
    assert r.ask(rating, None, None).answer == "-2"
    assert r.ask(number, None, None).answer == "7"
    r.close()
