"""A session an experimenter cannot get wrong (issue 13): locks, kills at start-up,
the device a session resumes on, the command printed after every interruption, and
analyses that refuse duplicated trials and keep model participants apart."""

from __future__ import annotations

import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import time

import pandas as pd
import pytest

from conftest import MINIMAL, ROOT, run_cli, run_printed, write_experiment
from vtexp.devices import open_device
from vtexp.errors import DeviceError, SessionError
from vtexp.experiment import load_experiment
from vtexp.lock import SessionLock
from vtexp.model import DeviceProfile
from vtexp.responders import make_responder
from vtexp.session import (SessionOptions, SessionPaths, TrialDone, mark_dead_sessions,
                           run_session)

ENV = dict(os.environ, PYTHONPATH=str(ROOT))
# Eight trials of 0.8-1 s on sim:realtime: long enough to be stopped mid-session, short
# enough that the run printed to continue it ends in seconds.
SLOW = MINIMAL.replace("repetitions: 2", "repetitions: 4").replace(
    "duration_ms: 200, soa_ms: 200", "duration_ms: 50, soa_ms: 50")
assert SLOW.count("duration_ms: 50") == 1


def vtexp(*args, cwd=None, **kw) -> subprocess.CompletedProcess:
    return run_cli(*map(str, args), cwd=cwd or ROOT, timeout=180, **kw)


def paths_of(data, participant="01", session=1, name="mini", task="mini"):
    return SessionPaths.of(data, name, task, participant, session)


def printed_command(text: str) -> list[str]:
    """The command on the line after 'To continue ...' (or after 'to continue: ')."""
    lines = text.splitlines()
    for i, line in enumerate(lines):
        if line.startswith("To continue") or "did not close" in line:
            return shlex.split(lines[i + 1].strip())
    raise AssertionError(f"no resume command printed in:\n{text}")


# --------------------------------------------------------------------------- the lock

@pytest.mark.process
def test_a_second_run_of_a_running_session_is_refused_naming_the_process(tmp_path):
    f = write_experiment(tmp_path, SLOW)
    data = tmp_path / "d"
    first = subprocess.Popen([sys.executable, "-m", "vtexp", "run", str(f), "-p", "01",
                              "--device", "sim:realtime", "--responder", "scripted:correct",
                              "--data", str(data)], env=ENV, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    try:
        lock = paths_of(data).record_dir / "session.lock"
        deadline = time.monotonic() + 60
        while not lock.exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert lock.exists(), first.stderr.read() if first.poll() is not None else "no lock"
        # Resumed from a second terminal while the first run goes on: refused.
        r = vtexp("run", f, "-p", "01", "--data", data, "--resume")
        assert r.returncode == 2 and "Traceback" not in r.stderr
        assert f"process {first.pid} on " in r.stderr and "running now" in r.stderr, r.stderr
        # Started anew with the same number: refused too, naming the process.
        r = vtexp("run", f, "-p", "01", "--responder", "scripted:correct", "--data", data)
        assert r.returncode == 2 and f"process {first.pid}" in r.stderr
        assert first.poll() is None                 # the first run was not disturbed
    finally:
        first.send_signal(signal.SIGTERM)
        first.communicate(timeout=60)
    meta = json.loads(paths_of(data).session_json.read_text())
    assert meta["status"] == "aborted" and not lock.exists()
    beh = pd.read_csv(paths_of(data).beh_tsv, sep="\t", dtype=str)
    assert not beh.duplicated(["trial"]).any()


@pytest.mark.process
def test_a_stale_lock_of_a_killed_run_is_recognised_and_the_session_marked(tmp_path):
    f = write_experiment(tmp_path, SLOW)
    data = tmp_path / "d"
    proc = subprocess.Popen([sys.executable, "-m", "vtexp", "run", str(f), "-p", "01",
                             "--device", "sim:realtime", "--responder", "scripted:correct",
                             "--data", str(data)], env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    beh = paths_of(data).beh_tsv
    deadline = time.monotonic() + 60
    while (not beh.exists() or beh.read_text().count("\n") < 2) and time.monotonic() < deadline:
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=30)
    d = paths_of(data).record_dir
    rec = paths_of(data).session_json
    assert (d / "session.lock").exists()            # left behind, held by no one
    assert json.loads(rec.read_text())["status"] == "running"
    # The next run of the experiment (here for another participant) finds it dead.
    r = vtexp("run", f, "-p", "02", "--responder", "scripted:correct", "--data", data,
              "--quiet", "--max-trials", "1")
    assert r.returncode == 0, r.stderr
    assert "Session 1 of participant 01 did not close" in r.stdout
    assert f"pid {proc.pid} on" in r.stdout and "marked interrupted" in r.stdout
    meta = json.loads(rec.read_text())
    assert meta["status"] == "interrupted" and f"pid {proc.pid}" in meta["reason"]
    # What the log holds, not the 0 of a record no run closed (one row per trial here).
    held = len(beh.read_text().splitlines()) - 1
    assert held >= 1 and meta["n_trials_logged"] == held
    assert f"did not close ({held} of 8 trials logged)" in r.stdout
    # The printed command continues it, from another folder, on the device it ran on.
    cmd = printed_command(r.stdout)
    assert cmd[cmd.index("--device") + 1] == "sim:realtime"
    r = run_printed(cmd + ["--quiet"], cwd=tmp_path, timeout=180)
    assert r.returncode == 0, r.stderr
    meta = json.loads(rec.read_text())
    assert meta["status"] == "completed" and meta["n_trials_logged"] == 8
    assert meta["resumes"][0]["previous_status"] == "interrupted"
    trials = pd.read_csv(paths_of(data).beh_tsv, sep="\t")["trial"]
    assert list(trials) == list(range(1, 9))


@pytest.mark.process
def test_the_lock_names_its_holder_and_is_released(tmp_path):
    lock = SessionLock.acquire(tmp_path, what="session 1 of participant 01")
    holder = json.loads((tmp_path / "session.lock").read_text())
    assert holder["pid"] == os.getpid() and holder["command"]
    # Another process cannot take it while this one holds it.
    code = ("import sys; from vtexp.lock import SessionLock, SessionBusy\n"
            f"try:\n    SessionLock.acquire({str(tmp_path)!r}, what='it')\n"
            "except SessionBusy as e:\n    print(e); sys.exit(3)\n")
    r = subprocess.run([sys.executable, "-c", code], env=ENV, capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 3 and f"process {os.getpid()}" in r.stdout
    lock.release()
    assert not (tmp_path / "session.lock").exists()
    r = subprocess.run([sys.executable, "-c", code], env=ENV, capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr


# --------------------------------------------------------------- killed at any instant

FS_CALLS = ("open", "write", "pwrite", "fsync", "ftruncate", "mkdir", "rename", "replace",
            "unlink", "rmdir")


#: A forked child that has not ended by then is taken as hung: this process had threads
#: when it forked (pytest-xdist's own, or those a test before left), and a lock one of
#: them held stays held in the child. A session's start takes well under a second.
CHILD_S = 30.0


def _run_killed_at(lx, data, k: int) -> int:
    """Run the session in a forked child that SIGKILLs itself just before its k-th file
    system call (k=0: never); return how many calls it made before its first trial was
    logged (k=0) or -1. A child that hangs (see CHILD_S) is killed there, which is a
    kill like any other for k >= 1; the count (k=0) is taken again."""
    for _ in range(3):
        got = _fork_killed_at(lx, data, k)
        if got is not None or k != 0:
            return -1 if got is None else got
        shutil.rmtree(data, ignore_errors=True)
    raise AssertionError("the forked session hung three times")


def _fork_killed_at(lx, data, k: int) -> int | None:
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:                                    # the child: count, and die at k
        os.close(r)
        n = [0]
        real = {name: getattr(os, name) for name in FS_CALLS}

        def counting(name):
            def call(*a, **kw):
                n[0] += 1
                if n[0] == k:
                    os.kill(os.getpid(), signal.SIGKILL)
                return real[name](*a, **kw)
            return call
        for name in FS_CALLS:
            setattr(os, name, counting(name))
        at_first = []

        def sink(record):
            if isinstance(record, TrialDone) and not at_first:
                at_first.append(n[0])
        try:
            with open_device("sim", DeviceProfile.load("vest_6x8")) as dev:
                run_session(lx, dev, make_responder("scripted:correct", "01", 1),
                            SessionOptions(participant="01", data_dir=data, device_spec="sim",
                                           responder_spec="scripted:correct"),
                            consumers=(sink,))
            real["write"](w, str(at_first[0]).encode())
        finally:
            os._exit(0)
    os.close(w)
    deadline = time.monotonic() + CHILD_S
    while os.waitpid(pid, os.WNOHANG) == (0, 0):
        if time.monotonic() > deadline:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            os.close(r)
            return None
        time.sleep(0.02)
    got = b""
    while chunk := os.read(r, 100):
        got += chunk
    os.close(r)
    return int(got) if got else -1


def _finish(lx, data) -> str:
    """What the experimenter does next: resume the session if it exists, else start it."""
    d = paths_of(data).record_dir
    resume = d.exists()
    if resume:
        # The next run first marks a dead session (and clears a dead staging folder).
        mark_dead_sessions(data, "mini")
    else:
        mark_dead_sessions(data, "mini")
        assert not list(d.parent.glob(".ses-*")) if d.parent.exists() else True
    with open_device("sim", DeviceProfile.load("vest_6x8")) as dev:
        res = run_session(lx, dev, make_responder("scripted:correct", "01", 1),
                          SessionOptions(participant="01", data_dir=data, resume=resume,
                                         device_spec="sim", responder_spec="scripted:correct"))
    assert res.status == "completed"
    return "resumed" if resume else "started"


def _logged(data):
    p = paths_of(data)
    # The device clock restarts with each run: onsets are compared within a trial only.
    beh = pd.read_csv(p.beh_tsv, sep="\t", dtype=str).drop(columns=["started_at",
                                                                   "stimulus_onset_ms"])
    ev = pd.read_csv(p.events_tsv, sep="\t", dtype=str).drop(columns=["onset_ms", "onset"])
    return beh, ev


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs fork")
def test_a_session_killed_at_every_step_of_its_start_can_be_resumed(tmp_path):
    """SIGKILL before each file-system call from the start of the session until its first
    trial is logged: every time, the next run completes the session, and the log equals
    an uninterrupted run's."""
    lx = load_experiment(write_experiment(tmp_path, MINIMAL))
    n_calls = _run_killed_at(lx, tmp_path / "ref", 0)
    assert n_calls > 10
    ref_beh, ref_ev = _logged(tmp_path / "ref")
    outcomes = {}
    for k in range(1, n_calls + 2):
        data = tmp_path / f"k{k}"
        assert _run_killed_at(lx, data, k) == -1
        outcomes[k] = _finish(lx, data)
        beh, ev = _logged(data)
        pd.testing.assert_frame_equal(beh, ref_beh)
        pd.testing.assert_frame_equal(ev, ref_ev)
        meta = json.loads(paths_of(data).session_json.read_text())
        assert meta["status"] == "completed"
        assert not (paths_of(data).record_dir / "session.lock").exists()
        assert not list(paths_of(data).record_dir.parent.glob(".ses-*"))
    # Kills before the session was renamed into place left no session; after, one to resume.
    assert {"started", "resumed"} == set(outcomes.values())
    print(f"\n{len(outcomes)} kills: {sum(v == 'started' for v in outcomes.values())} "
          f"before the session existed, {sum(v == 'resumed' for v in outcomes.values())} "
          "after")


def test_what_an_older_run_killed_at_start_left_is_rebuilt(tmp_path):
    """What a kill after the record folder was renamed into place can leave: the folder
    alone (its record lost), the record alone, or the trial log without the events log;
    each resumes."""
    lx = load_experiment(write_experiment(tmp_path, MINIMAL))
    ref = tmp_path / "ref"
    with open_device("sim", DeviceProfile.load("vest_6x8")) as dev:
        run_session(lx, dev, make_responder("scripted:correct", "01", 1),
                    SessionOptions(participant="01", data_dir=ref))
    ref_beh, ref_ev = _logged(ref)
    p = paths_of(ref)
    for case in ("folder only", "record only", "no events log", "empty trial log"):
        data = tmp_path / case.replace(" ", "_")
        q = paths_of(data)
        q.record_dir.mkdir(parents=True)
        if case in ("no events log", "empty trial log"):
            q.dir.mkdir(parents=True)
        if case != "folder only":
            meta = json.loads(p.session_json.read_text())
            meta.update(status="running", n_trials_logged=0, checksums=None, resumes=[])
            q.session_json.write_text(json.dumps(meta))
        if case in ("no events log", "empty trial log"):
            q.beh_json.write_bytes(p.beh_json.read_bytes())
            q.beh_tsv.write_bytes(b"" if case == "empty trial log" else
                                  p.beh_tsv.read_bytes().split(b"\n")[0] + b"\n")
        with open_device("sim", DeviceProfile.load("vest_6x8")) as dev:
            res = run_session(lx, dev, make_responder("scripted:correct", "01", 1),
                              SessionOptions(participant="01", data_dir=data, resume=True))
        assert res.status == "completed", case
        beh, ev = _logged(data)
        pd.testing.assert_frame_equal(beh, ref_beh)
        pd.testing.assert_frame_equal(ev, ref_ev)
        rebuilt = json.loads(q.session_json.read_text())["resumes"][0]["rebuilt"]
        assert rebuilt, case
        if case == "folder only":
            assert rebuilt[0].startswith(q.session_json.name)


# ------------------------------------------------------------ the device it resumes on

def test_a_serial_session_resumes_on_the_serial_device_and_not_on_sim(tmp_path):
    from vtexp.devices.emulator import PtyEmulator
    # stimuli of under a second: the emulator on its pty plays them in real time
    f = write_experiment(tmp_path, MINIMAL.replace("duration_ms: 200, soa_ms: 200",
                                                   "duration_ms: 50, soa_ms: 50"))
    data = tmp_path / "d"
    emu = PtyEmulator.for_profile(DeviceProfile.load("vest_6x8"))
    emu.start()
    try:
        r = vtexp("run", f, "-p", "01", "--device", f"serial:{emu.port}", "--responder",
                  "scripted:correct", "--data", data, "--quiet", "--max-trials", "2")
        assert r.returncode == 0, r.stderr
        plays_before = [a for a in emu.actuations() if a.cause == "play"]
        # Resumed with the responder only, on sim: refused, saying what was recorded.
        r = vtexp("run", f, "-p", "01", "--device", "sim", "--data", data, "--resume")
        assert r.returncode == 2 and "Traceback" not in r.stderr
        assert f"ran on serial:{emu.port} (a tactile array on {emu.port}" in r.stderr
        assert "feel nothing" in r.stderr and "--force-device" in r.stderr
        assert [a for a in emu.actuations() if a.cause == "play"] == plays_before
        # Resumed with nothing but --resume: the serial device and responder recorded.
        r = vtexp("run", f, "-p", "01", "--data", data, "--resume", "--quiet")
        assert r.returncode == 0, r.stderr
        assert f"device as recorded in the session record: serial:{emu.port}" in r.stdout
        assert "responder as recorded in the session record: scripted:correct" in r.stdout
        plays_after = [a for a in emu.actuations() if a.cause == "play"]
        assert len(plays_after) > len(plays_before)     # trials 3 and 4 played on it
    finally:
        emu.stop()
    meta = json.loads(paths_of(data).session_json.read_text())
    assert meta["status"] == "completed" and meta["device_spec"] == f"serial:{emu.port}"
    assert meta["resumes"][0]["device"]["backend"] == "serial"
    assert meta["resumes"][0]["forced_device"] is False
    ev = pd.read_csv(paths_of(data).events_tsv, sep="\t")
    assert sorted(ev["trial"].unique()) == [1, 2, 3, 4]


def test_force_device_continues_on_another_kind_and_says_so(tmp_path):
    lx = load_experiment(write_experiment(tmp_path, MINIMAL))
    data = tmp_path / "d"
    with open_device("sim", DeviceProfile.load("vest_6x8")) as dev:
        run_session(lx, dev, make_responder("scripted:correct", "01", 1),
                    SessionOptions(participant="01", data_dir=data, max_trials=1,
                                   device_spec="emulator"))
    meta = json.loads(paths_of(data).session_json.read_text())
    meta["device_spec"] = "serial:/dev/ttyACM0"          # as a serial session records it
    meta["device"].update(backend="serial", port="/dev/ttyACM0", firmware="vest 1.2")
    paths_of(data).session_json.write_text(json.dumps(meta))
    with pytest.raises(SessionError, match="ran on serial:/dev/ttyACM0 .*firmware vest 1.2"):
        with open_device("sim", DeviceProfile.load("vest_6x8")) as dev:
            run_session(lx, dev, make_responder("scripted:correct", "01", 1),
                        SessionOptions(participant="01", data_dir=data, resume=True,
                                       device_spec="sim"))
    with open_device("sim", DeviceProfile.load("vest_6x8")) as dev:
        res = run_session(lx, dev, make_responder("scripted:correct", "01", 1),
                          SessionOptions(participant="01", data_dir=data, resume=True,
                                         device_spec="sim", force_device=True))
    assert res.status == "completed"
    meta = json.loads(paths_of(data).session_json.read_text())
    assert meta["resumes"][-1]["forced_device"] is True


# ------------------------------------------------- the command printed after interruptions

@pytest.mark.parametrize("how", ["escape", "device fault", "crash"])
def test_every_interruption_prints_the_command_that_continues(tmp_path, monkeypatch, capsys,
                                                               how):
    from vtexp import cli
    from vtexp.devices.sim import SimDevice
    from vtexp.errors import SessionAborted
    from vtexp.responders.scripted import ScriptedResponder
    f = write_experiment(tmp_path, MINIMAL)
    data = tmp_path / "d"
    ask = ScriptedResponder.ask
    play = SimDevice._play
    calls = [0]

    def failing_ask(self, q, t, replay):
        if t.number == 3 and how == "escape":
            raise SessionAborted("the escape key was pressed in the participant window")
        if t.number == 3 and how == "crash":
            raise ZeroDivisionError("a bug")
        return ask(self, q, t, replay)

    def failing_play(self, schedule):
        calls[0] += 1
        if calls[0] == 3 and how == "device fault":
            raise DeviceError("lost contact with the tactile device (test)")
        return play(self, schedule)
    monkeypatch.setattr(ScriptedResponder, "ask", failing_ask)
    monkeypatch.setattr(SimDevice, "_play", failing_play)
    monkeypatch.chdir(tmp_path)
    args = ["run", str(f), "-p", "01", "--responder", "scripted:correct", "--data", "d",
            "--quiet"]
    if how == "crash":
        with pytest.raises(ZeroDivisionError):
            cli.main(args)
        rc = None
    else:
        rc = cli.main(args)
    err = capsys.readouterr().err
    assert rc == {"escape": 130, "device fault": 3, "crash": None}[how]
    assert "To continue session 1 of participant 01 where it stopped:" in err
    cmd = printed_command(err)
    monkeypatch.undo()
    r = run_printed(cmd + ["--quiet"], cwd=ROOT, timeout=180)
    assert r.returncode == 0, r.stderr
    meta = json.loads(paths_of(data).session_json.read_text())
    assert meta["status"] == "completed" and meta["n_trials_logged"] == 4
    assert meta["resumes"][0]["trials_done"] == 2


@pytest.mark.process
def test_ctrl_c_prints_the_command_that_continues(tmp_path):
    f = write_experiment(tmp_path, SLOW)
    data = tmp_path / "d"
    proc = subprocess.Popen([sys.executable, "-m", "vtexp", "run", str(f), "-p", "01",
                             "--device", "sim:realtime", "--responder", "scripted:correct",
                             "--data", str(data), "--quiet"], env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    beh = paths_of(data).beh_tsv
    deadline = time.monotonic() + 60
    while (not beh.exists() or beh.read_text().count("\n") < 2) and time.monotonic() < deadline:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130 and "Traceback" not in err, err
    cmd = printed_command(err)
    r = run_printed(cmd + ["--quiet"], cwd=tmp_path, timeout=180)
    assert r.returncode == 0, r.stderr
    assert json.loads(paths_of(data).session_json.read_text())["status"] == "completed"


def test_time_left_counts_the_trials_not_the_instructions():
    from vtexp.cli.run import format_minutes, time_left_s
    # 8 s per trial (6 s answering + a 2 s pause), 3 done, 90 left: 12 minutes.
    assert time_left_s(first_start=1000.0, now=1000.0 + 3 * 8 - 2, trials_done=3,
                       trials_left=90, iti_s=2.0) == pytest.approx(720.0)
    assert format_minutes(720.0) == "12 min" and format_minutes(20) == "<1 min"


def test_the_progress_line_estimates_from_the_first_trial_on(tmp_path, capsys):
    """Minutes of instructions before the first trial do not inflate the estimate."""
    from types import SimpleNamespace

    from vtexp.cli.run import _Progress
    clock = [5000.0]
    p = _Progress(False, iti_s=1.0, clock=lambda: clock[0])
    t0 = 5000.0 + 600                       # ten minutes of instructions before trial 1
    for n in (1, 2):
        clock[0] = t0 + n * 5 - 1           # 4 s to answer, then a 1 s pause
        rec = SimpleNamespace(correct=True, answer="circle",
                              started_at=pd.Timestamp(t0 + (n - 1) * 5, unit="s", tz="UTC")
                              .isoformat())
        trial = SimpleNamespace(number=n, condition=SimpleNamespace(label="x"))
        p(TrialDone(trial, (rec,), (), 98, wall_s=0.0, host_ms=0.0))
    line = capsys.readouterr().err.splitlines()[-1]
    assert "left ~8 min" in line            # 96 trials x 5 s
    assert "elapsed 0:09" in line


# ------------------------------------------------------------------------- analyses

def test_analyze_refuses_duplicated_trials_or_drops_them_when_asked(tmp_path):
    lx = load_experiment(write_experiment(tmp_path, MINIMAL))
    data = tmp_path / "d"
    with open_device("sim", DeviceProfile.load("vest_6x8")) as dev:
        run_session(lx, dev, make_responder("scripted:correct", "01", 1),
                    SessionOptions(participant="01", data_dir=data))
    p = paths_of(data)
    lines = p.beh_tsv.read_bytes().split(b"\n")
    p.beh_tsv.write_bytes(b"\n".join(lines[:3] + lines[2:]))       # trial 2 twice
    ev = p.events_tsv.read_bytes().split(b"\n")
    p.events_tsv.write_bytes(b"\n".join(ev[:3] + ev[1:]))
    r = vtexp("analyze", data, "--out", tmp_path / "out")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "trials logged twice" in r.stderr and f"{p.dir}: trials 2" in r.stderr
    r = vtexp("analyze", data, "--out", tmp_path / "out", "--drop-duplicates")
    assert r.returncode == 0, r.stderr
    assert "1 rows log a trial a second time (trials 2)" in r.stderr
    assert "device events are logged twice" in r.stderr
    assert "1 session(s), 4 trials" in r.stdout


def test_model_participants_are_kept_apart_from_people(tmp_path):
    f = write_experiment(tmp_path, MINIMAL)
    data = tmp_path / "d"
    r = vtexp("run", f, "-p", "01", "--responder", "model", "--data", data, "--quiet")
    assert r.returncode == 2 and "model participant's id starts with 'sim'" in r.stderr
    r = vtexp("run", f, "-p", "sim01", "--responder", "model", "--data", data, "--quiet")
    assert r.returncode == 0, r.stderr
    meta = json.loads(paths_of(data, "sim01").session_json.read_text())
    assert meta["participant_kind"] == "model"
    r = vtexp("run", f, "-p", "Sim7", "--responder", "console", "--data", data, "--quiet",
              input="")
    assert r.returncode == 2 and "kept for model participants" in r.stderr
    r = vtexp("run", f, "-p", "07", "--responder", "console", "--data", data, "--quiet",
              input="1\n2\n1\n2\n" * 2 + "\n")
    assert r.returncode == 0, r.stderr
    assert json.loads(paths_of(data, "07").session_json.read_text())["participant_kind"] == \
        "person"
    r = vtexp("analyze", data, "--out", tmp_path / "out")
    assert r.returncode == 0, r.stderr
    assert "1 simulated session(s)" in r.stderr and "sub-sim01" in r.stderr
    assert "1 session(s), 4 trials" in r.stdout
    r = vtexp("analyze", data, "--out", tmp_path / "out2", "--include-simulated")
    assert r.returncode == 0 and "2 session(s), 8 trials" in r.stdout
    assert "pooled with people's as asked" in r.stderr
    r = vtexp("analyze", paths_of(data, "sim01").dir, "--out", tmp_path / "out3")
    assert r.returncode == 0 and "are simulated" in r.stderr
