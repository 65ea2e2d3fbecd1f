"""The sim backend: virtual clock, records everything, safe by construction."""

from __future__ import annotations

import pytest

from vtexp.devices import Device, open_device
from vtexp.errors import InputError, UnsafeStimulus
from vtexp.model import DeviceProfile, Pulse, Schedule

VEST = DeviceProfile.load("vest_6x8")


def schedule(level=1):
    return Schedule(device="vest_6x8", pulses=[
        Pulse(row=0, col=1, onset_ms=100, duration_ms=200, level=level),
        Pulse(row=0, col=0, onset_ms=0, duration_ms=200, level=2)])


def test_sim_satisfies_the_device_protocol():
    assert isinstance(open_device("sim", VEST), Device)


def test_play_reports_onsets_and_advances_the_virtual_clock():
    with open_device("sim", VEST) as dev:
        info = dev.info()
        assert (info.backend, info.rows, info.cols) == ("sim", 8, 6)
        a = dev.play(schedule())
        dev.wait_ms(1000)
        b = dev.play(schedule())
    assert a.started_at_ms == 0 and a.duration_ms == 300
    assert [(p.row, p.col, p.onset_ms) for p in a.pulses] == [(0, 0, 0), (0, 1, 100)]
    assert b.started_at_ms == 1300
    kinds = [e.kind for e in dev.history]
    assert kinds == ["open", "play", "wait", "play", "all_off", "close"]


def test_unsafe_schedule_never_reaches_the_device():
    dev = open_device("sim", VEST)
    with dev, pytest.raises(UnsafeStimulus):
        dev.play(schedule(level=9))
    assert dev.plays == []


def test_error_during_play_turns_everything_off():
    dev = open_device("sim", VEST)

    def boom(s):
        dev.state[:] = 1
        raise RuntimeError("cable pulled")
    dev._play = boom
    with dev, pytest.raises(RuntimeError):
        dev.play(schedule())
    assert dev.state.max() == 0
    assert dev.history[-2].kind == "all_off"


def test_unknown_backend_is_a_clear_error():
    with pytest.raises(InputError, match="unknown device 'usb'; available: sim"):
        open_device("usb", VEST)
