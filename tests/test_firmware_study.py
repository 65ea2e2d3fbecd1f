"""A whole study on the reference firmware's ATmega2560 build, as a lab would run it.

``vtexp device emulate --firmware avr --profile sma_5x5 --lockstep`` serves the .elf a
lab flashes, in simavr, on a pseudo-terminal; ``vtexp run`` plays seed 002's
circle-vs-rectangle study on it through ``serial:PORT`` with a scripted participant,
keeping time by the simulated chip (the chip runs as fast as the computer goes: the
study's 80 s pass in a fraction of that; the firmware and its pins cannot tell).
Then the chip's pins (the harness's trace) are held against the session's log:
every pulse the log says was played rose on its pin at the logged onset, at its
amplitude, and nothing rose on any pin that the log does not explain.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from vtexp.devices import fwtrace

from conftest import session_record

ROOT = Path(__file__).resolve().parents[1]
STUDY = ROOT / "experiments" / "circle_vs_rectangle.yaml"
SLACK_US = 20           # edges come about 6.3 us after their 100 us tick (interrupt entry)
MAX_TICK_WAIT_CYCLES = 96   # 6 us: one receive or transmit interrupt, not a 64-bit routine
# A train's logged onset is its first edge as it happened; its later edges keep the tick
# grid. A tick that waited for a UART interrupt at the train's start puts the later
# edges up to that wait before onset + k periods.
EARLY_US = MAX_TICK_WAIT_CYCLES / 16

# The chip is served by `vtexp device emulate` in a process of its own, as a device is
# apart from the host, and stopped with Ctrl-C. `vtexp run` stays a child process too:
# the pins depend on when the host's frames reach the chip (a tick late for a
# preparation waits for the interrupt before it, docs/firmware.md), and in the test
# process the host's timing differs: there two runs in seven had a tick wait 114 cycles,
# past the bound below. As a child, one run in seven had a pulse the log does not explain
# until trains knew their end (docs/firmware.md, Known limits).
pytestmark = pytest.mark.process


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("avr_study")
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    trace = tmp / "pins.jsonl"
    emu = subprocess.Popen([sys.executable, "-m", "vtexp", "device", "emulate", "--firmware",
                            "avr", "--profile", "sma_5x5", "--lockstep", "--trace", str(trace)],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        first = emu.stdout.readline()
        assert first.startswith("emulating sma_5x5 with the reference firmware's ATmega2560"), \
            first + emu.stderr.read()
        hint = emu.stdout.readline()
        # the device exactly as suggested (a slower heartbeat and a longer wait for replies:
        # the simulated chip runs on while a loaded machine keeps the host's threads
        # waiting; the host's time is the chip's)
        port = hint.split("--device ")[1].split()[0]
        assert ",heartbeat_ms=1000,reply_ms=120,lockstep=" in port, hint

        run = subprocess.run(
            [sys.executable, "-m", "vtexp", "run", str(STUDY), "--participant", "01",
             "--device", port, "--responder", "scripted:random", "--data", str(tmp / "data")],
            stdin=subprocess.DEVNULL, capture_output=True, text=True, env=env, timeout=600)
    finally:
        emu.send_signal(signal.SIGINT)             # Ctrl-C, as at the terminal
        out, err = emu.communicate(timeout=30)
    return tmp, run, out, trace


def test_the_study_runs_to_its_end_on_the_chip(session):
    tmp, run, emu_out, _ = session
    assert run.returncode == 0, run.stderr
    assert "Traceback" not in run.stderr
    assert "device check passed; no actuator is on" in run.stdout
    assert "session completed: 20 trials logged" in run.stdout
    meta = json.loads(session_record(tmp / "data" / "circle_vs_rectangle" / "sub-01" /
                                     "ses-1").read_text())
    assert meta["status"] == "completed"
    assert meta["device"]["firmware"].startswith("vtexp-fw ") and "avr sma_5x5" in \
        meta["device"]["firmware"]
    assert "trace written to" in emu_out


def test_every_logged_pulse_is_on_the_pins_and_nothing_else(session):
    tmp, run, _, trace_path = session
    assert run.returncode == 0, run.stderr
    ses = tmp / "data" / "circle_vs_rectangle" / "sub-01" / "ses-1"
    meta = json.loads(session_record(ses).read_text())
    events = pd.read_csv(ses.parents[1] / meta["files"]["events"], sep="\t")
    tr = fwtrace.Trace.load(trace_path)
    edges = fwtrace.gate_edges(tr)
    rises = {i: np.array([tr.device_us(c) for c, s in e if s]) for i, e in edges.items()}
    times = {i: np.array([tr.device_us(c) for c, _ in e]) for i, e in edges.items()}
    states = {i: np.array([s for _, s in e]) for i, e in edges.items()}
    codes = fwtrace.dac_codes(tr)
    explained = {i: np.zeros(len(r), dtype=bool) for i, r in rises.items()}

    def high_at(pin: int, t_us: float) -> bool:
        k = np.searchsorted(times[pin], t_us, side="right") - 1
        return k >= 0 and bool(states[pin][k])

    for e in events.itertuples():
        pin = e.row * 5 + e.col
        t0 = e.onset_ms * 1000.0
        f_chz = round(e.frequency_hz * 100)
        k = np.arange(0, int(e.duration_ms * 1000 * f_chz // 100_000_000) + 1)
        want = t0 + (k * 100_000_000) // f_chz
        want = want[want < t0 + e.duration_ms * 1000]
        for w in want:
            d = rises[pin] - w
            hit = np.flatnonzero((d >= -EARLY_US) & (d <= SLACK_US))
            explained[pin][hit] = True
            # a rise there, or the pin already high: the pulse of the train it takes over
            # from ran into this instant (the latest started drives the pin)
            assert len(hit) == 1 or (w == t0 and high_at(pin, w)), \
                f"pin {pin}: no pulse at {w:.0f} us (trial {e.trial})"
            assert high_at(pin, w + SLACK_US), f"pin {pin}: low at {w:.0f} us"
        # the amplitude its DAC channel holds from the train's start (a train that takes
        # over a pin mid-flight gets it within the first tick: docs/firmware.md)
        held = [v for c, p, v in codes if p == pin and tr.device_us(c) <= t0 + 100]
        assert held and fwtrace.code_to_mv(held[-1], 2000) == round(e.amplitude_v * 1000)
    for pin, ok in explained.items():
        assert ok.all(), f"pin {pin}: {int((~ok).sum())} pulses the log does not explain"
    assert sum(len(r) for r in rises.values()) > len(events)    # trains of several pulses
    assert fwtrace.all_off_at_end(tr, 25)


def test_no_tick_waited_longer_than_one_short_interrupt(session):
    """A train's first edge is its logged onset and later edges keep the tick grid, so a
    tick held off (interrupts off in the main loop, a long handler) puts one edge off
    its train: the wait bounds how far (EARLY_US above). Counted in simulated cycles."""
    _, run, _, trace_path = session
    assert run.returncode == 0, run.stderr
    tr = fwtrace.Trace.load(trace_path)
    assert sum(tr.tick_latency.values()) > 100_000          # every tick of the session
    worst = tr.tick_latency_worst
    # the UART's receive handler (about 70 cycles) is the longest a tick may wait
    assert worst["cycles"] <= MAX_TICK_WAIT_CYCLES, \
        f"a tick waited {worst['cycles']} cycles at pc {worst['pc']:#x} (vector {worst['vector']})"
