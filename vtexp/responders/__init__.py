"""Responders behind one protocol (:class:`vtexp.responders.base.Responder`)."""

from __future__ import annotations

from ..errors import InputError
from .base import Responder, Response, correct_answer
from .scripted import ScriptedResponder, make_scripted


def make_responder(spec: str, participant: str, session: int) -> Responder:
    """Build a responder from a ``--responder`` spec such as ``scripted:correct``."""
    kind, _, arg = spec.partition(":")
    if kind == "scripted":
        return make_scripted(arg or "correct", participant, session)
    if kind == "console":
        from .console import make_console
        return make_console(arg)
    if kind == "window":
        from .window import make_window     # PsychoPy is imported only here
        return make_window(arg)
    raise InputError(f"unknown responder {spec!r}; available: console, scripted:correct, "
                     "scripted:random, scripted:accuracy=P, scripted:answers=FILE, "
                     "window[:windowed|fullscreen,screen=N,size=WxH,abort=KEY]",
                     key="--responder")


__all__ = ["Responder", "Response", "ScriptedResponder", "correct_answer", "make_responder"]
