"""A lock per running session: one process at a time may write a session's logs.

The lock is ``session.lock`` in the session folder, held with an exclusive
``flock`` for as long as the session runs. The kernel releases a ``flock`` when
its process ends, however it ends (SIGKILL, a crash, a power cut), so a lock
left behind by a dead process is recognised as stale by simply taking it. The
file names its holder (process id, host, command, since when) so that a refusal
can say who holds the session.

Where ``fcntl`` does not exist (Windows) the holder's process id is checked
instead: a lock whose process is gone, on this host, is stale.
"""

from __future__ import annotations

import json
import os
import platform
import sys
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from .errors import SessionError

try:
    import fcntl
except ImportError:             # Windows
    fcntl = None

LOCK_NAME = "session.lock"


def _now() -> str:
    return datetime.now(timezone.utc).astimezone().isoformat(timespec="seconds")


def holder_info() -> dict:
    """Who is taking a lock: this process."""
    return {"pid": os.getpid(), "host": platform.node(), "since": _now(),
            "command": " ".join(sys.argv)}


def describe_holder(h: dict) -> str:
    where = f"process {h.get('pid', '?')} on {h.get('host', '?')}"
    since = f" since {str(h.get('since', ''))[:19].replace('T', ' ')}" if h.get("since") else ""
    cmd = f" ({h['command']})" if h.get("command") else ""
    return where + since + cmd


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True
    return True


def read_holder(path: Path) -> dict:
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
        return data if isinstance(data, dict) else {}
    except (OSError, ValueError):
        return {}


class SessionBusy(SessionError):
    """The session is held by another process that is still alive."""

    def __init__(self, message: str, holder: dict):
        super().__init__(message)
        self.holder = holder


@dataclass
class SessionLock:
    """A held lock; :meth:`release` (or the process's end) gives it up."""

    path: Path
    fd: int | None
    stale: dict | None = None      # the holder of a stale lock taken over, if any

    @classmethod
    def acquire(cls, folder: Path | str, what: str = "this session") -> SessionLock:
        """Take the lock of the session in ``folder`` or raise :class:`SessionBusy`.

        A lock left by a process that has ended is taken over; ``stale`` then
        names that process.
        """
        path = Path(folder) / LOCK_NAME
        while True:
            try:
                fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
            except OSError as e:
                raise SessionError(f"cannot create the lock {path}: {e.strerror}") from None
            previous = read_holder(path)
            if fcntl is not None:
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except OSError:
                    os.close(fd)
                    raise SessionBusy(f"{what} is being run by another vtexp process "
                                      f"({describe_holder(previous)}); it was left untouched. "
                                      "Stop that run first (or wait for it to end).",
                                      previous) from None
                # The lock may have been released and its file removed between our open
                # and our flock: then we hold a lock on a file nobody else will open.
                try:
                    same = os.path.samestat(os.fstat(fd), os.stat(path))
                except FileNotFoundError:
                    same = False
                if not same:
                    os.close(fd)
                    continue
            elif previous and previous.get("host") == platform.node() and \
                    previous.get("pid") != os.getpid() and _pid_alive(int(previous.get("pid", 0))):
                os.close(fd)
                raise SessionBusy(f"{what} is being run by another vtexp process "
                                  f"({describe_holder(previous)}); it was left untouched.",
                                  previous)
            lock = cls(path, fd, previous or None)
            lock._write(holder_info())
            return lock

    @classmethod
    def probe(cls, folder: Path | str) -> dict | None:
        """The holder of the session's lock if a live process holds it, else None."""
        path = Path(folder) / LOCK_NAME
        if not path.exists():
            return None
        try:
            lock = cls.acquire(folder)
        except SessionBusy as e:
            return e.holder or {"pid": "?"}
        except SessionError:
            return None
        lock.release()
        return None

    def _write(self, info: dict) -> None:
        data = (json.dumps(info) + "\n").encode("utf-8")
        os.ftruncate(self.fd, 0)
        os.pwrite(self.fd, data, 0)
        os.fsync(self.fd)

    def move_to(self, folder: Path) -> None:
        """The session folder was renamed (staging -> final): follow it."""
        self.path = Path(folder) / LOCK_NAME

    def release(self) -> None:
        """Remove the lock file, then let go of it (so no one takes a file being removed)."""
        if self.fd is None:
            return
        try:
            self.path.unlink()
        except OSError:
            pass
        os.close(self.fd)
        self.fd = None
