"""Event markers for recorders that run beside a session (EEG, skin conductance).

A marker output is a consumer of the session's records (:class:`MarkerSink`,
:mod:`vtexp.session.records`): it hears each thing as it happens (the session starts,
a trial starts, a play starts, an answer is taken, a trial is on disk, the session
ends) and passes it on:

- ``lsl`` (:mod:`vtexp.markers.lsl`): a Lab Streaming Layer stream of type
  ``Markers``, one JSON string per pulse, answer, trial start and end, each stamped
  with *when it happened* on LSL's clock (a pulse: the onset the device reported,
  mapped from the device's clock), pushed once the trial is on disk;
- ``serial:PORT[,baud=N,reset_ms=N]`` and ``parallel:ADDRESS``
  (:mod:`vtexp.markers.trigger`): a trigger box that turns a byte into TTL lines on
  the recorder, sent at the moment of the event (:data:`CODES`).

The firmware's sync output (``docs/firmware.md``, PB6) is the µs-exact alternative:
a TTL edge at each onset instant, from the device itself.

:func:`open_markers` opens one from its spec; an output that cannot be opened is a
:class:`MarkerError`, one message before the first trial.
"""

from __future__ import annotations

from ..errors import InputError, VtexpError

#: The byte a trigger box receives for each event (1-255; 0 is "all lines low").
CODES: dict[str, int] = {
    "trial_start": 1,       # the trial begins (before its stimulus)
    "stimulus": 2,          # a play starts on the device (each replay too)
    "answer": 3,            # an answer was taken (one per question)
    "trial_end": 4,         # the trial's row is on disk
    "session_start": 100,   # before the first trial of this run
    "session_end": 101,     # the run ended (completed, aborted or failed)
}


class MarkerError(VtexpError):
    """A marker output could not be opened (or was lost)."""

    exit_code = 2


class MarkerSink:
    """A consumer of a session's records that passes them on to a recorder.

    :meth:`__call__` hands each record to the method named for its type, when the
    output has one (host times are the session clock's ms, ``Clock.now_ms``):

    - ``session_started(record)``: :class:`~vtexp.session.records.SessionStarted`;
    - ``trial_started(record)``: each attempt at a trial (a retry after a device fault
      starts it again);
    - ``play_started(record)``: a play starts on the device (its start on the device's
      clock, and on the host's when known);
    - ``answered(record)``: the question, the response, when it was asked and answered;
    - ``trial_done(record)``: the trial's rows and events are on disk (the session's
      writer has it before any marker output);
    - ``session_ended(record)``.

    An output must not raise: a recorder that goes away must not end a participant's
    session. It warns once (``warn``) and counts what it lost. (Should one raise all
    the same, the session warns and goes on.)
    """

    description = "markers"

    #: The record type's name -> the method that takes it.
    HANDLERS = {"SessionStarted": "session_started", "TrialStarted": "trial_started",
                "PlayStarted": "play_started", "Answered": "answered",
                "TrialDone": "trial_done", "SessionEnded": "session_ended"}

    def __init__(self, warn=None, clock=None):
        from ..clock import REAL

        self.warn = warn
        self.clock = clock or REAL
        self.lost = 0
        self._warned = False

    def __call__(self, record) -> None:
        handler = getattr(self, self.HANDLERS.get(type(record).__name__, ""), None)
        if callable(handler):
            handler(record)

    def failed(self, what: str) -> None:
        self.lost += 1
        if not self._warned and self.warn is not None:
            self._warned = True
            self.warn(f"{self.description}: {what}; the session goes on, markers are lost")

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def parse_spec(spec: str) -> tuple[str, str, dict[str, str]]:
    """``kind:target,key=value,...`` → ``(kind, target, options)``."""
    kind, _, rest = spec.partition(":")
    parts = [p for p in rest.split(",") if p] if rest else []
    target = ""
    opts: dict[str, str] = {}
    for p in parts:
        if "=" in p:
            k, _, v = p.partition("=")
            opts[k.strip()] = v.strip()
        elif not target:
            target = p
        else:
            raise InputError(f"{spec!r}: more than one port or address ({target!r}, {p!r})",
                             key="--markers")
    return kind.strip().lower(), target, opts


def open_markers(spec: str, *, experiment: str, participant: str, session: int,
                 warn=None, clock=None) -> MarkerSink:
    """Open the marker output ``spec`` names (see the module docstring); ``clock``: the
    session's (:class:`~vtexp.clock.Clock`, the real one unless given)."""
    kind, target, opts = parse_spec(spec)
    if kind == "lsl":
        from .lsl import LslMarkers                  # it imports MarkerSink from here

        unknown = set(opts) - {"name"}
        if unknown or target:
            raise InputError(f"{spec!r}: lsl takes only name=NAME", key="--markers")
        return LslMarkers.open(experiment=experiment, participant=participant,
                               session=session, name=opts.get("name"), warn=warn,
                               clock=clock)
    if kind in ("serial", "parallel"):
        from .trigger import ParallelTrigger, SerialTrigger     # likewise

        if not target:
            example = "serial:/dev/ttyUSB0" if kind == "serial" else "parallel:/dev/parport0"
            what = "port" if kind == "serial" else "address"
            raise InputError(f"{spec!r}: give the {what}, e.g. {example}", key="--markers")
        cls = SerialTrigger if kind == "serial" else ParallelTrigger
        return cls.open(target, opts, warn=warn, clock=clock)
    raise InputError(f"unknown marker output {spec!r}: lsl, serial:PORT[,baud=N,reset_ms=N] "
                     "or parallel:ADDRESS", key="--markers")
