"""The participant's window: a PsychoPy screen that shows the trial and takes the answer.

Screens (each one a loop of draw, flip, poll):

``instructions``  one page per block of text separated by a line ``---``; space, Enter
                  or a click anywhere continues
``ready``         "Ready - feel the stimulus" with a fixation cross, shown by
                  ``stimulus_starts`` (and for each replay) while the stimulus plays
``choice``        the prompt and one LARGE button per option (mouse or touch), options
                  also on the number keys 1..9; a "feel it again" button where the
                  question allows replays, greyed out when none are left
``rating``        a row of buttons from one end of a scale to the other (0..4, -2..+2),
                  the paper's labels under the ends (or under any point)
``number``        a count: typed digits + Enter, or the - / + buttons and OK
``break``         ``pause(text)``: space or a click continues
``end``           ``finish(text)``: space, Enter, Escape or a click closes the window

Reaction times come from PsychoPy's clock, reset by ``win.callOnFlip`` on the flip
that first shows the question (``ask`` is called when the stimulus has ended, so this
is the time from the end of the stimulus to the answer, to within one frame). A key's
time is the one PsychoPy stamped it with; a click's is the poll that saw it.

The abort key (Escape unless chosen otherwise) on any screen but the end screen closes
the window and raises :class:`~vtexp.errors.SessionAborted`: the session engine turns
every actuator off and marks the session aborted, keeping the completed trials. While a
stimulus plays, the device asks ``stop_requested`` every few ms whether the key was
pressed; if so, it turns every actuator off at once, then the window closes
(``stimulus_stopped``) and the session aborts.

PsychoPy is the optional ``gui`` extra and is imported only when a window responder is
made. Importing it is kept from changing this process: ``PSYCHOPYNOPACKAGES=1`` stops it
from rewriting ``PYTHONPATH``/``PYTHONUSERBASE``/``PATH`` for its plugin folder, and
when the user has no ``~/.psychopy3`` yet, its preference folder goes to a temporary
directory removed at exit instead of the home directory. No plugin is scanned or
loaded and nothing asks the network for a newer version (``psychopy.visual`` does
neither); its console log shows errors only.
"""

from __future__ import annotations

import atexit
import gc
import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from collections.abc import Callable, Sequence
from types import SimpleNamespace

from ..clock import REAL, Clock
from ..design import Trial
from ..errors import InputError, SessionAborted, SessionError
from .base import Replay, Response
from .layout import GAP, LINE as LAYOUT_LINE, MIN_TEXT, PAD as LAYOUT_PAD, Box, Cell, \
    Label, LayoutError, Screen, grid as layout_grid, needed_height, text_block
from .speech import PsychopyAudio, Speech, Voice, masking_noise, phrase_book

# At most this many frames a second. A display that waits for its refresh (vsync, as a
# lab monitor does) never reaches it; where the flip returns at once (a virtual X
# server, a driver with vsync off) the loop would otherwise draw as fast as it can,
# taking a whole core to show a screen that does not change. Keys are read once a frame:
# 240 a second reads them every ~4 ms, finer than a 60 Hz monitor's 16.7 ms.
MAX_FRAME_RATE = 240.0

INSTALL_HELP = (
    "the participant window needs PsychoPy, the 'gui' extra: pip install -e '.[gui]' "
    "(from the vtexp folder). PsychoPy brings opencv-python, which hides the contrib "
    "build vtexp needs; put it back with: pip uninstall -y opencv-python "
    "opencv-python-headless && pip install --force-reinstall --no-deps "
    "opencv-contrib-python-headless (make venv-test does all of this)")

# Colours in PsychoPy's rgb space (-1..1): white on black, yellow for what is active.
BACKGROUND = (-1.0, -1.0, -1.0)
TEXT = (1.0, 1.0, 1.0)
BUTTON_FILL = (-0.6, -0.6, -0.45)
BUTTON_LINE = (1.0, 1.0, 1.0)
HOVER_LINE = (1.0, 1.0, -1.0)
DISABLED = (-0.3, -0.3, -0.3)

DIGIT_KEYS = {**{str(d): d for d in range(10)}, **{f"num_{d}": d for d in range(10)}}
CONTINUE_KEYS = ("space", "return", "num_enter")


def import_psychopy():
    """Import PsychoPy's window parts quietly, or say how to install them.

    PsychoPy computes its preference folder from ``HOME`` when imported and
    ``psychopy.monitors`` writes a monitor file there; pyglet connects to the
    display as ``psychopy.event`` is imported.
    """
    os.environ.setdefault("PSYCHOPYNOPACKAGES", "1")
    home = os.environ.get("HOME")
    redirect = ("psychopy.visual" not in sys.modules and home is not None
                and not Path(home, ".psychopy3").is_dir())
    if redirect:
        scratch = tempfile.mkdtemp(prefix="vtexp-psychopy-")
        atexit.register(shutil.rmtree, scratch, True)
        os.environ["HOME"] = scratch
    try:
        from psychopy import logging
        logging.console.setLevel(logging.ERROR)
        from psychopy import core, event, visual
    except ImportError as e:
        raise InputError(f"{INSTALL_HELP} (import failed: {e})", key="--responder") from None
    except Exception as e:          # pyglet: NoSuchDisplayException, no OpenGL...
        raise SessionError(f"cannot open the participant window: {type(e).__name__}: {e}. "
                           "Is a screen attached and DISPLAY set (e.g. DISPLAY=:0)?") from None
    finally:
        if redirect:
            os.environ["HOME"] = home
    return core, event, visual


@dataclass
class Button:
    """A rectangle on screen in ``height`` units (centre x, y; width, height)."""

    label: str
    value: object
    x: float
    y: float
    w: float
    h: float
    key: str | None = None        # keyboard shortcut shown on the button
    enabled: bool = True
    cell: Cell | None = None      # its computed place, label and key hint

    def contains(self, pos: Sequence[float]) -> bool:
        return abs(pos[0] - self.x) <= self.w / 2 and abs(pos[1] - self.y) <= self.h / 2


#: How long the masking noise is heard before each stimulus starts (s), on top of the
#: sound output's latency (the time its samples take to reach the headphones).
NOISE_LEAD_S = 0.15


@dataclass(frozen=True)
class WindowOptions:
    fullscreen: bool = True
    screen: int = 0
    size: tuple[int, int] = (1280, 800)
    abort_key: str = "escape"
    scale: float | None = None          # None: the experiment's (presentation.scale) or 1
    audio: bool | None = None           # None: the experiment's (presentation.audio)
    language: str | None = None
    noise: bool | None = None
    device: str | None = None           # the audio mode's sound output (None: the default)

    @classmethod
    def parse(cls, spec: str) -> WindowOptions:
        """``windowed``, ``fullscreen``, ``screen=N``, ``size=WxH``, ``abort=KEY``,
        ``scale=S``, ``audio``, ``audio=off``, ``lang=LANG``, ``noise=on|off``,
        ``device=NAME`` (the audio mode's sound output: its number in ``vtexp device list
        --audio``, or a part of its name), comma-separated."""
        opts: dict = {}
        for part in filter(None, (p.strip() for p in spec.split(","))):
            name, eq, value = part.partition("=")
            if part in ("windowed", "fullscreen"):
                opts["fullscreen"] = part == "fullscreen"
            elif name == "screen" and eq and value.isdigit():
                opts["screen"] = int(value)
            elif name == "size" and eq:
                w, _, h = value.lower().partition("x")
                if not (w.isdigit() and h.isdigit() and int(w) >= 320 and int(h) >= 240):
                    raise InputError(f"window size {value!r} is not WIDTHxHEIGHT in pixels "
                                     "(at least 320x240), e.g. size=1024x768", key="--responder")
                opts["size"] = (int(w), int(h))
            elif name == "abort" and eq and value:
                opts["abort_key"] = value.lower()
            elif name == "scale" and eq:
                try:
                    opts["scale"] = float(value)
                except ValueError:
                    opts["scale"] = -1.0
                if not 1.0 <= opts["scale"] <= 2.5:
                    raise InputError(f"window scale {value!r} is not a number from 1 to 2.5 "
                                     "(2: every text twice the smallest size)", key="--responder")
            elif name == "audio" and (not eq or value in ("on", "off")):
                opts["audio"] = value != "off"
            elif name == "lang" and eq and value:
                opts["language"] = value
            elif name == "noise" and value in ("on", "off"):
                opts["noise"] = value == "on"
            elif name == "device" and eq and value:
                opts["device"] = value
            else:
                raise InputError(f"unknown window option {part!r}; use windowed, fullscreen, "
                                 "screen=N, size=WxH, abort=KEY, scale=S, audio, lang=LANG, "
                                 "noise=on|off, device=NAME (e.g. window:windowed,size=1024x768)",
                                 key="--responder")
        return cls(**opts)


# --------------------------------------------------------------------------- answer keys

LETTERS = "abcdefghijklmnopqrstuvwxyz"
REPLAY_KEY, REPEAT_KEY = "space", "tab"
PLUS_KEYS = ("plus", "equal", "num_add", "up")
MINUS_KEYS = ("minus", "num_subtract", "down")
ENTER_KEYS = ("return", "num_enter")


@dataclass
class AnswerKeys:
    """How keys answer a question: each option's key (``keys``) and the key named for it
    (``names``), or typed digits confirmed with Enter (``typed``)."""

    keys: dict[str, str]
    names: dict[str, str]
    typed: bool = False
    signed: bool = False            # ratings below zero: the minus key first
    letters: bool = False           # the options are letters, each on its own key


def answer_keys(question) -> AnswerKeys:
    """Keys that match what the participant hears and sees: a letter option on its letter
    key, other options on 1..9 (or on A..Z past nine), a rating on the number itself
    (minus first below zero), a number typed and confirmed with Enter."""
    kind = getattr(question, "kind", "choice")
    options = [str(o) for o in question.options]
    if kind == "number":
        return AnswerKeys({}, {}, typed=True, signed=getattr(question, "minimum", 0) < 0)
    if kind == "rating":
        scale = list(question.scale)
        if all(abs(v) <= 9 for v in scale):
            keys = {str(abs(v)) if v >= 0 else f"-{abs(v)}": str(v) for v in scale}
            keys.update({f"num_{k}": v for k, v in list(keys.items()) if not k.startswith("-")})
            names = {str(v): (f"\u2212 {abs(v)}" if v < 0 else str(v)) for v in scale}
            return AnswerKeys(keys, names, signed=min(scale) < 0)
        return AnswerKeys({}, {str(v): str(v) for v in scale}, typed=True,
                          signed=min(scale) < 0)
    if all(len(o) == 1 and o.isalpha() for o in options) and \
            len({o.lower() for o in options}) == len(options):
        return AnswerKeys({o.lower(): o for o in options}, {o: o.upper() for o in options},
                          letters=True)
    if len(options) <= 9:
        keys = {str(i + 1): o for i, o in enumerate(options)}
        keys.update({f"num_{i + 1}": o for i, o in enumerate(options)})
        return AnswerKeys(keys, {o: str(i + 1) for i, o in enumerate(options)})
    if len(options) <= 26:
        return AnswerKeys({LETTERS[i]: o for i, o in enumerate(options)},
                          {o: LETTERS[i].upper() for i, o in enumerate(options)})
    raise SessionError(f"the question {getattr(question, 'name', '')!r} has {len(options)} "
                       "options; the participant window gives a key to at most 26")


def shown(option: str) -> str:
    return option.replace("_", " ")


def rating_text(v: int, signed: bool) -> str:
    return f"+{v}" if v > 0 and signed else (f"\u2212{abs(v)}" if v < 0 else str(v))


class WindowResponder:
    """Answers come from the participant, in a PsychoPy window.

    The window opens on the first screen shown and closes after ``finish`` (or on
    an abort, or ``close()``). Pass ``win`` to draw in a window made elsewhere; pass
    ``lx`` (the experiment) to lay out every question and render every spoken clip
    before the first trial; ``audio`` replaces PsychoPy's sound (tests); ``clock`` is
    what the spoken clips are timed on (:class:`~vtexp.clock.Clock`, the real one unless
    given).
    """

    participant_kind = "person"

    def __init__(self, options: WindowOptions | None = None, *, win=None, lx=None, audio=None,
                 clock: Clock = REAL):
        self.options = options or WindowOptions()
        self._core, self._event, self._visual = import_psychopy()
        self.win = win
        self.clock = self._core.Clock()
        self.screen: str | None = None        # name of the screen on show
        self.buttons: list[Button] = []       # what can be clicked on it
        self.layout: Screen | None = None     # its computed layout
        self._draw: Callable[[], None] | None = None
        self._mouse = None
        self._mouse_at_entry = None
        self._was_pressed = False
        self._last_flip = 0.0
        self._stims: dict[tuple, object] = {}
        self._practice_seen = False
        self._paused = False
        self._frozen = False                  # see _freeze_garbage
        self.entered: list[str] = []          # every screen shown, in order
        pres = getattr(getattr(lx, "experiment", None), "presentation", None)
        o = self.options
        self.scale = o.scale if o.scale is not None else (pres.scale if pres else 1.0)
        self.audio_mode = o.audio if o.audio is not None else bool(pres and pres.audio)
        self.language = o.language or (pres.language if pres else "en")
        noise = o.noise if o.noise is not None else (pres.masking_noise if pres else True)
        self.smallest = MIN_TEXT * self.scale
        self.speech: Speech | None = None
        self.lx = lx
        if self.audio_mode:
            book = phrase_book(self.language, dict(pres.phrases) if pres else None)
            name = lx.experiment.name if lx is not None else "any"
            # The sound output first: a computer without one is told before anything is
            # written (the dataset, the session folder, the speech cache).
            if audio is None:
                audio = PsychopyAudio(o.device)
            voice = Voice(name, self.language)
            self.speech = Speech(voice, audio, book,
                                 masking_noise(voice.folder) if noise else None, clock=clock)
            if lx is not None:
                voice.prerender(self.sentences(lx.experiment))
            prepare = getattr(audio, "prepare", None)
            if prepare is not None and self.speech.noise is not None:
                # The output's stream opened now: a stream opened by the first clip lost
                # that clip's first ~100 ms through a sound server.
                prepare(self.speech.noise)
        mode = "fullscreen" if o.fullscreen else "windowed {}x{}".format(*o.size)
        extra = (f", scale {self.scale:g}" if self.scale != 1 else "") + (
            f", audio {self.language}" + (", masking noise" if noise else "")
            + (f", sound output {audio.output['name']}" if hasattr(audio, "output") else "")
            if self.audio_mode else "")
        self.description = f"window ({mode}, screen {o.screen}{extra})"

    # -- the window ---------------------------------------------------------------

    def open(self):
        if self.win is None:
            o = self.options
            try:
                self.win = self._visual.Window(
                    size=o.size, fullscr=o.fullscreen, screen=o.screen, units="height",
                    color=BACKGROUND, colorSpace="rgb", allowGUI=not o.fullscreen,
                    winType="pyglet", checkTiming=False, monitor=None)
            except Exception as e:      # pyglet says little more than "cannot connect"
                raise SessionError(f"cannot open the participant window on screen "
                                   f"{o.screen} ({type(e).__name__}: {e}); is a display "
                                   "attached (DISPLAY set), and does the screen exist?") from None
            if self.lx is not None:
                self.check_layouts(self.lx.experiment)
            self._freeze_garbage()
        if self._mouse is None:
            self._mouse = self._event.Mouse(win=self.win, visible=True)
        return self.win

    @property
    def aspect(self) -> float:
        w, h = self.open().size
        return w / h

    def _freeze_garbage(self) -> None:
        """In the audio mode, keep the garbage collector off everything made so far
        (PsychoPy, the window, the rendered layouts: a quarter of a million objects).
        A full collection looked at all of them while holding the GIL, for 0.1-0.4 s on a
        busy computer, and the sound output's callback, which needs the GIL, ran dry
        meanwhile: the prompt being said was heard broken up. Undone in :meth:`close`,
        unless the program had frozen objects itself before (it then expects them to stay
        so, and ours stay with them)."""
        if self.speech is not None and not self._frozen:
            ours = gc.get_freeze_count() == 0
            gc.collect()
            gc.freeze()
            self._frozen = ours

    def close(self) -> None:
        if self.speech is not None:
            self.speech.stop()
            self.speech.stop_noise()
        if self._frozen:
            gc.unfreeze()               # collectable again, once the window has gone
            self._frozen = False
        if self.win is not None:
            self.win.close()
        self.win = self._mouse = None
        self.screen, self.buttons, self._draw, self.layout = None, [], None, None
        self._stims.clear()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def grab(self, only=None):
        """The screen on show as a picture (a PIL image), drawn into the back buffer, not
        flipped; ``only``: draw just that label (the layout tests measure each label
        alone)."""
        if self._draw is None:
            raise RuntimeError("no screen is on show")
        if only is None:
            self._draw()
        else:
            self._label(only)
        frame = self.win.getMovieFrame(buffer="back")
        self.win.movieFrames.remove(frame)      # given here, not kept for a movie
        self.win.clearBuffer()
        return frame

    def capture(self, path: Path | str, only=None) -> Path:
        """Save the screen on show as a PNG (see :meth:`grab`)."""
        frame = self.grab(only)
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        frame.save(path)
        return path

    def check_layouts(self, exp) -> None:
        """Lay out every question of ``exp`` now, so that a scale too large for this
        screen is said before the first trial, not in the middle of the session."""
        for q in exp.asked():
            try:
                self.question_screen(q, practice=True, replays_left=q.replays,
                                     answered=None)
            except LayoutError as e:
                raise SessionError(f"the question {q.name!r} does not fit a "
                                   f"{self.win.size[0]}x{self.win.size[1]} window at scale "
                                   f"{self.scale:g}: {e}; use a smaller scale or a larger "
                                   "screen") from None

    # -- what is said ------------------------------------------------------------------

    def sentences(self, exp) -> list[str]:
        """Every sentence a session of ``exp`` may speak (rendered before the first trial)."""
        sp = self.speech
        out = [sp.phrase(k) for k in ("headphones", "masking", "keys", "continue", "begin",
                                      "ready", "practice", "practice_over", "not_a_key",
                                      "no_replays", "paused", "resumed", "finish", "minus",
                                      "choose_letter_key")]
        out += [p.strip() for p in (exp.instructions or "").split("\n---\n")]
        for q in exp.asked():
            out += self.question_sentences(q)
            out += [sp.phrase("replay", left=n) for n in range(1, q.replays + 1)]
            for o in q.options[:201]:
                out.append(sp.phrase("answer_taken", answer=self.spoken_answer(q, o)))
            if q.kind == "number":
                out += [sp.phrase("too_large", maximum=q.maximum),
                        sp.phrase("too_small", minimum=q.minimum)]
                out += [str(d) for d in range(10)]
        every = exp.design.break_every
        if every:
            n = exp.design.repetitions * len(exp.design.conditions or []) or None
            if n:
                out += [sp.phrase("break", done=d, total=n) for d in range(every, n, every)]
        return out

    def question_sentences(self, q) -> list[str]:
        """The question as spoken: the prompt, then how to answer it."""
        sp = self.speech
        ak = answer_keys(q)
        if q.kind == "number":
            how = [sp.phrase("number", minimum=q.minimum, maximum=q.maximum)]
        elif q.kind == "rating":
            how = [sp.phrase("rating", low=q.low, high=q.high)]
            if ak.signed:
                how.append(sp.phrase("rating_negative"))
            how += [sp.phrase("rating_point", value=self.spoken_number(v), label=q.labels[v])
                    for v in q.scale if v in q.labels]
        elif ak.letters:
            how = [sp.phrase("choose_letter_key")]
        else:
            how = [" ".join(sp.phrase("choose_digit", key=ak.names[o], option=shown(o))
                            for o in q.options)]
        return [q.prompt, *how]

    def spoken_number(self, v: int) -> str:
        """-2 as "minus 2", in the phrase book's word: what the participant presses."""
        return f"{self.speech.phrase('minus')} {abs(v)}" if v < 0 else str(v)

    def spoken_answer(self, q, answer: str) -> str:
        if q.kind in ("rating", "number") and answer.lstrip("-").isdigit():
            return self.spoken_number(int(answer))
        return shown(answer)

    def _say(self, *texts: str, wait: bool = False) -> None:
        if self.speech is None:
            return
        self.speech.say(*texts)
        if wait:
            self._until_quiet()

    def _until_quiet(self) -> None:
        """Keep the screen alive until everything queued has been said (the abort key
        still works)."""
        while self.speech is not None and self.speech.busy():
            self._frame()

    # -- the session's hooks ---------------------------------------------------------

    def instructions(self, text: str) -> None:
        pages = [p.strip() for p in text.split("\n---\n")] if text.strip() else []
        pages = pages or [""]
        for i, page in enumerate(pages):
            last = i == len(pages) - 1
            more = "begin" if last else "continue"
            spoken = [page, self.speech.phrase(more)] if self.speech else []
            if i == 0 and self.speech is not None:
                # How to take part comes first: headphones on, then the keys.
                spoken = [self.speech.phrase("headphones")] + (
                    [self.speech.phrase("masking")] if self.speech.noise else []) + [
                    self.speech.phrase("keys")] + spoken
            self._wait_to_continue("instructions", page or "Press space to begin.",
                                   f"Press space or click to {'begin' if last else 'go on'}",
                                   spoken=spoken)

    def stimulus_starts(self, trial: Trial) -> None:
        if self.speech is not None and trial is not None:
            if trial.practice:
                self._practice_seen = True
            elif self._practice_seen:
                self._practice_seen = False
                self._say(self.speech.phrase("practice_over"))
                self._until_quiet()
        self._show_ready(trial)
        if self.speech is not None:
            lines = ([self.speech.phrase("practice")] if trial is not None and trial.practice
                     else []) + [self.speech.phrase("ready")]
            self._say(*lines, wait=True)        # nothing is heard while the stimulus plays
            self._noise_first()

    def _noise_first(self) -> None:
        """Start the masking noise NOISE_LEAD_S plus the output's latency before the
        stimulus: its first samples were heard a few milliseconds after the stimulus's
        start otherwise (measured through a sound server, tests/test_audio_sound_server.py)."""
        if self.speech is not None and self.speech.noise is not None:
            self.speech.start_noise()
            lead = NOISE_LEAD_S + getattr(self.speech.audio, "latency_s", 0.0)
            until = time.perf_counter() + lead
            while time.perf_counter() < until:
                self._frame(collect=False)

    def stimulus_played(self, trial: Trial, report) -> None:
        if self.speech is not None:
            self.speech.stop_noise()

    def stop_requested(self) -> str | None:
        """Why to stop if the abort key was pressed, else None (the device polls this
        every few ms while a stimulus plays).

        Reads only the abort key, so other keys stay for the screen that comes next
        (which forgets them, as it forgets anything pressed before it was shown).
        """
        if self.win is None:
            return None
        key = self.options.abort_key
        if self._event.getKeys(keyList=[key]):
            return f"the {key} key was pressed in the participant window during the stimulus"
        return None

    def stimulus_stopped(self, trial: Trial) -> None:
        """The stimulus was stopped by the abort key (every actuator is off): close."""
        self.close()

    def device_paused(self, trial: Trial) -> None:
        """The device failed: the participant is told to wait, not to feel anything."""
        if self.speech is not None:
            self.speech.stop_noise()
        self._paused = True
        self._message_screen("paused", "Paused\n\nPlease wait: the experimenter is checking "
                             "the device.")
        self._say(self.speech.phrase("paused") if self.speech else "")
        self._frame()              # shown; the terminal waits for the experimenter now

    def device_resumed(self, trial: Trial) -> None:
        self._paused = False
        self._say(self.speech.phrase("resumed") if self.speech else "", wait=True)

    def pause(self, text: str) -> None:
        self._wait_to_continue("break", text or "Take a break.",
                               "Press space or click when you are ready to go on",
                               spoken=[text])

    def finish(self, text: str) -> None:
        try:
            self._wait_to_continue("end", text, "Press space or click to close", abort=False,
                                   spoken=[self.speech.phrase("finish")] if self.speech else [],
                                   listen_while_speaking=False)
        finally:
            self.close()

    def ask(self, question, trial: Trial, replay: Replay | None) -> Response:
        kind = getattr(question, "kind", None) or type(question).__name__
        screen = QUESTION_SCREENS.get(kind)
        if screen is None:
            raise SessionError(f"the participant window cannot ask a {kind} question "
                               f"(it knows {', '.join(QUESTION_SCREENS)})")
        return screen(self, question, replay, trial)

    # -- question screens ------------------------------------------------------------------

    def ask_choice(self, prompt: str, options: Sequence[str], replay: Replay | None = None,
                   replays_allowed: int = 0, trial: Trial | None = None) -> Response:
        """Forced choice: one button per option, each on a key (letters on their letter)."""
        q = SimpleNamespace(kind="choice", name="response", prompt=prompt,
                            options=list(options), replays=replays_allowed)
        return self._ask(q, replay, trial)

    def ask_rating(self, prompt: str, scale: Sequence[int], labels: dict[int, str],
                   replay: Replay | None = None, replays_allowed: int = 0,
                   trial: Trial | None = None) -> Response:
        """A rating from ``scale`` (e.g. 0..4 or -2..2): the number's key answers, with the
        minus key first below zero; ``labels`` in the buttons of the points they name."""
        scale = list(scale)
        q = SimpleNamespace(kind="rating", name="rating", prompt=prompt, scale=scale,
                            low=min(scale), high=max(scale), labels=dict(labels),
                            options=[str(v) for v in scale], replays=replays_allowed)
        return self._ask(q, replay, trial)

    def ask_number(self, prompt: str, minimum: int = 0, maximum: int = 99,
                   replay: Replay | None = None, replays_allowed: int = 0,
                   trial: Trial | None = None) -> Response:
        """A count: digits typed then Enter; up/down, + and - change it; Backspace corrects."""
        q = SimpleNamespace(kind="number", name="count", prompt=prompt, minimum=minimum,
                            maximum=maximum, options=[str(v) for v in range(minimum,
                                                                             maximum + 1)],
                            replays=replays_allowed)
        return self._ask(q, replay, trial)

    # -- layout -------------------------------------------------------------------------

    def question_screen(self, q, *, practice: bool, replays_left: int | None, answered,
                        typed: str = "", status: str = "") -> Screen:
        """The computed layout of a question screen (see :mod:`.layout`): from the top, the
        practice banner, the prompt, the answers, one status line (the answer taken, or how
        to answer when there is room), and the controls (feel it again, hear it again)."""
        a, s = self.aspect, self.smallest
        m = 0.02
        width = a - 2 * m
        screen = Screen(q.kind)
        top = 0.5 - m
        line = s * (LAYOUT_LINE + 2 * LAYOUT_PAD)
        if practice:
            screen.labels.append(text_block("PRACTICE – not counted",
                                            Box(0, top - line / 2, width, line), s, s, "banner"))
            top -= line + 0.01
        prompt_h = max(needed_height(q.prompt, width, s) or 1.0, 0.1)
        screen.labels.append(text_block(q.prompt, Box(0, top - prompt_h / 2, width, prompt_h),
                                        s, max(s, 0.06), "prompt"))
        top -= prompt_h + 0.01
        bottom = -0.5 + m
        controls = []
        if replays_left is not None and getattr(q, "replays", 0) > 0:
            controls.append(("again", f"space: feel it again ({replays_left} left)"
                             if replays_left else "no replays left"))
        if self.speech is not None:
            controls.append(("repeat", "Tab: hear it again"))
        if controls:
            for rows in (1, 2):
                ctl_h = rows * line + (rows - 1) * GAP
                try:
                    cells = layout_grid([(lbl, None) for _, lbl in controls],
                                        Box(0, bottom + ctl_h / 2, width, ctl_h), s, s,
                                        rows_only=(rows,))
                    break
                except LayoutError:
                    if rows == 2:
                        raise
            for (value, _), cell in zip(controls, cells):
                cell.value = value
                screen.cells.append(cell)
            bottom += ctl_h + 0.01
        status = status or (f"Taken: {shown(str(answered))}" if answered is not None else "")
        text = status
        if not text:
            hint = self._hint(q)
            text = hint if (needed_height(hint, width, s) or 1.0) <= line + 1e-9 else ""
        if text.strip():
            screen.labels.append(text_block(text, Box(0, bottom + line / 2, width, line), s, s,
                                            "status" if status else "hint"))
        bottom += line + 0.01
        area = Box(0, (top + bottom) / 2, width, top - bottom)
        if area.h < line:
            raise LayoutError("no room is left for the answers")
        ak = answer_keys(q)
        if q.kind == "number":
            self._number_layout(screen, q, area, typed)
            return screen
        if q.kind == "rating":
            keys = [None if not ak.keys else "key " + ak.names[str(v)] for v in q.scale]
            try:                    # from one end of the scale to the other, in one row
                cells = layout_grid([(rating_text(v, ak.signed)
                                      + (f"\n{q.labels[v]}" if v in q.labels else ""), k)
                                     for v, k in zip(q.scale, keys)],
                                    area, s, max(s, 0.075), rows_only=(1,))
            except LayoutError:     # or, when the labels are too long for that, in a column
                cells = layout_grid([(rating_text(v, ak.signed)
                                      + (f"   {q.labels[v]}" if v in q.labels else "")
                                      + (f"   ({k})" if k else ""), None)
                                     for v, k in zip(q.scale, keys)],
                                    area, s, max(s, 0.06), rows_only=(len(q.scale),))
        else:
            items = [(shown(o), None if ak.letters else "key " + ak.names[o]) for o in q.options]
            cells = layout_grid(items, area, s, max(s, 0.075 if not ak.letters else 0.09))
        for o, cell in zip(q.options, cells):
            cell.value = o
            screen.cells.append(cell)
        return screen

    def _hint(self, q) -> str:
        ak = answer_keys(q)
        if q.kind == "number":
            return "Type the number, then Enter (↑ ↓ change it)"
        if q.kind == "rating":
            return ("Press the number (− first below 0), or click" if ak.signed
                    else "Press the number, or click")
        if ak.letters:
            return "Press the letter's key, or click"
        return "Press an answer's key, or click it"

    def _number_layout(self, screen: Screen, q, area: Box, typed: str) -> None:
        """The number typed, between a minus and a plus button; OK below; its range."""
        s = self.smallest
        line = s * (LAYOUT_LINE + 2 * LAYOUT_PAD)
        range_h = line if area.h >= 4 * line else 0.0
        row_h = min(0.22, area.h - line - range_h - 0.02)
        if row_h < line:
            raise LayoutError("no room for the number and its buttons")
        y = area.top - row_h / 2
        bw = max(0.12, min(0.2, area.w / 6))
        value_box = Box(0, y, area.w - 2 * bw - 2 * GAP_X, row_h)
        for value, label, x in (("minus", "\u2212", -(area.w - bw) / 2),
                                ("plus", "+", (area.w - bw) / 2)):
            cell = layout_grid([(label, None)], Box(x, y, bw, row_h), s, 0.1)[0]
            cell.value = value
            screen.cells.append(cell)
        screen.labels.append(text_block(typed or "_", value_box, s, min(0.12, row_h * 0.6),
                                        "value"))
        ok_y = y - row_h / 2 - 0.01 - line / 2
        ok = layout_grid([("OK (Enter)", None)], Box(0, ok_y, min(area.w, max(0.5, 8 * s)),
                                                     line), s, s)[0]
        ok.value = "ok"
        screen.cells.append(ok)
        if range_h:
            screen.labels.append(text_block(f"from {q.minimum} to {q.maximum}",
                                            Box(0, ok_y - line / 2 - 0.01 - range_h / 2, area.w,
                                                range_h), s, s, "range"))

    def _message_screen(self, name: str, text: str, hint: str = "") -> None:
        self.open()
        a, s = self.aspect, self.smallest
        screen = Screen(name)
        line = s * (LAYOUT_LINE + 2 * LAYOUT_PAD)
        hint_h = 2 * line if hint else 0.0
        screen.labels.append(text_block(text, Box(0, (hint_h + 0.02) / 2, a - 0.06,
                                                  1 - 0.06 - hint_h), s, max(s, 0.05)))
        if hint:
            screen.labels.append(text_block(hint, Box(0, -0.5 + 0.02 + hint_h / 2, a - 0.06,
                                                      hint_h), s, s * 1.2, "hint"))
        self._enter(name, screen)

    # -- the loop behind every screen -----------------------------------------------

    def _ask(self, q, replay: Replay | None, trial: Trial | None) -> Response:
        win = self.open()
        practice = bool(trial is not None and getattr(trial, "practice", False))
        left = q.replays if replay is not None else 0
        used = 0
        state = {"typed": "", "sign": "", "status": ""}
        ak = answer_keys(q)

        def show(answered=None, status="", entering=False):
            screen = self.question_screen(q, practice=practice,
                                          replays_left=(left - used) if left else None,
                                          answered=answered, typed=state["sign"] + state["typed"],
                                          status=status)
            self._enter(q.kind, screen, keep_input=not entering, chosen=answered)
            for b in self.buttons:
                if b.value == "again":
                    b.enabled = used < left

        def speak_question():
            if self.speech is not None:
                extra = [self.speech.phrase("replay", left=left - used)] if used < left else []
                self._say(*self.question_sentences(q), *extra)

        show(entering=True)
        win.callOnFlip(self.clock.reset)        # the time origin: the flip that shows it
        self._first_frame()
        speak_question()
        while True:
            for key, t, button in self._frame():
                value = button.value if button is not None else None
                if value == "again" or (key == REPLAY_KEY and left):
                    if used >= left:
                        self._say(self.speech.phrase("no_replays") if self.speech else "")
                        continue
                    used += 1
                    self._show_ready(trial)
                    if self.speech is not None:
                        self._say(self.speech.phrase("ready"), wait=True)
                        self._noise_first()
                    replay()
                    show(entering=True)
                    win.callOnFlip(self.clock.reset)
                    self._first_frame()
                    speak_question()
                    break
                if value == "repeat" or key == REPEAT_KEY:
                    speak_question()
                    continue
                answer = self._answer_from(q, ak, key, value, state)
                if answer is None:
                    if state["status"]:
                        show(status=state["status"])
                    continue
                rt = round(t, 4)
                self._confirm(q, answer, show)
                return Response(answer=str(answer), rt_s=rt, replays=used)

    def _answer_from(self, q, ak: AnswerKeys, key, value, state) -> str | None:
        """The answer a key or click gives, or None (typed input kept in ``state``)."""
        state["status"] = ""
        if value is not None and value not in ("minus", "plus", "ok"):
            return str(value)
        if q.kind == "number" or ak.typed:
            return self._typed(q, key, value, state)
        if key is None:
            return None
        if ak.signed and key in MINUS_KEYS[:2]:
            state["sign"] = "-"
            state["status"] = "\u2212 …"
            self._say(self.speech.phrase("minus") if self.speech else "")
            return None
        k = key[4:] if key.startswith("num_") and key[4:].isdigit() else key
        if state["sign"] and k.isdigit():
            k = "-" + k
        state["sign"] = ""
        if k in ak.keys:
            return ak.keys[k]
        if key not in ("lshift", "rshift", "capslock", "lctrl", "rctrl"):
            self._say(self.speech.phrase("not_a_key") if self.speech else "")
        return None

    def _typed(self, q, key, value, state) -> str | None:
        lo = q.minimum if q.kind == "number" else q.low
        hi = q.maximum if q.kind == "number" else q.high
        text = state["sign"] + state["typed"]
        current = int(text) if text.lstrip("-") else None

        def set_value(v):
            v = max(lo, min(hi, v))
            state["sign"], state["typed"] = ("-" if v < 0 else ""), str(abs(v))
            self._say(str(v))

        if key in DIGIT_KEYS:
            cand = state["typed"] + str(DIGIT_KEYS[key])
            v = int(state["sign"] + cand)
            if v > hi:
                state["status"] = f"{hi} is the largest"
                self._say(self.speech.phrase("too_large", maximum=hi) if self.speech else "")
            else:
                state["typed"] = cand.lstrip("0") or "0"
                self._say(str(DIGIT_KEYS[key]))
        elif key == "backspace":
            state["typed"] = state["typed"][:-1]
            if not state["typed"]:
                state["sign"] = ""
        elif (key in ("minus", "num_subtract") and lo < 0 and not state["typed"]):
            state["sign"] = "-"
            self._say(self.speech.phrase("minus") if self.speech else "")
        elif key in MINUS_KEYS or value == "minus":
            set_value((current if current is not None else lo + 1) - 1)
        elif key in PLUS_KEYS or value == "plus":
            set_value((current if current is not None else lo - 1) + 1)
        elif key in ENTER_KEYS or value == "ok":
            if current is None:
                return None
            if current < lo:
                state["status"] = f"{lo} is the smallest"
                self._say(self.speech.phrase("too_small", minimum=lo) if self.speech else "")
                return None
            return str(current)
        state["status"] = state["status"] or "\u00a0"     # redraw with the typed value
        return None

    def _confirm(self, q, answer: str, show) -> None:
        """The answer is shown taken (its button filled) and said back, before moving on."""
        show(answered=answer)
        self._first_frame()
        if self.speech is not None:
            self._say(self.speech.phrase("answer_taken", answer=self.spoken_answer(q, answer)))
        until = self._core.getTime() + CONFIRM_S
        while self._core.getTime() < until or (self.speech is not None and self.speech.busy()):
            self._frame(collect=False)

    def _wait_to_continue(self, name: str, text: str, hint: str, abort: bool = True,
                          spoken: Sequence[str] = (), listen_while_speaking: bool = True) -> None:
        self._message_screen(name, text, hint)
        self._first_frame()
        if self.speech is not None and spoken:
            self._say(*spoken)
            if not listen_while_speaking:       # the end: said in full before it closes
                while self.speech.busy():
                    self._frame(abort=abort, collect=False)
        while True:
            for key, _, _button in self._frame(abort=abort, click_anywhere=True):
                if key == REPEAT_KEY and self.speech is not None:
                    self._say(*spoken)
                    continue
                if key in CONTINUE_KEYS or key == "click" or (not abort and
                                                              key == self.options.abort_key):
                    if self.speech is not None:
                        self.speech.stop()
                    return

    def _first_frame(self) -> None:
        """Draw the screen just entered once, before anything is said over it: its first
        drawing makes its text (a quarter of a second for a question screen on a busy
        computer), holding the GIL that the sound output's callback needs, and a clip
        started before it was heard broken up. Keys wait for the screen's own loop."""
        if self.speech is not None:
            self._frame(collect=False)

    def _show_ready(self, trial: Trial | None = None) -> None:
        self.open()
        a, s = self.aspect, self.smallest
        screen = Screen("ready")
        line = s * (LAYOUT_LINE + 2 * LAYOUT_PAD)
        if trial is not None and trial.practice:
            screen.labels.append(text_block("PRACTICE (does not count)",
                                            Box(0, 0.5 - 0.02 - line / 2, a - 0.06, line), s,
                                            s * 1.2, "banner"))
        screen.labels.append(text_block("Ready", Box(0, 0.25, a - 0.06, 0.14), s, 0.07))
        screen.labels.append(text_block("Feel the stimulus", Box(0, -0.25, a - 0.06, 0.14), s,
                                        0.06))
        self._enter("ready", screen, cross=True)
        self._frame()           # shown now; Escape pressed before it aborts here

    def _enter(self, name: str, screen: Screen, keep_input: bool = False, cross: bool = False,
               chosen=None) -> None:
        """Make ``name`` the screen on show; forget input meant for the one before,
        except the abort key (pressed between two trials, it aborts here)."""
        buttons = []
        for c in screen.cells:
            b = c.box
            buttons.append(Button(c.label.text, getattr(c, "value", None), b.x, b.y, b.w, b.h,
                                  key=c.key.text if c.key else None, cell=c))
        entering = not keep_input
        self.screen, self.layout, self.buttons = name, screen, buttons
        win = self.win

        def draw():
            for b in self.buttons:
                self._button(b, chosen=chosen is not None and str(b.value) == str(chosen))
            for lb in screen.labels:
                self._label(lb)
            if cross:
                self._stim(("cross",), lambda: self._visual.ShapeStim(
                    win, vertices="cross", size=0.12, lineWidth=0, fillColor=TEXT,
                    colorSpace="rgb")).draw()
        self._draw = draw
        if not entering:
            return
        self.entered.append(name)
        key = self.options.abort_key
        if self._event.getKeys(keyList=[key]):
            self.close()
            raise SessionAborted(f"the {key} key was pressed in the participant window")
        self._event.clearEvents()
        self._was_pressed = bool(self._mouse.getPressed()[0])
        self._mouse_at_entry = tuple(self._mouse.getPos())

    def _frame(self, abort: bool = True, click_anywhere: bool = False, collect: bool = True):
        """Draw and flip the screen; return its input as (key, time, button) tuples."""
        if self.speech is not None:
            self.speech.update()
        self._draw()
        wait = self._last_flip + 1.0 / MAX_FRAME_RATE - time.perf_counter()
        if wait > 0:            # the display did not wait for its refresh: pace the frames
            time.sleep(wait)
        self.win.flip()
        self._last_flip = time.perf_counter()
        got = []
        if not collect:         # keys wait for the next screen (the abort key aborts there)
            return got
        for key, t in self._event.getKeys(timeStamped=self.clock):
            if abort and key == self.options.abort_key:
                self.close()
                raise SessionAborted(f"the {key} key was pressed in the participant window")
            got.append((key, t, None))
        pressed = bool(self._mouse.getPressed()[0])
        if pressed and not self._was_pressed:
            pos = self._mouse.getPos()
            hit = next((b for b in self.buttons if b.enabled and b.contains(pos)), None)
            if hit is not None or click_anywhere:
                got.append(("click", self.clock.getTime(), hit))
        self._was_pressed = pressed
        return got

    # -- drawing ------------------------------------------------------------------------

    def _stim(self, key: tuple, make: Callable[[], object]):
        """A stimulus made once and drawn every frame (making text costs milliseconds)."""
        stim = self._stims.get(key)
        if stim is None:
            stim = self._stims[key] = make()
        return stim

    def _text(self, text, x, y, height, wrap=None, color=TEXT):
        self._stim(("text", text, x, y, height, wrap, color), lambda: self._visual.TextStim(
            self.win, text, pos=(x, y), height=height, wrapWidth=wrap, color=color,
            colorSpace="rgb", font="DejaVu Sans", alignText="center",
            anchorHoriz="center")).draw()

    def _label(self, lb: Label, color=None) -> None:
        color = color or {"hint": HOVER_LINE, "key": HOVER_LINE, "banner": HOVER_LINE,
                          "status": HOVER_LINE}.get(lb.role, TEXT)
        # The lines are broken already; the wrap width only keeps PsychoPy from breaking them.
        self._text(lb.text, lb.box.x, lb.box.y, lb.height, wrap=self.aspect * 2, color=color)

    def _button(self, b: Button, chosen: bool = False):
        moved = self._mouse is not None and self._mouse_at_entry is not None and \
            tuple(self._mouse.getPos()) != self._mouse_at_entry
        hover = b.enabled and moved and b.contains(self._mouse.getPos())
        fill = (CHOSEN_FILL if chosen else BUTTON_FILL) if b.enabled else BACKGROUND
        line = (HOVER_LINE if hover or chosen else BUTTON_LINE) if b.enabled else DISABLED
        self._stim(("rect", b.x, b.y, b.w, b.h, fill, line), lambda: self._visual.Rect(
            self.win, width=b.w, height=b.h, pos=(b.x, b.y), lineWidth=4, fillColor=fill,
            lineColor=line, colorSpace="rgb")).draw()
        color = (CHOSEN_TEXT if chosen else TEXT) if b.enabled else DISABLED
        self._label(b.cell.label, color=color)
        if b.cell.key is not None and b.enabled:
            self._label(b.cell.key, color=CHOSEN_TEXT if chosen else HOVER_LINE)


def rating_label(value) -> str:
    try:
        v = int(str(value))
    except ValueError:
        return str(value)
    return f"+{v}" if v > 0 else (f"\u2212{abs(v)}" if v < 0 else str(v))


CHOSEN_FILL = (1.0, 1.0, -1.0)        # the answer taken: yellow, black text
CHOSEN_TEXT = (-1.0, -1.0, -1.0)
CONFIRM_S = 0.6                       # how long the answer taken is shown, at least
GAP_X = 0.025


def _choice(r: WindowResponder, q, replay, trial=None):
    return r._ask(q, replay, trial)


def _rating(r: WindowResponder, q, replay, trial=None):     # vtexp.experiment.RatingQuestion
    scale = list(q.scale)
    q = SimpleNamespace(kind="rating", name=getattr(q, "name", "rating"), prompt=q.prompt,
                        scale=scale, low=min(scale), high=max(scale),
                        labels=dict(getattr(q, "labels", {}) or {}),
                        options=[str(v) for v in scale], replays=getattr(q, "replays", 0))
    return r._ask(q, replay, trial)


def _number(r: WindowResponder, q, replay, trial=None):     # vtexp.experiment.NumberQuestion
    lo, hi = getattr(q, "minimum", 0), getattr(q, "maximum", 99)
    q = SimpleNamespace(kind="number", name=getattr(q, "name", "count"), prompt=q.prompt,
                        minimum=lo, maximum=hi, replays=getattr(q, "replays", 0),
                        options=[str(v) for v in range(lo, min(hi, lo + 200) + 1)])
    return r._ask(q, replay, trial)


# Question kind (the model's ``kind`` field, else its class name) -> the screen that asks it.
QUESTION_SCREENS: dict[str, Callable[..., Response]] = {
    "ChoiceQuestion": _choice, "choice": _choice,
    "RatingQuestion": _rating, "rating": _rating,
    "NumberQuestion": _number, "number": _number,
}


def make_window(spec: str, lx=None) -> WindowResponder:
    """Build the window responder from the part of ``--responder`` after ``window:``."""
    return WindowResponder(WindowOptions.parse(spec), lx=lx)
