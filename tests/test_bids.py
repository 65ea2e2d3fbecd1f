"""Every data folder vtexp writes is a valid BIDS dataset (issue 14, part 1), the layout
before it still loads, and many datasets pool through DuckDB (issue 15)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from conftest import MINIMAL, ROOT, run_cli, write_experiment

OLD = ROOT / "tests" / "data" / "old_layout"


def _validator() -> list[str] | None:
    exe = Path(sys.executable).parent / "bids-validator-deno"
    if exe.exists():
        return [str(exe)]
    return shutil.which("bids-validator-deno") and ["bids-validator-deno"]


def validate(dataset: Path) -> dict:
    """The official validator's verdict (schema validator 3.x): issues by severity."""
    cmd = _validator()
    if cmd is None:
        pytest.skip("bids-validator-deno is not installed (the 'test' extra)")
    r = subprocess.run(cmd + ["--format", "json", str(dataset)], capture_output=True,
                       text=True, timeout=300)
    report = json.loads(r.stdout)
    issues = report["issues"]["issues"]
    return {"errors": [i for i in issues if i["severity"] == "error"],
            "warnings": sorted({(i["code"], i.get("subCode") or "") for i in issues
                                if i["severity"] == "warning"}),
            "summary": report["summary"]}


#: The warnings left, each explained in docs/bids.md: what the lab, not vtexp, knows.
EXPECTED_WARNINGS = {
    ("JSON_KEY_RECOMMENDED", "HEDVersion"), ("JSON_KEY_RECOMMENDED", "License"),
    ("JSON_KEY_RECOMMENDED", "SourceDatasets"), ("NO_AUTHORS", "Authors"),
    ("TOO_FEW_AUTHORS", ""), ("SIDECAR_KEY_RECOMMENDED", "CogAtlasID"),
    ("SIDECAR_KEY_RECOMMENDED", "CogPOID"), ("SIDECAR_KEY_RECOMMENDED", "InstitutionName"),
    ("SIDECAR_KEY_RECOMMENDED", "InstitutionAddress"),
    ("SIDECAR_KEY_RECOMMENDED", "InstitutionalDepartmentName"),
}


@pytest.fixture(scope="module")
def demo(demo_run):
    return demo_run[0]


@pytest.mark.parametrize("study", ["six_mode_ball", "duration_interval_grid", "whirlpool",
                                   "circle_vs_rectangle"])
def test_the_demo_datasets_are_valid_bids(demo, study):
    v = validate(demo / study)
    assert v["errors"] == [], v["errors"]
    assert set(v["warnings"]) <= EXPECTED_WARNINGS, v["warnings"]
    assert v["summary"]["subjects"] == ["sim01", "sim02", "sim03"]
    assert "beh" in v["summary"]["modalities"] or "behavioral" in str(v["summary"]).lower()
    d = demo / study
    desc = json.loads((d / "dataset_description.json").read_text())
    assert desc["DatasetType"] == "raw" and desc["GeneratedBy"][0]["Name"] == "vtexp"
    assert json.loads((d / "derivatives" / "vtexp" / "dataset_description.json")
                      .read_text())["DatasetType"] == "derivative"
    assert not (d / "report").exists()


def test_a_resumed_session_and_participants_info_stay_valid(tmp_path):
    f = write_experiment(tmp_path, MINIMAL.replace(
        "device: vest_6x8", "device: vest_6x8\nparticipants:\n  years_blind: {description: "
        "years since the loss of sight, type: number, units: year}"))
    data = tmp_path / "data"
    base = ["run", str(f), "--responder", "scripted:correct", "--data", str(data), "--quiet"]
    r = run_cli(*base, "-p", "01", "--max-trials", "2", "--participant-info",
                "group=blind,age=41,handedness=l,years_blind=12")
    assert r.returncode == 0, r.stderr
    assert "--resume" in r.stdout
    mid = validate(data / "mini")                  # valid as it is written, mid-session
    assert mid["errors"] == [], mid["errors"]
    r = run_cli(*base, "-p", "01", "--resume")
    assert r.returncode == 0 and "session completed" in r.stdout, r.stderr
    r = run_cli(*base, "-p", "02", "--participant-info", "group=sighted,vision=sighted")
    assert r.returncode == 0, r.stderr
    v = validate(data / "mini")
    assert v["errors"] == [], v["errors"]
    assert set(v["warnings"]) <= EXPECTED_WARNINGS, v["warnings"]
    table = pd.read_csv(data / "mini" / "participants.tsv", sep="\t", dtype=str,
                        keep_default_na=False)
    assert list(table.columns) == ["participant_id", "group", "age", "handedness", "vision",
                                   "years_blind"]
    assert table.values.tolist() == [["sub-01", "blind", "41", "left", "n/a", "12"],
                                     ["sub-02", "sighted", "n/a", "n/a", "sighted", "n/a"]]
    side = json.loads((data / "mini" / "participants.json").read_text())
    assert side["years_blind"]["Units"] == "year" and "blind" in side["vision"]["Levels"]
    # What was given at the first session is kept: a contradiction is refused.
    r = run_cli(*base, "-p", "01", "--session", "2", "--participant-info", "group=sighted")
    assert r.returncode == 2 and "already says group=blind for sub-01" in r.stderr
    assert "Traceback" not in r.stderr


@pytest.mark.parametrize("info, message", [
    ("colour=red", "unknown participant field 'colour'; the fields are group, age"),
    ("age=old", "age is a number in years, got 'old'"),
    ("handedness=both", "handedness is one of left, right, ambidextrous"),
    ("group", "'group' is not FIELD=VALUE"),
])
def test_a_wrong_participant_field_is_one_clear_message(tmp_path, info, message):
    f = write_experiment(tmp_path, MINIMAL)
    r = run_cli("run", str(f), "-p", "01", "--responder", "scripted:correct", "--data",
                str(tmp_path / "d"), "--participant-info", info)
    assert r.returncode == 2 and message in r.stderr and "--participant-info" in r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "d" / "mini" / "sub-01").exists()


def test_participant_fields_in_the_experiment_are_checked(tmp_path):
    f = write_experiment(tmp_path, MINIMAL.replace(
        "device: vest_6x8", "device: vest_6x8\nparticipants:\n  years: {descripton: x}"))
    r = run_cli("validate", str(f))
    assert r.returncode == 2 and "exp.yaml:5: participants.years" in r.stderr
    assert "description: required key is missing" in r.stderr


def test_an_unreadable_participants_table_is_named(tmp_path):
    f = write_experiment(tmp_path, MINIMAL)
    r = run_cli("run", str(f), "-p", "01", "--responder", "scripted:correct", "--data",
                str(tmp_path / "d"), "--quiet")
    assert r.returncode == 0, r.stderr
    table = tmp_path / "d" / "mini" / "participants.tsv"
    table.write_bytes(b"\xff\xfe garbage")
    r = run_cli("run", str(f), "-p", "02", "--responder", "scripted:correct", "--data",
                str(tmp_path / "d"), "--quiet")
    assert r.returncode == 2 and str(table) in r.stderr and "not UTF-8" in r.stderr
    assert "Traceback" not in r.stderr


def test_the_layout_before_bids_still_loads(tmp_path):
    from vtexp.analysis import load_sessions
    trials, sessions = load_sessions([OLD / "mini"])
    assert len(sessions) == 2 and len(trials) == 8
    assert sorted(trials["participant"].unique()) == ["01", "02"]
    assert all(s.checksum == "verified" for s in sessions)
    r = run_cli("analyze", str(OLD / "mini"), "--out", str(tmp_path / "out"))
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "out" / "mini" / "report.html").is_file()
    # No new session is added to such a folder: it would mix two layouts.
    shutil.copytree(OLD / "mini", tmp_path / "data" / "mini")
    r = run_cli("run", str(OLD / "mini.yaml"), "-p", "03", "--responder", "scripted:correct",
                "--data", str(tmp_path / "data"))
    assert r.returncode != 0 and "layout of vtexp before BIDS" in r.stderr


def test_analyze_writes_the_report_as_a_derivative(tmp_path):
    f = write_experiment(tmp_path, MINIMAL)
    for p in ("01", "02"):
        assert run_cli("run", str(f), "-p", p, "--responder", "scripted:correct", "--data",
                       str(tmp_path / "d"), "--quiet").returncode == 0
    r = run_cli("analyze", str(tmp_path / "d" / "mini"))
    assert r.returncode == 0, r.stderr
    out = tmp_path / "d" / "mini" / "derivatives" / "vtexp"
    assert (out / "mini" / "report.html").is_file()
    assert json.loads((out / "dataset_description.json").read_text())["DatasetType"] == \
        "derivative"
    v = validate(tmp_path / "d" / "mini")
    assert v["errors"] == [], v["errors"]


# ----------------------------------------------------------------- pooled through DuckDB

@pytest.fixture(scope="module")
def labs(tmp_path_factory):
    """Two labs' datasets of one experiment, with the same participant ids."""
    base = tmp_path_factory.mktemp("labs")
    f = write_experiment(base, MINIMAL)
    for lab, groups in (("labA", ("blind", "sighted")), ("labB", ("sighted", "blind"))):
        for p, g in zip(("01", "02"), groups):
            r = run_cli("run", str(f), "-p", p, "--responder", "scripted:accuracy=0.5",
                        "--data", str(base / "raw" / lab), "--quiet",
                        "--participant-info", f"group={g}")
            assert r.returncode == 0, r.stderr
        shutil.move(str(base / "raw" / lab / "mini"), str(base / "labs" / lab))
    return base / "labs"


def test_the_pooled_table_is_the_per_dataset_loads_concatenated(labs, monkeypatch):
    pytest.importorskip("duckdb")
    from vtexp.analysis import load_sessions
    from vtexp.analysis.pool import load_pooled
    monkeypatch.chdir(labs.parent)
    pooled, sessions = load_pooled("labs/*/")
    parts = []
    for lab in ("labA", "labB"):
        t, _ = load_sessions([labs / lab])
        t.insert(0, "dataset", f"labs/{lab}")
        parts.append(t)
    want = pd.concat(parts, ignore_index=True)

    def plain(df):
        return df.astype({c: object for c in df.columns
                          if isinstance(df[c].dtype, pd.CategoricalDtype)})
    pd.testing.assert_frame_equal(plain(pooled), plain(want))
    assert len(sessions) == 4 and list(pooled["dataset"].unique()) == ["labs/labA", "labs/labB"]


def test_analyze_pools_a_glob_of_datasets(labs, tmp_path):
    pytest.importorskip("duckdb")
    r = run_cli("analyze", "--pool", str(labs / "*"), "--out", str(tmp_path / "out"))
    assert r.returncode == 0, r.stderr
    assert "pooled 2 dataset(s) through DuckDB" in r.stdout
    assert "occur in several datasets" in r.stderr             # 01 and 02 in both labs
    assert "4 session(s)" in r.stdout
    r = run_cli("analyze", "--pool", str(tmp_path / "nowhere" / "*"))
    assert r.returncode == 2 and "matches no folder" in r.stderr and "--pool" in r.stderr
    assert "Traceback" not in r.stderr


def test_pooling_without_duckdb_says_which_extra(labs, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "duckdb", None)    # vtexp imports it when it pools
    r = run_cli("analyze", "--pool", str(labs / "*"), timeout=120)
    assert r.returncode == 2 and "pip install 'vtexp[pool]'" in r.stderr, r.stderr


def test_participants_started_at_once_in_a_new_data_folder_make_one_dataset(tmp_path):
    """Sessions of several participants starting at the same moment in a data folder that
    does not exist yet: each makes the dataset if it is not there, and none fails (they
    staged dataset_description.json under one temporary name: "cannot write ...: No such
    file or directory" for 2 of 12 pairs of processes)."""
    import threading
    from vtexp import bids

    failures = []
    for k in range(20):
        root = tmp_path / f"data{k}" / "mini"
        start = threading.Barrier(6)

        def make():
            start.wait()
            try:
                bids.ensure_dataset(root, "mini", "A minimal experiment")
            except Exception as e:            # noqa: BLE001 - what failed is the finding
                failures.append(repr(e))
        threads = [threading.Thread(target=make) for _ in range(6)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert json.loads((root / "dataset_description.json").read_text())["Name"] == \
            "A minimal experiment"
        assert (root / "README.md").read_text().startswith("# A minimal experiment")
        assert not list(root.glob(".*.tmp"))
    assert failures == []
