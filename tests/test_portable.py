"""vtexp where ``fcntl``, ``termios``, ``tty`` and ``pty`` do not exist (Windows).

The commands run in a child Python in which those modules cannot be imported: a
finder placed before every other refuses them, as Windows' Python would. pyserial
chooses its backend by ``os.name`` (``serialwin32`` on Windows, which needs none of
them); its POSIX backend is loaded before they are hidden and stands in for it. The
child runs a list of commands through ``vtexp.cli.main`` and reports each one's exit
status and output, which modules it tried to import, and which lock it used.

The session lock is also held the Windows way (``msvcrt.locking``), with a stand-in
``msvcrt`` whose ``locking`` is a ``flock``: the two-process rules are the same.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time

import pandas as pd
import pytest

from conftest import MINIMAL, ROOT, write_experiment
from vtexp import lock as vlock
from vtexp.devices.firmware import Firmware, FirmwareConfig
from vtexp.lock import SessionBusy, SessionLock
from vtexp.model import DeviceProfile
from vtexp.session import SessionPaths

ENV = dict(os.environ, PYTHONPATH=str(ROOT))
HIDDEN = ("fcntl", "termios", "tty", "pty", "msvcrt")

#: Run first in each child: hides HIDDEN (and, with a stand-in msvcrt, gives it).
BOOT = """\
import importlib.abc, sys
HIDDEN = {hidden!r}
import serial, serial.tools.list_ports     # pyserial's own backend (see the test's docstring)
if {fake_msvcrt!r}:
    import fcntl as _fcntl, types
    msvcrt = types.ModuleType("msvcrt")
    msvcrt.LK_UNLCK, msvcrt.LK_LOCK, msvcrt.LK_NBLCK, msvcrt.LK_RLCK, msvcrt.LK_NBRLCK = range(5)

    def _locking(fd, mode, nbytes):
        # Windows locks bytes of one handle until it is closed or its process ends;
        # a flock of the whole file behaves alike between processes.
        if mode == msvcrt.LK_UNLCK:
            _fcntl.flock(fd, _fcntl.LOCK_UN)
            return
        try:
            _fcntl.flock(fd, _fcntl.LOCK_EX | _fcntl.LOCK_NB)
        except BlockingIOError:
            raise PermissionError(13, "Permission denied") from None
    msvcrt.locking = _locking
tried = []


class NoPosix(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name in HIDDEN:
            tried.append(name)
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
        return None


for _name in HIDDEN:
    sys.modules.pop(_name, None)
sys.meta_path.insert(0, NoPosix())
if {fake_msvcrt!r}:
    sys.modules["msvcrt"] = msvcrt
"""

#: The child that runs vtexp commands: argv[1] is a JSON list of command lines; an entry
#: ["kill", PID] kills that process and waits until it is gone.
COMMANDS = """
import contextlib, io, json, os, signal, time
from vtexp.cli import main
results = []
for argv in json.loads(sys.argv[1]):
    if argv[0] == "kill":
        os.kill(argv[1], signal.SIGKILL)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            try:
                os.kill(argv[1], 0)         # still there until its parent reaps it
            except ProcessLookupError:
                break
            time.sleep(0.02)
        continue
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as e:
            code = e.code
    results.append({"argv": argv, "code": code, "stdout": out.getvalue(),
                    "stderr": err.getvalue()})
import vtexp.lock
print(json.dumps({"results": results, "tried": sorted(set(tried)),
                  "loaded": [n for n in HIDDEN if n in sys.modules],
                  "lock": vtexp.lock.METHOD}))
"""


def boot(fake_msvcrt: bool = False) -> str:
    hidden = tuple(n for n in HIDDEN if not (fake_msvcrt and n == "msvcrt"))
    return BOOT.format(hidden=hidden, fake_msvcrt=fake_msvcrt)


def run_without_posix(commands: list[list], timeout: float = 240) -> dict:
    """Run vtexp ``commands`` in one child without fcntl, termios, tty and pty."""
    r = subprocess.run([sys.executable, "-c", boot() + COMMANDS,
                        json.dumps([[str(a) if not isinstance(a, int) else a for a in c]
                                    for c in commands])],
                       env=ENV, capture_output=True, text=True, timeout=timeout,
                       stdin=subprocess.DEVNULL)
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout.strip().splitlines()[-1])
    assert report["loaded"] == [], report          # none of them was ever imported
    assert report["lock"] == "exclusive file"
    return report


def one_line(text: str) -> str:
    lines = [ln for ln in text.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in text, text
    return lines[0]


# --------------------------------------------------------------------------- a device on TCP

class FirmwareOnTcp:
    """The device's state machine served on a TCP port, as pyserial's ``socket://`` reaches
    it: bytes in to :meth:`Firmware.receive`, its frames back out, :meth:`Firmware.tick`
    when it is due."""

    def __init__(self, profile: DeviceProfile):
        self._t0 = time.perf_counter_ns()
        self.firmware = Firmware(FirmwareConfig.for_profile(profile), self.clock_us)
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.connections = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def clock_us(self) -> int:
        return (time.perf_counter_ns() - self._t0) // 1000

    def _serve(self) -> None:
        self.server.settimeout(0.1)
        while not self._stop.is_set():
            try:
                conn, _ = self.server.accept()
            except TimeoutError:
                continue
            self.connections += 1
            with conn:
                self._talk(conn)

    def _talk(self, conn: socket.socket) -> None:
        fw = self.firmware
        while not self._stop.is_set():
            deadline = fw.next_deadline_us()
            wait_s = 0.05 if deadline is None else (deadline - self.clock_us()) / 1e6
            conn.settimeout(min(0.05, max(wait_s, 0.0005)))
            try:
                data = conn.recv(4096)
                if not data:
                    return                      # the host closed the port
                out = fw.receive(data)
            except TimeoutError:
                out = fw.tick()
            except OSError:
                return
            for frame in out:
                conn.sendall(frame)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self.server.close()


# --------------------------------------------------------------------------- the commands

SLOW = MINIMAL.replace("repetitions: 2", "repetitions: 50")
FAST = MINIMAL.replace("name: mini", "name: fast").replace("duration_ms: 200, soa_ms: 200",
                                                          "duration_ms: 50, soa_ms: 50")


def test_the_core_runs_without_fcntl_termios_tty_and_pty(tmp_path):
    """run (sim, serial through pyserial), resume, a second run of a running session
    refused naming its holder, a dead holder's lock found free, analyze, stats, encode,
    live from a video; the pty tools refuse in one line."""
    from vtexp.live.synthetic import write_video

    exp = write_experiment(tmp_path, MINIMAL)
    slow = write_experiment(tmp_path, SLOW, name="slow.yaml")
    fast = write_experiment(tmp_path, FAST, name="fast.yaml")
    data, held = tmp_path / "data", tmp_path / "held"
    video = tmp_path / "square.avi"
    write_video(video, "rectangle", seconds=1.0, fps=10, width=160, height=120)
    device = FirmwareOnTcp(DeviceProfile.load("vest_6x8"))
    # A session that holds its lock, in a process of its own, without fcntl either.
    holder = subprocess.Popen(
        [sys.executable, "-c", boot() + "from vtexp.cli import main\nsys.exit(main(sys.argv[1:]))",
         "run", str(slow), "-p", "01", "--device", "sim:realtime", "--responder",
         "scripted:correct", "--data", str(held), "--quiet"],
        env=ENV, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True)
    reaper = threading.Thread(target=holder.wait, daemon=True)     # reaps it when killed
    try:
        lock = SessionPaths.of(held, "mini", "mini", "01", 1).record_dir / "session.lock"
        deadline = time.monotonic() + 60
        while not (lock.exists() and vlock.read_holder(lock)) and time.monotonic() < deadline:
            assert holder.poll() is None, holder.stderr.read()
            time.sleep(0.05)
        reaper.start()
        common = ["--responder", "scripted:correct", "--data", data]
        report = run_without_posix([
            ["run", slow, "-p", "01", "--data", held, "--resume"],
            ["run", slow, "-p", "01", "--responder", "scripted:correct", "--data", held],
            ["kill", holder.pid],
            ["run", slow, "-p", "02", "--device", "sim", "--responder", "scripted:correct",
             "--data", held, "--max-trials", "1", "--quiet"],
            ["run", exp, "-p", "01", "--device", "sim", *common, "--max-trials", "2"],
            ["run", exp, "-p", "01", *common, "--resume"],
            ["run", fast, "-p", "01", "--device", f"serial:socket://127.0.0.1:{device.port}",
             *common],
            ["analyze", data / "mini", "--out", tmp_path / "report"],
            ["stats", "rm-anova", ROOT / "tests" / "data" / "grid_3x4.csv", "--dv", "score",
             "--within", "shape", "soa", "--subject", "participant"],
            ["encode", "shape:shape=square", "--pipeline", "edge-trace", "--device",
             "vest_6x8", "--json", tmp_path / "encoded.json"],
            ["live", video, "--pipeline", "edge-trace", "--device", "sim", "--no-pace",
             "--record", tmp_path / "live"],
            ["device", "emulate", "--profile", "vest_6x8"],
            ["device", "emulate", "--profile", "vest_6x8", "--firmware", "host"],
            ["device", "monitor", "--device", f"serial:socket://127.0.0.1:{device.port}"],
        ])
    finally:
        if holder.poll() is None:
            holder.kill()
        holder.wait(30)
        device.close()
    res = {i: r for i, r in enumerate(report["results"])}
    # A second run of a running session is refused, naming the process that runs it.
    for r in (res[0], res[1]):
        assert r["code"] == 2, r
        assert f"process {holder.pid} on " in r["stderr"] and "running now" in r["stderr"], r
    # Killed, its lock is free: the next run finds the session dead and says so.
    r = res[2]
    assert r["code"] == 0, r
    assert "Session 1 of participant 01 did not close" in r["stdout"], r
    assert f"pid {holder.pid} on" in r["stdout"] and "marked interrupted" in r["stdout"], r
    meta = json.loads(SessionPaths.of(held, "mini", "mini", "01", 1).session_json.read_text())
    assert meta["status"] == "interrupted"
    # On sim: stopped after two trials, resumed, complete; the lock is gone.
    assert res[3]["code"] == 0 and "stopped after 2 trials" in res[3]["stdout"], res[3]
    assert res[4]["code"] == 0, res[4]
    p1 = SessionPaths.of(data, "mini", "mini", "01", 1)
    meta = json.loads(p1.session_json.read_text())
    assert meta["status"] == "completed" and meta["n_trials_logged"] == 4, meta
    assert len(meta["resumes"]) == 1
    assert list(pd.read_csv(p1.beh_tsv, sep="\t")["trial"]) == [1, 2, 3, 4]
    assert b"\r" not in p1.beh_tsv.read_bytes()
    assert not (p1.record_dir / "session.lock").exists()
    # On the device through pyserial: every trial played there, everything off at the end.
    assert res[5]["code"] == 0, res[5]
    p2 = SessionPaths.of(data, "fast", "fast", "01", 1)
    meta = json.loads(p2.session_json.read_text())
    assert meta["status"] == "completed" and meta["n_trials_logged"] == 4
    assert device.connections >= 1 and device.firmware.history
    assert all(s.is_off for s in device.firmware.outputs)
    # The rest of the core.
    assert res[6]["code"] == 0 and (tmp_path / "report").is_dir(), res[6]
    assert res[7]["code"] == 0 and "soa: F(" in res[7]["stdout"], res[7]
    assert res[8]["code"] == 0 and (tmp_path / "encoded.json").is_file(), res[8]
    assert res[9]["code"] == 0 and "every actuator is off" in res[9]["stdout"], res[9]
    assert json.loads((tmp_path / "live" / "live.json").read_text())["status"] == "completed"
    # What needs a pseudo-terminal says so, in one line, naming what to use instead.
    for r in (res[10], res[11], res[12]):
        assert r["code"] != 0 and r["stdout"] == "", r
        line = one_line(r["stderr"])
        assert "serial:COM3" in line, line
    assert "pseudo-terminal" in one_line(res[10]["stderr"])
    assert "--device sim" in one_line(res[10]["stderr"])
    assert "pseudo-terminals" in one_line(res[11]["stderr"])
    assert "pseudo-terminal" in one_line(res[12]["stderr"])


# --------------------------------------------------------------------------- the lock alone

HOLD = """
from vtexp.lock import METHOD, SessionLock
lock = SessionLock.acquire(sys.argv[1], what="it")
print(METHOD, flush=True)
sys.stdin.readline()
"""

PROBE = """
import json
from vtexp.lock import SessionBusy, SessionLock, exclusive
try:
    SessionLock.acquire(sys.argv[1], what="it")
    print(json.dumps({"busy": None}), flush=True)
except SessionBusy as e:
    print(json.dumps({"busy": str(e), "holder": e.holder}), flush=True)
sys.stdin.readline()                        # the holder is killed meanwhile
lock = SessionLock.acquire(sys.argv[1], what="it")
with exclusive(sys.argv[1] + "/.dataset.lock"):
    pass
print(json.dumps({"stale": lock.stale, "file": json.load(open(lock.path))}), flush=True)
lock.release()
"""


@pytest.mark.parametrize("windows", [False, True], ids=["exclusive-file", "msvcrt"])
def test_the_lock_holds_between_processes_without_flock(tmp_path, windows):
    """Held: another process is refused, naming the holder. Killed: its lock is free and
    taken over, naming the dead holder. Released: the file is gone."""
    code = boot(fake_msvcrt=windows)
    popen = dict(env=ENV, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                 stderr=subprocess.PIPE, text=True)
    holder = subprocess.Popen([sys.executable, "-c", code + HOLD, str(tmp_path)], **popen)
    prober = None
    try:
        assert holder.stdout.readline().strip() == ("msvcrt" if windows else "exclusive file"), \
            holder.stderr.read()
        prober = subprocess.Popen([sys.executable, "-c", code + PROBE, str(tmp_path)], **popen)
        first = json.loads(prober.stdout.readline() or prober.stderr.read())
        assert first["busy"] and f"process {holder.pid} on " in first["busy"]
        assert first["holder"]["pid"] == holder.pid
        holder.send_signal(signal.SIGKILL)
        holder.wait(30)
        assert (tmp_path / "session.lock").exists()           # left behind
        prober.stdin.write("\n")
        prober.stdin.flush()
        second = json.loads(prober.stdout.readline() or prober.stderr.read())
        assert second["stale"]["pid"] == holder.pid
        assert second["file"]["pid"] == prober.pid
        prober.communicate(timeout=30)
        assert prober.returncode == 0
        assert not (tmp_path / "session.lock").exists()
    finally:
        for p in (holder, prober):
            if p is not None and p.poll() is None:
                p.kill()
                p.wait(30)


@pytest.fixture
def exclusive_file(monkeypatch):
    """The lock held as where neither flock nor msvcrt exist."""
    monkeypatch.setattr(vlock, "METHOD", "exclusive file")


def _ended_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_an_exclusive_lock_of_another_computer_is_refused_saying_what_to_do(
        tmp_path, exclusive_file):
    (tmp_path / "session.lock").write_text(json.dumps(
        {"pid": os.getpid(), "host": "another-lab-pc", "since": "2024-05-01T10:00:00+02:00"}))
    with pytest.raises(SessionBusy) as e:
        SessionLock.acquire(tmp_path, what="session 1 of participant 01")
    assert f"process {os.getpid()} on another-lab-pc since 2024-05-01 10:00:00" in str(e.value)
    assert f"delete {tmp_path / 'session.lock'}" in str(e.value)
    assert SessionLock.probe(tmp_path)["host"] == "another-lab-pc"


def test_an_exclusive_lock_of_an_ended_process_is_taken_over(tmp_path, exclusive_file):
    import platform
    dead = {"pid": _ended_pid(), "host": platform.node(), "since": "2024-05-01T10:00:00+02:00"}
    (tmp_path / "session.lock").write_text(json.dumps(dead))
    lock = SessionLock.acquire(tmp_path)
    assert lock.stale == dead
    assert vlock.read_holder(tmp_path / "session.lock")["pid"] == os.getpid()
    assert [p.name for p in tmp_path.iterdir()] == ["session.lock"]
    with pytest.raises(SessionBusy):            # one holder per session, this process too
        SessionLock.acquire(tmp_path)
    lock.release()
    assert not (tmp_path / "session.lock").exists()


def test_an_exclusive_lock_left_empty_is_free_after_a_moment(tmp_path, exclusive_file):
    path = tmp_path / "session.lock"
    path.write_bytes(b"")
    t0 = time.monotonic()
    lock = SessionLock.acquire(tmp_path)        # its maker may be writing it: waited for
    assert time.monotonic() - t0 >= vlock._EMPTY_GRACE_S * 0.9
    lock.release()
    path.write_bytes(b"")
    old = time.time() - 60                      # left by a process killed long ago
    os.utime(path, (old, old))
    t0 = time.monotonic()
    SessionLock.acquire(tmp_path).release()
    assert time.monotonic() - t0 < 1


def test_the_command_to_continue_is_quoted_for_the_shell_of_the_platform(monkeypatch):
    from vtexp.cli.run import resume_command
    exp, data = "/lab data/exp.yaml", "/lab data/d"
    assert f"run '{exp}' " in resume_command(exp, "01", 1, "sim", None, data)
    monkeypatch.setattr(sys, "platform", "win32")       # cmd.exe reads no single quotes
    line = resume_command(exp, "01", 1, "serial:COM3", None, data)
    assert f'run "{exp}" ' in line and f'--data "{data}" --resume' in line
