"""The session engine and its log: files, contents, refusals, and surviving SIGKILL."""

from __future__ import annotations

import json
import os
import random
import re
import signal
import subprocess
import sys
import time

import pandas as pd
import pytest

import session_child
from conftest import GRID, ROOT, write_experiment, session_record
from forked import Child
from vtexp.analysis import read_session
from vtexp.devices import open_device
from vtexp.errors import InputError, SessionError
from vtexp.experiment import load_experiment
from vtexp.log import sha256_file
from vtexp.model import DeviceProfile
from vtexp.responders import ScriptedResponder, make_responder
from vtexp.session import SessionOptions, SessionPaths, run_session


def run(lx, data, participant="01", session=1, responder=None):
    responder = responder or make_responder("scripted:accuracy=0.7", participant, session)
    with open_device("sim", DeviceProfile.load(lx.experiment.device)) as dev:
        return run_session(lx, dev, responder, SessionOptions(
            participant=participant, session=session, data_dir=data)), dev


@pytest.fixture(scope="module")
def grid_lx():
    return load_experiment(GRID)


def test_session_writes_bids_files_and_a_complete_record(tmp_path, grid_lx):
    res, dev = run(grid_lx, tmp_path)
    root = tmp_path / "duration_interval_grid"
    d = root / "sub-01" / "ses-1" / "beh"
    assert res.paths.dir == d and res.status == "completed"
    prefix = "sub-01_ses-1_task-durationIntervalGrid"
    assert sorted(p.name for p in d.iterdir()) == sorted(
        [f"{prefix}_beh.tsv", f"{prefix}_beh.json", f"{prefix}_events.tsv",
         f"{prefix}_events.json"])
    assert sorted(p.name for p in res.paths.record_dir.iterdir()) == [f"{prefix}_session.json"]
    assert {"dataset_description.json", "README.md", "participants.tsv",
            "participants.json"} <= {p.name for p in root.iterdir()}

    beh = pd.read_csv(d / f"{prefix}_beh.tsv", sep="\t", dtype=str, keep_default_na=False)
    assert len(beh) == 96 and list(beh["trial"]) == [str(i) for i in range(1, 97)]
    assert {"shape", "timing", "answer", "correct", "rt_s", "replays"} <= set(beh.columns)
    assert (beh["correct"] == (beh["answer"] == beh["correct_answer"]).map({True: "1",
                                                                          False: "0"})).all()
    assert (beh["rt_s"] == "n/a").all()        # scripted answers have no reaction time

    side = json.loads((d / f"{prefix}_beh.json").read_text())
    assert side["TaskName"] == "durationIntervalGrid" and "Instructions" in side
    assert side["TaskFullName"] == grid_lx.experiment.title
    assert set(beh.columns) <= set(side) | {"experiment"}
    assert side["rt_s"]["Units"] == "s"

    meta = json.loads(session_record(d).read_text())
    assert meta["status"] == "completed" and meta["n_trials_logged"] == 96
    assert meta["seed"] == res.seed and meta["experiment_file"]["sha256"] == grid_lx.sha256
    assert meta["experiment_loaded"]["name"] == "duration_interval_grid"
    assert meta["device"]["backend"] == "sim" and meta["device_profile"]["name"] == "vest_6x8"
    assert meta["environment"]["packages"]["numpy"]
    assert meta["started_at"] <= meta["ended_at"]
    assert len(meta["checksums"]) == 4
    for name, digest in meta["checksums"].items():
        assert sha256_file(root / name) == digest

    # The events log holds every pulse the device played, with device onsets.
    ev = pd.read_csv(d / f"{prefix}_events.tsv", sep="\t")
    assert len(ev) == sum(len(p.pulses) for p in dev.plays) == beh["n_pulses"].astype(int).sum()
    first = ev[ev["trial"] == 1]
    assert (first["onset_ms"] - first["scheduled_onset_ms"]).abs().max() == 0
    # BIDS: onset and duration in seconds first, from the session's first stimulus, sorted.
    assert list(ev.columns[:2]) == ["onset", "duration"] and ev["onset"].iloc[0] == 0
    assert ev["onset"].is_monotonic_increasing
    assert (ev["duration"] * 1000 - ev["duration_ms"]).abs().max() < 1e-6
    events_side = json.loads((d / f"{prefix}_events.json").read_text())
    assert set(ev.columns) <= set(events_side) and events_side["onset"]["Units"] == "s"


def test_trial_order_in_the_log_is_the_planned_order(tmp_path, grid_lx):
    from vtexp.compile import compile_conditions
    from vtexp.design import trial_list
    res, _ = run(grid_lx, tmp_path, participant="P7", session=2)
    trials, _ = trial_list(grid_lx.experiment, compile_conditions(grid_lx), "P7", 2)
    logged = read_session(res.paths.dir).trials
    assert list(logged["shape"]) == [t.levels["shape"] for t in trials]
    assert list(logged["timing"]) == [t.levels["timing"] for t in trials]


def test_a_session_is_never_overwritten(tmp_path, grid_lx):
    res, _ = run(grid_lx, tmp_path)
    before = {p.name: sha256_file(p) for p in res.paths.dir.iterdir()}
    with pytest.raises(SessionError, match="already exists.*nothing was overwritten"):
        run(grid_lx, tmp_path)
    assert {p.name: sha256_file(p) for p in res.paths.dir.iterdir()} == before


@pytest.mark.parametrize("bad", ["../x", "a/b", "..", "", "sub 1", "a_b", "x" * 65])
def test_participant_must_be_a_plain_token(tmp_path, grid_lx, bad):
    with pytest.raises(InputError, match="not a plain token"):
        run(grid_lx, tmp_path, participant=bad)
    assert not (tmp_path / "duration_interval_grid").exists()


def test_replays_are_played_and_counted(tmp_path, grid_lx):
    responder = ScriptedResponder(lambda q, t: t.levels["shape"], replays=2)
    res, dev = run(grid_lx, tmp_path, responder=responder)
    assert all(r.replays == 2 for r in res.records)
    assert len(dev.plays) == 3 * 96
    ev = pd.read_csv(res.paths.events_tsv, sep="\t")
    assert sorted(ev["play"].unique()) == [0, 1, 2]


def test_failure_mid_session_keeps_completed_trials_and_says_why(tmp_path, minimal_yaml):
    lx = load_experiment(write_experiment(tmp_path, minimal_yaml))
    calls = []

    def flaky(q, t):
        calls.append(t.number)
        if t.number == 3:
            raise RuntimeError("response box unplugged")
        return "square"
    with pytest.raises(RuntimeError):
        run(lx, tmp_path / "d", responder=ScriptedResponder(flaky))
    d = tmp_path / "d" / "mini" / "sub-01" / "ses-1"
    meta = json.loads(session_record(d).read_text())
    assert meta["status"] == "failed" and "response box unplugged" in meta["reason"]
    assert meta["n_trials_logged"] == 2
    assert len(read_session(d).trials) == 2


def test_unwritable_data_folder_is_a_clear_error(tmp_path, grid_lx):
    if os.geteuid() == 0:
        # root ignores permissions; use a path under a regular file instead
        (tmp_path / "file").write_text("x")
        data = tmp_path / "file" / "data"
    else:
        data = tmp_path / "ro"
        data.mkdir(mode=0o500)
    with pytest.raises(SessionError, match="cannot (create the session folder|write the "
                                           "dataset)"):
        run(grid_lx, data)


def _child(data, participant, delay, *more):
    """The session of ``participant`` in a process of its own (tests/session_child.py),
    each answer ``delay`` seconds late."""
    return Child(session_child.main, str(GRID), str(data), participant, str(delay), *more)


def _complete_rows(path):
    text = path.read_bytes().decode()
    lines = text.split("\n")
    complete, partial = lines[:-1], lines[-1]
    return complete, partial


@pytest.mark.process
@pytest.mark.parametrize("kill_after", [1, 7, 23])
def test_sigkill_between_trials_keeps_every_completed_row(tmp_path, kill_after):
    proc = _child(tmp_path, "K", 0.01)
    seen = 0
    for line in proc:
        if line.startswith("logged"):
            seen = int(line.split()[1])
            if seen >= kill_after:
                proc.kill()
                break
    assert proc.wait() == -signal.SIGKILL
    paths = SessionPaths.of(tmp_path, "duration_interval_grid", "durationIntervalGrid", "K", 1)
    complete, partial = _complete_rows(paths.beh_tsv)
    header = complete[0].split("\t")
    rows = [r.split("\t") for r in complete[1:]]
    assert len(rows) >= seen
    assert all(len(r) == len(header) for r in rows)
    assert [int(r[0]) for r in rows] == list(range(1, len(rows) + 1))
    data = read_session(paths.dir)
    assert len(data.trials) == len(rows)
    assert any("did not close" in w for w in data.warnings)
    assert json.loads(paths.session_json.read_text())["status"] == "running"


@pytest.mark.process
def test_sigkill_at_random_moments_never_corrupts_the_log(tmp_path):
    rng = random.Random(20261122)
    for i in range(6):
        proc = _child(tmp_path, f"R{i}", 0.005)
        # Wait for the first trial, then kill at a random moment.
        for line in proc:
            if line.startswith("logged"):
                break
        time.sleep(rng.uniform(0.0, 0.25))
        proc.kill()
        proc.wait()
        paths = SessionPaths.of(tmp_path, "duration_interval_grid", "durationIntervalGrid",
                                f"R{i}", 1)
        complete, partial = _complete_rows(paths.beh_tsv)
        width = len(complete[0].split("\t"))
        assert all(len(r.split("\t")) == width for r in complete[1:])
        data = read_session(paths.dir)
        assert len(data.trials) == len(complete) - 1 >= 1
        if partial:
            assert any("incomplete" in w for w in data.warnings)


def test_truncated_last_row_is_reported_and_ignored(tmp_path, grid_lx):
    res, _ = run(grid_lx, tmp_path)
    with open(res.paths.beh_tsv, "ab") as f:
        f.write(b"97\t0\t1\tcirc")
    data = read_session(res.paths.dir)
    assert len(data.trials) == 96
    assert any("last row is incomplete" in w for w in data.warnings)
    assert any("changed since the session ended" in w for w in data.warnings)


@pytest.mark.process
def test_sigterm_aborts_cleanly_and_marks_the_session(tmp_path):
    # sim:realtime takes the stimuli's real time, so the session is still running
    # when the signal arrives; the CLI turns SIGTERM into an orderly abort.
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-m", "vtexp", "run", str(GRID), "-p", "T",
                             "--device", "sim:realtime", "--responder", "scripted:correct",
                             "--data", str(tmp_path)], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    paths = SessionPaths.of(tmp_path, "duration_interval_grid", "durationIntervalGrid", "T", 1)
    deadline = time.monotonic() + 60
    while not paths.beh_tsv.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.3)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 130, err
    assert "every actuator was turned off" in err and "Traceback" not in err
    meta = json.loads(paths.session_json.read_text())
    assert meta["status"] == "aborted" and meta["checksums"]
    assert read_session(paths.dir).warnings == [f"{paths.dir}: session aborted (interrupted by "
                                                "the experimenter)"]


class _FlakyDevice:
    """Wraps the sim so that chosen plays fail as a pulled cable does."""

    def __init__(self, profile, fail_on: set[int]):
        from vtexp.devices import open_device as _open
        self.dev = _open("sim", profile)
        self.fail_on = fail_on
        self.calls = 0
        self.reopened = 0
        inner = self.dev._play

        def play(schedule):
            self.calls += 1
            if self.calls in self.fail_on:
                from vtexp.errors import DeviceError
                raise DeviceError("lost contact with the tactile device (test)")
            return inner(schedule)
        self.dev._play = play
        close = self.dev._close

        def counting_close():
            self.reopened += 1
            close()
        self.dev._close = counting_close


@pytest.mark.parametrize("choice", ["retry", "skip", "abort"])
def test_a_device_fault_pauses_the_session_for_the_experimenter(tmp_path, minimal_yaml, choice):
    lx = load_experiment(write_experiment(tmp_path, minimal_yaml))
    flaky = _FlakyDevice(DeviceProfile.load("vest_6x8"), fail_on={2})
    asked = []

    def handler(error, trial):
        asked.append((trial.number, str(error)))
        assert flaky.dev.state.max() == 0          # everything is off while paused
        return choice
    responder = make_responder("scripted:correct", "01", 1)
    run = lambda: run_session(lx, flaky.dev, responder,  # noqa: E731
                              SessionOptions(participant="01", data_dir=tmp_path / "d",
                                             on_device_error=handler))
    if choice == "abort":
        with pytest.raises(Exception, match="lost contact"):
            run()
    else:
        res = run()
        assert res.status == "completed"
    assert asked == [(2, "lost contact with the tactile device (test)")]
    d = tmp_path / "d" / "mini" / "sub-01" / "ses-1"
    rows = read_session(d).trials
    meta = json.loads(session_record(d).read_text())
    if choice == "retry":
        assert list(rows["status"]) == ["ok"] * 4 and flaky.reopened >= 1
        assert rows["correct"].sum() == 4
    elif choice == "skip":
        assert list(rows["status"]) == ["ok", "device_error", "ok", "ok"]
        assert rows["answer"].isna().sum() == 1 and rows["correct"].isna().sum() == 1
    else:
        assert meta["status"] == "failed" and "lost contact" in meta["reason"]
        assert len(rows) == 1


def test_screen_hooks_and_abort_from_the_responder(tmp_path, minimal_yaml):
    from vtexp.errors import SessionAborted
    lx = load_experiment(write_experiment(tmp_path, minimal_yaml))
    seen = []

    class Screen(ScriptedResponder):
        def instructions(self, text):
            seen.append(("instructions", text))

        def stimulus_starts(self, trial):
            seen.append(("ready", trial.number))

        def finish(self, text):
            seen.append(("finish", text))

    res, _ = run(lx, tmp_path / "a", responder=Screen(lambda q, t: t.levels["shape"]))
    assert res.status == "completed"
    assert seen[0][0] == "instructions" and seen[-1][0] == "finish"
    assert [n for k, n in seen if k == "ready"] == [1, 2, 3, 4]

    def escape(q, t):
        if t.number == 3:
            raise SessionAborted("aborted by the participant (Escape)")
        return t.levels["shape"]
    with pytest.raises(SessionAborted):
        run(lx, tmp_path / "b", responder=ScriptedResponder(escape))
    d = tmp_path / "b" / "mini" / "sub-01" / "ses-1"
    meta = json.loads(session_record(d).read_text())
    assert meta["status"] == "aborted" and "Escape" in meta["reason"]
    assert len(read_session(d).trials) == 2


def _comparable(paths):
    """The session's data without what differs between runs (wall clock, device clock)."""
    beh = pd.read_csv(paths.beh_tsv, sep="\t", dtype=str, keep_default_na=False)
    ev = pd.read_csv(paths.events_tsv, sep="\t", dtype=str, keep_default_na=False)
    # A resumed run's onsets are placed at its wall-clock start: onset differs too.
    return (beh.drop(columns=["started_at", "stimulus_onset_ms"]),
            ev.drop(columns=["onset_ms", "onset"]))


@pytest.mark.process
def test_killed_at_random_moments_and_resumed_equals_an_uninterrupted_run(tmp_path):
    # The reference: the same participant's session run straight through.
    ref = _child(tmp_path / "ref", "K9", 0.0)
    assert ref.wait() == 0
    ref_paths = SessionPaths.of(tmp_path / "ref", "duration_interval_grid",
                                "durationIntervalGrid", "K9", 1)
    # The same session killed with SIGKILL at random moments, resumed each time.
    rng = random.Random(7)
    data = tmp_path / "killed"
    paths = SessionPaths.of(data, "duration_interval_grid", "durationIntervalGrid", "K9", 1)
    kills = 0
    for _ in range(60):
        proc = _child(data, "K9", 0.004, *(["resume"] if paths.session_json.exists() else []))
        out = ""
        for line in proc:                           # wait until this run has made progress
            out += line + "\n"
            if line.startswith("logged") or line.startswith("done"):
                break
        time.sleep(rng.uniform(0.0, 0.15))          # then kill at a random moment
        if proc.poll() is None:
            proc.kill()
            kills += 1
        out += proc.rest()
        # A kill can land after the session was marked completed but before "done" said.
        if "done" in out or (paths.session_json.exists() and json.loads(
                paths.session_json.read_text()).get("status") == "completed"):
            break
    else:
        pytest.fail("the session never finished")
    assert kills >= 3
    meta = json.loads(paths.session_json.read_text())
    # Some kills land during start-up, before the session is reopened: fewer resumes.
    assert meta["status"] == "completed" and 3 <= len(meta["resumes"]) <= kills
    beh, ev = _comparable(paths)
    ref_beh, ref_ev = _comparable(ref_paths)
    pd.testing.assert_frame_equal(beh, ref_beh)
    pd.testing.assert_frame_equal(ev, ref_ev)


def test_resume_refuses_what_it_cannot_continue(tmp_path, minimal_yaml, grid_lx):
    res, _ = run(grid_lx, tmp_path)
    with pytest.raises(SessionError, match="already completed"):
        with open_device("sim", DeviceProfile.load("vest_6x8")) as dev:
            run_session(grid_lx, dev, make_responder("scripted:correct", "01", 1),
                        SessionOptions(participant="01", data_dir=tmp_path, resume=True))
    with pytest.raises(SessionError, match="no session 2 .* to resume"):
        with open_device("sim", DeviceProfile.load("vest_6x8")) as dev:
            run_session(grid_lx, dev, make_responder("scripted:correct", "01", 2),
                        SessionOptions(participant="01", session=2, data_dir=tmp_path,
                                       resume=True))
    # A different experiment file (edited since the session began) is refused.
    lx = load_experiment(write_experiment(tmp_path, minimal_yaml))
    with pytest.raises(RuntimeError):
        run(lx, tmp_path / "m", responder=ScriptedResponder(
            lambda q, t: (_ for _ in ()).throw(RuntimeError("stop")) if t.number == 3
            else t.levels["shape"]))
    edited = load_experiment(write_experiment(tmp_path, minimal_yaml.replace(
        "Which shape?", "Which shape did you feel?")))
    with pytest.raises(SessionError, match="SHA-256 differs"):
        with open_device("sim", DeviceProfile.load("vest_6x8")) as dev:
            run_session(edited, dev, make_responder("scripted:correct", "01", 1),
                        SessionOptions(participant="01", data_dir=tmp_path / "m", resume=True))
    # The same file continues at trial 3.
    with open_device("sim", DeviceProfile.load("vest_6x8")) as dev:
        res = run_session(lx, dev, make_responder("scripted:correct", "01", 1),
                          SessionOptions(participant="01", data_dir=tmp_path / "m", resume=True))
    assert res.status == "completed" and [r.trial for r in res.records] == [3, 4]
    assert list(read_session(res.paths.dir).trials["trial"]) == [1, 2, 3, 4]


def test_disk_full_stops_before_the_next_trial_with_the_reason(tmp_path, minimal_yaml,
                                                               monkeypatch):
    import errno

    import vtexp.log as vlog
    lx = load_experiment(write_experiment(tmp_path, minimal_yaml))
    real_write = os.write
    state = {"beh_rows": 0}

    def write(fd, data):
        # The third trial's device events find the disk full after writing half of them
        # (an events row: onset in seconds, duration, trial).
        cells = data.split(b"\t", 3)
        if len(cells) > 3 and b"." in cells[0] and cells[2] == b"3":
            real_write(fd, data[: len(data) // 2])
            raise OSError(errno.ENOSPC, "No space left on device")
        if data[:1].isdigit():
            state["beh_rows"] += 1
        return real_write(fd, data)
    monkeypatch.setattr(vlog.os, "write", write)
    with pytest.raises(SessionError, match="No space left on device.*every row written before "
                                           "is intact"):
        run(lx, tmp_path / "d", responder=make_responder("scripted:correct", "01", 1))
    monkeypatch.setattr(vlog.os, "write", real_write)
    d = tmp_path / "d" / "mini" / "sub-01" / "ses-1" / "beh"
    data = read_session(d)
    assert list(data.trials["trial"]) == [1, 2]                   # nothing corrupted
    assert not paths_events_complete(d)                            # trial 3's event row cut
    meta = json.loads(session_record(d).read_text())
    assert meta["status"] == "failed" and "No space left" in meta["reason"]
    # With space again, the session resumes at trial 3.
    with open_device("sim", DeviceProfile.load("vest_6x8")) as dev:
        res = run_session(lx, dev, make_responder("scripted:correct", "01", 1),
                          SessionOptions(participant="01", data_dir=tmp_path / "d", resume=True))
    assert [r.trial for r in res.records] == [3, 4]
    assert list(read_session(d).trials["trial"]) == [1, 2, 3, 4]
    assert paths_events_complete(d)
    ev = pd.read_csv(next(d.glob("*_events.tsv")), sep="\t")
    played = {t: len(ev[ev["trial"] == t]) for t in (1, 2, 3, 4)}
    assert played == {r.trial: r.n_pulses for r in res.records} | {
        t: n for t, n in zip((1, 2), read_session(d).trials["n_pulses"][:2], strict=True)}


def paths_events_complete(d) -> bool:
    return next(d.glob("*_events.tsv")).read_bytes().endswith(b"\n")


def test_retry_while_still_unplugged_asks_again(tmp_path, minimal_yaml):
    from vtexp.errors import DeviceError
    lx = load_experiment(write_experiment(tmp_path, minimal_yaml))
    flaky = _FlakyDevice(DeviceProfile.load("vest_6x8"), fail_on={2})
    real_open = flaky.dev._open
    opens = {"n": 0}

    def open_once_failing():
        opens["n"] += 1
        if opens["n"] == 2:                       # the first reconnection attempt fails
            raise DeviceError("no device on the port (test)")
        return real_open()
    flaky.dev._open = open_once_failing
    answers = iter(["retry", "retry"])
    asked = []

    def handler(error, trial):
        asked.append(str(error))
        return next(answers)
    res = run_session(lx, flaky.dev, make_responder("scripted:correct", "01", 1),
                      SessionOptions(participant="01", data_dir=tmp_path / "d",
                                     on_device_error=handler))
    assert res.status == "completed" and [r.status for r in res.records] == ["ok"] * 4
    assert asked == ["lost contact with the tactile device (test)",
                     "no device on the port (test)"]


WHIRL = GRID.parent / "whirlpool.yaml"


def test_several_questions_give_one_row_each_and_resume_by_whole_trials(tmp_path):
    lx = load_experiment(WHIRL)
    answers = iter(["3", "2", "4", "3"])          # (sensation, turns) for trials 1 and 2

    def rule(q, t):
        if t.number == 2 and q.name == "turns":
            raise RuntimeError("participant left")  # cut between the two questions
        return next(answers)
    with pytest.raises(RuntimeError):
        run(lx, tmp_path, responder=ScriptedResponder(rule))
    paths = SessionPaths.of(tmp_path, "whirlpool", "whirlpool", "01", 1)
    rows = pd.read_csv(paths.beh_tsv, sep="\t", dtype=str)
    assert list(zip(rows["trial"], rows["question"], rows["answer"])) == [
        ("1", "sensation", "3"), ("1", "turns", "2")]   # trial 2's one answer was not kept
    with open_device("sim", DeviceProfile.load("sma_5x5")) as dev:
        res = run_session(lx, dev,
                          ScriptedResponder(lambda q, t: "1" if q.name == "sensation" else "3"),
                          SessionOptions(participant="01", data_dir=tmp_path, resume=True))
    assert res.status == "completed" and res.records[0].trial == 2
    rows = pd.read_csv(paths.beh_tsv, sep="\t", dtype=str)
    assert len(rows) == 2 * 18 and list(rows["trial"][:4]) == ["1", "1", "2", "2"]
    assert list(rows["question"][:4]) == ["sensation", "turns", "sensation", "turns"]
    side = json.loads(paths.beh_json.read_text())
    assert set(side["question"]["Levels"]) == {"sensation", "turns"}


def test_resume_refuses_a_coding_file_changed_since_the_session_began(tmp_path, minimal_yaml):
    """A coding taken by reference is part of what the session played: if its file changed,
    the trials still to come would not be the ones the first trials belong with."""
    coding = tmp_path / "codings" / "mine.yaml"
    coding.parent.mkdir()
    coding.write_text("name: mine\ndescription: test\nreference: a test\n"
                      "protocol: sequential-trace\nparams: {duration_ms: 200, soa_ms: 100}\n",
                      encoding="utf-8")
    text = re.sub(r"(?m)^coding:\n(  .*\n)+", "coding:\n  ref: codings/mine.yaml\n",
                  minimal_yaml)
    assert "ref: codings/mine.yaml" in text
    lx = load_experiment(write_experiment(tmp_path, text))
    with pytest.raises(RuntimeError):
        run(lx, tmp_path / "m", responder=ScriptedResponder(
            lambda q, t: (_ for _ in ()).throw(RuntimeError("stop")) if t.number == 2
            else t.levels["shape"]))
    coding.write_text(coding.read_text().replace("soa_ms: 100", "soa_ms: 300"))
    changed = load_experiment(tmp_path / "exp.yaml")
    with pytest.raises(SessionError, match="coding file .*mine.yaml.* SHA-256 differs"):
        with open_device("sim", DeviceProfile.load("vest_6x8")) as dev:
            run_session(changed, dev, make_responder("scripted:correct", "01", 1),
                        SessionOptions(participant="01", data_dir=tmp_path / "m", resume=True))


def test_a_logged_value_is_written_as_its_plain_text():
    """The log's cells: numbers as Python writes them (a NumPy number too, rounded to a
    microsecond's digits), missing as n/a, booleans as 1/0, a tab or line end inside a
    text as a space."""
    import numpy as np
    from vtexp.log import NA, format_value
    cases = [(None, NA), (True, "1"), (False, "0"), (3, "3"), (np.int64(-4), "-4"),
             (0.1 + 0.2, "0.3"), (float("nan"), NA), (np.nan, NA), (np.float64(2.123456789),
             "2.123457"), (np.float32(0.5), "0.5"), (float("inf"), "inf"), ("plain", "plain"),
             ("a\tb\nc\rd", "a b c d"), ((1, 2), "(1, 2)")]
    assert [format_value(v) for v, _ in cases] == [want for _, want in cases]
