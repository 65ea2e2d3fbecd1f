"""Aborting while a stimulus plays: ``play(schedule, should_stop=...)`` on every backend.

``should_stop`` turns true in the middle of a long schedule: the play must end with
every actuator off (what the device itself says: the sim's state, the emulated
firmware's outputs and its record of the ALL_OFF it received) and raise
``SessionAborted``; a session aborted that way keeps its completed trials. The time
from the stop to the ALL_OFF at the device is printed (``pytest -s``), not asserted:
``bench/timing.py`` measures timing, tests check order and outcome.

The participant's window reading a real Escape key during a stimulus is in
``tests/test_window.py``.
"""

from __future__ import annotations

import json
import time

import pandas as pd
import pytest
from conftest import MINIMAL, write_experiment, session_record
from test_device_contract import VEST, expected, make_backend, vest_schedule

from vtexp.devices import open_device, wire
from vtexp.errors import SessionAborted
from vtexp.experiment import load_experiment
from vtexp.model import DeviceProfile, Pulse, Schedule
from vtexp.responders import Response
from vtexp.session import SessionOptions, run_session

# How soon everything is off after a stop, in real time: real time is its subject.
pytestmark = pytest.mark.realtime


@pytest.fixture(params=["sim", "emulator", "emulator-host-timing", "serial-pty"])
def backend(request):
    b = make_backend(request.param)
    yield b
    b.cleanup()


class StopAfter:
    """A ``should_stop`` that says stop ``delay_s`` after its first call (the play's start)."""

    def __init__(self, delay_s: float, reason: str | bool = "stopped by the test"):
        self.delay_s = delay_s
        self.reason = reason
        self.calls = 0
        self.first: float | None = None
        self.stopped_at: float | None = None

    def __call__(self):
        self.calls += 1
        now = time.perf_counter()
        if self.first is None:
            self.first = now
        if now - self.first >= self.delay_s:
            if self.stopped_at is None:
                self.stopped_at = now
            return self.reason
        return None


def emulator_of(dev):
    return getattr(dev, "emulator", None) or getattr(dev, "test_emulator", None)


def watch_all_off(dev) -> dict:
    """Record when the device receives (emulator) or performs (sim) its first ALL_OFF."""
    seen: dict[str, float] = {}
    emu = emulator_of(dev)
    if emu is not None:
        def trace(direction, item):
            if direction == "to_device" and isinstance(item, wire.AllOff):
                seen.setdefault("all_off", time.perf_counter())
        emu.trace = trace
    else:
        all_off = dev._all_off

        def timed_all_off():
            seen.setdefault("all_off", time.perf_counter())
            all_off()
        dev._all_off = timed_all_off
    return seen


def long_schedule() -> Schedule:
    return Schedule(device="vest_6x8", pulses=[
        Pulse(row=r, col=0, onset_ms=0, duration_ms=1500, level=2) for r in range(4)]
        + [Pulse(row=r, col=3, onset_ms=200, duration_ms=1200, level=1) for r in range(4)])


def test_a_stop_mid_schedule_turns_everything_off_at_once(backend):
    dev = backend.open(VEST, realtime=True)
    stop = StopAfter(0.4)
    with dev:
        seen = watch_all_off(dev)
        t = time.perf_counter()
        with pytest.raises(SessionAborted, match="stopped by the test"):
            dev.play(long_schedule(), should_stop=stop)
        elapsed = time.perf_counter() - t
        assert backend.all_off(dev)
        emu = emulator_of(dev)
        if emu is not None:
            acts = emu.actuations()
            offs = [a for a in acts if a.cause == "all_off"]
            assert offs, "ALL_OFF did not switch off what was on"
            assert not [a for a in acts if a.cause == "play" and a.t_us > offs[0].t_us]
        else:
            kinds = [e.kind for e in dev.history]
            assert kinds[-2:] == ["stopped", "all_off"] and dev.plays == []
        # The device is still usable: the next play runs to its end.
        rep = dev.play(vest_schedule())
        assert rep.completed and backend.all_off(dev)
    assert elapsed < 1.5                    # stopped, not played to its end (1.5 s)
    assert stop.calls > 2                   # polled while the schedule played
    assert stop.stopped_at < seen["all_off"]
    print(f"\n{backend.name}: should_stop true -> ALL_OFF at the device "
          f"{(seen['all_off'] - stop.stopped_at) * 1000:.1f} ms")


def test_a_stop_before_the_play_plays_nothing(backend):
    dev = backend.open(VEST, realtime=True)
    with dev:
        with pytest.raises(SessionAborted, match="stopped while the stimulus played"):
            dev.play(vest_schedule(), should_stop=lambda: True)
        assert backend.driven(dev) == [] and backend.all_off(dev)


def test_without_a_stop_the_poll_changes_nothing(backend):
    dev = backend.open(VEST, realtime=True)
    stop = StopAfter(60.0)
    with dev:
        rep = dev.play(vest_schedule(), should_stop=stop)
    assert rep.completed and stop.calls >= 1 and stop.stopped_at is None
    assert sorted(backend.driven(dev)) == expected(vest_schedule())


class StopsDuringTheSecondStimulus:
    """A responder whose stop_requested says stop 0.1 s into the second stimulus."""

    description = "test: stop during the second stimulus"

    def __init__(self):
        self.stimuli = 0
        self.stopped: list[int] = []
        self._stop: StopAfter | None = None

    def stimulus_starts(self, trial) -> None:
        self.stimuli += 1
        self._stop = StopAfter(0.1, "the test stopped trial 2") if self.stimuli == 2 else None

    def stop_requested(self):
        return self._stop() if self._stop is not None else None

    def stimulus_stopped(self, trial) -> None:
        self.stopped.append(trial.number)

    def ask(self, question, trial, replay) -> Response:
        return Response(answer=question.options[0], rt_s=0.5)


def test_a_session_stopped_during_a_stimulus_is_aborted_and_keeps_its_trials(tmp_path):
    lx = load_experiment(write_experiment(tmp_path, MINIMAL.replace(
        "{duration_ms: 200, soa_ms: 200}", "{duration_ms: 30, soa_ms: 30}")))
    r = StopsDuringTheSecondStimulus()
    with open_device("sim:realtime", DeviceProfile.load(lx.experiment.device)) as dev:
        with pytest.raises(SessionAborted, match="the test stopped trial 2"):
            run_session(lx, dev, r, SessionOptions(participant="01", data_dir=tmp_path / "data"))
        assert float(dev.state.max()) == 0.0
    kinds = [e.kind for e in dev.history]
    assert kinds.count("play") == 1 and kinds[kinds.index("stopped") + 1] == "all_off"
    assert r.stopped == [2]
    d = tmp_path / "data" / "mini" / "sub-01" / "ses-1"
    meta = json.loads(session_record(d).read_text())
    beh = pd.read_csv(next(d.glob("beh/*_beh.tsv")), sep="\t", dtype=str)
    events = pd.read_csv(next(d.glob("beh/*_events.tsv")), sep="\t")
    assert meta["status"] == "aborted" and meta["reason"] == "the test stopped trial 2"
    assert list(beh["trial"]) == ["1"] and set(events["trial"]) == {1}
