"""Real key presses on an X display, through its XTEST extension (python-xlib): what a
participant's keyboard sends, for the tests whose window runs on Xvfb."""

from __future__ import annotations

import time

import pytest


class XKeyboard:
    """Real key presses, sent to the X server through its XTEST extension (as a keyboard's).

    PsychoPy's own ``event.getKeys`` reads them, so this drives the real input path.
    """

    def __init__(self, display_name: str):
        pytest.importorskip("Xlib", reason="python-xlib (installed with PsychoPy on Linux)")
        from Xlib import XK, display
        self.XK = XK
        self.d = display.Display(display_name)
        assert self.d.has_extension("XTEST"), "the X server has no XTEST extension"

    def focus(self, win) -> None:
        from Xlib import X
        w = self.d.create_resource_object("window", win.winHandle._window)
        self.d.set_input_focus(w, X.RevertToParent, X.CurrentTime)
        self.d.sync()

    def press(self, keysym: str) -> float:
        """Press and release a key; return when it was pressed (``time.perf_counter``)."""
        from Xlib import X
        from Xlib.ext import xtest
        code = self.d.keysym_to_keycode(self.XK.string_to_keysym(keysym))
        assert code, f"no key for {keysym}"
        t = time.perf_counter()
        xtest.fake_input(self.d, X.KeyPress, code)
        xtest.fake_input(self.d, X.KeyRelease, code)
        self.d.sync()
        return t

    def close(self) -> None:
        self.d.close()
