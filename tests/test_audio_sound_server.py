"""The audio mode through a real sound stack (issue 22, part 2).

A PulseAudio server started here (user mode, a private runtime folder, a null sink: no
sound card, no kernel module), PsychoPy's sounddevice backend playing into it through
ALSA's ``pulse`` plugin, and ``parec`` recording the sink's monitor while a short
session in the audio mode (two trials) runs in a window on Xvfb, answered with real key
presses. From the recording alone:

- every clip the session says it played is heard, in order, near where the session says
  it played it, no two at once (each rendered clip found in the recording by
  cross-correlation: whole, or, where PortAudio reported the output run dry while it
  played, at its place with blocks missing), and nothing else is heard outside the
  masking noise (energy, frame by frame);
- no speech overlaps a stimulus (the device's play, as timed around it);
- the masking noise starts before each stimulus and ends after it;
- nothing clips (peak below full scale).

And without any sound output: one message before anything is written.

Nothing here can wait for ever: the participant presses a key only when the window
listens for it and presses it again until the session visibly moves on; every wait has a
deadline (no speed is checked: the deadlines only end a stuck run), after which the
session is aborted with Escape and the test fails naming what it waited for; the whole
session has a last-resort alarm. PulseAudio, parec and pacat are stopped in ``finally``
and die with the test's process if it is killed (``setpriv --pdeathsig``).
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
import wave
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT, dies_with_us, record_plays, write_experiment
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
RATE = 48000                 # the null sink's and the recording's rate
SINK = "vt_null"

#: The longest one step of the session may take (a prompt said, a key taken) before the
#: test gives up on it: far longer than any step takes on a busy computer. Not a speed
#: check: it only keeps a stuck run from waiting for ever.
STEP_DEADLINE_S = 45.0
#: How long a key press may go unanswered before the participant presses it again.
PRESS_AGAIN_S = 2.0
#: The whole session's last resort (an alarm in the test's thread), should the abort key
#: not end it either.
SESSION_DEADLINE_S = 300.0

pytestmark = pytest.mark.realtime

#: A short session: two trials, every phrase short, a stimulus of about half a second.
EXPERIMENT = """\
name: audio_check
title: The audio mode through a sound server
device: vest_6x8
instructions: Two shapes.
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
    masking: Noise.
    keys: Use keys.
    begin: Press space.
    ready: Ready.
    choose_digit: "{key} {option}."
    answer_taken: "{answer}."
    finish: The end.
"""
TRIALS = 2
BEGIN = "Press space."           # the instructions' last sentence
OPTIONS = "1 square. 2 circle."  # the question's last sentence
ANSWERS = ("square.", "circle.")  # an answer said back
END = "The end."
#: Everything the session says, in order, when each question is answered with key 1.
SAID = ["Headphones on.", "Noise.", "Use keys.", "Two shapes.", BEGIN,
        *["Ready.", "Which shape?", OPTIONS, "square."] * TRIALS, END]


def _pulse_missing() -> str | None:
    for exe in ("pulseaudio", "pactl", "parec", "pacat"):
        if shutil.which(exe) is None:
            return exe
    return None


def _stop(proc: subprocess.Popen | None, sig: int = signal.SIGTERM) -> None:
    """Stop ``proc`` with ``sig``, killed if it has not gone within 5 s; reaped."""
    if proc is None or proc.poll() is not None:
        return
    with contextlib.suppress(ProcessLookupError):
        proc.send_signal(sig)
    try:
        proc.wait(5)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(5)


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
    log = run / "pulseaudio.log"
    old = os.environ.get("PULSE_SERVER")
    proc = None
    try:
        with open(log, "wb") as err:
            proc = subprocess.Popen(dies_with_us(
                ["pulseaudio", "--daemonize=no", "--exit-idle-time=-1", "-n",
                 "--log-target=stderr", "--disallow-exit",
                 f"--load=module-native-protocol-unix auth-anonymous=1 socket={socket}",
                 f"--load=module-null-sink sink_name={SINK} rate={RATE} channels=2"]),
                env=env, stdout=subprocess.DEVNULL, stderr=err)
        os.environ["PULSE_SERVER"] = f"unix:{socket}"
        deadline = time.monotonic() + STEP_DEADLINE_S
        while not _answers(["pactl", "info"]):
            if proc.poll() is not None or time.monotonic() > deadline:
                _stop(proc, signal.SIGKILL)
                pytest.fail(f"PulseAudio did not start (its log: {log}): "
                            f"{log.read_text(errors='replace')[-800:]}")
            time.sleep(0.05)
        yield os.environ["PULSE_SERVER"]
    finally:
        backend = sys.modules.get("psychopy.sound.backend_sounddevice")
        for stream in list(backend.streams.values()) if backend else []:
            with contextlib.suppress(Exception):   # before the server goes: no PortAudio
                stream._sdStream.abort()          # errors
                stream._sdStream.close()
        if backend:
            backend.streams.clear()
        _stop(proc)
        if old is None:
            os.environ.pop("PULSE_SERVER", None)
        else:
            os.environ["PULSE_SERVER"] = old


def _answers(command: list[str]) -> bool:
    try:
        return subprocess.run(command, capture_output=True, timeout=5).returncode == 0
    except subprocess.TimeoutExpired:
        return False


@pytest.fixture(scope="module")
def speech_cache(tmp_path_factory):
    old = os.environ.get("VTEXP_SPEECH_CACHE")
    os.environ["VTEXP_SPEECH_CACHE"] = str(tmp_path_factory.mktemp("speech"))
    yield
    if old is None:
        os.environ.pop("VTEXP_SPEECH_CACHE", None)
    else:
        os.environ["VTEXP_SPEECH_CACHE"] = old


class Underflows(list):
    """The monotonic times at which the sound output's stream was found run dry (PortAudio's
    output-underflow flag, as the stream's callback receives it): on a computer so busy
    that the process went unscheduled for longer than the output's buffer, blocks of
    the clip then playing were lost. Recorded for the streams opened while it is
    installed (:meth:`install`, on ``sounddevice.OutputStream``, which PsychoPy's
    backend opens its stream with)."""

    def install(self, monkeypatch) -> Underflows:
        import sounddevice as sd
        init = sd.OutputStream.__init__
        times = self

        def counting_init(stream, *args, callback=None, **kwargs):
            if callback is not None:
                inner = callback

                def callback(outdata, frames, t, status):
                    if status.output_underflow:
                        times.append(time.monotonic())
                    return inner(outdata, frames, t, status)
            init(stream, *args, callback=callback, **kwargs)
        monkeypatch.setattr(sd.OutputStream, "__init__", counting_init)
        return self


class Recorder:
    """``parec`` on the sink's monitor (mono, 16 bit, RATE), raw into a file; a ``pacat``
    of silence keeps the sink running, so that the recording has no gaps. ``t0``: the
    monotonic time of the recording's first sample (from when its bytes came). Use it in
    a ``with``: both programs are stopped when it ends, however it ends."""

    def __init__(self, path: Path):
        self.path = path
        self.keep = self.proc = self.out = None
        self.t0 = 0.0

    def __enter__(self) -> Recorder:
        try:
            self._start()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _start(self) -> None:
        self.keep = subprocess.Popen(dies_with_us(
            ["pacat", "--playback", f"--device={SINK}", "--raw", f"--rate={RATE}",
             "--channels=2", "--format=s16le"]),
            stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        threading.Thread(target=self._silence, args=(self.keep,), daemon=True).start()
        self.out = open(self.path, "wb")
        self.err = open(self.path.with_suffix(".parec.log"), "wb")
        self.proc = subprocess.Popen(dies_with_us(
            ["parec", f"--device={SINK}.monitor", "--raw", f"--rate={RATE}", "--channels=1",
             "--format=s16le", "--latency-msec=10"]), stdout=self.out, stderr=self.err)
        # The first sample's time: from the bytes there are and the time now, the least
        # of several readings (a reading taken late, the process being descheduled,
        # only makes it later).
        deadline = time.monotonic() + STEP_DEADLINE_S
        readings: list[float] = []
        while len(readings) < 50:
            size = self.path.stat().st_size
            now = time.monotonic()
            if size >= 2 * RATE // 20:              # 50 ms are there
                readings.append(now - size / 2 / RATE)
            elif self.proc.poll() is not None or now > deadline:
                self.close()
                raise AssertionError(
                    f"parec recorded nothing from {SINK}.monitor in {STEP_DEADLINE_S:.0f} s: "
                    + self.path.with_suffix(".parec.log").read_text(errors="replace")[-500:])
            time.sleep(0.004)
        self.t0 = min(readings)

    @staticmethod
    def _silence(keep: subprocess.Popen) -> None:
        block = bytes(4 * RATE // 50)            # 20 ms of stereo silence
        try:
            while keep.poll() is None:
                keep.stdin.write(block)
        except (BrokenPipeError, ValueError, OSError):
            pass

    def seconds(self) -> float:
        return self.path.stat().st_size / 2 / RATE

    def samples(self, until: float) -> np.ndarray:
        """The recording, once it holds the sound up to the monotonic time ``until``."""
        deadline = time.monotonic() + STEP_DEADLINE_S
        while self.seconds() < until - self.t0:
            if self.proc.poll() is not None or time.monotonic() > deadline:
                raise AssertionError(f"the recording stopped at {self.seconds():.2f} s, "
                                     f"before the session's end at {until - self.t0:.2f} s")
            time.sleep(0.01)
        self.close()
        return np.frombuffer(self.path.read_bytes(), "<i2").astype(np.float64) / 32768.0

    def close(self) -> None:
        _stop(self.proc, signal.SIGINT)
        _stop(self.keep)
        for f in (self.out, getattr(self, "err", None)):
            if f is not None:
                f.close()
        if self.keep is not None and self.keep.stdin is not None:
            with contextlib.suppress(OSError):
                self.keep.stdin.close()


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




class Stuck(Exception):
    """What the participant waited for did not come within STEP_DEADLINE_S."""


class Participant:
    """Takes part in the session from a thread of its own, with real key presses. It
    presses a key only once the window listens for it (what was to be said before it has
    been said), and again every PRESS_AGAIN_S until the session visibly moves on (a key
    pressed just before a screen starts listening is forgotten by that screen). Every wait
    has a deadline; past it, or on any error, :attr:`problem` says what was awaited and
    Escape is pressed (and put in PsychoPy's key buffer) until the session has ended."""

    def __init__(self, display: str, responder):
        self.display, self.r, self.sp = display, responder, responder.speech
        self.waiting = "the participant to start"
        self.problem: str | None = None
        self.ended = threading.Event()          # set by the test when the session is over
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.kb: XKeyboard | None = None

    def start(self) -> None:
        self.thread.start()

    def stop(self) -> None:
        """The session is over (however it ended): stop pressing, and wait for the thread."""
        self.ended.set()
        self.thread.join(STEP_DEADLINE_S)
        if self.thread.is_alive() and self.problem is None:
            self.problem = f"the participant's thread did not end (it waited for {self.waiting})"

    # -- what it observes ---------------------------------------------------------------

    def said(self, text: str) -> int:
        """How many times ``text`` was said to its end."""
        return sum(p.text == text for p in list(self.sp.played))

    def answers_taken(self) -> int:
        """How many answers have been said back (begun, waiting or done): the session
        took the key."""
        current = self.sp.current
        return (sum(p.text in ANSWERS for p in list(self.sp.played))
                + sum(t in ANSWERS for t, _ in list(self.sp.queue))
                + (current is not None and current[0] in ANSWERS))

    def where(self) -> str:
        last = self.sp.played[-1].text if self.sp.played else None
        return f"on screen {self.r.screen!r}, screens {self.r.entered}, last said {last!r}"

    # -- waiting and pressing -------------------------------------------------------------

    def until(self, cond, what: str) -> None:
        self.waiting = what
        deadline = time.monotonic() + STEP_DEADLINE_S
        while not cond():
            if self.ended.is_set():
                raise Stuck(f"the session ended while the participant waited for {what} "
                            f"({self.where()})")
            if time.monotonic() > deadline:
                raise Stuck(f"no {what} within {STEP_DEADLINE_S:.0f} s ({self.where()})")
            time.sleep(0.01)

    def press_until(self, key: str, moved, what: str) -> int:
        """Press ``key`` until ``moved()``; how many presses it took."""
        self.waiting = what
        deadline = time.monotonic() + STEP_DEADLINE_S
        presses = 0
        while not moved():
            if time.monotonic() > deadline:
                raise Stuck(f"no {what} within {STEP_DEADLINE_S:.0f} s of pressing {key} "
                            f"({presses} presses; {self.where()})")
            if self.ended.is_set():
                raise Stuck(f"the session ended while the participant waited for {what} "
                            f"({self.where()})")
            win = self.r.win
            if win is not None:
                with contextlib.suppress(Exception):      # it may close meanwhile
                    self.kb.focus(win)
            self.kb.press(key)
            presses += 1
            again = time.monotonic() + PRESS_AGAIN_S
            while not moved() and time.monotonic() < again and not self.ended.is_set():
                time.sleep(0.01)
        return presses

    # -- the session as the participant takes part ------------------------------------------

    def _run(self) -> None:
        r = self.r
        try:
            self.kb = XKeyboard(self.display)
            self.until(lambda: r.win is not None and r.screen == "instructions",
                       "instructions screen")
            self.until(lambda: self.said(BEGIN) >= 1,
                       f"end of the instructions ({BEGIN!r} said)")
            self.press_until("space", lambda: r.screen != "instructions",
                             "next screen after space on the instructions")
            for n in range(1, TRIALS + 1):
                self.until(lambda: self.said(OPTIONS) >= n,
                           f"question of trial {n} said to its end ({OPTIONS!r})")
                self.press_until("1", lambda: self.answers_taken() >= n,
                                 f"answer of trial {n} said back after key 1")
            self.until(lambda: self.said(END) >= 1, f"end screen's {END!r} said")
            self.press_until("space", lambda: self.ended.is_set() or r.win is None,
                             "window closed after space on the end screen")
        except Exception as e:
            self.problem = str(e) if isinstance(e, Stuck) else f"{type(e).__name__}: {e}"
            self._abort()
        finally:
            if self.kb is not None:
                self.kb.close()

    def _abort(self) -> None:
        """Escape until the session has ended (a screen forgets the keys pressed before it
        listened: one press could be lost)."""
        from psychopy import event
        deadline = time.monotonic() + STEP_DEADLINE_S
        while not self.ended.is_set() and time.monotonic() < deadline:
            event._keyBuffer.append(("escape", [], time.monotonic()))
            with contextlib.suppress(Exception):
                self.kb.press("Escape")
            self.ended.wait(0.5)


class SessionHung(BaseException):
    """The last resort's alarm: a BaseException, so that no ``except Exception`` in the
    session takes it for an error of its own."""


@contextlib.contextmanager
def alarm(seconds: float, what: str):
    """Raise :class:`SessionHung` (saying ``what``) in this thread after ``seconds``, should
    the code within still run; only in the main thread, where signals arrive."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def expired(signum, frame):
        raise SessionHung(what)
    old = signal.signal(signal.SIGALRM, expired)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def _a_session_recorded(display: str, tmp_path: Path, cli, monkeypatch, underflows):
    """A session of EXPERIMENT run in the audio mode on the sink, answered with key 1, and
    the sink's monitor recorded meanwhile: (recording, recorder, speech, window, the
    stimuli's (start, end) on the monotonic clock)."""
    from vtexp.responders.window import WindowOptions, WindowResponder
    listed = cli("device", "list", "--audio")
    assert listed.returncode == 0 and " pulse " in listed.stdout, listed.stdout
    underflows.install(monkeypatch)
    lx = load_experiment(write_experiment(tmp_path, EXPERIMENT))
    r = WindowResponder(WindowOptions(fullscreen=False, size=(1280, 800), device="pulse"),
                        lx=lx)
    assert r.speech.audio.output["name"] == "pulse"
    sp = r.speech
    who = Participant(display, r)
    session_end = None
    with Recorder(tmp_path / "monitor.raw") as rec:
        try:
            with open_device("sim:realtime", DeviceProfile.load(lx.experiment.device)) as dev:
                plays = record_plays(dev)
                who.start()
                try:
                    run_session(lx, dev, r, SessionOptions(participant="01",
                                                           data_dir=tmp_path / "data"))
                finally:
                    session_end = time.monotonic()
                    who.stop()
        except (Exception, SessionHung) as e:
            with contextlib.suppress(Exception):
                r.close()                   # the window, the speech and the noise stop
            if who.problem is not None:
                pytest.fail(f"{who.problem} (the session then ended: {type(e).__name__}: "
                            f"{e})")
            if isinstance(e, SessionHung):
                pytest.fail(f"{e}; the participant waited for {who.waiting} ({who.where()})")
            raise
        assert who.problem is None, who.problem
        x = rec.samples(until=max(session_end, sp.played[-1].end) + 0.5)
    return x, rec, sp, r, plays


#: How alike a clip and the recording where it was found must be (normalised correlation,
#: 1: the same samples): a clip played whole is found at 0.99 or more. Where the output
#: ran dry while it played (Underflows) blocks of it were lost: 0.72 was measured on a
#: computer whose CPUs were contended 90 % of the time. A clip searched for where another
#: was heard gives 0.44 at most, 0.58 for a word of a longer clip ('square.' in '1 square.
#: 2 circle.'); two clips heard at once are caught apart (their spans overlap).
HEARD_WHOLE, HEARD_WITH_DROPOUTS = 0.9, 0.6


def test_the_audio_mode_heard_through_a_sound_server(pulse, speech_cache, xvfb, tmp_path,
                                                     cli, monkeypatch):
    t_start = time.monotonic()
    underflows = Underflows()
    with alarm(SESSION_DEADLINE_S, f"the test did not end within {SESSION_DEADLINE_S:.0f} s"):
        x, rec, sp, r, plays = _a_session_recorded(xvfb, tmp_path, cli, monkeypatch,
                                                   underflows)
    assert len(plays) == TRIALS and len(sp.noise_on) == TRIALS
    assert r.entered.count("ready") == TRIALS and r.entered[-1] == "end", r.entered

    # The recording as a timeline: sample k was heard at rec.t0 + k / RATE (monotonic).
    def at(t: float) -> int:
        return int(round((t - rec.t0) * RATE))

    # Every clip said, found in the recording where it was logged (from just before its
    # start to a second after: the output's latency), in order.
    found = []
    for p in sp.played:
        c = _clip(p.path)
        k, corr = _find(x, c, at(p.start) - RATE // 4, at(p.start) + RATE)
        # The clip as heard: from its first to its last loud sample (not its silences).
        lit = np.flatnonzero(np.abs(c) > 10 ** (-40 / 20))
        found.append((p, k, corr, k + lit[0], k + lit[-1]))
    latency = [(k / RATE + rec.t0 - p.start) * 1000 for p, k, *_ in found]
    corrs = [f[2] for f in found]
    starts = [f[1] for f in found]
    heard = [(a / RATE, b / RATE) for *_, a, b in found]
    # The clips during which the output ran dry (blocks of them were lost, or came late).
    latency_s = sp.audio.latency_s
    starved = [any(p.start - 0.1 <= u <= p.end + latency_s + 0.1 for u in underflows)
               for p in sp.played]
    least = [HEARD_WITH_DROPOUTS if dry else HEARD_WHOLE for dry in starved]

    # Energy: every 10 ms frame above -40 dBFS is inside a clip found or the noise (from
    # its start to its stop and the output's latency, when its last samples are heard).
    frame = 0.010
    m = int(frame * RATE)
    rms = np.sqrt((x[: x.size // m * m].reshape(-1, m) ** 2).mean(axis=1))
    loud = rms > 10 ** (-40 / 20)
    noise_rec = [((a - rec.t0), (b - rec.t0)) for a, b in sp.noise_on]
    segments = _segments(loud, frame)
    # (A clip the output ran dry in was heard in pieces: where it is best found may leave
    # a piece before or after.)
    spans = [(a - 0.3, b + 0.3) if dry else (a, b) for (a, b), dry in zip(heard, starved)] \
        + [(s, e + latency_s) for s, e in noise_rec]
    t = np.arange(loud.size) * frame
    covered = np.zeros(loud.size, bool)
    for a, b in spans:
        covered |= (t >= a - 0.05) & (t + frame <= b + 0.05)
    stray = _segments(loud & ~covered, frame)

    def inside(a, b, spans, slack):
        return any(s - slack <= a and b <= e + slack for s, e in spans)
    # Speech segments: the loud runs that are not noise, against the clips rendered.
    speech = [(a, b) for a, b in segments
              if not inside(a, b, [(s, e + latency_s) for s, e in noise_rec], 0.05)]

    # No speech while a stimulus plays; the masking noise covers every stimulus.
    overlaps, leads, lags, unmasked = [], [], [], []
    for t0, t1 in plays:
        s0, s1 = t0 - rec.t0, t1 - rec.t0
        overlaps += [(a, b) for a, b in heard if a < s1 and b > s0]
        # The noise as heard: the loud run around the stimulus.
        run = [(a, b) for a, b in segments if a <= s0 and b >= s1]
        if not run:
            unmasked.append((s0, s1))
            continue
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
        f"clips said by the session: {len(sp.played)}; found in the recording whole "
        f"(correlation > {HEARD_WHOLE}): {sum(c > HEARD_WHOLE for c in corrs)}; correlation "
        f"min {min(corrs):.3f}",
        f"output ran dry (underflows): {len(underflows)}, during {sum(starved)} clips",
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
         f"{p.text}" + ("  (output ran dry)" if dry else "")
         for (p, k, corr, a, b), dry in zip(found, starved)]
    print("\n" + "\n".join(lines))
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "audio_sound_server.txt").write_text("\n".join(lines) + "\n")
    assert [p.text for p in sp.played] == SAID
    heard_clips = [p.text for (p, k, corr, *_), lo in zip(found, least) if corr > lo]
    assert heard_clips == [p.text for p in sp.played], \
        [(p.text, round(corr, 3), lo) for (p, k, corr, *_), lo in zip(found, least)]
    assert starts == sorted(starts) and len(set(starts)) == len(starts), starts
    together = [(p.text, q.text) for (p, *_, b), (q, _, _, a, _) in zip(found, found[1:])
                if a < b]
    assert not together, f"two clips heard at once: {together}"
    assert not overlaps, f"speech during a stimulus: {overlaps}"
    assert not unmasked, f"no sound all through the stimulus: {unmasked}"
    assert min(leads) > 0 and min(lags) > 0, (leads, lags)
    assert not stray, f"heard outside every clip and the noise: {stray}"
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
