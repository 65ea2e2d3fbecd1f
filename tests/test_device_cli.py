"""``vtexp device list|check|monitor|emulate``, run as a person would run them."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from vtexp.devices.emulator import PtyEmulator
from vtexp.devices.serial_device import SerialDevice
from vtexp.model import DeviceProfile, Pulse, Schedule

ROOT = Path(__file__).resolve().parents[1]
VEST = DeviceProfile.load("vest_6x8")
ENV = dict(os.environ, PYTHONPATH=str(ROOT))


def vtexp(*args: str) -> subprocess.Popen:
    """``vtexp ARGS`` as a child process: for commands that serve until a signal stops them."""
    return subprocess.Popen([sys.executable, "-m", "vtexp", *args], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)


@pytest.fixture
def emu():
    e = PtyEmulator.for_profile(VEST)
    e.start()
    yield e
    e.stop()


def test_device_list_runs_and_points_to_the_emulator(cli):
    r = cli("device", "list")
    assert r.returncode == 0, r.stderr
    assert "vtexp device emulate --profile" in r.stdout


def test_check_unattended_plays_every_actuator_once(cli, emu):
    r = cli("device", "check", "--device", f"serial:{emu.port}", "--profile", "vest_6x8",
            "--yes", "--on-ms", "10", "--pings", "5")
    assert r.returncode == 0, r.stderr
    assert "firmware: vtexp-emulator" in r.stdout and "protocol: vtexp-wire/1" in r.stdout
    assert "round trip (5 heartbeats): p50" in r.stdout
    assert "48 of 48 actuators played (not confirmed by a person: --yes)" in r.stdout
    on = [a.index for a in emu.actuations() if not a.setting.is_off]
    assert on == list(range(48))                # each in turn, row by row, once
    assert {a.setting.level for a in emu.actuations() if a.index == 5} == {0, 1}   # low level


def test_check_asks_a_person_and_reports_what_did_not_move(cli, emu):
    r = cli("device", "check", "--device", f"serial:{emu.port}", "--profile", "vest_6x8",
            "--on-ms", "10", "--pings", "1", input="y\nn\nr\ny\nq\n", timeout=60)
    assert r.returncode == 1, r.stderr
    assert "stopped after 3 of 48 actuators" in r.stdout
    assert "1 of 3 actuators did not move: (row 0, col 1)" in r.stdout
    on = [a.index for a in emu.actuations() if not a.setting.is_off]
    assert on == [0, 1, 2, 2, 3]                # 'r' played (0, 2) again; 'q' after (0, 3)


def test_check_refuses_the_wrong_profile_without_a_traceback(cli, emu):
    r = cli("device", "check", "--device", f"serial:{emu.port}", "--profile", "pad_20x20",
            "--yes")
    assert r.returncode == 3
    assert r.stderr.startswith("vtexp: error: the device on") and "Traceback" not in r.stderr
    assert "profile 'pad_20x20' describes 20x20" in r.stderr
    assert emu.actuations() == []


def test_check_on_a_missing_port(cli):
    r = cli("device", "check", "--device", "serial:/dev/no-such-port", "--profile", "vest_6x8")
    assert r.returncode == 3 and "Traceback" not in r.stderr
    assert "cannot open the serial port '/dev/no-such-port'" in r.stderr


@pytest.mark.process
def test_emulate_prints_its_port_and_serves_until_stopped():
    p = vtexp("device", "emulate", "--profile", "vest_6x8")
    try:
        first = p.stdout.readline()
        assert first.startswith("emulating vest_6x8 (8x6, vtexp-emulator")
        port = first.split(" on ")[-1].strip()
        assert p.stdout.readline().startswith(f"use it with --device serial:{port}")
        with SerialDevice(VEST, port) as dev:
            rep = dev.play(Schedule(device="vest_6x8", pulses=[
                Pulse(row=1, col=1, onset_ms=0, duration_ms=20, level=2)]))
        assert len(rep.pulses) == 1
        p.send_signal(signal.SIGTERM)
        out, err = p.communicate(timeout=10)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 0, err
    assert "emulator stopped:" in out and "0 bad" in out and "0 watchdog trips" in out


@pytest.mark.process
def test_emulate_can_pretend_to_be_another_geometry(cli):
    p = vtexp("device", "emulate", "--profile", "vest_6x8", "--rows", "4")
    try:
        port = p.stdout.readline().split(" on ")[-1].strip()
        r = cli("device", "check", "--device", f"serial:{port}", "--profile", "vest_6x8",
                "--yes", timeout=60)
        assert r.returncode == 3 and "reports 4x6 coin_tactor actuators" in r.stderr
    finally:
        p.send_signal(signal.SIGINT)
        p.communicate(timeout=10)


@pytest.mark.process
def test_monitor_decodes_the_traffic_between_host_and_device(emu):
    p = vtexp("device", "monitor", "--device", f"serial:{emu.port}")
    try:
        first = p.stdout.readline()
        assert first.startswith(f"monitoring serial:{emu.port}; connect the experiment to")
        tap = first.split("connect the experiment to serial:")[1].split()[0]
        with SerialDevice(VEST, tap) as dev:
            dev.play(Schedule(device="vest_6x8", pulses=[
                Pulse(row=0, col=2, onset_ms=0, duration_ms=20, level=1)]))
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=10)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 0, err
    lines = out.splitlines()
    assert any("host -> device  seq   0  Hello protocol=1" in ln for ln in lines)
    assert any("device -> host" in ln and "HelloReply" in ln and "rows=8 cols=6" in ln
               for ln in lines)
    assert any("UploadChunk play 1 pulses 0..0" in ln for ln in lines)
    assert any("Onset play_id=1 first=0 count=1" in ln for ln in lines)
    assert any("PlayDone play 1 finished" in ln for ln in lines)
    assert any("host -> device" in ln and "AllOff" in ln for ln in lines)
    # the tap is transparent: the device drove what the host asked for
    assert [a.index for a in emu.actuations() if not a.setting.is_off] == [2]


def _fast(yaml_text: str, ms: int) -> str:
    return yaml_text.replace("duration_ms: 200, soa_ms: 200", f"duration_ms: {ms}, soa_ms: {ms}")


def test_run_a_session_on_the_emulator_backend(cli, tmp_path, minimal_yaml):
    exp = tmp_path / "mini.yaml"
    exp.write_text(_fast(minimal_yaml, 10), encoding="utf-8")
    r = cli("run", str(exp), "-p", "01", "--device", "emulator", "--responder",
            "scripted:correct", "--data", str(tmp_path / "data"), "-q")
    assert r.returncode == 0, r.stderr
    assert "session completed: 4 trials logged" in r.stdout
    meta = json.loads(next((tmp_path / "data").rglob("*_session.json")).read_text())
    assert meta["device"]["backend"] == "emulator"
    assert meta["device"]["protocol"] == "vtexp-wire/1"
    events = next((tmp_path / "data").rglob("*_events.tsv")).read_text().splitlines()
    assert len(events) > 4                  # device-reported onsets, logged per pulse


def test_cable_pulled_during_a_session_ends_it_with_a_message_not_a_traceback(
        cli, tmp_path, minimal_yaml, emu):
    exp = tmp_path / "mini.yaml"
    exp.write_text(_fast(minimal_yaml, 100), encoding="utf-8")

    def pull_the_cable():
        deadline = time.monotonic() + 30
        while len(emu.actuations()) < 3 and time.monotonic() < deadline:
            time.sleep(0.01)
        emu.unplug()                        # mid-trial: the first stimulus is playing

    puller = threading.Thread(target=pull_the_cable, daemon=True)
    puller.start()
    r = cli("run", str(exp), "-p", "01", "--device", f"serial:{emu.port}", "--responder",
            "scripted:correct", "--data", str(tmp_path / "data"), "-q", timeout=60)
    puller.join(5)
    err = r.stderr
    assert r.returncode == 3, err
    assert err.startswith(f"vtexp: error: lost contact with the tactile device on {emu.port}")
    assert "Traceback" not in err
    meta = json.loads(next((tmp_path / "data").rglob("*_session.json")).read_text())
    assert meta["status"] == "failed" and "lost contact" in meta["reason"]
    time.sleep(0.3)
    assert emu.all_outputs_off()
