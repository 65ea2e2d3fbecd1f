"""A Lab Streaming Layer marker stream (the ``lsl`` extra: pylsl, whose wheel bundles liblsl).

One stream of type ``Markers``, one string channel, irregular rate; its
``source_id`` is ``vtexp:<experiment>:sub-<participant>:ses-<session>``, so a
recorder (LabRecorder) finds the same stream again after a restart or a resume.
Each marker is a compact JSON object::

    {"event":"pulse","trial":3,"play":0,"pulse":2,"row":1,"col":4,"device_ms":51234.5,...}

with ``event`` one of ``session_start``, ``trial_start``, ``pulse``, ``answer``,
``trial_end``, ``session_end``; trial markers carry ``stimulus``, ``condition``
(factor → level) and ``practice``.

**Timestamps are when it happened, not when it was pushed.** A pulse is stamped
with the onset the device reported (the events file's ``onset_ms``, also in the
marker as ``device_ms``), put on this computer's monotonic clock (the session's
:class:`~vtexp.clock.Clock`, ``time.monotonic`` on the real one) through the play's
clock mapping (``PlayReport.started_at_host_ms``, from the device's heartbeats:
``vtexp.devices.clock``) and then on LSL's clock: ``local_clock()`` minus the clock's
``now()``, measured when the stream opens (on Linux both read CLOCK_MONOTONIC, and the
offset is below a microsecond). A trial's markers are pushed once its row is on disk
(the stream takes the session's ``TrialDone`` record after the session's writer), so
the stream holds exactly what the session logged (a trial played again after a device
fault is marked once); a recorder orders them by their stamps.
"""

from __future__ import annotations

import json
import statistics
from typing import Any

from .. import __version__
from ..clock import REAL
from . import MarkerError, MarkerSink


def monotonic_to_lsl_s(local_clock, clock=REAL) -> float:
    """``local_clock() − clock.now()`` in s: the median of 15 bracketed readings."""
    offs = []
    for _ in range(15):
        a = clock.now()
        b = local_clock()
        c = clock.now()
        offs.append(b - (a + c) / 2.0)
    return statistics.median(offs)


def answer_host_ms(rt_s: float | None, asked_ms: float, answered_ms: float) -> float:
    """When the answer was given: the question's start plus the reaction time the
    responder measured, when that falls within the question; else when it returned
    (a responder without a real reaction time)."""
    if rt_s is not None and rt_s == rt_s and 0 <= rt_s * 1000.0 <= answered_ms - asked_ms + 1.0:
        return asked_ms + rt_s * 1000.0
    return answered_ms


def trial_markers(trial, records, plays, started_host_ms: float | None,
                  answers: dict[str, tuple[float, float]], logged_host_ms: float
                  ) -> list[tuple[float, dict[str, Any]]]:
    """A logged trial's markers as ``(host_ms, marker)``, in time order.

    ``answers``: question → (asked, answered) host ms. Pulses of a play without a
    mapping of the device's clock are left out (counted in ``LslMarkers.unmapped``).
    """
    base = {"trial": trial.number, "stimulus": trial.stimulus, "condition": dict(trial.levels),
            "practice": bool(trial.practice)}
    out: list[tuple[float, dict[str, Any]]] = []
    if started_host_ms is not None:
        out.append((started_host_ms, {"event": "trial_start", **base}))
    for i, rep in enumerate(plays):
        host0 = rep.started_at_host_ms
        if host0 is None:
            continue                # a device that cannot map its clock: no honest stamp
        for j, p in enumerate(rep.pulses):
            out.append((host0 + p.onset_ms, {
                "event": "pulse", **base, "play": i, "pulse": j, "row": p.row, "col": p.col,
                "device_ms": rep.started_at_ms + p.onset_ms}))
    for rec in records:
        if rec.status != "ok" and rec.answer is None:
            continue
        asked, answered = answers.get(rec.question, (logged_host_ms, logged_host_ms))
        out.append((answer_host_ms(rec.rt_s, asked, answered),
                    {"event": "answer", **base, "question": rec.question, "answer": rec.answer,
                     "correct": rec.correct, "rt_s": rec.rt_s}))
    status = records[0].status if records else "ok"
    out.append((logged_host_ms, {"event": "trial_end", **base, "status": status}))
    out.sort(key=lambda x: x[0])            # stable: a pulse at its trial's start stays after it
    return out


class LslMarkers(MarkerSink):
    """The ``lsl`` marker output (see the module docstring)."""

    description = "LSL marker stream"

    def __init__(self, outlet, info, local_clock, offset_s: float, source_id: str, warn=None,
                 clock=None):
        super().__init__(warn, clock)
        self.outlet = outlet
        self.info = info
        self.local_clock = local_clock
        self.offset_s = offset_s
        self.source_id = source_id
        self.pushed = 0
        self.unmapped = 0
        self._trial_start: float | None = None
        self._answers: dict[str, tuple[float, float]] = {}

    @classmethod
    def open(cls, *, experiment: str, participant: str, session: int, name: str | None = None,
             warn=None, clock=None) -> LslMarkers:
        try:
            import pylsl
        except ImportError as e:
            raise MarkerError(f"the LSL marker stream needs pylsl ({e}): install the 'lsl' "
                              "extra, pip install 'vtexp[lsl]'") from None
        except Exception as e:      # the bundled liblsl did not load (an old glibc?)
            raise MarkerError(f"the LSL marker stream cannot start: pylsl could not load "
                              f"liblsl ({e})") from None

        source_id = f"vtexp:{experiment}:sub-{participant}:ses-{session}"
        try:
            info = pylsl.StreamInfo(name or f"vtexp {experiment}", "Markers", 1,
                                    pylsl.IRREGULAR_RATE, "string", source_id)
            offset = monotonic_to_lsl_s(pylsl.local_clock, clock or REAL)
            desc = info.desc()
            for k, v in (("experiment", experiment), ("participant", participant),
                         ("session", str(session)), ("vtexp_version", __version__),
                         ("format", "json: event, trial, stimulus, condition, practice; "
                                    "pulse: play, pulse, row, col, device_ms; answer: "
                                    "question, answer, correct, rt_s"),
                         ("timestamps", "when it happened: pulses at the device-reported "
                                        "onset mapped to local_clock, not the push time"),
                         ("monotonic_to_lsl_s", repr(offset))):
                desc.append_child_value(k, v)
            outlet = pylsl.StreamOutlet(info)
        except Exception as e:
            raise MarkerError(f"cannot open the LSL marker stream {source_id!r}: {e}") from None
        return cls(outlet, info, pylsl.local_clock, offset, source_id, warn, clock)

    # -- records ----------------------------------------------------------------------------
    def _push(self, host_ms: float, marker: dict) -> None:
        if self.outlet is None:
            return
        try:
            self.outlet.push_sample([json.dumps(marker, separators=(",", ":"), default=str)],
                                    host_ms / 1000.0 + self.offset_s)
            self.pushed += 1
        except Exception as e:
            self.failed(f"a marker could not be pushed ({e})")

    def session_started(self, r) -> None:
        self._push(r.host_ms, {"event": "session_start", "experiment": r.experiment,
                               "participant": r.participant, "session": r.session,
                               "resume": r.resume, "trials_done": r.trials_done})

    def trial_started(self, r) -> None:
        self._trial_start = r.host_ms
        self._answers = {}

    def answered(self, r) -> None:
        self._answers[r.question.name] = (r.asked_host_ms, r.answered_host_ms)

    def trial_done(self, r) -> None:
        # Here the trial is on disk (the session's writer took the record first).
        now = self.clock.now_ms()
        markers = trial_markers(r.trial, r.rows, r.plays, self._trial_start, self._answers,
                                now)
        self.unmapped += sum(len(p.pulses) for p in r.plays if p.started_at_host_ms is None)
        self._trial_start = None            # a trial with no start of its own gets none
        self._answers = {}
        for host_ms, m in markers:
            self._push(host_ms, m)

    def session_ended(self, r) -> None:
        self._push(r.host_ms, {"event": "session_end", "status": r.status})

    def close(self) -> None:
        self.outlet = None      # liblsl closes the outlet when its last reference goes
