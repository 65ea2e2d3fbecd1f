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
import os
import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from collections.abc import Callable, Sequence

from ..design import Trial
from ..errors import InputError, SessionAborted, SessionError
from .base import Replay, Response

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

    def contains(self, pos: Sequence[float]) -> bool:
        return abs(pos[0] - self.x) <= self.w / 2 and abs(pos[1] - self.y) <= self.h / 2


@dataclass(frozen=True)
class WindowOptions:
    fullscreen: bool = True
    screen: int = 0
    size: tuple[int, int] = (1280, 800)
    abort_key: str = "escape"

    @classmethod
    def parse(cls, spec: str) -> WindowOptions:
        """``windowed``, ``fullscreen``, ``screen=N``, ``size=WxH``, ``abort=KEY``, comma-separated."""
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
            else:
                raise InputError(f"unknown window option {part!r}; use windowed, fullscreen, "
                                 "screen=N, size=WxH, abort=KEY (e.g. window:windowed,"
                                 "size=1024x768)", key="--responder")
        return cls(**opts)


class WindowResponder:
    """Answers come from the participant, in a PsychoPy window.

    The window opens on the first screen shown and closes after ``finish`` (or on
    an abort, or ``close()``). Pass ``win`` to draw in a window made elsewhere.
    """

    def __init__(self, options: WindowOptions | None = None, *, win=None):
        self.options = options or WindowOptions()
        self._core, self._event, self._visual = import_psychopy()
        self.win = win
        self.clock = self._core.Clock()
        self.screen: str | None = None        # name of the screen on show
        self.buttons: list[Button] = []       # what can be clicked on it
        self._draw: Callable[[], None] | None = None
        self._mouse = None
        self._was_pressed = False
        self._stims: dict[tuple, object] = {}
        mode = "fullscreen" if self.options.fullscreen else \
            "windowed {}x{}".format(*self.options.size)
        self.description = f"window ({mode}, screen {self.options.screen})"

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
        if self._mouse is None:
            self._mouse = self._event.Mouse(win=self.win, visible=True)
        return self.win

    def close(self) -> None:
        if self.win is not None:
            self.win.close()
        self.win = self._mouse = None
        self.screen, self.buttons, self._draw = None, [], None
        self._stims.clear()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def capture(self, path: Path | str) -> Path:
        """Save the screen on show as a PNG (drawn into the back buffer, not flipped)."""
        if self._draw is None:
            raise RuntimeError("no screen is on show")
        self._draw()
        frame = self.win.getMovieFrame(buffer="back")
        self.win.movieFrames.remove(frame)      # saved here, not kept for a movie
        self.win.clearBuffer()
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        frame.save(path)
        return path

    # -- the session's hooks ---------------------------------------------------------

    def instructions(self, text: str) -> None:
        pages = [p.strip() for p in text.split("\n---\n")] if text.strip() else []
        for i, page in enumerate(pages or ["Press space to begin."]):
            more = "next page" if i < len(pages) - 1 else "begin"
            self._wait_to_continue("instructions", page, f"Press space or click to {more}")

    def stimulus_starts(self, trial: Trial) -> None:
        self._show_ready()

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

    def pause(self, text: str) -> None:
        self._wait_to_continue("break", text or "Take a break.",
                               "Press space or click when you are ready to go on")

    def finish(self, text: str) -> None:
        try:
            self._wait_to_continue("end", text, "Press space or click to close", abort=False)
        finally:
            self.close()

    def ask(self, question, trial: Trial, replay: Replay | None) -> Response:
        kind = getattr(question, "kind", None) or type(question).__name__
        screen = QUESTION_SCREENS.get(kind)
        if screen is None:
            raise SessionError(f"the participant window cannot ask a {kind} question "
                               f"(it knows {', '.join(QUESTION_SCREENS)})")
        return screen(self, question, replay)

    # -- question screens (ready for the schema's rating and number questions) ----------

    def ask_choice(self, prompt: str, options: Sequence[str], replay: Replay | None = None,
                   replays_allowed: int = 0) -> Response:
        """Forced choice: one big button per option; number keys 1..9 choose too."""
        n = len(options)
        cols = n if n <= 4 else (3 if n in (5, 6, 9) else 4)
        rows = -(-n // cols)
        aspect = self.open().size[0] / self.open().size[1]
        w = min(0.42, (aspect - 0.1) / cols - 0.03)
        h = min(0.16, 0.5 / rows - 0.03)
        buttons = []
        for i, opt in enumerate(options):
            r, c = divmod(i, cols)
            in_row = min(cols, n - r * cols)
            x = (c - (in_row - 1) / 2) * (w + 0.03)
            y = 0.1 - r * (h + 0.03)
            buttons.append(Button(opt.replace("_", " "), opt, x, y, w, h,
                                  key=str(i + 1) if i < 9 else None))
        keys = {b.key: b.value for b in buttons if b.key}
        keys.update({f"num_{k}": v for k, v in list(keys.items())})
        return self._question("choice", prompt, buttons, keys, replay, replays_allowed)

    def ask_rating(self, prompt: str, scale: Sequence[int], labels: dict[int, str],
                   replay: Replay | None = None, replays_allowed: int = 0) -> Response:
        """A rating from ``scale`` (e.g. 0..4 or -2..2), ``labels`` under the points named.

        Keys: on a scale of single non-negative digits the digit is the rating;
        otherwise 1..n choose from the left.
        """
        scale = list(scale)
        digits = all(0 <= v <= 9 for v in scale)
        aspect = self.open().size[0] / self.open().size[1]
        w = min(0.2, (aspect - 0.1) / len(scale) - 0.02)
        buttons = []
        for i, v in enumerate(scale):
            x = (i - (len(scale) - 1) / 2) * (w + 0.02)
            key = str(v) if digits else (str(i + 1) if i < 9 else None)
            text = f"+{v}" if v > 0 and min(scale) < 0 else str(v)
            buttons.append(Button(text, v, x, 0.05, w, 0.16, key=key))
        keys = {b.key: b.value for b in buttons if b.key}
        keys.update({f"num_{k}": v for k, v in list(keys.items())})
        notes = [(labels[b.value], b.x, 0.05 - 0.16) for b in buttons if b.value in labels]
        return self._question("rating", prompt, buttons, keys, replay, replays_allowed,
                              notes=notes, show_keys=not digits)

    def ask_number(self, prompt: str, minimum: int = 0, maximum: int = 99,
                   replay: Replay | None = None, replays_allowed: int = 0) -> Response:
        """A count: digits typed then Enter, or - / + and OK; Backspace corrects."""
        state = {"text": ""}

        def value() -> int | None:
            return int(state["text"]) if state["text"] else None

        def set_value(v: int) -> None:
            state["text"] = str(max(minimum, min(maximum, v)))

        minus = Button("\u2212", "minus", -0.3, 0.05, 0.16, 0.16)
        plus = Button("+", "plus", 0.3, 0.05, 0.16, 0.16)
        ok = Button("OK", "ok", 0, -0.22, 0.3, 0.12, key="Enter")

        def on_input(key: str | None, button: Button | None):
            if key in DIGIT_KEYS:
                typed = state["text"] + str(DIGIT_KEYS[key])
                if int(typed) <= maximum:
                    state["text"] = typed.lstrip("0") or "0"
            elif key == "backspace":
                state["text"] = state["text"][:-1]
            elif key in ("minus", "num_subtract") or (button is minus):
                set_value((value() if value() is not None else minimum + 1) - 1)
            elif key in ("plus", "equal", "num_add") or (button is plus):
                set_value((value() if value() is not None else minimum - 1) + 1)
            elif (key in ("return", "num_enter") or button is ok) and value() is not None \
                    and value() >= minimum:
                return value()
            ok.enabled = value() is not None and value() >= minimum
            return None

        ok.enabled = False

        def draw_value():
            self._text(state["text"] or "_", 0, 0.05, 0.12)
            self._text(f"from {minimum} to {maximum}", 0, -0.09, 0.035)

        return self._question("number", prompt, [minus, plus, ok], on_input, replay,
                              replays_allowed, extra=draw_value)

    # -- the loop behind every screen -----------------------------------------------

    def _question(self, name, prompt, buttons, keys, replay, replays_allowed, *,
                  notes=(), show_keys=True, extra=None) -> Response:
        win = self.open()
        left = replays_allowed if replay is not None else 0
        again = Button("Feel it again", "again", 0, -0.38, 0.5, 0.1, key="R") if left else None
        used = 0

        def draw():
            self._text(prompt, 0, 0.36, 0.06, wrap=win.size[0] / win.size[1] - 0.15)
            for b in buttons:
                self._button(b, show_key=show_keys)
            for text, x, y in notes:
                self._text(text, x, y, 0.035, wrap=0.3)
            if extra:
                extra()
            if again:
                again.label = f"Feel it again ({left - used} left)" if left - used else \
                    "No replays left"
                again.enabled = used < left
                self._button(again, show_key=True)

        all_buttons = buttons + ([again] if again else [])
        self._enter(name, draw, all_buttons)
        rt_reset = True
        while True:
            if rt_reset:
                # The time origin is the flip that (first) shows the question.
                win.callOnFlip(self.clock.reset)
                rt_reset = False
            for key, t, button in self._frame():
                if again is not None and again.enabled and (button is again or key == "r"):
                    used += 1
                    self._show_ready()
                    replay()
                    self._enter(name, draw, all_buttons)
                    break
                if callable(keys):                   # a screen with its own input rules
                    v = keys(key, button)
                else:
                    v = button.value if button is not None and button in buttons else \
                        keys.get(key)
                if v is not None:
                    return Response(answer=str(v), rt_s=round(t, 4), replays=used)

    def _wait_to_continue(self, name: str, text: str, hint: str, abort: bool = True) -> None:
        win = self.open()

        def draw():
            self._text(text, 0, 0.08, 0.05, wrap=win.size[0] / win.size[1] - 0.2)
            self._text(hint, 0, -0.4, 0.035, color=HOVER_LINE)

        self._enter(name, draw, [])
        while True:
            for key, _, _button in self._frame(abort=abort, click_anywhere=True):
                if key in CONTINUE_KEYS or key == "click" or (not abort and
                                                              key == self.options.abort_key):
                    return

    def _show_ready(self) -> None:
        win = self.open()

        def draw():
            self._text("Ready", 0, 0.25, 0.07)
            self._stim(("cross",), lambda: self._visual.ShapeStim(
                win, vertices="cross", size=0.12, lineWidth=0, fillColor=TEXT,
                colorSpace="rgb")).draw()
            self._text("Feel the stimulus", 0, -0.25, 0.06)

        self._enter("ready", draw, [])
        self._frame()           # shown now; Escape pressed before it aborts here

    def _enter(self, name: str, draw: Callable[[], None], buttons: list[Button]) -> None:
        """Make ``name`` the screen on show; forget input meant for the one before,
        except the abort key (pressed between two trials, it aborts here)."""
        self.screen, self._draw, self.buttons = name, draw, buttons
        key = self.options.abort_key
        if self._event.getKeys(keyList=[key]):
            self.close()
            raise SessionAborted(f"the {key} key was pressed in the participant window")
        self._event.clearEvents()
        self._was_pressed = bool(self._mouse.getPressed()[0])

    def _frame(self, abort: bool = True, click_anywhere: bool = False):
        """Draw and flip the screen; return its input as (key, time, button) tuples."""
        self._draw()
        self.win.flip()
        got = []
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

    def _button(self, b: Button, show_key: bool = True):
        hover = b.enabled and self._mouse is not None and b.contains(self._mouse.getPos())
        fill = BUTTON_FILL if b.enabled else BACKGROUND
        line = (HOVER_LINE if hover else BUTTON_LINE) if b.enabled else DISABLED
        self._stim(("rect", b.x, b.y, b.w, b.h, fill, line), lambda: self._visual.Rect(
            self.win, width=b.w, height=b.h, pos=(b.x, b.y), lineWidth=6, fillColor=fill,
            lineColor=line, colorSpace="rgb")).draw()
        color = TEXT if b.enabled else DISABLED
        self._text(b.label, b.x, b.y, min(0.06, b.h * 0.4), wrap=b.w * 0.95, color=color)
        if show_key and b.key and b.enabled:
            self._text(f"key {b.key}", b.x + b.w / 2 - 0.06, b.y - b.h / 2 + 0.02, 0.025,
                       color=HOVER_LINE)


def _choice(r: WindowResponder, q, replay):
    return r.ask_choice(q.prompt, q.options, replay, q.replays)


def _rating(r: WindowResponder, q, replay):     # vtexp.experiment.RatingQuestion
    return r.ask_rating(q.prompt, q.scale, dict(getattr(q, "labels", {}) or {}), replay,
                        getattr(q, "replays", 0))


def _number(r: WindowResponder, q, replay):     # vtexp.experiment.NumberQuestion
    return r.ask_number(q.prompt, getattr(q, "minimum", 0), getattr(q, "maximum", 99), replay,
                        getattr(q, "replays", 0))


# Question kind (the model's ``kind`` field, else its class name) -> the screen that asks it.
QUESTION_SCREENS: dict[str, Callable[[WindowResponder, object, Replay | None], Response]] = {
    "ChoiceQuestion": _choice, "choice": _choice,
    "RatingQuestion": _rating, "rating": _rating,
    "NumberQuestion": _number, "number": _number,
}


def make_window(spec: str) -> WindowResponder:
    """Build the window responder from the part of ``--responder`` after ``window:``."""
    return WindowResponder(WindowOptions.parse(spec))
