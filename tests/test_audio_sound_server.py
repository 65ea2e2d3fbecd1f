"""The audio mode through a real sound stack (issue 22, part 2).

A PulseAudio server started here (user mode, a private runtime folder, a null sink: no
sound card, no kernel module), PsychoPy's sounddevice backend playing into it through
ALSA's ``pulse`` plugin, and ``parec`` recording the sink's monitor while a short
session in the audio mode runs in a window on Xvfb, answered with real key presses.
From the recording alone:

- every clip the session says is heard, in order, where the session says it played it
  (each rendered clip found in the recording by cross-correlation), and nothing else
  is heard outside the masking noise (energy segments);
- no speech overlaps a stimulus (the device's play, as timed around it);
- the masking noise starts before each stimulus and ends after it;
- nothing clips (peak below full scale).

And without any sound output: one message before anything is written.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import signal
import subprocess
import threading
import time
import wave
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT, write_experiment

if importlib.util.find_spec("psychopy") is None:
    pytest.skip("PsychoPy is not installed (the 'gui' extra)", allow_module_level=True)
if shutil.which("espeak-ng") is None:
    pytest.fail("espeak-ng is not installed: apt-get install espeak-ng (make test installs it)")

from vtexp.devices import open_device                    # noqa: E402
from vtexp.experiment import load_experiment            # noqa: E402
from vtexp.model import DeviceProfile                   # noqa: E402
from vtexp.session import SessionOptions, run_session   # noqa: E402

OUT = ROOT / "test-output"
RATE = 48000                 # the null sink's and the recording's rate
SINK = "vt_null"

pytestmark = pytest.mark.realtime

#: A short session: two trials, every phrase short, a stimulus of about half a second.
EXPERIMENT = """\
name: audio_check
title: The audio mode through a sound server
device: vest_6x8
instructions: Feel two shapes.
stimuli:
  square: {generator: shape, params: {shape: square}}
  circle: {generator: shape, params: {shape: circle}}
encoding:
  pipeline: edge-trace
coding:
  protocol: sequential-trace
  params: {duration_ms: 40, soa_ms: 40}
factors:
  shape:
    sets: stimulus
    levels: [square, circle]
design:
  repetitions: 1
  iti_ms: 0
question:
  prompt: Which shape?
  options: [square, circle]
  correct: "{shape}"
presentation:
  audio: true
  phrases:
    headphones: Headphones on.
    masking: You will hear noise.
    keys: Answer with keys.
    begin: Press space.
    ready: Ready.
    choose_digit: "{key}, {option}."
    answer_taken: "{answer}."
    finish: The end.
"""


def _pulse_missing() -> str | None:
    for exe in ("pulseaudio", "pactl", "parec", "pacat"):
        if shutil.which(exe) is None:
            return exe
    return None


@pytest.fixture(scope="module")
def pulse(tmp_path_factory):
    """A PulseAudio server of this test only, with a null sink; ``PULSE_SERVER`` points
    every client in this process (PortAudio's ALSA ``pulse`` plugin, parec) at it."""
    missing = _pulse_missing()
    if missing:
        pytest.fail(f"{missing} is not installed: apt-get install --no-install-recommends "
                    "pulseaudio pulseaudio-utils libasound2-plugins (make test installs them)")
    if not Path("/usr/share/alsa/alsa.conf.d/pulse.conf").exists() and \
            not Path("/etc/alsa/conf.d/99-pulse.conf").exists():
        pytest.fail("ALSA's pulse plugin is not installed: apt-get install libasound2-plugins "
                    "(make test installs it)")
    run = tmp_path_factory.mktemp("pulse-runtime")
    env = dict(os.environ, XDG_RUNTIME_DIR=str(run), HOME=str(run))
    socket = run / "native"
    proc = subprocess.Popen(
        ["pulseaudio", "--daemonize=no", "--exit-idle-time=-1", "-n", "--log-target=stderr",
         "--disallow-exit", f"--load=module-native-protocol-unix auth-anonymous=1 "
                            f"socket={socket}",
         f"--load=module-null-sink sink_name={SINK} rate={RATE} channels=2"],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    old = os.environ.get("PULSE_SERVER")
    os.environ["PULSE_SERVER"] = f"unix:{socket}"
    deadline = time.monotonic() + 10
    while subprocess.run(["pactl", "info"], capture_output=True).returncode != 0:
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            pytest.fail(f"PulseAudio did not start: {proc.stderr.read().decode()[-800:]}")
        time.sleep(0.05)
    try:
        yield os.environ["PULSE_SERVER"]
    finally:
        import sys
        backend = sys.modules.get("psychopy.sound.backend_sounddevice")
        for stream in list(backend.streams.values()) if backend else []:
            stream._sdStream.abort()       # before the server goes: no PortAudio errors
            stream._sdStream.close()
        if backend:
            backend.streams.clear()
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        if old is None:
            os.environ.pop("PULSE_SERVER", None)
        else:
            os.environ["PULSE_SERVER"] = old


@pytest.fixture(scope="module")
def speech_cache(tmp_path_factory):
    old = os.environ.get("VTEXP_SPEECH_CACHE")
    os.environ["VTEXP_SPEECH_CACHE"] = str(tmp_path_factory.mktemp("speech"))
    yield
    if old is None:
        os.environ.pop("VTEXP_SPEECH_CACHE", None)
    else:
        os.environ["VTEXP_SPEECH_CACHE"] = old


class Recorder:
    """``parec`` on the sink's monitor (mono, 16 bit, RATE), raw into a file; a ``pacat``
    of silence keeps the sink running, so that the recording has no gaps. ``t0``: the
    monotonic time of the recording's first sample (from when its first bytes came)."""

    def __init__(self, path: Path):
        self.path = path
        self.keep = subprocess.Popen(["pacat", "--playback", f"--device={SINK}", "--raw",
                                      f"--rate={RATE}", "--channels=2", "--format=s16le"],
                                     stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL)
        self._feed = threading.Thread(target=self._silence, daemon=True)
        self._feed.start()
        self.out = open(path, "wb")
        self.proc = subprocess.Popen(["parec", f"--device={SINK}.monitor", "--raw",
                                      f"--rate={RATE}", "--channels=1", "--format=s16le",
                                      "--latency-msec=10"], stdout=self.out,
                                     stderr=subprocess.PIPE)
        deadline = time.monotonic() + 5
        while path.stat().st_size < 2 * RATE // 10:      # the first 100 ms arrived
            assert time.monotonic() < deadline, self.proc.stderr.read()[-500:]
            time.sleep(0.002)
        now = time.monotonic()
        self.t0 = now - path.stat().st_size / 2 / RATE

    def _silence(self):
        block = bytes(4 * RATE // 50)            # 20 ms of stereo silence
        try:
            while self.keep.poll() is None:
                self.keep.stdin.write(block)
        except (BrokenPipeError, ValueError, OSError):
            pass

    def stop(self) -> np.ndarray:
        time.sleep(0.3)                          # the last clip's tail
        self.proc.send_signal(signal.SIGINT)
        self.proc.wait(5)
        self.out.close()
        self.keep.terminate()
        self.keep.wait(5)
        return np.frombuffer(self.path.read_bytes(), "<i2").astype(np.float64) / 32768.0


def _clip(path: Path) -> np.ndarray:
    """A rendered clip as the sink plays it: mono, at RATE, full scale 1."""
    from scipy.signal import resample_poly
    with wave.open(str(path), "rb") as w:
        rate, n, ch = w.getframerate(), w.getnframes(), w.getnchannels()
        x = np.frombuffer(w.readframes(n), "<i2").astype(np.float64) / 32768.0
    x = x.reshape(-1, ch).mean(axis=1)
    g = np.gcd(RATE, rate)
    return resample_poly(x, RATE // g, rate // g)


def _find(rec: np.ndarray, clip: np.ndarray, lo: int, hi: int) -> tuple[int, float]:
    """Where ``clip`` starts in ``rec`` between samples lo and hi, and the normalised
    correlation there (1: the same samples)."""
    from scipy.signal import correlate
    lo, hi = max(lo, 0), min(hi, rec.size - clip.size)
    seg = rec[lo:hi + clip.size]
    c = correlate(seg, clip, mode="valid", method="fft")
    cs = np.r_[0.0, np.cumsum(seg ** 2)]
    e = np.sqrt(np.maximum(cs[clip.size:] - cs[:-clip.size], 0.0))     # each window's energy
    k = int(np.argmax(c / np.maximum(e, 1e-9)))
    return lo + k, float(c[k] / max(e[k], 1e-9) / np.linalg.norm(clip))


def _segments(loud: np.ndarray, frame: float) -> list[tuple[float, float]]:
    """Runs of loud frames as (start, end) in seconds."""
    edges = np.flatnonzero(np.diff(np.r_[0, loud.astype(int), 0]))
    return [(a * frame, b * frame) for a, b in zip(edges[::2], edges[1::2])]


class XKeys:
    """Real key presses through XTEST (as tests/test_accessible_window.py sends them)."""

    def __init__(self, display_name):
        from Xlib import XK, display
        self.XK, self.d = XK, display.Display(display_name)

    def focus(self, win):
        from Xlib import X
        w = self.d.create_resource_object("window", win.winHandle._window)
        w.set_input_focus(X.RevertToParent, X.CurrentTime)
        self.d.sync()

    def press(self, keysym):
        from Xlib import X
        from Xlib.ext import xtest
        code = self.d.keysym_to_keycode(self.XK.string_to_keysym(keysym))
        xtest.fake_input(self.d, X.KeyPress, code)
        xtest.fake_input(self.d, X.KeyRelease, code)
        self.d.sync()


def _wait(cond, timeout=20.0) -> bool:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def test_the_audio_mode_heard_through_a_sound_server(pulse, speech_cache, xvfb, tmp_path,
                                                     cli):
    from vtexp.responders.window import WindowOptions, WindowResponder
    t_start = time.monotonic()
    listed = cli("device", "list", "--audio")
    assert listed.returncode == 0 and " pulse " in listed.stdout, listed.stdout
    lx = load_experiment(write_experiment(tmp_path, EXPERIMENT))
    r = WindowResponder(WindowOptions(fullscreen=False, size=(1280, 800), device="pulse"),
                        lx=lx)
    assert r.speech.audio.output["name"] == "pulse"
    sp = r.speech

    def quiet():
        return sp.current is None and not sp.queue

    problems: list[str] = []

    def participant():
        kb = XKeys(xvfb)
        try:
            if not _wait(lambda: r.win is not None and r.screen == "instructions"):
                problems.append("no instructions")
                return
            kb.focus(r.win)
            time.sleep(0.2)
            _wait(lambda: quiet() and any(p.text == "Press space." for p in sp.played))
            kb.press("space")
            for n in (1, 2):
                if not _wait(lambda: r.entered.count("ready") >= n and r.screen == "choice"
                             and quiet() and any(p.text == "Which shape?"
                                                 for p in sp.played[-3:])):
                    problems.append(f"trial {n}: never asked (on {r.screen})")
                    return
                kb.press("1")
                _wait(lambda: r.screen != "choice")
            if not _wait(lambda: r.screen == "end" and quiet()):
                problems.append(f"no end screen (on {r.screen})")
                return
            kb.press("space")
        except Exception as e:
            problems.append(repr(e))
        finally:
            kb.d.close()
            if problems:
                from psychopy import event
                event._keyBuffer.append(("escape", 0, 0.0))

    plays: list[tuple[float, float]] = []
    rec = Recorder(tmp_path / "monitor.raw")
    try:
        with open_device("sim:realtime", DeviceProfile.load(lx.experiment.device)) as dev:
            play = dev.play

            def timed(schedule, **kw):
                t0 = time.monotonic()
                rep = play(schedule, **kw)
                plays.append((t0, time.monotonic()))
                return rep
            dev.play = timed
            thread = threading.Thread(target=participant, daemon=True)
            thread.start()
            try:
                run_session(lx, dev, r, SessionOptions(participant="01",
                                                       data_dir=tmp_path / "data"))
            finally:
                thread.join(20)
                assert not problems, problems
    finally:
        x = rec.stop()
    assert not problems, problems
    assert len(plays) == 2

    # The recording as a timeline: sample k was heard at rec.t0 + k / RATE (monotonic).
    def at(t: float) -> int:
        return int(round((t - rec.t0) * RATE))

    # Every clip said, found in the recording near where it was logged, in order.
    played = [p for p in sp.played if p.end - p.start > 0.05]
    found = []
    for p in played:
        c = _clip(p.path)
        n = min(c.size, int((p.end - p.start) * RATE))
        k, corr = _find(x, c[:n], at(p.start) - RATE // 2, at(p.start) + RATE // 2)
        # The clip as heard: from its first to its last loud sample (not its silences).
        lit = np.flatnonzero(np.abs(c[:n]) > 10 ** (-40 / 20))
        found.append((p, k, n, corr, k + lit[0], k + lit[-1]))
    latency = [(k / RATE + rec.t0 - p.start) * 1000 for p, k, *_ in found]
    corrs = [f[3] for f in found]
    starts = [f[1] for f in found]
    heard = [(a / RATE, b / RATE) for *_, a, b in found]

    # Energy: 10 ms frames above -40 dBFS, outside the noise, are all inside a found clip.
    frame = 0.010
    m = int(frame * RATE)
    rms = np.sqrt((x[: x.size // m * m].reshape(-1, m) ** 2).mean(axis=1))
    loud = rms > 10 ** (-40 / 20)
    noise_rec = [((a - rec.t0), (b - rec.t0)) for a, b in sp.noise_on]
    segments = _segments(loud, frame)

    def inside(a, b, spans, slack):
        return any(s - slack <= a and b <= e + slack for s, e in spans)
    stray = [(a, b) for a, b in segments
             if not inside(a, b, heard + [(s, e + 0.2) for s, e in noise_rec], 0.1)]
    # Speech segments: the loud runs that are not noise, against the clips rendered.
    speech = [(a, b) for a, b in segments if not inside(a, b, noise_rec, 0.15)]

    # No speech while a stimulus plays; the masking noise covers every stimulus.
    overlaps, leads, lags = [], [], []
    for t0, t1 in plays:
        s0, s1 = t0 - rec.t0, t1 - rec.t0
        overlaps += [(a, b) for a, b in heard if a < s1 and b > s0]
        # The noise as heard: the loud run around the stimulus.
        run = [(a, b) for a, b in segments if a <= s0 + 0.05 and b >= s1 - 0.05]
        assert run, f"no sound during the stimulus {s0:.3f}-{s1:.3f} s"
        a, b = run[0]
        # The run may begin with "Ready." said just before it: the noise starts after
        # the clip that ends last before the stimulus.
        before = [e for s, e in heard if e <= s0 + 0.01]
        nstart = max([a] + [e for e in before if e > a])
        leads.append((s0 - nstart) * 1000)
        lags.append((b - s1) * 1000)
    peak = float(np.max(np.abs(x)))
    wall = time.monotonic() - t_start
    lines = [
        f"recording: {x.size / RATE:.2f} s at {RATE} Hz from {SINK}.monitor",
        f"clips said by the session: {len(sp.played)}; heard (correlation > 0.9, in "
        f"order): {sum(c > 0.9 for c in corrs)}; correlation min {min(corrs):.3f}",
        f"speech segments by energy (not noise): {len(speech)}",
        f"output latency (heard - logged start): {min(latency):.1f}-{max(latency):.1f} ms",
        f"stimuli: {len(plays)}, "
        + ", ".join(f"{a - rec.t0:.3f}-{b - rec.t0:.3f} s" for a, b in plays),
        f"speech overlapping a stimulus: {len(overlaps)}",
        "masking noise lead before stimulus: " + ", ".join(f"{v:.0f} ms" for v in leads),
        "masking noise lag after stimulus: " + ", ".join(f"{v:.0f} ms" for v in lags),
        f"peak level: {peak:.3f} of full scale ({20 * np.log10(peak):.1f} dBFS)",
        f"test wall time so far: {wall:.1f} s",
    ] + [f"  {k / RATE:7.3f} s  heard {a / RATE:7.3f}-{b / RATE:7.3f} s  r={corr:.3f}  "
         f"{p.text}" for p, k, n, corr, a, b in found]
    print("\n" + "\n".join(lines))
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "audio_sound_server.txt").write_text("\n".join(lines) + "\n")
    assert min(corrs) > 0.9, [(f[0].text, round(f[3], 3)) for f in found]
    assert starts == sorted(starts) and len(set(starts)) == len(starts)
    assert max(latency) - min(latency) < 60, latency
    assert not stray, stray
    assert not overlaps, overlaps
    assert min(leads) > 0 and min(lags) > 0, (leads, lags)
    assert peak < 0.99, f"clipping: peak {peak:.3f} of full scale"


def test_no_sound_output_is_one_message_before_anything_is_written(monkeypatch, tmp_path,
                                                                   cli):
    from vtexp.responders import speech
    monkeypatch.setenv("VTEXP_SPEECH_CACHE", str(tmp_path / "speech"))
    monkeypatch.setattr(speech, "output_devices", lambda refresh=True: [])
    exp = write_experiment(tmp_path, EXPERIMENT)
    res = cli("run", exp, "-p", "01", "--responder", "window:audio,windowed",
              "--data", tmp_path / "data", cwd=tmp_path)
    assert res.returncode != 0
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    assert "no sound output" in lines[0] and "window:audio,device=NAME" in lines[0]
    assert "vtexp device list --audio" in lines[0]
    assert not (tmp_path / "data").exists()
    assert not (tmp_path / "speech").exists()
    # The command it names works as printed.
    listed = cli("device", "list", "--audio")
    assert listed.returncode == 0 and "no sound output found" in listed.stdout


def test_an_unknown_sound_output_is_named_with_the_ones_there_are(monkeypatch, tmp_path,
                                                                  speech_cache, cli):
    from vtexp.responders import speech
    devs = [{"index": 0, "name": "pulse", "hostapi": "ALSA", "channels": 32, "default": False},
            {"index": 1, "name": "default", "hostapi": "ALSA", "channels": 32,
             "default": True}]
    monkeypatch.setattr(speech, "output_devices", lambda refresh=True: devs)
    assert speech.choose_output(None)["name"] == "default"
    assert speech.choose_output("PULSE")["index"] == 0
    assert speech.choose_output("0")["name"] == "pulse"
    res = cli("run", write_experiment(tmp_path, EXPERIMENT), "-p", "01", "--responder",
              "window:audio,windowed,device=headset", "--data", tmp_path / "data",
              cwd=tmp_path)
    assert res.returncode == 2 and "no sound output 'headset'" in res.stderr
    assert "0: pulse; 1: default" in res.stderr and not (tmp_path / "data").exists()
