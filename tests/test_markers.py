"""Event markers beside a session: an LSL stream received on loopback, a trigger box on a pty.

LSL runs on this machine only (``ResolveScope = machine``, the one known peer
127.0.0.1): the test's inlet finds the session's outlet without the lab's network.
"""

from __future__ import annotations

import atexit
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

import pandas as pd
import pytest

from conftest import MINIMAL, write_experiment

_CFG = Path(tempfile.mkdtemp(prefix="vtexp-lsl-")) / "lsl_api.cfg"
atexit.register(shutil.rmtree, _CFG.parent, True)
_CFG.write_text("[ports]\nIPv6 = disable\n[multicast]\nResolveScope = machine\n"
                "[lab]\nKnownPeers = {127.0.0.1}\n")
os.environ.setdefault("LSLAPICFG", str(_CFG))   # before liblsl reads its configuration

SHORT = MINIMAL.replace("repetitions: 2", "repetitions: 1").replace(
    "params: {duration_ms: 200, soa_ms: 200}", "params: {duration_ms: 60, soa_ms: 80}")


class Recorder:
    """A consumer that keeps what the session told it (the plays as reported)."""

    def __init__(self):
        self.plays: dict[int, list] = {}

    def __call__(self, record):
        from vtexp.session import TrialDone

        if isinstance(record, TrialDone):
            self.plays[record.trial.number] = record.plays


def _session(tmp_path, device_spec: str, markers):
    from vtexp.devices import open_device
    from vtexp.experiment import load_experiment
    from vtexp.model import DeviceProfile
    from vtexp.responders import make_responder
    from vtexp.session import SessionOptions, run_session

    lx = load_experiment(write_experiment(tmp_path, SHORT))
    rec = Recorder()
    device = open_device(device_spec, DeviceProfile.load(lx.experiment.device))
    with device:
        res = run_session(lx, device, make_responder("scripted:correct", "01", 1, lx),
                          SessionOptions(participant="01", data_dir=tmp_path / "data"),
                          consumers=(rec, *markers))
    assert res.status == "completed"
    events = pd.read_csv(res.paths.events_tsv, sep="\t")
    return res, events, rec, device


def _pull_all(inlet, until: str, timeout_s: float = 20.0) -> list[tuple[dict, float]]:
    got: list[tuple[dict, float]] = []
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        samples, stamps = inlet.pull_chunk(timeout=0.2)
        got += [(json.loads(s[0]), t) for s, t in zip(samples, stamps)]
        if got and got[-1][0]["event"] == until:
            break
    return got


@pytest.mark.realtime          # LSL stamps on the computer's clock, as a recorder sees them
@pytest.mark.parametrize("device_spec", ["emulator", "sim:realtime"])
def test_every_onset_reaches_an_lsl_inlet_stamped_with_the_device_onset(tmp_path, device_spec):
    import pylsl

    from vtexp.markers import open_markers

    markers = open_markers("lsl", experiment="mini", participant="01", session=1)
    try:
        found = pylsl.resolve_byprop("source_id", markers.source_id, timeout=10)
        assert found, "the marker stream was not found on loopback"
        info = found[0]
        assert info.type() == "Markers" and info.channel_format() == pylsl.cf_string
        inlet = pylsl.StreamInlet(info, recover=False)
        inlet.open_stream(timeout=10)
        res, events, rec, device = _session(tmp_path, device_spec, [markers])
        got = _pull_all(inlet, "session_end")
    finally:
        markers.close()
    kinds = [m["event"] for m, _ in got]
    n_trials = len(res.records)
    assert kinds[0] == "session_start" and kinds[-1] == "session_end"
    assert kinds.count("trial_start") == kinds.count("trial_end") == n_trials
    assert kinds.count("answer") == n_trials
    pulses = [(m, t) for m, t in got if m["event"] == "pulse"]
    assert len(pulses) == len(events) > 0
    stamps = [t for _, t in got]
    assert stamps == sorted(stamps)                 # when it happened, in order

    # Each row of the events file has its marker: same pulse, the same device-reported
    # onset, stamped with that onset mapped to LSL's clock through the play's mapping.
    offset = markers.offset_s
    assert abs(offset) < 0.001          # Linux: local_clock and time.monotonic are one clock
    by_key = {(m["trial"], m["play"], m["row"], m["col"], round(m["device_ms"], 3)): t
              for m, t in pulses}
    for r in events.itertuples():
        t = by_key[(r.trial, r.play, r.row, r.col, round(r.onset_ms, 3))]
        play = rec.plays[r.trial][r.play]
        expected = (play.started_at_host_ms + (r.onset_ms - play.started_at_ms)) / 1000 + offset
        assert abs(t - expected) < 1e-4, (r, t, expected)
        if device_spec == "emulator":
            # and that mapping is the emulated device's real clock: its µs count from its
            # own power-on (perf_counter, CLOCK_MONOTONIC like time.monotonic on Linux)
            truth = device.emulator._origin_ns / 1e9 + r.onset_ms / 1000 + offset
            assert abs(t - truth) < play.host_clock_error_ms / 1000 + 1e-4, (t, truth)
    answers = [m for m, _ in got if m["event"] == "answer"]
    assert all(m["correct"] is True and m["answer"] == m["condition"]["shape"] for m in answers)


def test_a_trigger_box_gets_one_code_per_event_in_order(tmp_path):
    from vtexp.markers import CODES, open_markers

    master, slave = os.openpty()
    try:
        os.set_blocking(master, False)
        box = open_markers(f"serial:{os.ttyname(slave)},baud=115200", experiment="mini",
                           participant="01", session=1)
        try:
            res, events, _, _ = _session(tmp_path, "sim", [box])
        finally:
            box.close()
        time.sleep(0.05)
        data = b""
        while True:
            try:
                chunk = os.read(master, 4096)
            except BlockingIOError:
                break
            if not chunk:
                break
            data += chunk
    finally:
        os.close(master)
        os.close(slave)
    per_trial = [CODES["trial_start"], CODES["stimulus"], CODES["answer"], CODES["trial_end"]]
    assert list(data) == [CODES["session_start"], *per_trial * len(res.records),
                          CODES["session_end"]]
    assert [c for _, c in box.sent] == list(data) and box.lost == 0


def test_codes_are_the_documented_ones():
    from vtexp.markers import CODES

    doc = (Path(__file__).resolve().parents[1] / "docs" / "markers.md").read_text()
    for event, code in CODES.items():
        assert f"| {code} | `{event}` |" in doc


@pytest.mark.parametrize("spec, says", [
    ("serial:/dev/vtexp-no-such-port", "cannot open the trigger box on '/dev/vtexp-no-such-port'"),
    ("parallel:/dev/vtexp-no-such-parport", "cannot open the parallel port"),
    ("lsl:bogus=1", "lsl takes only name=NAME"),
    ("eeg", "unknown marker output 'eeg'"),
])
def test_a_marker_output_that_cannot_be_opened_is_one_message_before_any_trial(
        cli, tmp_path, spec, says):
    f = write_experiment(tmp_path, SHORT)
    data = tmp_path / "data"
    r = cli("run", str(f), "-p", "01", "--responder", "scripted:correct", "--data", str(data),
            "--quiet", "--markers", spec)
    assert r.returncode == 2, r.stderr
    assert says in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert "device check" not in r.stdout and not (data / "mini").exists()


def test_run_with_lsl_markers_from_the_command_line(cli, tmp_path):
    f = write_experiment(tmp_path, SHORT)
    r = cli("run", str(f), "-p", "01", "--responder", "scripted:correct", "--data",
            str(tmp_path / "data"), "--quiet", "--markers", "lsl")
    assert r.returncode == 0, r.stderr
    assert "markers: LSL marker stream (source_id vtexp:mini:sub-01:ses-1)" in r.stdout
