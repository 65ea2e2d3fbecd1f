"""``vtexp device conform``: a third party's check of a firmware against wire protocol v1.

It passes against vtexp's emulator over a real pty, against the C firmware's host
build and against its ATmega2560 build in simavr (each with its own vector runner),
fails a device that answers one rule otherwise (naming the row), and says in one line
that a port where nothing answers has no device on it, or that a vector runner's port
does not open.
"""

from __future__ import annotations

import os

import pytest

from vtexp.devices import conform, vectors, wire
from vtexp.devices.emulator import PtyEmulator
from vtexp.devices.firmware import Firmware
from vtexp.model import DeviceProfile

VEST = DeviceProfile.load("vest_6x8")
pytestmark = pytest.mark.realtime          # a device on a real pty, in real time


def _failed(rows):
    return [(r.name, r.detail) for r in rows if r.outcome == "FAIL"]


def test_the_emulator_over_a_real_pty_conforms(cli):
    r = cli("device", "conform", "--device", "emulator", timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    n_rules, n_vectors = len(conform.RULES), len(list(vectors.check_each(
        vectors.PythonRunner())))
    assert (f"{n_rules + n_vectors} passed, 0 failed (rules {n_rules}/{n_rules}, vectors "
            f"{n_vectors}/{n_vectors}): conforms") in r.stdout
    assert "conversations/onsets_after_a_watchdog_trip" in r.stdout


def test_the_c_firmwares_host_build_conforms():
    rows = conform.conform("emulator:host")
    assert _failed(rows) == []
    assert {r.kind for r in rows} == {"rule", "vector"}
    assert len([r for r in rows if r.kind == "rule"]) == len(conform.RULES)


@pytest.mark.slow
def test_the_atmega2560_build_in_simavr_conforms():
    rows = conform.conform("emulator:avr")
    assert _failed(rows) == []
    assert len([r for r in rows if r.kind == "rule" and r.outcome == "pass"]) == len(
        conform.RULES)


class _ReadsTheOldText(Firmware):
    """A device written from the previous edition's text: an unknown drive kind in
    UPLOAD_BEGIN is a malformed payload."""

    def _upload_begin(self, seq, msg):
        if msg.drive not in (wire.DRIVE_LEVEL, wire.DRIVE_TRAIN):
            return self._nak(seq, wire.NakReason.BAD_PAYLOAD)
        return super()._upload_begin(seq, msg)


def test_a_device_that_reads_the_old_text_fails_with_the_row_named(cli):
    emu = PtyEmulator.for_profile(VEST)
    emu.line.firmware = _ReadsTheOldText(emu.config, emu.line.clock_us)
    with emu:
        r = cli("device", "conform", "--device", f"serial:{emu.port}", "--vectors", "python",
                timeout=300)
    assert r.returncode == 1, r.stderr
    line = next(ln for ln in r.stdout.splitlines()
                if "upload_begin_of_an_unknown_drive_is_wrong_drive" in ln)
    assert "FAIL" in line and "UPLOAD_BEGIN of drive kind 3: answered Nak" in line
    assert "BAD_PAYLOAD" in line and "expected NAK WRONG_DRIVE" in line
    assert r.stdout.rstrip().endswith(
        "FAILED upload_begin_of_an_unknown_drive_is_wrong_drive")
    assert "Traceback" not in r.stdout + r.stderr


def test_a_device_without_vector_runner_says_the_vectors_were_not_run(cli):
    with PtyEmulator.for_profile(VEST) as emu:
        r = cli("device", "conform", "--device", f"serial:{emu.port}", timeout=300)
    assert r.returncode == 0, r.stderr
    assert "not run" in r.stdout and "--vectors serial:PORT" in r.stdout
    assert "1 not run" in r.stdout and "no failure in what was run" in r.stdout


def test_a_port_where_nothing_answers_is_one_message(cli):
    master, slave = os.openpty()
    try:
        r = cli("device", "conform", "--device", f"serial:{os.ttyname(slave)}", timeout=60)
    finally:
        os.close(master)
        os.close(slave)
    assert r.returncode != 0
    assert r.stdout == ""
    err = r.stderr.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert "no device answered the vtexp handshake (HELLO) on /dev/" in err


def test_a_vector_runner_port_that_does_not_open_is_named():
    """--vectors serial:PORT where no port is: a message naming it, not pyserial's
    traceback."""
    from vtexp.errors import DeviceError

    with pytest.raises(DeviceError, match="cannot open the vector runner's serial port "
                                          "'/dev/vtexp-no-such-port'"):
        with conform.vector_runner("serial:/dev/vtexp-no-such-port"):
            pass


class _PreviousEdition(Firmware):
    """A device of the previous edition: GET_ONSETS only within a session."""

    def _get_onsets(self, seq, msg):
        if not self.session:
            return self._nak(seq, wire.NakReason.NO_SESSION)
        return super()._get_onsets(seq, msg)


def test_a_device_of_the_previous_edition_fails_the_onsets_row_only():
    import serial

    emu = PtyEmulator.for_profile(VEST)
    emu.line.firmware = _PreviousEdition(emu.config, emu.line.clock_us)
    with emu:
        port = serial.serial_for_url(emu.port, baudrate=1_000_000, timeout=0.01)
        try:
            rows = list(conform.check_rules(port, emu.port))
        finally:
            port.close()
    [(name, detail)] = _failed(rows)
    assert name == "onsets_after_a_watchdog_trip"
    assert "answered Nak" in detail and "NO_SESSION" in detail and "cannot be recovered" in detail
