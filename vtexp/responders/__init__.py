"""Responders behind one protocol (:class:`vtexp.responders.base.Responder`)."""

from __future__ import annotations

from ..errors import InputError
from .base import Responder, Response, correct_answer
from .console import make_console
from .scripted import ScriptedResponder, make_scripted


def make_responder(spec: str, participant: str, session: int, lx=None) -> Responder:
    """Build a responder from a ``--responder`` spec such as ``scripted:correct``.

    ``model[:seed=N][,typical]`` is a model participant (``vtexp.observer``); it needs
    the experiment ``lx``.
    """
    kind, _, arg = spec.partition(":")
    if kind == "model":
        return _make_model(arg, participant, session, lx)
    if kind == "scripted":
        return make_scripted(arg or "correct", participant, session, lx)
    if kind == "console":
        return make_console(arg)
    if kind == "window":
        from .window import make_window     # PsychoPy is imported only here
        return make_window(arg, lx)
    raise InputError(f"unknown responder {spec!r}; available: console, scripted:correct, "
                     "scripted:random, scripted:accuracy=P, scripted:answers=FILE, "
                     "scripted:psychometric:threshold=T[,slope=S,lapse=L], "
                     "model[:seed=N,typical], "
                     "window[:windowed|fullscreen,screen=N,size=WxH,abort=KEY,audio,device=NAME]",
                     key="--responder")


def _make_model(arg: str, participant: str, session: int, lx) -> Responder:
    # Here, not above: the model participant loads the compiler (OpenCV, SciPy), and its
    # responder imports .base of this package.
    from ..observer import ModelObserver, ObserverModel

    if lx is None:
        raise InputError("the model participant needs the experiment", key="--responder")
    seed, typical = 0, False
    for part in filter(None, (x.strip() for x in arg.split(","))):
        key, _, value = part.partition("=")
        if key == "typical" and not value:
            typical = True
        elif key == "seed" and value.lstrip("-").isdigit():
            seed = int(value)
        else:
            raise InputError(f"unknown model option {part!r}; use model, model:seed=N or "
                             "model:seed=N,typical", key="--responder")
    return ModelObserver(ObserverModel.for_experiment(lx), participant, session, seed=seed,
                         typical=typical)


__all__ = ["Responder", "Response", "ScriptedResponder", "correct_answer", "make_responder"]
