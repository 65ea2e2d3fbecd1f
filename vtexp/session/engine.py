"""The session engine: carries out a plan's steps, plays, asks, and emits records.

:func:`run_session` is the one way in: it checks the run (:func:`~vtexp.session.options.check_run`,
before anything is written or opened), opens the session's files (the BIDS writer says
how many trials its log holds), and gives the :class:`Engine` the plan of the trials
still to come (:func:`~vtexp.session.plan.session_plan`).

The engine knows steps, a device, a responder and consumers of records; it does not know
files, designs or adaptive procedures. Every record goes to the BIDS writer first (a
trial's rows are on disk before anyone else hears of it; its trouble, a full disk, ends
the session), then to the responder's screens (a ``SessionAborted`` from them aborts),
then to the other consumers (progress line, markers): one of these that raises is
reported once through ``warn`` and the session goes on. Pause, retry, skip and abort on
a device fault are the engine's (:meth:`Engine.device_fault`).
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from ..clock import iso
from ..errors import DeviceError, PlayInterrupted, SessionAborted, SessionError
from ..experiment import LoadedExperiment
from ..model import PlayReport, TrialRecord
from ..responders.base import Responder, call_hook
from ..design import Trial
from .bids_writer import BidsWriter
from .options import SessionOptions, SessionSetup, check_run
from .paths import SessionPaths
from .plan import (Break, End, Instructions, Plan, RunTrial, Step, StoppedTrial, Wait,
                   session_plan)
from .records import (Answered, Consumer, DevicePaused, DeviceResumed, Felt, PlayStarted,
                      Record, SessionEnded, SessionStarted, TrialDone, TrialStarted,
                      trial_rows)


@dataclass
class SessionResult:
    paths: SessionPaths
    status: str
    records: list[TrialRecord] = field(default_factory=list)
    seed: int = 0


def run_session(lx: LoadedExperiment, device, responder: Responder, options: SessionOptions,
                *, consumers: Sequence[Consumer] = ()) -> SessionResult:
    """Run one session (``options``: who, where, how; see :class:`SessionOptions`) of the
    experiment on ``device`` with ``responder``, and log it; each record of the session
    also goes to ``consumers``, in order.

    Refused before anything is written or opened when the run cannot be (see
    :func:`~vtexp.session.options.check_run`): a session that exists (unless resumed), one
    to resume that cannot be, ... A resumed session continues at the first trial its log
    lacks. The session is locked while it runs (``session.lock``). Whatever ends it, every
    actuator is turned off and the session record says how it ended.
    """
    setup = check_run(lx, device, responder, options)
    writer = BidsWriter.open(setup, device.open, responder)
    engine = Engine(setup, device, responder, store=writer, consumers=consumers)
    plan = session_plan(lx.experiment, setup.trials, writer.held,
                        max_trials=options.max_trials, adaptive=setup.adaptive)
    return engine.run(plan, writer.held)


def _say_on_stderr(text: str) -> None:
    print(f"vtexp: warning: {text}", file=sys.stderr, flush=True)


class ResponderScreens:
    """The responder's hooks that are notifications, as a consumer of records: where a
    resumed session continues (``resume_at``), and the pause screen while the device is
    faulty (``device_paused``/``device_resumed``)."""

    def __init__(self, responder: Responder):
        self.responder = responder

    def __call__(self, record: Record) -> None:
        if isinstance(record, SessionStarted):
            call_hook(self.responder, "resume_at", record.trials_done)
        elif isinstance(record, DevicePaused):
            call_hook(self.responder, "device_paused", record.trial)
        elif isinstance(record, DeviceResumed):
            call_hook(self.responder, "device_resumed", record.trial)


class Engine:
    """Carries out a plan on a device with a responder (see the module docstring)."""

    def __init__(self, setup: SessionSetup, device, responder: Responder, *,
                 store: Consumer, consumers: Sequence[Consumer] = ()):
        self.setup, self.device, self.responder = setup, device, responder
        self.clock = setup.clock
        self.questions = setup.lx.experiment.asked()
        self.camera = setup.camera
        self.on_device_error = setup.options.on_device_error
        self.store = store
        self.screens = ResponderScreens(responder)
        self.consumers = list(consumers)
        self.warn: Callable[[str], None] = setup.options.warn or _say_on_stderr
        self._failed: set[int] = set()
        self.records: list[TrialRecord] = []

    # -- records ------------------------------------------------------------------------
    def emit(self, record: Record) -> None:
        """The record to the writer first, then the responder's screens, then the rest."""
        self.store(record)
        self.screens(record)
        self._tell_others(record)

    def _tell_others(self, record: Record) -> None:
        for consumer in self.consumers:
            try:
                consumer(record)
            except Exception as e:      # a progress line or a recorder must not end it
                if id(consumer) not in self._failed:
                    self._failed.add(id(consumer))
                    name = (getattr(consumer, "description", None)
                            or getattr(consumer, "__name__", None) or type(consumer).__name__)
                    self.warn(f"{name} failed on a {type(record).__name__} record "
                              f"({type(e).__name__}: {e}); the session goes on")

    # -- the run ------------------------------------------------------------------------
    def run(self, plan: Plan, held: int) -> SessionResult:
        """Carry out ``plan`` (the log held ``held`` trials); whatever ends the run, every
        actuator off, then :class:`SessionEnded` (the writer closes the record)."""
        s = self.setup
        status, reason = "failed", None
        try:
            self.emit(SessionStarted(s.lx.experiment.name, s.paths.participant, s.paths.session,
                                     s.options.resume, held, len(s.trials), self.clock.now_ms()))
            status, reason = self._carry_out(plan)
        except (KeyboardInterrupt, SessionAborted) as e:
            status, reason = "aborted", (str(e) if isinstance(e, SessionAborted)
                                         else "interrupted by the experimenter")
            raise
        except BaseException as e:
            status, reason = "failed", f"{type(e).__name__}: {e}"
            raise
        finally:
            try:
                self.device.all_off()
            finally:
                self._end(SessionEnded(status, reason, self.clock.now_ms()))
        return SessionResult(s.paths, status, self.records, s.seed)

    def _end(self, ended: SessionEnded) -> None:
        try:
            self.store(ended)
        finally:
            self._tell_others(ended)

    def _carry_out(self, plan: Plan) -> tuple[str, str | None]:
        step = next(plan)
        while True:
            done = self.do(step)
            if isinstance(step, End):
                return ("completed", None) if step.stopped_early is None else \
                    ("aborted", step.stopped_early)
            step = plan.send(done)

    def do(self, step: Step) -> TrialDone | None:
        """Carry out one step; a trial's :class:`TrialDone` (already emitted) or None."""
        if isinstance(step, RunTrial):
            return self.trial(step.trial, step.total)
        if isinstance(step, StoppedTrial):
            rows = trial_rows(step.trial, self.questions, iso(self.clock), status="stopped")
            return self._done(step.trial, rows, [], step.total, self.clock.wall())
        if isinstance(step, Wait):
            self.device.wait_ms(step.ms)
        elif isinstance(step, Instructions):
            call_hook(self.responder, "instructions", step.text)
        elif isinstance(step, Break):
            call_hook(self.responder, "pause", step.text)
        elif isinstance(step, End):
            call_hook(self.responder, "finish", step.text)
        else:
            raise TypeError(f"not a step of a session's plan: {step!r}")
        return None

    def _done(self, trial: Trial, rows, plays: list[PlayReport], total: int,
              wall_s: float) -> TrialDone:
        done = TrialDone(trial, tuple(rows), tuple(plays), total, wall_s, self.clock.now_ms())
        self.emit(done)
        self.records.extend(rows)
        return done

    # -- a trial ------------------------------------------------------------------------
    def trial(self, trial: Trial, total: int) -> TrialDone:
        """A trial, with the experimenter's choice when the device fails during it.

        Every play the device reported is logged with the trial, a retry's included: one
        it stopped part-way (:class:`~vtexp.errors.PlayInterrupted`) with the pulses it
        did play, in order (``play`` 0, 1, ... over the trial's attempts). A trial skipped
        after a fault is logged with status ``device_error``; so is one that had a fault
        and plays and then ended the session (an abort after the fault, Escape or an error
        in a retry), with those plays, rather than leave them out of the log; a resume goes
        on after such a trial."""
        wall = self.clock.wall()
        plays: list[PlayReport] = []
        faulted = False
        while True:
            started_at = iso(self.clock)
            self.emit(TrialStarted(trial, started_at, self.clock.now_ms()))
            try:
                rows = self._play_and_ask(trial, started_at, plays)
            except DeviceError as e:
                faulted = True
                try:
                    choice = self.device_fault(e, trial)
                except BaseException:
                    self._cut_short(trial, started_at, plays, total, wall)
                    raise
                if choice == "retry":
                    continue
                rows = self._device_error_rows(trial, started_at)
            except BaseException:
                if faulted:
                    self._cut_short(trial, started_at, plays, total, wall)
                raise
            return self._done(trial, rows, plays, total, wall)

    def _device_error_rows(self, trial: Trial, started_at: str) -> tuple[TrialRecord, ...]:
        return trial_rows(trial, self.questions, started_at, status="device_error")

    def _cut_short(self, trial: Trial, started_at: str, plays: list[PlayReport], total: int,
                   wall: float) -> None:
        """A trial that had a device fault ends the session: logged ``device_error`` with
        the plays the device reported, if any (felt, so never left out of the log)."""
        if plays:
            self._done(trial, self._device_error_rows(trial, started_at), plays, total, wall)

    def device_fault(self, error: DeviceError, trial: Trial) -> str:
        """Every actuator is already off; the session pauses on the experimenter's choice:
        ``retry`` (after the device was reopened) or ``skip``; ``abort`` raises."""
        self.emit(DevicePaused(trial, error, self.clock.now_ms()))
        ask = self.on_device_error
        choice = ask(error, trial) if ask else "abort"
        while choice == "retry":
            try:
                self.device.close()
            except DeviceError:
                pass                    # it was lost; closing releases what is left
            try:
                self.device.open()
                break
            except DeviceError as again:    # still unplugged: ask again
                error = again
                choice = ask(error, trial)
        if choice != "abort":
            self.emit(DeviceResumed(trial, choice, self.clock.now_ms()))
        if choice in ("retry", "skip"):
            return choice
        raise error

    def _play_and_ask(self, trial: Trial, started_at: str, plays: list[PlayReport]
                      ) -> tuple[TrialRecord, ...]:
        """Play the stimulus, then ask each question in turn; each play (an interrupted
        one too) is appended to ``plays``, which may hold an earlier attempt's."""
        schedule, stim_file = trial.condition.schedule, None
        if trial.condition.camera:
            if self.camera is None:
                raise SessionError(f"trial {trial.number}: stimulus {trial.stimulus!r} is a "
                                   "camera")
            schedule, stim_file, live = self.camera.take(trial, self.device)
            if live is not None:
                return self._live_trial(trial, live, started_at, stim_file)
        first = len(plays)
        call_hook(self.responder, "stimulus_starts", trial)
        self._play(trial, schedule, plays)
        answers: dict = {}
        self._ask_all(trial, answers, plays,
                      lambda q, before: self._replay(trial, schedule, q, plays, before))
        return trial_rows(trial, self.questions, started_at, answers=answers,
                          felt=Felt.played(plays[first], stim_file))

    def _play(self, trial: Trial, schedule, plays: list[PlayReport]) -> PlayReport:
        """One play (the first, or a replay); the responder's abort key is read while it
        plays: the device turns every actuator off at once and raises SessionAborted."""
        index = len(plays)

        def started(device_ms: float, host_ms: float | None) -> None:
            self.emit(PlayStarted(trial, index, device_ms, host_ms))
        try:
            report = self.device.play(schedule, on_started=started,
                                      should_stop=getattr(self.responder, "stop_requested", None))
        except SessionAborted:
            call_hook(self.responder, "stimulus_stopped", trial)
            raise
        except PlayInterrupted as e:    # what the device played before it stopped is kept
            plays.append(e.report)
            raise
        plays.append(report)
        call_hook(self.responder, "stimulus_played", trial, report)
        return report

    def _replay(self, trial: Trial, schedule, q, plays: list[PlayReport], before: int):
        def replay() -> PlayReport:
            if len(plays) - before >= q.replays:
                raise SessionError(f"trial {trial.number}: no replays left "
                                   f"(the question allows {q.replays})")
            return self._play(trial, schedule, plays)
        return replay

    def _ask_all(self, trial: Trial, answers: dict, plays: list[PlayReport],
                 replay_for: Callable | None) -> None:
        """Each question in turn: ``answers[name] = (response, replays used)``."""
        for q in self.questions:
            before = len(plays)
            replay = replay_for(q, before) if replay_for is not None and q.replays > 0 else None
            asked = self.clock.now_ms()
            response = self.responder.ask(q, trial, replay)
            self.emit(Answered(trial, q, response, asked, self.clock.now_ms()))
            answers[q.name] = (response, len(plays) - before)

    def _live_trial(self, trial: Trial, live, started_at: str, stim_file: str
                    ) -> tuple[TrialRecord, ...]:
        """The camera felt continuously while the participant answers each question."""
        call_hook(self.responder, "stimulus_starts", trial)
        live.start()
        answers: dict = {}
        try:
            self._ask_all(trial, answers, [], None)
        finally:
            played_ms = live.stop("the participant answered" if answers else "stopped")
        return trial_rows(trial, self.questions, started_at, answers=answers,
                          felt=Felt(None, played_ms, 0, stim_file))
