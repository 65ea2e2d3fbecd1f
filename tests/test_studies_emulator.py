"""The five studies of experiments/ on the emulated device, through the real command line.

Each study runs its first trials (``--max-trials``) with ``--device emulator``: the
serial backend talks wire protocol v1 over a pseudo-terminal to the emulated
firmware, which plays each schedule in real time from its own clock and reports
the onsets. The runs go one after another, in the test process (``run_cli``); each
test then checks one study's files, and the last reads them all back with
``vtexp analyze``.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pandas as pd
import pytest

from conftest import run_cli, session_record

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENTS = ROOT / "experiments"
N_TRIALS = 2

#: Who answers: the correct option where the study scores one, else a random one
#: (ratings and counts have no correct answer).
STUDIES = {                              # the longest trials first
    "six_mode_ball": "scripted:correct",
    "duration_interval_grid": "scripted:correct",
    "letters": "scripted:correct",
    "whirlpool": "scripted:random",
    "circle_vs_rectangle": "scripted:random",
}
QUESTIONS = {"whirlpool": 2}            # rows per trial in the log


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    data = tmp_path_factory.mktemp("studies")

    def run(study: str) -> subprocess.CompletedProcess:
        return run_cli("run", str(EXPERIMENTS / f"{study}.yaml"), "--participant", "01",
                       "--device", "emulator", "--responder", STUDIES[study],
                       "--max-trials", str(N_TRIALS), "--data", str(data), timeout=120)

    results = {study: run(study) for study in STUDIES}
    return data, results


@pytest.mark.parametrize("study", STUDIES)
def test_study_runs_on_the_emulator(runs, study):
    data, results = runs
    r = results[study]
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    # The device check came first, with the link's round trip and everything off.
    assert r.stdout.startswith("device check before the first trial:\n  device:   emulator")
    assert "round trip (20 heartbeats)" in r.stdout
    assert "device check passed; no actuator is on" in r.stdout
    assert f"session aborted: {N_TRIALS} trials logged" in r.stdout
    assert f"stopped after {N_TRIALS} trials as asked (--max-trials {N_TRIALS})" in r.stdout

    ses = data / study / "sub-01" / "ses-1"
    meta = json.loads(session_record(ses).read_text())
    assert meta["status"] == "aborted" and meta["reason"] == \
        f"stopped after {N_TRIALS} trials as asked"
    assert meta["n_trials_logged"] == N_TRIALS
    assert meta["device"]["backend"] == "emulator"
    assert meta["device"]["firmware"].startswith("vtexp-emulator")
    root = data / study
    assert set(meta["checksums"]) == {p.relative_to(root).as_posix()
                                      for p in ses.glob("beh/sub-01_ses-1_*")}

    beh = pd.read_csv(root / meta["files"]["beh"], sep="\t", keep_default_na=False)
    assert len(beh) == N_TRIALS * QUESTIONS.get(study, 1)
    assert list(beh["trial"].unique()) == list(range(1, N_TRIALS + 1))
    assert (beh["status"] == "ok").all()
    if STUDIES[study] == "scripted:correct":
        assert (beh["correct"] == 1).all()

    # Every pulse the emulated firmware reported playing, at its own clock's onset.
    events = pd.read_csv(root / meta["files"]["events"], sep="\t")
    per_trial = beh.drop_duplicates("trial").set_index("trial")
    assert events.groupby("trial").size().to_dict() == per_trial["n_pulses"].to_dict()
    assert (events["play"] == 0).all()               # scripted answers ask no replay
    assert events["onset_ms"].notna().all()
    start = events["trial"].map(per_trial["stimulus_onset_ms"])
    late_ms = events["onset_ms"] - start - events["scheduled_onset_ms"]
    assert (late_ms >= -0.01).all(), late_ms.min()  # never before its time
    assert (late_ms < 1000).all(), late_ms.max()    # timing is measured by bench/timing.py
    assert (late_ms != 0).any()                      # measured, not copied from the schedule


def test_analyze_reads_the_emulator_sessions(runs, tmp_path):
    data, results = runs
    assert all(r.returncode == 0 for r in results.values())
    r = run_cli("analyze", str(data), "--out", str(tmp_path / "report"), timeout=300)
    assert r.returncode == 0, r.stderr
    n_rows = N_TRIALS * sum(QUESTIONS.get(s, 1) for s in STUDIES)
    assert f"{len(STUDIES)} session(s), {n_rows} trials." in r.stdout
    assert r.stderr.count(f"session aborted (stopped after {N_TRIALS} trials as asked)") == \
        len(STUDIES)                                # listed, their trials kept
    for study in STUDIES:
        assert f"{study}: report " in r.stdout
        assert (tmp_path / "report" / study / "report.html").is_file()
