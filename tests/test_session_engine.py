"""The session as plan -> engine -> records: the plan's steps, the records every consumer
gets (the writer first), a consumer that fails, and the refusals made before anything is
written or opened."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from conftest import MINIMAL, ROOT, write_experiment
from vtexp.compile import compile_conditions
from vtexp.design import trial_list
from vtexp.devices.sim import SimDevice
from vtexp.devices.wire import Onset
from vtexp.errors import DeviceError, InputError, PlayInterrupted, SessionError
from vtexp.experiment import load_experiment
from vtexp.model import DeviceProfile
from vtexp.responders import Response, ScriptedResponder, make_responder
from vtexp.session import (Answered, Break, DevicePaused, DeviceResumed, End, Instructions,
                           PlayStarted, RunTrial, SessionEnded, SessionOptions, SessionPaths,
                           SessionStarted, TrialDone, TrialStarted, Wait, run_session,
                           session_plan, trial_rows)

STAIR = ROOT / "experiments" / "shape_soa_staircase.yaml"
RATING = ROOT / "experiments" / "circle_vs_rectangle.yaml"


def _drive(plan, answer=None):
    """Every step of a plan, sending back for each trial step what ``answer(step)`` gives."""
    steps, reply = [], None
    while True:
        try:
            step = plan.send(reply) if steps else next(plan)
        except StopIteration:
            return steps
        steps.append(step)
        reply = answer(step) if answer is not None and isinstance(step, RunTrial) else None


# ------------------------------------------------------------------------------ the plan

def test_the_plan_is_the_session_as_steps(tmp_path):
    lx = load_experiment(write_experiment(tmp_path, MINIMAL.replace(
        "  iti_ms: 0\n", "  iti_ms: 250\n  practice: 1\n  break_every: 2\n")))
    exp = lx.experiment
    trials, _ = trial_list(exp, compile_conditions(lx), "01", 1)
    assert [t.practice for t in trials] == [True, False, False, False, False]
    steps = _drive(session_plan(exp, trials))
    kinds = [type(s).__name__ for s in steps]
    assert kinds == ["Instructions"] + ["RunTrial", "Wait"] * 3 + ["Break"] + \
        ["RunTrial", "Wait"] * 2 + ["End"]
    assert steps[0] == Instructions(exp.instructions.strip() or exp.asked()[0].prompt)
    assert [s.trial.number for s in steps if isinstance(s, RunTrial)] == [1, 2, 3, 4, 5]
    assert all(s.total == 5 for s in steps if isinstance(s, RunTrial))
    assert {s for s in steps if isinstance(s, Wait)} == {Wait(250)}
    assert steps[7] == Break("Time for a break. 2 of 4 trials are done. Continue when you "
                             "are ready.")                  # after main trial 2, not after 4
    assert steps[-1] == End("Thank you. The session is over.", None)

    # A resumed run starts where the log ends; max_trials ends it early, saying so.
    steps = _drive(session_plan(exp, trials, 2, max_trials=2))
    assert [s.trial.number for s in steps if isinstance(s, RunTrial)] == [3, 4]
    assert steps[-1].stopped_early == "stopped after 2 trials as asked"
    steps = _drive(session_plan(exp, trials, 3, max_trials=9))
    assert [s.trial.number for s in steps if isinstance(s, RunTrial)] == [4, 5]
    assert steps[-1].stopped_early is None


def test_an_adaptive_plan_learns_from_the_trials_sent_back():
    lx = load_experiment(STAIR)
    exp = lx.experiment
    from vtexp.adaptive.track import AdaptiveRun

    conditions = compile_conditions(lx)
    trials, seed = trial_list(exp, conditions, "01", 1)

    def levels(correct: bool) -> list[tuple[str, float]]:
        def answer(step):
            t = step.trial
            q = exp.asked()[0]
            given = t.stimulus if correct else next(o for o in q.options if o != t.stimulus)
            rows = trial_rows(t, exp.asked(), "2026-01-01T00:00:00",
                              answers={q.name: (Response(given, None), 0)})
            return TrialDone(t, rows, (), len(trials), 0.0, 0.0)
        plan = session_plan(exp, trials, max_trials=12,
                            adaptive=AdaptiveRun.of(lx, conditions, seed))
        return [(s.trial.levels["start"], s.trial.proposed)
                for s in _drive(plan, answer) if isinstance(s, RunTrial)]

    right, wrong = levels(True), levels(False)
    assert right[0] == wrong[0]                              # nothing learnt yet
    slow_right = [p for track, p in right if track == "slow"]
    slow_wrong = [p for track, p in wrong if track == "slow"]
    assert slow_right[0] == slow_wrong[0] == 400
    assert min(slow_right) < 400 <= min(slow_wrong)          # correct answers: shorter SOA


# ------------------------------------------------------------------------------ records

class Keeper:
    """A consumer that keeps every record, and what the trial log held when it came."""

    def __init__(self):
        self.records = []
        self.rows_on_disk = {}

    def __call__(self, record):
        self.records.append(record)
        if isinstance(record, TrialDone):
            beh = SessionPaths.of(self.data, "mini", "mini", "01", 1).beh_tsv
            self.rows_on_disk[record.trial.number] = len(beh.read_text().splitlines()) - 1


def _session(tmp_path, consumers=(), responder=None, device=None, **options):
    lx = load_experiment(write_experiment(tmp_path, MINIMAL))
    device = device or SimDevice(DeviceProfile.load("vest_6x8"))
    responder = responder or make_responder("scripted:correct", "01", 1, lx)
    with device:
        return run_session(lx, device, responder, SessionOptions(
            participant="01", data_dir=tmp_path / "data", **options), consumers=consumers)


def test_every_consumer_gets_the_records_in_order_the_writer_first(tmp_path):
    keeper = Keeper()
    keeper.data = tmp_path / "data"
    res = _session(tmp_path, [keeper])
    kinds = [type(r).__name__ for r in keeper.records]
    per_trial = ["TrialStarted", "PlayStarted", "Answered", "TrialDone"]
    assert kinds == ["SessionStarted", *per_trial * 4, "SessionEnded"]
    start = keeper.records[0]
    assert isinstance(start, SessionStarted) and (start.trials_done, start.trials_planned,
                                                  start.resume) == (0, 4, False)
    done = [r for r in keeper.records if isinstance(r, TrialDone)]
    # The writer had each trial's row on disk before any other consumer heard of it.
    assert keeper.rows_on_disk == {1: 1, 2: 2, 3: 3, 4: 4}
    assert [r for d in done for r in d.rows] == res.records
    assert all(len(d.plays) == 1 and d.total == 4 for d in done)
    plays = [r for r in keeper.records if isinstance(r, PlayStarted)]
    assert [p.device_ms for p in plays] == [d.plays[0].started_at_ms for d in done]
    answers = [r for r in keeper.records if isinstance(r, Answered)]
    assert all(a.asked_host_ms <= a.answered_host_ms for a in answers)
    assert [a.response.answer for a in answers] == [r.answer for r in res.records]
    starts = [r for r in keeper.records if isinstance(r, TrialStarted)]
    assert [s.started_at for s in starts] == [r.started_at for r in res.records]
    assert keeper.records[-1] == SessionEnded("completed", None, keeper.records[-1].host_ms)


def test_a_device_fault_is_a_pause_and_a_resume_in_the_records(tmp_path):
    dev = SimDevice(DeviceProfile.load("vest_6x8"))
    inner, calls = dev._play, [0]

    def play(schedule):
        calls[0] += 1
        if calls[0] == 2:
            raise DeviceError("lost contact with the tactile device (test)")
        return inner(schedule)
    dev._play = play
    keeper = Keeper()
    keeper.data = tmp_path / "data"
    res = _session(tmp_path, [keeper], device=dev, on_device_error=lambda e, t: "skip")
    kinds = [type(r).__name__ for r in keeper.records]
    assert kinds[5:10] == ["TrialStarted", "DevicePaused", "DeviceResumed", "TrialDone",
                           "TrialStarted"]
    paused, resumed = keeper.records[6], keeper.records[7]
    assert isinstance(paused, DevicePaused) and "lost contact" in str(paused.error)
    assert isinstance(resumed, DeviceResumed) and resumed.choice == "skip"
    assert [r.status for r in res.records] == ["ok", "device_error", "ok", "ok"]


def test_a_consumer_that_raises_costs_the_session_nothing(tmp_path):
    said = []
    keeper = Keeper()
    keeper.data = tmp_path / "data"

    def broken(record):
        raise RuntimeError("the progress display went away")
    res = _session(tmp_path, [broken, keeper], warn=said.append)
    assert res.status == "completed" and len(res.records) == 4
    assert len(said) == 1 and "broken failed" in said[0] and "goes on" in said[0]
    # The consumers after it got every record, the session end included.
    assert len(keeper.records) == 2 + 4 * 4 and isinstance(keeper.records[-1], SessionEnded)
    meta = json.loads(res.paths.session_json.read_text())
    assert meta["status"] == "completed" and meta["n_trials_logged"] == 4
    assert len(pd.read_csv(res.paths.beh_tsv, sep="\t")) == 4


def test_a_consumer_that_fails_at_the_end_leaves_the_record_closed(tmp_path):
    said = []

    def fails_at_the_end(record):
        if isinstance(record, SessionEnded):
            raise OSError("the recorder is gone")
    res = _session(tmp_path, [fails_at_the_end], warn=said.append)
    meta = json.loads(res.paths.session_json.read_text())
    assert meta["status"] == "completed" and meta["checksums"] and len(said) == 1
    assert not (res.paths.record_dir / "session.lock").exists()


# ---------------------------------------------------------------- refused before anything

class Untouched:
    """A sim device that counts its openings."""

    def __init__(self, profile="vest_6x8"):
        self.dev = SimDevice(DeviceProfile.load(profile))
        self.opened = 0
        inner = self.dev._open

        def counting():
            self.opened += 1
            return inner()
        self.dev._open = counting


def _nothing_made(data, untouched):
    assert untouched.opened == 0
    assert not data.exists() or not any(data.rglob("*")), sorted(data.rglob("*"))


@pytest.mark.parametrize("case, error, words", [
    ("participant", InputError, "not a plain token"),
    ("session", InputError, "session must be a whole number"),
    ("model id", InputError, "model participant's id starts with 'sim'"),
    ("max trials", InputError, "--max-trials: must be 1 or more"),
    ("device", InputError, "declared for device 'vest_6x8'"),
    ("unscored", InputError, "needs a question with a correct answer"),
    ("answer list", InputError, "answer 2 of the list, 'triangle'"),
    ("info", InputError, "unknown participant field 'colour'"),
    ("resume nothing", SessionError, "no session 1 of participant 01 .* to resume"),
])
def test_a_run_that_cannot_be_is_refused_before_anything_is_made(tmp_path, case, error,
                                                                  words):
    lx = load_experiment(write_experiment(tmp_path, MINIMAL))
    data = tmp_path / "data"
    u = Untouched("sma_5x5" if case == "device" else "vest_6x8")
    responder = make_responder("scripted:correct", "01", 1, lx)
    options = dict(participant="01", data_dir=data)
    if case == "participant":
        options["participant"] = "a/b"
    elif case == "session":
        options["session"] = 0
    elif case == "model id":
        responder.participant_kind = "model"
    elif case == "max trials":
        options["max_trials"] = 0
    elif case == "unscored":
        lx = load_experiment(write_experiment(tmp_path, MINIMAL.replace(
            '  correct: "{shape}"\n', "")))
    elif case == "answer list":
        responder = ScriptedResponder(answers=["square", "triangle"])
    elif case == "info":
        options["participant_info"] = {"colour": "blue"}
    elif case == "resume nothing":
        options["resume"] = True
    with pytest.raises(error, match=words):
        run_session(lx, u.dev, responder, SessionOptions(**options))
    _nothing_made(data, u)


def test_what_contradicts_participants_tsv_is_refused_before_it_is_touched(tmp_path):
    res = _session(tmp_path, participant_info={"group": "blind"})
    table = res.paths.root / "participants.tsv"
    before = table.read_bytes()
    lx = load_experiment(tmp_path / "exp.yaml")
    u = Untouched()
    with pytest.raises(InputError, match="already says group=blind for sub-01, not sighted"):
        run_session(lx, u.dev, make_responder("scripted:correct", "01", 2, lx),
                    SessionOptions(participant="01", session=2, data_dir=tmp_path / "data",
                                   participant_info={"group": "sighted"}))
    assert u.opened == 0 and table.read_bytes() == before
    assert not SessionPaths.of(tmp_path / "data", "mini", "mini", "01", 2).record_dir.exists()


def test_a_resume_its_record_refuses_opens_nothing(tmp_path):
    lx = load_experiment(write_experiment(tmp_path, MINIMAL))
    data = tmp_path / "data"
    model = make_responder("scripted:correct", "sim01", 1, lx)
    model.participant_kind = "model"
    with SimDevice(DeviceProfile.load("vest_6x8")) as dev:
        res = run_session(lx, dev, model, SessionOptions(participant="sim01", data_dir=data,
                                                         max_trials=2))
    u = Untouched()
    scripted = make_responder("scripted:correct", "sim01", 1, lx)
    with pytest.raises(SessionError, match="answered by a model, and cannot be continued by "
                                           "a scripted"):
        run_session(lx, u.dev, scripted, SessionOptions(participant="sim01", data_dir=data,
                                                        resume=True))
    edited = load_experiment(write_experiment(tmp_path, MINIMAL.replace("Which shape?",
                                                                        "Which one?")))
    with pytest.raises(SessionError, match="SHA-256 differs"):
        run_session(edited, u.dev, model, SessionOptions(participant="sim01", data_dir=data,
                                                         resume=True))
    meta = json.loads(res.paths.session_json.read_text())
    meta["device_spec"] = "serial:/dev/ttyACM0"
    res.paths.session_json.write_text(json.dumps(meta))
    record = res.paths.session_json.read_bytes()
    with pytest.raises(SessionError, match="ran on serial:/dev/ttyACM0 .*the device given is "
                                           "sim .*--force-device"):
        run_session(lx, u.dev, model, SessionOptions(participant="sim01", data_dir=data,
                                                     resume=True, device_spec="sim"))
    assert u.opened == 0 and res.paths.session_json.read_bytes() == record


def test_the_command_line_refuses_a_responder_that_cannot_answer_before_anything(cli,
                                                                                 tmp_path):
    data = tmp_path / "d"
    r = cli("run", str(RATING), "-p", "01", "--responder", "scripted:correct", "--data",
            str(data), "--quiet")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "--responder: scripted:correct needs a question with a correct answer, but " \
           "question 'shape_rating' (rating) has none" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1          # and no command to continue
    assert "To continue" not in r.stderr + r.stdout and "--resume" not in r.stderr
    assert "device check" not in r.stdout                   # the device was not opened
    assert not data.exists()                                # no folder, no participants.tsv


# ------------------------------------------------------------- a play the device stopped

class StallDuring:
    """A consumer that makes the host stall in trial ``trial``'s first play: from its
    PlayStarted the link sends no heartbeat, so the device's watchdog stops the play and
    ends the session; heartbeats go again when the session pauses. ``lose_onsets``: the
    ONSET events of that play after its first are lost on the line."""

    def __init__(self, dev, trial: int, lose_onsets: bool = False):
        self.dev, self.trial, self.lose_onsets = dev, trial, lose_onsets
        self.stalled = False
        self.lost: list = []

    def __call__(self, record):
        link = self.dev._link
        if isinstance(record, PlayStarted) and record.trial.number == self.trial \
                and not self.stalled:
            self.stalled = True
            link.may_heartbeat = lambda now: False
            if self.lose_onsets:
                hear = link.on_event

                def lossy(msg):
                    if isinstance(msg, Onset) and msg.first > 0:
                        self.lost.append(msg)
                    else:
                        hear(msg)
                link.on_event = lossy
        elif isinstance(record, DevicePaused) and link is not None:
            link.may_heartbeat = self.dev._may_heartbeat
            link.on_event = self.dev._on_event


def _rose(emu, cols: int = 6) -> dict[int, list[tuple[int, int, float]]]:
    """The pulses the emulated device's record says rose, by play: (row, col, device ms)."""
    out: dict[int, list] = {}
    for a in emu.actuations():
        if a.cause == "play" and not a.setting.is_off:
            out.setdefault(a.play_id, []).append((a.index // cols, a.index % cols,
                                                  round(a.t_us / 1000, 3)))
    return out


def _logged(paths, trial: int) -> dict[int, list[tuple[int, int, float]]]:
    """The device events the session logged for ``trial``, by play: (row, col, device ms)."""
    ev = pd.read_csv(paths.events_tsv, sep="\t")
    out: dict[int, list] = {}
    for r in ev[ev["trial"] == trial].itertuples():
        out.setdefault(int(r.play), []).append((int(r.row), int(r.col), round(r.onset_ms, 3)))
    return {k: sorted(v) for k, v in out.items()}


@pytest.fixture
def emulated_vest():
    """The emulated vest in-process on a virtual clock, kept across the device's reopening,
    and the device on it."""
    from vtexp.clock import VirtualClock
    from vtexp.devices.emulator import LoopbackEmulator
    from vtexp.devices.serial_device import SerialDevice

    clock = VirtualClock()
    profile = DeviceProfile.load("vest_6x8")
    emu = LoopbackEmulator.for_profile(profile, clock=clock)
    emu.start()
    yield emu, SerialDevice(profile, emu.port, clock=clock)
    emu.stop()


@pytest.mark.parametrize("choice", ["skip", "retry", "abort"])
def test_a_play_the_watchdog_stopped_is_logged_as_far_as_it_played(tmp_path, emulated_vest,
                                                                   choice):
    """The host stalls in trial 2's play and the device's watchdog stops it part-way. The
    trial's logged events are the pulses the emulated device's record says rose, no
    more, no fewer, then the fault policy goes on: a skipped trial is logged
    device_error, a retried one plays again after them (play 1), an aborted session
    logs the trial device_error and a resume goes on after it."""
    emu, dev = emulated_vest
    stall = StallDuring(dev, trial=2)
    asked = []

    def experimenter(error, trial):
        asked.append((error, trial))
        return choice
    run = lambda: _session(tmp_path, [stall], device=dev,  # noqa: E731
                           on_device_error=experimenter)
    if choice == "abort":
        with pytest.raises(PlayInterrupted):
            run()
    else:
        assert run().status == "completed"
    [(error, trial)] = asked
    assert isinstance(error, PlayInterrupted) and emu.firmware.counters.watchdog_trips == 1
    paths = SessionPaths.of(tmp_path / "data", "mini", "mini", "01", 1)
    rose = list(_rose(emu).values())            # one entry per play, in the order played
    scheduled = len(trial.condition.schedule.pulses)
    interrupted = sorted(rose[1])
    assert 0 < len(interrupted) < scheduled      # stopped part-way: the test means something
    logged = _logged(paths, 2)
    assert logged[0] == interrupted              # no more, no fewer, at the device's times
    assert [p.row * 6 + p.col for p in error.report.pulses] == \
        [r * 6 + c for r, c, _ in sorted(rose[1], key=lambda x: x[2])]
    beh = pd.read_csv(paths.beh_tsv, sep="\t")
    status = dict(zip(beh["trial"], beh["status"]))
    if choice == "retry":
        assert logged[1] == sorted(rose[2]) and len(logged[1]) == scheduled
        assert status == {1: "ok", 2: "ok", 3: "ok", 4: "ok"}
        row = beh[beh["trial"] == 2].iloc[0]
        assert row["stimulus_onset_ms"] == pytest.approx(min(t for _, _, t in rose[2]), abs=1)
    else:
        assert set(logged) == {0}
        assert status[2] == "device_error"
    if choice == "skip":
        assert status == {1: "ok", 2: "device_error", 3: "ok", 4: "ok"}
    if choice == "abort":
        assert status == {1: "ok", 2: "device_error"}
        meta = json.loads(paths.session_json.read_text())
        assert meta["status"] == "failed" and "watchdog" in meta["reason"]
        res = _session(tmp_path, device=dev, resume=True)
        assert res.status == "completed" and [r.trial for r in res.records] == [3, 4]
        assert _logged(paths, 2) == logged      # the resume kept them


def test_a_device_of_the_previous_edition_keeps_only_the_onsets_heard(tmp_path,
                                                                      emulated_vest):
    """A device of the previous edition answers GET_ONSETS without a session with
    NO_SESSION: of the interrupted play, the session logs the onsets whose ONSET events
    it heard and no other (it never guesses one)."""
    from vtexp.devices.wire import NakReason

    emu, dev = emulated_vest
    fw = emu.firmware
    serve = fw._get_onsets

    def previous_edition(seq, msg):
        return serve(seq, msg) if fw.session else fw._nak(seq, NakReason.NO_SESSION)
    fw._get_onsets = previous_edition
    stall = StallDuring(dev, trial=2, lose_onsets=True)
    asked = []
    res = _session(tmp_path, [stall], device=dev,
                   on_device_error=lambda e, t: asked.append(e) or "skip")
    assert res.status == "completed"
    paths = SessionPaths.of(tmp_path / "data", "mini", "mini", "01", 1)
    rose = sorted(list(_rose(emu).values())[1])
    lost = {(o.first, o.t_us) for o in stall.lost}
    assert lost and len(stall.lost) < len(rose)       # some heard, some lost
    heard = sorted(x for x in rose if not any(round(t / 1000, 3) == x[2] for _, t in lost))
    assert _logged(paths, 2) == {0: heard}
    assert "are not known" in str(asked[0]) and "previous edition" in str(asked[0])


def test_a_link_lost_while_the_onsets_are_asked_for_keeps_those_heard(tmp_path,
                                                                       emulated_vest):
    """The line fails just as the host asks for the stopped play's onsets: the error is
    still the interrupted play (saying that contact was then lost), the onsets heard are
    logged, and the retried trial plays on the reconnected device."""
    from vtexp.devices.emulator import Faults

    emu, dev = emulated_vest
    fw = emu.firmware
    serve = fw._get_onsets

    def line_fails(seq, msg):
        if not fw.session:
            emu.faults = Faults(drop_rate=1.0, direction="to_host")
        return serve(seq, msg)
    fw._get_onsets = line_fails
    stall = StallDuring(dev, trial=2)
    asked = []

    def experimenter(error, trial):
        asked.append(error)
        emu.faults = Faults()                       # the cable is back
        return "retry"
    res = _session(tmp_path, [stall], device=dev, on_device_error=experimenter)
    assert res.status == "completed" and [r.status for r in res.records] == ["ok"] * 4
    [error] = asked
    assert isinstance(error, PlayInterrupted) and "contact with it was lost" in str(error)
    paths = SessionPaths.of(tmp_path / "data", "mini", "mini", "01", 1)
    rose = list(_rose(emu).values())
    logged = _logged(paths, 2)
    assert 0 < len(logged[0]) and logged[0] == sorted(rose[1])
    assert logged[1] == sorted(rose[2])


def test_a_retried_trial_aborted_after_the_fault_keeps_the_stopped_play(tmp_path,
                                                                         emulated_vest):
    """The experimenter retries trial 2 after the device stopped its play, then Escape
    ends the session at its question: the trial is logged device_error with both plays
    (the stopped one and the one played again), and a resume goes on after it."""
    from vtexp.errors import SessionAborted

    emu, dev = emulated_vest
    stall = StallDuring(dev, trial=2)
    lx = load_experiment(write_experiment(tmp_path, MINIMAL))
    scripted = make_responder("scripted:correct", "01", 1, lx)

    class EscapeAtTrial2:
        description = "escape at trial 2"

        def ask(self, q, trial, replay):
            if trial.number == 2:
                raise SessionAborted("the experimenter pressed Escape")
            return scripted.ask(q, trial, replay)
    with pytest.raises(SessionAborted):
        _session(tmp_path, [stall], device=dev, responder=EscapeAtTrial2(),
                 on_device_error=lambda e, t: "retry")
    paths = SessionPaths.of(tmp_path / "data", "mini", "mini", "01", 1)
    rose = list(_rose(emu).values())
    assert _logged(paths, 2) == {0: sorted(rose[1]), 1: sorted(rose[2])}
    beh = pd.read_csv(paths.beh_tsv, sep="\t")
    assert list(beh["status"]) == ["ok", "device_error"]
    res = _session(tmp_path, device=dev, resume=True)
    assert res.status == "completed" and [r.trial for r in res.records] == [3, 4]
