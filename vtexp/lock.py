"""A lock per running session: one process at a time may write a session's logs.

The lock is ``session.lock`` in the session folder, held for as long as the
session runs. The file names its holder (process id, host, command, since when)
so that a refusal can say who holds the session. How it is held depends on what
the platform offers (:data:`METHOD`):

``flock`` (Linux, macOS, the BSDs: ``fcntl`` exists)
    An exclusive ``flock`` on the file. The kernel releases a ``flock`` when its
    process ends, however it ends (SIGKILL, a crash, a power cut), so a lock left
    behind by a dead process is recognised as free by simply taking it. It holds
    between the processes of one computer, and across computers on file systems
    that pass ``flock`` on (NFS on Linux).

``msvcrt`` (Windows)
    ``msvcrt.locking`` on one byte far past the holder's text (Windows locks are
    mandatory: a locked byte cannot be read, so the text is left outside). Windows
    releases the lock when the process ends, however it ends, so a dead holder's
    lock is taken as with ``flock``. The file is opened sharing deletion, so that
    the session folder can be renamed while the lock is held (a new session is
    made in a staging folder) and the file removed when the lock is given up.

``exclusive file`` (a Python that has neither)
    The file is created exclusively (``O_EXCL``) and names its holder; it is free
    when it does not exist, or when the process it names has ended. That can only
    be checked on the computer that runs it: a lock naming another computer stays
    held until someone removes the file (the refusal says which), and so does a
    lock whose process id a new process took after the holder died. Two processes
    taking over the same dead holder's lock at once are told apart by an atomic
    rename.

:func:`exclusive` holds a file the same way for a short operation, waiting its
turn (the dataset's ``participants.tsv`` is written under it).
"""

from __future__ import annotations

import contextlib
import json
import os
import platform
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from .errors import SessionError

try:
    import fcntl
except ImportError:             # Windows
    fcntl = None
try:
    import msvcrt
except ImportError:             # everywhere but Windows
    msvcrt = None

LOCK_NAME = "session.lock"

#: How locks are held here: "flock", "msvcrt" or "exclusive file" (module docstring).
METHOD = "flock" if fcntl is not None else "msvcrt" if msvcrt is not None else "exclusive file"

_BINARY = getattr(os, "O_BINARY", 0)
#: Where the msvcrt lock sits: past any holder's text, below 2 GiB (msvcrt's offsets).
_LOCKED_BYTE = 1 << 30
#: An exclusive lock file still empty after this long was left by a process killed
#: between creating it and writing its holder.
_EMPTY_GRACE_S = 2.0
#: How long a lock file being removed by its holder may keep us from opening it (Windows).
_RETRY_S = 2.0


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
    """Whether process ``pid`` of this computer is running (or exists and is not ours to
    ask about)."""
    if pid <= 0:
        return False
    if os.name == "nt":
        # os.kill(pid, 0) would end the process there (TerminateProcess): ask instead.
        import ctypes
        from ctypes import wintypes
        k32 = ctypes.WinDLL("kernel32", use_last_error=True)
        k32.OpenProcess.restype = wintypes.HANDLE
        k32.OpenProcess.argtypes = (wintypes.DWORD, wintypes.BOOL, wintypes.DWORD)
        k32.GetExitCodeProcess.argtypes = (wintypes.HANDLE, ctypes.POINTER(wintypes.DWORD))
        k32.CloseHandle.argtypes = (wintypes.HANDLE,)
        handle = k32.OpenProcess(0x1000, False, pid)     # PROCESS_QUERY_LIMITED_INFORMATION
        if not handle:
            return ctypes.get_last_error() == 5          # access denied: it exists
        try:
            code = wintypes.DWORD()
            return not k32.GetExitCodeProcess(handle, ctypes.byref(code)) or code.value == 259
        finally:                                         # 259: STILL_ACTIVE
            k32.CloseHandle(handle)
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


def _read_holder_fd(fd: int) -> dict:
    """The holder written in the open lock file ``fd`` (read through it: on Windows another
    handle would keep its holder from removing it)."""
    try:
        os.lseek(fd, 0, os.SEEK_SET)
        chunks = []
        while chunk := os.read(fd, 65536):
            chunks.append(chunk)
        data = json.loads(b"".join(chunks).decode("utf-8"))
        return data if isinstance(data, dict) else {}
    except (OSError, ValueError):
        return {}


class SessionBusy(SessionError):
    """The session is held by another process that is still alive."""

    def __init__(self, message: str, holder: dict):
        super().__init__(message)
        self.holder = holder


def _busy(what: str, holder: dict, path: Path | None = None) -> SessionBusy:
    if path is None:
        advice = "Stop that run first (or wait for it to end)."
    else:                       # an exclusive file whose holder cannot be checked from here
        advice = f"If that run has ended, delete {path} and try again."
    return SessionBusy(f"{what} is being run by another vtexp process "
                       f"({describe_holder(holder)}); it was left untouched. {advice}", holder)


# --------------------------------------------------------------------------- flock

# Each way of taking a lock returns (fd, the holder the file named before) once it holds
# it, or (None, a dead holder whose lock it cleared) when it must try again; it raises
# SessionBusy when a live process holds it.

def _take_flock(path: Path, what: str) -> tuple[int | None, dict]:
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as e:
        raise SessionError(f"cannot create the lock {path}: {e.strerror}") from None
    previous = read_holder(path)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        raise _busy(what, previous) from None
    # The lock may have been released and its file removed between our open and our
    # flock: then we hold a lock on a file nobody else will open.
    if not _same_file(fd, path):
        os.close(fd)
        return None, {}
    return fd, previous


def _same_file(fd: int, path: Path) -> bool:
    try:
        return os.path.samestat(os.fstat(fd), os.stat(path))
    except OSError:             # gone, or (Windows) being removed
        return False


# --------------------------------------------------------------------------- msvcrt

def _open_sharing_delete(path: Path) -> int:
    """``path`` opened read-write (created if missing) as a C file descriptor, in a way that
    lets the file be removed, and its folder renamed, while it is open."""
    if os.name != "nt":         # (a stand-in msvcrt under test)
        return os.open(path, os.O_RDWR | os.O_CREAT | _BINARY, 0o644)
    import ctypes
    from ctypes import wintypes
    k32 = ctypes.WinDLL("kernel32", use_last_error=True)
    k32.CreateFileW.restype = wintypes.HANDLE
    k32.CreateFileW.argtypes = (wintypes.LPCWSTR, wintypes.DWORD, wintypes.DWORD,
                                wintypes.LPVOID, wintypes.DWORD, wintypes.DWORD,
                                wintypes.HANDLE)
    handle = k32.CreateFileW(str(path), 0x80000000 | 0x40000000,   # GENERIC_READ | WRITE
                             0x1 | 0x2 | 0x4,       # FILE_SHARE_READ | WRITE | DELETE
                             None, 4, 0x80, None)   # OPEN_ALWAYS, FILE_ATTRIBUTE_NORMAL
    if handle is None or handle == wintypes.HANDLE(-1).value:
        raise ctypes.WinError(ctypes.get_last_error())
    return msvcrt.open_osfhandle(handle, 0)         # binary, read-write


def _take_msvcrt(path: Path, what: str) -> tuple[int | None, dict]:
    deadline = time.monotonic() + _RETRY_S
    while True:
        try:
            fd = _open_sharing_delete(path)
            break
        except PermissionError:     # its holder is removing it: gone in a moment
            if time.monotonic() > deadline:
                raise SessionError(f"cannot open the lock {path}: it is being removed by "
                                   "another process; try again") from None
            time.sleep(0.02)
        except OSError as e:
            raise SessionError(f"cannot create the lock {path}: {e.strerror}") from None
    try:
        os.lseek(fd, _LOCKED_BYTE, os.SEEK_SET)
        msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
    except OSError:
        previous = _read_holder_fd(fd)
        os.close(fd)
        raise _busy(what, previous) from None
    if not _same_file(fd, path):
        _unlock_msvcrt(fd)
        os.close(fd)
        return None, {}
    return fd, _read_holder_fd(fd)


def _unlock_msvcrt(fd: int) -> None:
    try:
        os.lseek(fd, _LOCKED_BYTE, os.SEEK_SET)
        msvcrt.locking(fd, msvcrt.LK_UNLCK, 1)
    except OSError:
        pass


# --------------------------------------------------------------------------- exclusive file

def _take_exclusive(path: Path, what: str) -> tuple[int | None, dict]:
    """Create the file exclusively; a dead holder's file is moved away first."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL | _BINARY, 0o644)
        return fd, {}
    except FileExistsError:
        pass
    except OSError as e:
        raise SessionError(f"cannot create the lock {path}: {e.strerror}") from None
    holder = read_holder(path)
    if not holder:
        try:
            age_s = time.time() - os.stat(path).st_mtime
        except FileNotFoundError:
            return None, {}
        if age_s < _EMPTY_GRACE_S:          # its holder is writing it: ask again soon
            time.sleep(0.02)
            return None, {}
    elif holder.get("host") != platform.node():
        raise _busy(what, holder, path)
    else:
        try:
            pid = int(holder.get("pid", 0))
        except (TypeError, ValueError):
            pid = 0
        if _pid_alive(pid):
            raise _busy(what, holder)
    # The holder is gone: move its file away, atomically, and see that it was that one
    # (another process may have taken it over and made its own since we read it).
    moved = path.with_name(f".{path.name}.stale-{os.getpid()}")
    try:
        os.replace(path, moved)
    except FileNotFoundError:
        return None, {}                     # someone else moved it
    except OSError as e:
        raise SessionError(f"cannot take over the lock {path} of a process that has "
                           f"ended: {e.strerror}") from None
    if read_holder(moved) == holder:
        moved.unlink(missing_ok=True)
        return None, holder
    try:                                    # a live holder's: put it back
        os.link(moved, path)
    except OSError:
        pass
    moved.unlink(missing_ok=True)
    return None, {}


# --------------------------------------------------------------------------- the lock

_TAKE = {"flock": _take_flock, "msvcrt": _take_msvcrt, "exclusive file": _take_exclusive}


@dataclass
class SessionLock:
    """A held lock; :meth:`release` (or the process's end) gives it up."""

    path: Path
    fd: int | None
    stale: dict | None = None      # the holder of a stale lock taken over, if any
    method: str = "flock"

    @classmethod
    def acquire(cls, folder: Path | str, what: str = "this session") -> SessionLock:
        """Take the lock of the session in ``folder`` or raise :class:`SessionBusy`.

        A lock left by a process that has ended is taken over; ``stale`` then
        names that process.
        """
        return cls._acquire(Path(folder) / LOCK_NAME, what)

    @classmethod
    def _acquire(cls, path: Path, what: str) -> SessionLock:
        method = METHOD
        stale: dict = {}
        while True:
            fd, previous = _TAKE[method](path, what)
            if fd is not None:
                break
            stale = previous or stale
        lock = cls(path, fd, previous or stale or None, method)
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
        if hasattr(os, "pwrite"):
            os.pwrite(self.fd, data, 0)
        else:                                   # Windows
            os.lseek(self.fd, 0, os.SEEK_SET)
            os.write(self.fd, data)
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
        if self.method == "msvcrt":
            _unlock_msvcrt(self.fd)
        os.close(self.fd)
        self.fd = None


@contextlib.contextmanager
def exclusive(path: Path | str, what: str = "the dataset") -> Iterator[None]:
    """Hold ``path`` for a short operation, waiting while another process holds it.

    With ``flock`` the file is left in place when released; otherwise a
    lock is taken and released as :class:`SessionLock` does (a dead holder's is taken
    over; one that cannot be checked is waited for a minute, then refused naming it).
    """
    path = Path(path)
    if METHOD == "flock":
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            yield
        finally:
            os.close(fd)                    # releases the flock
        return
    deadline = time.monotonic() + 60.0
    while True:
        try:
            lock = SessionLock._acquire(path, what)
            break
        except SessionBusy as e:
            if time.monotonic() > deadline:
                raise SessionError(f"{what} has been held for a minute by "
                                   f"{describe_holder(e.holder)}; if that process has "
                                   f"ended, delete {path} and try again") from None
            time.sleep(0.01)
    try:
        yield
    finally:
        lock.release()
