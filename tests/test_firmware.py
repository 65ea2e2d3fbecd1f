"""The reference firmware in C (firmware/): built as a lab builds it, held to the vectors.

The host build and the ATmega2560 build (the vector runner's .elf, in simavr through
vtexp-simavr's own pty bridge) both replay every vector of
protocols/wire/v1_vectors.json and must answer byte for byte. A profile that does
not fit the chip stops the build; the headers are what the profiles say.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from vtexp.devices import cfirmware, vectors
from vtexp.devices.cfirmware import AvrSimulator
from vtexp.resources import firmware_dir

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def built():
    return cfirmware.build()


def test_profile_headers_are_what_the_profiles_say(tmp_path):
    subprocess.run([sys.executable, str(ROOT / "firmware" / "tools" / "gen_profiles.py"),
                    str(tmp_path)], check=True, capture_output=True)
    for h in (ROOT / "firmware" / "profiles").glob("*.h"):
        assert (tmp_path / h.name).read_text() == h.read_text(), h.name


def test_host_build_answers_every_vector_byte_for_byte(built):
    runner = vectors.ProcessRunner(built / "host" / "vtexp-fw-vectors")
    try:
        n, bad = vectors.replay(runner)
    finally:
        runner.close()
    assert bad == []
    assert n > 200


def test_atmega2560_build_answers_every_vector_byte_for_byte(built):
    with AvrSimulator(None, elf=built / "avr" / "vectors" / "vtexp-fw-vectors.elf") as sim:
        runner = vectors.SerialRunner(sim.port)
        try:
            n, bad = vectors.replay(runner)
        finally:
            runner.close()
    assert bad == []
    assert n > 200


def test_a_wrong_byte_is_reported_with_what_was_expected(built):
    runner = vectors.ProcessRunner(built / "host" / "vtexp-fw-vectors")

    def off_by_one(line: str) -> str:
        a = runner(line)
        if line.startswith("at 4000 ") and len(a) > 8:    # a trigger's ACK
            a = a[:-4] + ("00" if a[-4:-2] != "00" else "01") + a[-2:]
        return a
    try:
        _, bad = vectors.replay(off_by_one)
    finally:
        runner.close()
    assert bad and bad[0].section == "conversations"
    assert "expected" in bad[0].detail


def test_a_profile_that_does_not_fit_the_ram_stops_the_build(tmp_path):
    r = subprocess.run(["make", "-s", "-C", str(firmware_dir()), f"O={tmp_path}",
                        "PROFILE=pad_20x20", "MAX_PULSES=400", "avr"],
                       capture_output=True, text=True)
    assert r.returncode != 0
    assert "the capacities of this profile exceed the RAM of the chip" in r.stderr
    assert not (tmp_path / "avr" / "pad_20x20" / "vtexp-fw.elf").exists()


@pytest.mark.parametrize("profile", cfirmware.PROFILES)
def test_each_build_fits_the_chip_with_room_for_its_stack(built, profile):
    r = subprocess.run(["avr-size", "-A", str(built / "avr" / profile / "vtexp-fw.elf")],
                       capture_output=True, text=True, check=True)
    sizes = {ln.split()[0]: int(ln.split()[1]) for ln in r.stdout.splitlines()
             if ln.startswith(".")}
    ram = sizes.get(".data", 0) + sizes.get(".bss", 0) + sizes.get(".noinit", 0)
    flash = sizes.get(".text", 0) + sizes.get(".data", 0)
    assert ram + 384 <= 7680            # vt_profile.h's stack reserve, in 7.5 of 8 KiB
    assert flash < 256 * 1024
