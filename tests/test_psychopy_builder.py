"""The psychopy-vtexp plugin: the example Builder experiment, compiled and run.

``examples/psychopy/tactile_shapes.psyexp`` (a fixation, a tactile shape, a keyboard
answer, 8 trials from ``conditions.csv``) is compiled as Builder compiles it: the plugin
installed (``pip install``, into a folder of the test's), PsychoPy's plugins activated,
then ``compileScript``, in one process. The compiled script runs as a process of its own
on Xvfb, answered with real key presses (XTEST). Its array is the emulated firmware
behind a pseudo-terminal, as ``--device emulator`` starts it, but started here, in the
test's process, and reached by the script as ``serial:PTY``: what the emulated device
drove is then read from outside the process under test, which cannot report it wrongly
or forget to. The compiled script's device is all that is changed.

The runtime (``vtexp.builder``) is also tested in this process: the ``emulator`` and
``sim`` devices, a stop mid-play, and the one-line messages of a user's mistakes.
"""

from __future__ import annotations

import ast
import csv
import gc
import importlib.util
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from conftest import ROOT

if importlib.util.find_spec("psychopy") is None:
    pytest.skip("PsychoPy is not installed (the 'gui' extra: pip install -e '.[gui]'; "
                "make test installs it)", allow_module_level=True)

from vtexp import builder                                # noqa: E402
from vtexp.devices import wire                          # noqa: E402
from vtexp.devices.emulator import PtyEmulator          # noqa: E402
from vtexp.model import DeviceProfile                   # noqa: E402

EXAMPLE = ROOT / "examples" / "psychopy"
PLUGIN = ROOT / "plugins" / "psychopy-vtexp"
PROFILE = "vest_6x8"

# A window on Xvfb answered with real key presses, a device on a pty: real time.
pytestmark = pytest.mark.realtime


# --------------------------------------------------------------------------- the plugin

@pytest.fixture(scope="module")
def plugin_site(tmp_path_factory) -> Path:
    """The plugin installed with pip (no dependencies: vtexp and PsychoPy are here)."""
    tmp = tmp_path_factory.mktemp("plugin")
    src = tmp / "src"
    shutil.copytree(PLUGIN, src, ignore=shutil.ignore_patterns("build", "*.egg-info",
                                                                "__pycache__"))
    site = tmp / "site"
    r = subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps",
                        "--no-build-isolation", "--no-input", "--target", str(site), str(src)],
                       capture_output=True, text=True, timeout=180)
    assert r.returncode == 0, r.stderr[-2000:]
    return site


def _env(site: Path, home: Path, display: str | None = None) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("PSYCHOPY")}
    env.update(PYTHONPATH=os.pathsep.join([str(site), str(ROOT)]), HOME=str(home),
               OPENBLAS_NUM_THREADS="1")
    if display:
        env["DISPLAY"] = display
    return env


COMPILE = """
import sys
from psychopy import plugins
plugins.activatePlugins()            # as Builder does when it starts
print("LISTED", sorted(plugins.listPlugins("all")))
print("LOADED", plugins.isPluginLoaded("psychopy-vtexp"))
from psychopy.experiment import getAllComponents
print("COMPONENT", "TactileStimulusComponent" in getAllComponents())
print("ICON", getAllComponents()["TactileStimulusComponent"].iconFile)
from psychopy.scripts.psyexpCompile import compileScript
compileScript(sys.argv[1], None, sys.argv[2])
"""


@pytest.fixture(scope="module")
def compiled(plugin_site, tmp_path_factory) -> Path:
    """The example compiled by PsychoPy's compiler with the plugin active, beside its
    conditions file."""
    d = tmp_path_factory.mktemp("example")
    for f in ("tactile_shapes.psyexp", "conditions.csv"):
        shutil.copy(EXAMPLE / f, d / f)
    r = subprocess.run([sys.executable, "-c", COMPILE, str(d / "tactile_shapes.psyexp"),
                        str(d / "tactile_shapes.py")], capture_output=True, text=True,
                       env=_env(plugin_site, d), timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    (d / "compile.out").write_text(r.stdout)
    script = (d / "tactile_shapes.py").read_text(encoding="utf-8-sig")
    assert "Unknown component" not in r.stderr + script
    assert "vtexp_builder.TactileStimulus(" in script and "prepare_rows(" in script
    return d / "tactile_shapes.py"


def test_psychopy_finds_the_plugin_through_its_entry_point(compiled):
    """PsychoPy's own scan of installed distributions (``activatePlugins``, as Builder
    calls it at start) lists the plugin, loads it and offers its component."""
    said = {ln.split(" ", 1)[0]: ln.split(" ", 1)[1]
            for ln in (compiled.parent / "compile.out").read_text().splitlines()
            if ln.startswith(("LISTED ", "LOADED ", "COMPONENT "))}
    assert "psychopy-vtexp" in ast.literal_eval(said["LISTED"])
    assert said["LOADED"] == "True"
    assert said["COMPONENT"] == "True"


def test_builder_finds_the_components_icon_in_every_theme(compiled):
    """Builder (psychopy-app 2026.2) looks for ``iconFile``'s stem in a folder per theme
    beside it, and fails to start when a component has none there."""
    out = (compiled.parent / "compile.out").read_text().splitlines()
    icon = Path(next(ln.split(" ", 1)[1] for ln in out if ln.startswith("ICON ")))
    for theme in ("classic", "dark", "light"):
        assert sorted(p.name for p in (icon.parent / theme).glob(f"{icon.stem}*.png")) == [
            f"{icon.stem}.png", f"{icon.stem}@2x.png"], theme


# --------------------------------------------------------------------------- a run

class Keys:
    """Real key presses sent to the X server (XTEST), held as a finger holds them."""

    def __init__(self, display_name: str):
        pytest.importorskip("Xlib", reason="python-xlib (installed with PsychoPy on Linux)")
        from Xlib import XK, X, display
        from Xlib.ext import xtest
        self.X, self.XK, self.xtest = X, XK, xtest
        self.d = display.Display(display_name)

    def focus_window(self, title: str = "PsychoPy") -> bool:
        X = self.X
        for w in self.d.screen().root.query_tree().children:
            try:
                if w.get_wm_name() == title and w.get_attributes().map_state == X.IsViewable:
                    w.set_input_focus(X.RevertToParent, X.CurrentTime)
                    self.d.sync()
                    return True
            except Exception:                       # noqa: BLE001 - a window gone meanwhile
                continue
        return False

    def press(self, keysym: str, hold_s: float = 0.1) -> float:
        code = self.d.keysym_to_keycode(self.XK.string_to_keysym(keysym))
        t = time.monotonic()
        self.xtest.fake_input(self.d, self.X.KeyPress, code)
        self.d.sync()
        time.sleep(hold_s)
        self.xtest.fake_input(self.d, self.X.KeyRelease, code)
        self.d.sync()
        return t

    def close(self) -> None:
        self.d.close()


def _plays(emu) -> list[int]:
    """The play ids the emulated device started, in order."""
    ids: list[int] = []
    for a in emu.actuations():
        if a.cause == "play" and a.play_id not in ids:
            ids.append(a.play_id)
    return ids


def _wait(cond, proc, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while not cond():
        if proc.poll() is not None or time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


#: Put after the script's PsychoPy imports: every flip waits for the next 1/60 s, as a
#: flip on a 60 Hz lab monitor waits for its refresh. Xvfb's flip returns at once, and the
#: script would draw as fast as Mesa's software OpenGL can, a core busy drawing frames that
#: do not change (as tests/conftest.py's TEST_DISPLAY_HZ, for vtexp's own window).
PACED_FLIP = """
import time as _time
_flip, _next_flip = visual.Window.flip, [0.0]


def _flip_at_60_hz(self, *args, **kwargs):
    now = _time.perf_counter()
    if now < _next_flip[0]:
        _time.sleep(_next_flip[0] - now)
    _next_flip[0] = max(now, _next_flip[0]) + 1 / 60
    return _flip(self, *args, **kwargs)


visual.Window.flip = _flip_at_60_hz
"""


def _sixty_hz(script: str) -> str:
    """Xvfb has no refresh to measure, nor to wait for: the window's frame rate is taken
    as 60 Hz, a lab monitor's, instead of measured (which takes about 4 s), and each flip
    waits for it (PACED_FLIP)."""
    anchor = ("from psychopy import sound, gui, visual, core, data, event, logging, clock, "
              "colors, layout, hardware\n")
    assert script.count(anchor) == 1
    script = script.replace(anchor, anchor + PACED_FLIP)
    return script.replace("win.getActualFrameRate(", "(lambda **_: 60.0)(")


#: The link the compiled script gets to the device served here: a heartbeat of 1 s, so
#: 600 ms of silence before the device counts as lost (the default 200 ms, or 500 ms,
#: lost it on a busy machine; the link is not what these tests are about).
LINK = "heartbeat_ms=1000"


def _serve(emu) -> str:
    """Start the emulated device in this process, for a script in another. A full garbage
    collection of this test process holds Python's lock for long enough that the device
    falls silent past the link's limit, so what the tests before made is left out of
    collections too (``gc.freeze``, as tests/conftest.py does after collection)."""
    gc.collect()
    gc.freeze()
    return emu.start()


def _unserve(emu) -> None:
    emu.stop()


def _run(compiled: Path, plugin_site: Path, display: str, tmp_path: Path, *,
         escape_in_trial: int | None = None):
    """The compiled example against an emulated device served here; answers every trial
    with key 1 as soon as the play has ended (or Escape 0.1 s into trial
    ``escape_in_trial``'s play, the pulses then 150 ms long). Returns the emulator
    (stopped), the process's result, the data file's rows and the time Escape was
    pressed."""
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    for f in ("tactile_shapes.psyexp", "conditions.csv"):
        shutil.copy(compiled.parent / f, run_dir / f)
    emu = PtyEmulator.for_profile(DeviceProfile.load(PROFILE))
    _record_onsets_sent(emu)
    port = _serve(emu)
    script = compiled.read_text(encoding="utf-8-sig")
    # the one change: the device, the emulated array served here (with LINK), named twice:
    # where the array is added to the device manager and where it opens
    assert script.count("device='emulator'") == 2
    script = script.replace("device='emulator'", f"device='serial:{port},{LINK}'")
    # Xvfb has no refresh to measure: 60 Hz, as a lab's monitor (saves ~4 s a run)
    script = _sixty_hz(script)
    if escape_in_trial is not None:
        # pulses of 150 ms, one after another, not 40: Escape, pressed 0.1 s into a play,
        # must be seen by the script while the play lasts (a 12-pulse circle lasts 0.48 s
        # at 40 ms: on a busy machine the play ended first)
        assert script.count("duration_ms=40, soa_ms=40") == 2  # checked at start, played
        script = script.replace("duration_ms=40, soa_ms=40", "duration_ms=150, soa_ms=150")
    (run_dir / "tactile_shapes.py").write_text(script, encoding="utf-8")
    keys = Keys(display)
    proc = subprocess.Popen([sys.executable, str(run_dir / "tactile_shapes.py")], cwd=run_dir,
                            env=_env(plugin_site, tmp_path, display), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    escaped_at = None
    try:
        if not _wait(lambda: keys.focus_window(), proc, 60):
            proc.kill()
            pytest.fail("no PsychoPy window appeared: " + proc.communicate()[1][-3000:])
        for trial in range(1, 9):
            if not _wait(lambda: len(_plays(emu)) >= trial, proc, 30):
                proc.kill()
                pytest.fail(f"trial {trial} not played: " + proc.communicate()[1][-3000:])
            if trial == escape_in_trial:
                time.sleep(0.1)
                escaped_at = keys.press("Escape")
                break
            # the play ended: the answer's keyboard starts at the next frame; press until the
            # next trial's play starts (or the experiment ends)
            assert _wait(lambda: emu.firmware.play is None, proc, 10)
            while proc.poll() is None and len(_plays(emu)) == trial:
                keys.press("1")
                time.sleep(0.1)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        keys.close()
        time.sleep(0.05)
        _unserve(emu)
    data = sorted((run_dir / "data").glob("*.csv"))
    assert len(data) == 1, (out, err[-3000:])
    with open(data[0], encoding="utf-8-sig", newline="") as f:
        rows = list(csv.DictReader(f))
    return emu, proc.returncode, (out, err), rows, escaped_at


def _record_onsets_sent(emu) -> None:
    """``emu.onsets_sent[play_id][pulse]``: the device time (us) of each pulse's start as
    the emulated firmware sends it in its ONSET events."""
    emu.onsets_sent = {}
    firmware = emu.firmware
    send = firmware._send

    def _send(msg):
        if isinstance(msg, wire.Onset):
            play = emu.onsets_sent.setdefault(msg.play_id, {})
            play.update({msg.first + i: msg.t_us for i in range(msg.count)})
        return send(msg)
    firmware._send = _send


def _on_actuations(emu, play_id: int) -> list:
    return [a for a in emu.actuations()
            if a.cause == "play" and a.play_id == play_id and not a.setting.is_off]


def test_the_example_runs_and_saves_every_onset_on_psychopys_clock(
        compiled, plugin_site, xvfb, tmp_path):
    t0 = time.monotonic()
    emu, rc, (out, err), rows, _ = _run(compiled, plugin_site, xvfb, tmp_path)
    wall = time.monotonic() - t0
    assert rc == 0, err[-3000:]
    assert "Traceback" not in err
    assert len(rows) == 8
    plays = _plays(emu)
    assert len(plays) == 8                          # one play per trial, nothing more
    for row, play_id in zip(rows, plays, strict=True):
        on = _on_actuations(emu, play_id)
        onsets = ast.literal_eval(row["tactile.onsets"])
        assert row["tactile.completed"] == "True"
        assert int(row["tactile.pulses_played"]) == int(row["tactile.pulses_scheduled"])
        # every pulse the device played is in the data file, in the order played
        assert len(onsets) == len(on) == int(row["tactile.pulses_played"]) > 0
        assert ast.literal_eval(row["tactile.actuators"]) == [
            f"{a.index // 6},{a.index % 6}" for a in on]
        # the onsets are the device's: the times the emulated firmware sent in its ONSET
        # events (seen here, on the device's side of the wire), their spacing kept to the
        # data file's microsecond (the emulator keeps real time, so how long after its
        # output change a pulse is stamped depends on the computer's load: that is the
        # device's report, which the data file must hold, whatever it says)
        reported = ast.literal_eval(row["tactile.device_onsets_ms"])
        sent = emu.onsets_sent[play_id]
        assert sorted(sent) == list(range(len(reported)))
        for k in range(1, len(reported)):
            spacing_ms = (reported[k] - reported[0])
            assert abs((onsets[k] - onsets[0]) - spacing_ms / 1000.0) < 2.5e-6
            assert abs(spacing_ms - (sent[k] - sent[0]) / 1000.0) < 2.5e-3
        # on PsychoPy's clock: after the flip that started the component, before it stopped
        started, stopped = float(row["tactile.started"]), float(row["tactile.stopped"])
        assert started - 0.002 <= onsets[0] and onsets[-1] <= stopped
        assert row["answer.keys"] == "1"
    # every actuator off at the end, by the script: the device's watchdog had nothing to do
    assert emu.all_outputs_off()
    assert not [a for a in emu.actuations() if a.cause == "watchdog"]
    assert emu.firmware.counters.watchdog_trips == 0 or emu.firmware.history[-1].cause != "watchdog"
    print(f"\nthe example's run: {wall:.1f} s wall")


def test_escape_during_a_stimulus_turns_every_actuator_off(
        compiled, plugin_site, xvfb, tmp_path):
    emu, rc, (out, err), rows, escaped_at = _run(compiled, plugin_site, xvfb, tmp_path,
                                                 escape_in_trial=3)
    assert rc == 0, err[-3000:]
    assert "Traceback" not in err
    plays = _plays(emu)
    assert len(plays) == 3                          # the third trial's play, and no other
    cut = emu.firmware.last_play
    assert cut is not None and cut.play_id == plays[-1]
    played = [t for t in cut.onsets if t != wire.NOT_PLAYED]
    assert 0 < len(played) < len(cut.pulses)        # stopped mid-play
    off = [a for a in emu.actuations() if a.cause == "all_off"]
    assert off, "no ALL_OFF turned an output off after Escape"
    assert emu.all_outputs_off()
    assert not [a for a in emu.actuations() if a.cause == "watchdog"]
    # the two answered trials are in the data file with their onsets
    done = [r for r in rows if r.get("tactile.onsets")]
    assert len(done) == 2
    for r in done:
        assert len(ast.literal_eval(r["tactile.onsets"])) == int(r["tactile.pulses_played"])


def test_a_crash_mid_stimulus_turns_every_actuator_off(compiled, plugin_site, xvfb, tmp_path):
    """The script raises an error (a bug of its own) 0.2 s into the first stimulus: the
    array is turned off on the way out (PsychoPy's device manager at exit), not by the
    device's watchdog."""
    run_dir = tmp_path / "crash"
    run_dir.mkdir()
    shutil.copy(compiled.parent / "conditions.csv", run_dir / "conditions.csv")
    emu = PtyEmulator.for_profile(DeviceProfile.load(PROFILE))
    _record_onsets_sent(emu)
    port = _serve(emu)
    try:
        script = _sixty_hz(compiled.read_text(encoding="utf-8-sig")).replace(
            "device='emulator'", f"device='serial:{port},{LINK}'")
        # pulses of 150 ms (as in the Escape test): the first stimulus lasts 2 s, and
        # the crash 0.2 s into it comes while it plays however busy the machine
        assert script.count("duration_ms=40, soa_ms=40") == 2
        script = script.replace("duration_ms=40, soa_ms=40", "duration_ms=150, soa_ms=150")
        escape_check = '            if defaultKeyboard.getKeys(keyList=["escape"]):\n'
        assert script.count(escape_check) == 1
        script = script.replace(escape_check, (
            "            if tactile.status == STARTED and t > 0.6:\n"
            "                raise RuntimeError('a crash mid-stimulus')\n") + escape_check)
        (run_dir / "tactile_shapes.py").write_text(script, encoding="utf-8")
        r = subprocess.run([sys.executable, str(run_dir / "tactile_shapes.py")], cwd=run_dir,
                           env=_env(plugin_site, tmp_path, xvfb), capture_output=True,
                           text=True, timeout=120)
        time.sleep(0.05)
    finally:
        _unserve(emu)
    assert r.returncode == 1 and "RuntimeError: a crash mid-stimulus" in r.stderr
    assert len(_plays(emu)) == 1
    cut = emu.firmware.last_play
    played = [t for t in cut.onsets if t != wire.NOT_PLAYED]
    assert 0 < len(played) < len(cut.pulses)        # stopped mid-play
    assert any(a.cause == "all_off" for a in emu.actuations())
    assert emu.all_outputs_off()
    assert not [a for a in emu.actuations() if a.cause == "watchdog"]


def test_a_missing_stimulus_file_stops_before_the_first_routine_in_one_line(
        compiled, plugin_site, xvfb, tmp_path):
    """A conditions file naming an image that is not there: one line naming the
    component, the file and row, and the value; no traceback; nothing played."""
    run_dir = tmp_path / "bad"
    run_dir.mkdir()
    text = (compiled.parent / "conditions.csv").read_text()
    text = text.replace("shape:shape=circle,circle,3", "shapes/missing.png,circle,3", 1)
    (run_dir / "conditions.csv").write_text(text)
    script = _sixty_hz(compiled.read_text(encoding="utf-8-sig").replace(
        "device='emulator'", "device='sim'"))
    (run_dir / "tactile_shapes.py").write_text(script, encoding="utf-8")
    r = subprocess.run([sys.executable, str(run_dir / "tactile_shapes.py")], cwd=run_dir,
                       env=_env(plugin_site, tmp_path, xvfb), capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 1
    assert "Traceback" not in r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("vtexp: error:")]
    assert len(lines) == 1, r.stderr[-2000:]
    assert "tactile, conditions.csv row 3" in lines[0]
    assert "missing.png" in lines[0] and "not found" in lines[0]
    assert "trial.started" not in "".join(p.read_text() for p in
                                          (run_dir / "data").glob("*.csv"))


# --------------------------------------------------------------------------- the runtime

class FakeClock:
    """PsychoPy's clock as the script hands it over (``getTime(format='float')``)."""

    def __init__(self, offset_s: float):
        self.offset_s = offset_s

    def getTime(self, format: str = "float") -> float:  # noqa: A002 - PsychoPy's name
        return time.monotonic() + self.offset_s


def test_the_runtime_plays_on_the_emulator_and_maps_onsets_to_the_given_clock():
    arr = builder.TactileArray(f"emulator:{LINK}", PROFILE, name="arr")   # LINK: as above
    try:
        arr.open(say=lambda line: None)
        stim = builder.TactileStimulus(arr, "tactile", folder=EXAMPLE)
        stim.prepare_rows([("c.csv", [{"s": "shape:shape=triangle"}])], {},
                          stimulus="s", pipeline="'edge-trace'", coding="''",
                          encoding_params="''", coding_params="'duration_ms=30, soa_ms=30'")
        clock = FakeClock(offset_s=-1000.0)
        stim.start_routine(clock, stimulus="shape:shape=triangle", pipeline="edge-trace",
                           coding="", encoding_params="", coding_params="duration_ms=30, soa_ms=30")
        before = clock.getTime()
        stim.play()
        assert _wait_true(lambda: stim.finished, 10)
        after = clock.getTime()
        d = stim.data()
        emu = arr.device.emulator
        on = [a for a in emu.actuations() if a.cause == "play" and not a.setting.is_off]
        assert d["tactile.pulses_played"] == len(on) == len(d["tactile.onsets"]) > 0
        assert before <= d["tactile.onsets"][0] and d["tactile.onsets"][-1] <= after
    finally:
        arr.close()
    assert emu.all_outputs_off()
    # closed at the end of the experiment; opened anew when it runs again in this process
    assert arr.device is None
    arr.open(say=lambda line: None)
    try:
        assert arr.device.emulator is not emu
        again = builder.TactileStimulus(arr, "tactile")
        again.start_routine(None, stimulus="shape:shape=triangle", pipeline="edge-trace",
                            coding="", encoding_params="", coding_params="")
        again.play()
        assert _wait_true(lambda: again.finished, 10)
        assert again.data()["tactile.completed"] is True
    finally:
        arr.close()


@pytest.mark.parametrize("device", ["sim", "emulator"])
def test_a_stop_mid_play_turns_every_actuator_off_and_keeps_what_was_played(device):
    arr = builder.TactileArray(device, PROFILE, name="arr")
    try:
        arr.open(say=lambda line: None)
        stim = builder.TactileStimulus(arr, "tactile")
        stim.start_routine(FakeClock(0.0), stimulus="shape:shape=square",
                           pipeline="edge-trace", coding="", encoding_params="",
                           coding_params="")
        stim.play()
        time.sleep(0.3)                         # 20 pulses of 60 ms: 1.2 s
        assert not stim.finished
        stim.stop()
        d = stim.data()
        assert d["tactile.completed"] is False
        assert 0 < d["tactile.pulses_played"] < d["tactile.pulses_scheduled"] == 20
        assert len(d["tactile.onsets"]) == d["tactile.pulses_played"]
        if device == "sim":
            assert not arr.device.state.any()
            assert any(e.kind == "stopped" for e in arr.device.history)
        else:
            emu = arr.device.emulator
            assert emu.all_outputs_off()
            on = [a for a in emu.actuations() if a.cause == "play" and not a.setting.is_off]
            assert len(on) == d["tactile.pulses_played"]
            assert any(a.cause == "all_off" for a in emu.actuations())
    finally:
        arr.close()


def _wait_true(cond, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.005)
    return True


@pytest.mark.parametrize("device, profile, expected", [
    ("usb:3", PROFILE, "tactileArray (device 'usb:3', profile 'vest_6x8'): --device: "
                       "unknown device 'usb:3'"),
    ("sim", "vest_9x9", "unknown device profile 'vest_9x9'"),
    ("serial:", PROFILE, "give the port after 'serial:'"),
])
def test_a_wrong_device_or_profile_is_one_message(device, profile, expected):
    with pytest.raises(builder.BuilderError) as e:
        builder.TactileArray(device, profile).open(say=lambda line: None)
    assert expected in str(e.value)
    assert str(e.value).startswith("vtexp: error: ") and "\n" not in str(e.value)


def test_two_components_naming_one_array_with_different_settings_is_one_message():
    """Components that share a device name share one array; one that asks it for another
    device or profile ends the script before anything opens, naming both."""
    array = builder.TactileArray("sim", PROFILE, name="vest")
    for other, said in ((dict(device="emulator", profile=PROFILE), "'sim' and 'emulator'"),
                        (dict(device="sim", profile="pad_20x20"),
                         "'vest_6x8' and 'pad_20x20'")):
        with pytest.raises(builder.BuilderError) as e:
            array.open(say=lambda line: None, **other)
        assert said in str(e.value) and "\n" not in str(e.value)
        assert str(e.value).startswith("vtexp: error: vest: two components name this array")
    assert array.device is None                      # nothing was opened
    assert array.open(say=lambda line: None, device="sim", profile=PROFILE) is array
    try:
        assert array.device is not None
    finally:
        array.close()


@pytest.mark.parametrize("spec, expected", [
    (dict(stimulus="shape:shape=hexagon"), "conditions.csv row 2: stimulus: 'shape:shape=hexagon'"),
    (dict(stimulus="blob:x=1"), "unknown stimulus generator 'blob'"),
    (dict(stimulus="shape:shape=square", pipeline="edges"), "unknown pipeline 'edges'"),
    (dict(stimulus="shape:shape=square", coding_params="duration_ms=5000"),
     "unsafe on vest_6x8"),
    (dict(stimulus="shape:shape=square", coding_params="duration_ms"), "expected key=value"),
])
def test_a_wrong_or_unsafe_stimulus_is_refused_before_anything_plays(spec, expected):
    arr = builder.TactileArray("sim", PROFILE)
    try:
        arr.open(say=lambda line: None)
        stim = builder.TactileStimulus(arr, "tactile")
        full = dict(stimulus="", pipeline="edge-trace", coding="", encoding_params="",
                    coding_params="")
        full.update(spec)
        with pytest.raises(builder.BuilderError) as e:
            stim.prepare("conditions.csv row 2", **full)
        assert expected in str(e.value), str(e.value)
        assert "Nothing was played" in str(e.value)
        assert not [h for h in arr.device.history if h.kind == "play"]
    finally:
        arr.close()


def test_a_pattern_file_from_vtexp_encode_plays_its_schedule(tmp_path, cli):
    pat = tmp_path / "square.json"
    r = cli("encode", "shape:shape=square", "--pipeline", "edge-trace", "--device",
            PROFILE, "--json", str(pat))
    assert r.returncode == 0, r.stderr
    profile = DeviceProfile.load(PROFILE)
    s = builder.compile_spec(profile, stimulus=str(pat))
    import json
    assert s.model_dump(mode="json") == json.loads(pat.read_text())["schedule"]
    other = DeviceProfile.load("pad_20x20")
    with pytest.raises(Exception) as e:
        builder.compile_spec(other, stimulus=str(pat))
    assert "written for device profile 'vest_6x8'" in str(e.value)


def test_a_damaged_pattern_file_is_refused_in_one_message_or_played_within_the_limits(
        tmp_path, cli):
    """The pattern file's reader, held to the rule of tests/fuzz.py: each damaged file
    is refused with a message (InputError, UnsafeStimulus) or gives a schedule within
    the profile's limits; no other exception."""
    import random

    import fuzz
    from vtexp.errors import InputError, UnsafeStimulus
    from vtexp.safety import check_schedule

    pat = tmp_path / "square.json"
    assert cli("encode", "shape:shape=square", "--pipeline", "edge-trace", "--device",
               PROFILE, "--json", str(pat)).returncode == 0
    text = pat.read_text()
    profile = DeviceProfile.load(PROFILE)
    outcomes = {"refused": 0, "accepted": 0}
    for seed in range(40):
        said: list[str] = []
        damaged = tmp_path / f"damaged-{seed}.json"
        damaged.write_text(fuzz.mutate_text(text, "json", random.Random(seed), said))
        try:
            s = builder.compile_spec(profile, stimulus=str(damaged))
        except (InputError, UnsafeStimulus) as e:
            assert str(e).strip() and "\n" not in str(e).strip(), (seed, said)
            outcomes["refused"] += 1
            continue
        except Exception as e:                               # noqa: BLE001
            pytest.fail(f"seed {seed} ({said}): {type(e).__name__}: {e}")
        check_schedule(s, profile)
        outcomes["accepted"] += 1
    assert outcomes["refused"] > 0


def test_an_image_file_is_encoded_as_vtexp_run_encodes_it(tmp_path):
    """An image file beside the experiment (a path relative to its folder) gives the
    schedule vtexp's own compile path gives for the same image."""
    from PIL import Image

    from vtexp.compile import compile_stimulus
    from vtexp.stimuli import render

    profile = DeviceProfile.load(PROFILE)
    gray = render("shape", {"shape": "triangle"}, profile.rows, profile.cols)
    (tmp_path / "shapes").mkdir()
    Image.fromarray(gray).save(tmp_path / "shapes" / "triangle.png")
    s = builder.compile_spec(profile, stimulus="shapes/triangle.png", pipeline="edge-trace",
                             coding_params="duration_ms=40", folder=tmp_path)
    _, expected = compile_stimulus(gray, profile, pipeline="edge-trace", encoding_params={},
                                   protocol="sequential-trace",
                                   coding_params={"duration_ms": 40})
    assert s == expected and len(s.pulses) > 0
