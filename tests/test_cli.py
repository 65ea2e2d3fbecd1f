"""The command line as a user meets it: plan, run, analyze, demo."""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from conftest import GRID, ROOT


def test_plan_prints_the_trial_list(cli):
    r = cli("plan", str(GRID), "--participant", "01")
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert "96 trials" in lines[0] and "seed 10676162643557027387" in lines[0]
    assert lines[1].split()[:3] == ["trial", "shape", "timing"]
    assert len(lines) == 2 + 96
    assert cli("plan", str(GRID), "--participant", "01").stdout == r.stdout


def test_plan_tsv_differs_between_participants(cli):
    a = cli("plan", str(GRID), "-p", "01", "--format", "tsv").stdout
    b = cli("plan", str(GRID), "-p", "02", "--format", "tsv").stdout
    assert a != b and len(a.splitlines()) == len(b.splitlines()) == 97


def test_plan_refuses_a_path_as_participant(cli):
    r = cli("plan", str(GRID), "-p", "../../etc")
    assert r.returncode == 2 and "not a plain token" in r.stderr and "Traceback" not in r.stderr


def test_run_then_analyze(cli, tmp_path):
    data = tmp_path / "data"
    r = cli("run", str(GRID), "-p", "01", "--responder", "scripted:correct", "--data", str(data),
            "--quiet")
    assert r.returncode == 0, r.stderr
    assert "session completed: 96 trials" in r.stdout and "96/96 correct" in r.stdout
    again = cli("run", str(GRID), "-p", "01", "--responder", "scripted:correct", "--data",
                str(data), "--quiet")
    assert again.returncode == 2 and "already exists" in again.stderr
    r = cli("analyze", str(data / "duration_interval_grid"), "--out", str(tmp_path / "out"))
    assert r.returncode == 0, r.stderr
    rates = pd.read_csv(tmp_path / "out" / "duration_interval_grid_rates_by_condition.csv")
    assert len(rates) == 32 and (rates["rate"] == 1.0).all()
    assert (tmp_path / "out" / "report.md").is_file()


def test_run_with_an_answer_file(cli, tmp_path, minimal_yaml):
    from conftest import write_experiment
    f = write_experiment(tmp_path, minimal_yaml)
    answers = tmp_path / "answers.txt"
    answers.write_text("square\ncircle\ncircle\nsquare\n")
    r = cli("run", str(f), "-p", "01", "--responder", f"scripted:answers={answers}",
            "--data", str(tmp_path / "d"), "--quiet")
    assert r.returncode == 0, r.stderr
    tsv = next((tmp_path / "d").rglob("*_beh.tsv"))
    assert list(pd.read_csv(tsv, sep="\t")["answer"]) == ["square", "circle", "circle", "square"]


def test_demo_runs_the_four_studies_with_model_participants(cli, tmp_path, demo_run):
    # A demo of two participants over a copy of the suite's demo of three (tests/conftest.py,
    # run once): a demo replaces the datasets an earlier demo made, and the same seed gives
    # the same participant the same answers.
    import shutil
    root = tmp_path / "demo"
    shutil.copytree(demo_run[0], root)
    first = (next(root.glob("whirlpool/sub-sim01/ses-1/beh/*_beh.tsv"))).read_text()
    (root / "whirlpool" / "sub-sim01" / "ses-1" / "beh" / "left-over.tsv").write_text("x")
    r = cli("demo", "--data", str(root), "--participants", "2", cwd=tmp_path, timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[-3:] == demo_run[1].splitlines()[-3:]    # what to do next
    assert not (root / "whirlpool" / "sub-sim01" / "ses-1" / "beh" / "left-over.tsv").exists()
    for name in ("six_mode_ball", "duration_interval_grid", "whirlpool", "circle_vs_rectangle"):
        sessions = sorted(root.glob(f"{name}/sourcedata/vtexp/sub-*/ses-1/*_session.json"))
        assert len(sessions) == 2, name                # the third of the old demo is gone
        meta = [json.loads(s.read_text()) for s in sessions]
        assert all(m["status"] == "completed" for m in meta)
        assert all(m["responder"].startswith("model observer (seed 0") for m in meta)
        # the short version that was run is the file the sessions record
        assert all(Path(m["experiment_file"]["path"]) == root / "experiments" / f"{name}.yaml"
                   for m in meta)
        html = root / name / "derivatives" / "vtexp" / name / "report.html"
        assert str(html) in r.stdout
        if name != "whirlpool":                        # it declares no figure
            assert "data:image/png;base64," in html.read_text()   # figures embedded
        assert "<table" in html.read_text() and name in r.stdout
        assert (root / name / "derivatives" / "vtexp" / "report.md").is_file()
    assert "effect of display: F(" in r.stdout and "effect of shape: F(" in r.stdout
    assert "vtexp simulate" in r.stdout
    again = (next(root.glob("whirlpool/sub-sim01/ses-1/beh/*_beh.tsv"))).read_text()
    drop_time = [ln.rsplit("\t", 1)[0] for ln in first.splitlines()]
    assert drop_time == [ln.rsplit("\t", 1)[0] for ln in again.splitlines()]
    # The study's reanalysis script reproduces the paper's Table 1 layout from the data.
    import subprocess
    import sys
    from conftest import ROOT
    t1 = subprocess.run([sys.executable, str(ROOT / "analysis" / "duration_interval_grid.py"),
                         str(root), "--out", str(tmp_path / "t1.csv")], capture_output=True,
                        text=True)
    assert t1.returncode == 0, t1.stderr
    table = pd.read_csv(tmp_path / "t1.csv", index_col=0)
    assert list(table.columns) == ["triangle", "circle", "square", "rectangle", "mean"]
    assert len(table) == 8 and table.to_numpy().min() >= 0 and table.to_numpy().max() <= 1
    other = tmp_path / "precious"
    other.mkdir()
    r = cli("demo", "--data", str(other))
    assert r.returncode == 2 and "was not made by 'vtexp demo'" in r.stderr


def test_simulate_reports_power_and_predictions(cli, tmp_path):
    out = tmp_path / "power.json"
    r = cli("simulate", "experiments/circle_vs_rectangle.yaml", "--participants", "4",
            "--studies", "40", "--json", str(out), "--quiet", timeout=300)
    assert r.returncode == 0, r.stderr
    assert "Power at N = 4 (40 studies" in r.stdout
    assert "shape (answer)" in r.stdout and "Predicted mean per condition" in r.stdout
    doc = json.loads(out.read_text())
    assert doc["participants"] == 4 and doc["studies"] == 40
    effects = {p["effect"]: p for p in doc["power"]}
    shape = effects["shape (answer)"]
    assert 0 <= shape["ci_low"] <= shape["power"] <= shape["ci_high"] <= 1
    bad = cli("simulate", "experiments/circle_vs_rectangle.yaml", "--alpha", "2")
    assert bad.returncode == 2 and "alpha" in bad.stderr and "Traceback" not in bad.stderr


def test_version(cli):
    r = cli("--version")
    assert r.returncode == 0 and r.stdout.startswith("vtexp ")


@pytest.mark.process
def test_the_installed_vtexp_script_exits_with_the_commands_status(tmp_path):
    # The entry point pip installs (vtexp = vtexp.cli:main), run for real; the other
    # tests call vtexp.cli.main in the test process.
    exe = Path(sys.executable).parent / "vtexp"
    assert exe.is_file(), f"vtexp is not installed beside {sys.executable}: pip install -e ."
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    r = subprocess.run([str(exe), "--version"], capture_output=True, text=True, env=env,
                       cwd=tmp_path, timeout=60)
    assert r.returncode == 0 and r.stdout.startswith("vtexp ") and r.stderr == ""
    r = subprocess.run([str(exe), "plan", str(tmp_path / "missing.yaml"), "-p", "01"],
                       capture_output=True, text=True, env=env, cwd=tmp_path, timeout=60)
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr == f"vtexp: error: {tmp_path / 'missing.yaml'}: file not found\n"
    r = subprocess.run([str(exe), "plan"], capture_output=True, text=True, env=env,
                       cwd=tmp_path, timeout=60)
    assert r.returncode == 2 and r.stderr.startswith("usage: vtexp plan ")
    assert "Traceback" not in r.stderr


def test_six_mode_study_end_to_end_with_its_papers_analyses(cli, tmp_path):
    six = GRID.parent / "six_mode_ball.yaml"
    for p in ("01", "02", "03"):
        r = cli("run", str(six), "-p", p, "--responder", "scripted:accuracy=0.6", "--data",
                str(tmp_path), "--quiet")
        assert r.returncode == 0, r.stderr
    r = cli("analyze", str(tmp_path / "six_mode_ball"), "--out", str(tmp_path / "out"))
    assert r.returncode == 0, r.stderr
    # The 2 x 2 of seed 000 over the dynamic modes only, and its simple effects (Table 3).
    assert "timing × intensity (display = dynamic): effect of timing: F(1, 2)" in r.stdout
    assert "Simple effect of intensity at timing = varied (display = dynamic)" in r.stdout
    assert "effect of display: F(1, 2)" in r.stdout
    _reanalysis_script_runs("six_mode_ball", tmp_path, "Recognition rate (%) per mode")


def test_circle_vs_rectangle_ratings_end_to_end(cli, tmp_path):
    study = GRID.parent / "circle_vs_rectangle.yaml"
    for p in ("01", "02", "03"):
        r = cli("run", str(study), "-p", p, "--responder", "scripted:random", "--data",
                str(tmp_path), "--quiet")
        assert r.returncode == 0, r.stderr
    tsv = next((tmp_path / "circle_vs_rectangle").rglob("*_beh.tsv"))
    beh = pd.read_csv(tsv, sep="\t", keep_default_na=False)
    assert set(beh["answer"].astype(int)) <= {-2, -1, 0, 1, 2}
    assert (beh["correct"] == "n/a").all()                   # ratings are not scored
    side = json.loads(next((tmp_path / "circle_vs_rectangle").rglob("*_beh.json")).read_text())
    assert side["answer"]["Levels"]["-2"] == "rectangle"
    r = cli("analyze", str(tmp_path / "circle_vs_rectangle"), "--out", str(tmp_path / "out"))
    assert r.returncode == 0, r.stderr
    assert "Shape rating, shape × corners: effect of corners: F(1, 2)" in r.stdout
    assert "Friedman test of shape on the shape rating" in r.stdout
    _reanalysis_script_runs("circle_vs_rectangle", tmp_path, "Mean rating per shape")


def test_whirlpool_two_questions_end_to_end(cli, tmp_path):
    study = GRID.parent / "whirlpool.yaml"
    for p in ("01", "02", "03"):
        r = cli("run", str(study), "-p", p, "--responder", "scripted:random", "--data",
                str(tmp_path), "--quiet")
        assert r.returncode == 0, r.stderr
        assert "18 trials logged" in r.stdout
    r = cli("analyze", str(tmp_path / "whirlpool"), "--out", str(tmp_path / "out"))
    assert r.returncode == 0, r.stderr
    assert "Sensation rating, phantom × frequency: effect of phantom: F(1, 2)" in r.stdout
    assert "Number of turns, phantom × frequency: effect of phantom: F(1, 2)" in r.stdout
    assert "Friedman test of frequency on the sensation rating: χ²(2, N = 3)" in r.stdout
    html = (tmp_path / "out" / "whirlpool" / "report.html").read_text()
    assert html.count("data:image/png;base64,") == 4            # a figure per question
    assert "Number of turns by frequency and phantom" in html
    _reanalysis_script_runs("whirlpool", tmp_path, "Mean turns counted")


def _reanalysis_script_runs(study: str, data, heading: str) -> None:
    import subprocess
    import sys
    from conftest import ROOT
    r = subprocess.run([sys.executable, str(ROOT / "analysis" / f"{study}.py"),
                        str(data / study), "--out", str(data / "tables")],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert heading in r.stdout and "(3 participants)" in r.stdout
    assert "Analyses declared in the experiment file:" in r.stdout
    assert list((data / "tables").glob(f"{study}_table_*.csv"))


def test_schema_for_editors(cli, tmp_path):
    out = tmp_path / "vtexp.schema.json"
    r = cli("schema", "--out", str(out))
    assert r.returncode == 0, r.stderr
    schema = json.loads(out.read_text())
    defs = schema["$defs"]
    assert schema["additionalProperties"] is False                 # unknown keys refused
    assert defs["DesignSpec"]["additionalProperties"] is False
    assert "height-contours" in defs["EncodingSpec"]["properties"]["pipeline"]["enum"]
    assert "pulse-trains" in defs["CodingSpec"]["properties"]["protocol"]["enum"]
    assert set(schema["properties"]["device"]["enum"]) >= {"pad_20x20", "vest_6x8", "sma_5x5"}
    assert {"ChoiceQuestion", "RatingQuestion", "NumberQuestion"} <= set(defs)


def test_console_responder_through_standard_input(cli, tmp_path, minimal_yaml):
    from conftest import write_experiment
    f = write_experiment(tmp_path, minimal_yaml.replace('correct: "{shape}"',
                                                         'correct: "{shape}"\n  replays: 1'))
    # instructions (Enter), then: a wrong entry, a replay, then answers by number or text.
    stdin = "\n" + "x\nr\n1\n" + "2\n" + "circle\n" + "square\n"
    r = cli("run", str(f), "-p", "01", "--responder", "console", "--data", str(tmp_path / "d"),
            "--quiet", input=stdin, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "1. square" in r.stdout and "'x' is not an answer here" in r.stdout
    tsv = next((tmp_path / "d").rglob("*_beh.tsv"))
    beh = pd.read_csv(tsv, sep="\t")
    assert list(beh["answer"]) == ["square", "circle", "circle", "square"]
    assert list(beh["replays"]) == [1, 0, 0, 0] and (beh["rt_s"] >= 0).all()
    # The input ends before the last trial: the session is aborted, the rest kept.
    r = cli("run", str(f), "-p", "02", "--responder", "console", "--data", str(tmp_path / "d"),
            "--quiet", input="\n1\n", timeout=60)
    assert r.returncode == 130 and "input ended" in r.stderr and "Traceback" not in r.stderr
    meta = json.loads(next((tmp_path / "d").rglob("sub-02/ses-1/*_session.json")).read_text())
    assert meta["status"] == "aborted" and meta["n_trials_logged"] == 1


# --------------------------------------------------------------------------- the experimenter's side of run

def _at_a_terminal(args: list[str], answers: str, timeout: float = 60):
    """Run ``vtexp ARGS`` with a pseudo-terminal as standard input holding ``answers``."""
    import os
    import pty
    import subprocess
    import sys

    from conftest import ROOT
    master, slave = pty.openpty()
    try:
        os.write(master, answers.encode())      # queued, read a line at a time
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        return subprocess.run([sys.executable, "-m", "vtexp", *args], stdin=slave,
                              capture_output=True, text=True, env=env, timeout=timeout,
                              check=False)
    finally:
        os.close(slave)
        os.close(master)


def test_run_without_a_participant_and_no_terminal_is_one_message(cli, tmp_path, minimal_yaml):
    from conftest import write_experiment
    f = write_experiment(tmp_path, minimal_yaml)
    r = cli("run", str(f), "--responder", "scripted:correct", "--data", str(tmp_path / "d"))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.splitlines() == [
        ("vtexp: error: --participant: missing: give the participant id (e.g. --participant "
         "01), or run 'vtexp run' at a terminal to be asked for it")]
    assert not (tmp_path / "d").exists()
    r = cli("run", str(f), "-p", "01", "--test-pulse", "--responder", "scripted:correct",
            "--data", str(tmp_path / "d"))
    assert r.returncode == 2 and "--test-pulse: asks the experimenter at a terminal" in r.stderr


@pytest.mark.process
def test_run_asks_the_experimenter_at_a_terminal(tmp_path, minimal_yaml):
    from conftest import write_experiment
    f = write_experiment(tmp_path, minimal_yaml)
    run = ["run", str(f), "--responder", "scripted:correct", "--data", str(tmp_path / "d"),
           "--quiet"]
    # A bad id is refused with the reason and asked again; the session defaults to 1.
    # A new participant: what participants.tsv records is asked (a wrong value again).
    r = _at_a_terminal(run + ["--max-trials", "1"], "a/b\n07\n\nblind\nold\n34\nr\n\n")
    assert r.returncode == 0, r.stderr
    assert "Participant 07 is new to" in r.stdout and "  group (one word): " in r.stdout
    assert "age is a number in years, got 'old'" in r.stdout
    assert "  vision (sighted, low-vision, blind): " in r.stdout
    table = (tmp_path / "d" / "mini" / "participants.tsv").read_text()
    assert table.splitlines()[1] == "sub-07\tblind\t34\tright\tn/a"
    assert "Participant id: " in r.stdout and "'a/b' is not a plain token" in r.stdout
    assert "Participant 07 has no sessions yet" in r.stdout and "New session [1]: " in r.stdout
    assert "session aborted: 1 trials logged" in r.stdout
    assert "stopped after 1 trial as asked (--max-trials 1)" in r.stdout
    # The sessions that exist are shown and the unfinished one is offered first; declined,
    # a session that exists is refused at the prompt; the next free number is the default.
    r = _at_a_terminal(run, "07\nn\n1\n\n")
    assert r.returncode == 0, r.stderr
    assert "Sessions of participant 07 already in" in r.stdout
    assert "ses-1  aborted, 1 of 4 trials" in r.stdout
    assert "Session 1 did not finish (aborted, 1 of 4 trials). Continue it? [Y/n] " in r.stdout
    assert "New session [2]: " in r.stdout and "session 1 already exists (aborted" in r.stdout
    assert "session completed: 4 trials logged" in r.stdout and "sub-07/ses-2" in r.stdout
    # Offered again, Enter continues the unfinished session where it stopped.
    r = _at_a_terminal(run, "07\n\n")
    assert r.returncode == 0, r.stderr
    assert "Continue it? [Y/n] " in r.stdout and "New session" not in r.stdout
    assert "session completed: 3 trials" in r.stdout and "sub-07/ses-1" in r.stdout
    # With --resume and nothing unfinished, it says so.
    r = _at_a_terminal(run + ["--resume"], "07\n")
    assert r.returncode == 2 and "no unfinished session" in r.stderr
    # A participant id given on the command line is not asked again; session 1 exists.
    r = _at_a_terminal(run + ["-p", "07"], "")
    assert r.returncode == 2 and "Participant id" not in r.stdout
    assert "session 1 of participant 07 already exists" in r.stderr
    assert "(completed, 4 of 4 trials)" in r.stderr and "the next free one is 3" in r.stderr


def test_run_checks_the_device_before_the_first_trial(cli, tmp_path, minimal_yaml):
    from conftest import write_experiment
    # stimuli of under a second: the emulator on its pty plays them in real time
    f = write_experiment(tmp_path, minimal_yaml.replace("duration_ms: 200, soa_ms: 200",
                                                        "duration_ms: 50, soa_ms: 50"))
    r = cli("run", str(f), "-p", "01", "--responder", "scripted:correct", "--data",
            str(tmp_path / "d"), "--device", "emulator", "--quiet")
    assert r.returncode == 0, r.stderr
    out = r.stdout.splitlines()
    assert out[0] == "device check before the first trial:"
    assert out[1].startswith("  device:   emulator /dev/")
    assert out[2].startswith("  firmware: vtexp-emulator") and "vtexp-wire/1" in out[2]
    assert out[3] == "  geometry: 8 x 6 as profile vest_6x8 expects (coin_tactor, levels)"
    assert any(e.startswith("  round trip (20 heartbeats): p50 ") for e in out)
    assert "  actuators: all off (ALL_OFF acknowledged, the device reports it is idle)" in out
    assert out[-2] == "device check passed; no actuator is on"
    assert out[-1].startswith("session completed: 4 trials logged")


def test_a_failed_device_check_stops_before_any_trial(tmp_path, minimal_yaml, monkeypatch,
                                                      capsys):
    from conftest import write_experiment

    from vtexp import cli
    from vtexp.devices.sim import SimDevice
    f = write_experiment(tmp_path, minimal_yaml)

    def stuck(self):                        # all-off does not reach one actuator
        self.state[:] = 0.0
        self.state[2, 3] = 1.0
    monkeypatch.setattr(SimDevice, "_all_off", stuck)
    rc = cli.main(["run", str(f), "-p", "01", "--responder", "scripted:correct", "--data",
                   str(tmp_path / "d")])
    err = capsys.readouterr().err
    assert rc == 3
    assert err.splitlines()[-1] == (
        "vtexp: error: device check failed, before any trial: the simulated device still "
        "drives an actuator after all-off. No trial was played and no session data were "
        "written.")
    assert not (tmp_path / "d").exists()


@pytest.mark.process
def test_max_trials_stops_and_the_session_resumes(cli, tmp_path, minimal_yaml):
    from conftest import write_experiment
    f = write_experiment(tmp_path, minimal_yaml)
    run = ["run", str(f), "-p", "01", "--responder", "scripted:correct", "--data",
           str(tmp_path / "d"), "--quiet"]
    r = cli(*run, "--max-trials", "0")
    assert r.returncode == 2 and "--max-trials: must be 1 or more" in r.stderr
    r = cli(*run, "--max-trials", "3")
    assert r.returncode == 0, r.stderr
    assert "session aborted: 3 trials logged" in r.stdout
    printed = r.stdout.split("to continue: ", 1)[1].strip()
    assert printed == (f"{sys.executable} -m vtexp run {f} --participant 01 --session 1 "
                       f"--device sim --responder scripted:correct --data {tmp_path / 'd'} "
                       "--resume")
    meta_path = next((tmp_path / "d").rglob("*_session.json"))
    meta = json.loads(meta_path.read_text())
    assert meta["status"] == "aborted" and meta["n_trials_logged"] == 3
    assert meta["reason"] == "stopped after 3 trials as asked"
    r = cli("analyze", str(tmp_path / "d"), "--out", str(tmp_path / "out"))
    assert r.returncode == 0, r.stderr
    assert "session aborted (stopped after 3 trials as asked)" in r.stderr
    # The command printed works as printed, from another folder (more trials than are
    # left: it completes).
    r = subprocess.run(shlex.split(printed) + ["--quiet", "--max-trials", "5"], cwd=tmp_path,
                       capture_output=True, text=True, timeout=120,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert r.returncode == 0, r.stderr
    assert "session completed: 1 trials logged" in r.stdout
    meta = json.loads(meta_path.read_text())
    assert meta["status"] == "completed" and meta["n_trials_logged"] == 4
    assert meta["resumes"][0]["previous_reason"] == "stopped after 3 trials as asked"


@pytest.mark.process
def test_test_pulse_plays_only_when_the_experimenter_says_yes(tmp_path, minimal_yaml):
    from conftest import write_experiment

    from vtexp.devices.emulator import PtyEmulator
    from vtexp.model import DeviceProfile
    f = write_experiment(tmp_path, minimal_yaml.replace("duration_ms: 200, soa_ms: 200",
                                                        "duration_ms: 50, soa_ms: 50"))
    with PtyEmulator.for_profile(DeviceProfile.load("vest_6x8")) as emu:
        run = ["run", str(f), "--device", f"serial:{emu.port}", "--responder",
               "scripted:correct", "--data", str(tmp_path / "d"), "--quiet", "--test-pulse",
               "--max-trials", "1", "--participant-info",
               "group=a,age=30,handedness=right,vision=sighted"]
        r = _at_a_terminal(run + ["-p", "01"], "\n")           # the default is no
        assert r.returncode == 0, r.stderr
        assert ("Play a test pulse on actuator (row 0, col 0), level 1 for 300 ms? [y/N] "
                in r.stdout) and "no test pulse played" in r.stdout
        plays = _plays(emu.actuations())
        assert len(plays) == 1 and len(plays[1]) > 2          # the trial's only
        n = len(emu.actuations())
        r = _at_a_terminal(run + ["-p", "02"], "y\ny\n")
        assert r.returncode == 0, r.stderr
        plays = _plays(emu.actuations()[n:])                   # each run counts from 1
        assert plays[1] == [(0, 1), (0, 0)] and len(plays) == 2    # then the trial
        n = len(emu.actuations())
        r = _at_a_terminal(run + ["-p", "03"], "y\nn\n")        # not felt: no session
        assert r.returncode == 3 and "the test pulse on actuator (row 0, col 0) was not felt" \
            in r.stderr
        assert _plays(emu.actuations()[n:]) == {1: [(0, 1), (0, 0)]}
        assert not (tmp_path / "d" / "mini" / "sub-03").exists()


def _plays(actuations) -> dict[int, list[tuple[int, int]]]:
    """What each play drove on the emulated vest: (actuator, level) in turn."""
    plays: dict[int, list[tuple[int, int]]] = {}
    for a in actuations:
        if a.cause == "play":
            plays.setdefault(a.play_id, []).append((a.index, a.setting.level))
    return plays


def test_run_with_a_model_participant(cli, tmp_path):
    args = ["run", "experiments/circle_vs_rectangle.yaml", "-p", "sim1", "--responder",
            "model:seed=4", "--data", str(tmp_path), "--quiet"]
    r = cli(*args)
    assert r.returncode == 0, r.stderr
    meta = json.loads(next(tmp_path.rglob("*_session.json")).read_text())
    assert meta["status"] == "completed" and meta["responder"].startswith("model observer (seed 4")
    bad = cli(*args[:5], "model:seed=x", "--data", str(tmp_path / "b"))
    assert bad.returncode == 2 and "unknown model option" in bad.stderr


@pytest.mark.process
def test_a_terminal_that_goes_away_at_a_prompt_is_one_message(tmp_path, minimal_yaml):
    import os
    import pty
    import subprocess
    import sys

    from conftest import ROOT, write_experiment
    f = write_experiment(tmp_path, minimal_yaml)
    master, slave = pty.openpty()
    p = subprocess.Popen([sys.executable, "-m", "vtexp", "run", str(f), "--responder",
                          "scripted:correct", "--data", str(tmp_path / "d")], stdin=slave,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         env=dict(os.environ, PYTHONPATH=str(ROOT)))
    os.close(slave)
    seen = b""
    while b"Participant id: " not in seen:
        chunk = os.read(p.stdout.fileno(), 100)
        assert chunk, p.stderr.read()
        seen += chunk
    os.close(master)                        # the terminal window is closed
    _, err = p.communicate(timeout=60)
    assert p.returncode == 2 and "Traceback" not in err
    assert err == "vtexp: error: --participant: missing: no participant id was given\n"
