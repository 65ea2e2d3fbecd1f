"""Crash-safe files: append-only TSV logs and atomically replaced JSON.

Each TSV row is written with a single ``write`` and ``fsync``'d before the
next trial starts, so a killed process (SIGKILL, power cut after the fsync)
loses no completed trial; at worst the row being written is cut short, which
readers detect (no final newline) and report. JSON records are replaced
atomically (write to a temporary file, fsync, rename, fsync the folder).

Files are written in binary with ``\n`` line ends on every platform (on Windows a file
opened without ``O_BINARY`` would turn them into ``\r\n``), so a session's files are
the same bytes wherever it ran.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from pathlib import Path
from typing import Any
from collections.abc import Iterable

from .errors import SessionError

NA = "n/a"   # BIDS's marker for a missing value
_BINARY = getattr(os, "O_BINARY", 0)     # Windows: no newline translation


def fsync_dir(path: Path) -> None:
    """Make the names in folder ``path`` (a file created or renamed there) durable.

    Windows cannot open a folder as a file to flush it; NTFS writes a rename to its
    metadata journal, so after a crash the name is either the old file or the new one,
    whole. There this does nothing.
    """
    if os.name == "nt":
        return
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def format_value(v: Any) -> str:
    t = type(v)                 # the common cases first: a trial writes hundreds of values
    if t is float:
        return NA if v != v else repr(round(v, 6))
    if t is int:
        return str(v)
    if t is str and "\t" not in v and "\n" not in v and "\r" not in v:
        return v
    if v is None:
        return NA
    if isinstance(v, bool):
        return "1" if v else "0"
    if isinstance(v, float):
        if math.isnan(v):
            return NA
        return repr(float(round(v, 6)))     # a numpy float as a Python float
    s = str(v)
    # A tab or newline inside a value would shift columns or split the row.
    return s.replace("\t", " ").replace("\r", " ").replace("\n", " ")


class TsvLog:
    """An append-only TSV file, created exclusively; every row fsync'd."""

    def __init__(self, path: Path, columns: Iterable[str]):
        self.path = Path(path)
        self.columns = list(columns)
        try:
            self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_APPEND
                               | _BINARY, 0o644)
        except FileExistsError:
            raise SessionError(f"{self.path} already exists; nothing was overwritten") from None
        except OSError as e:
            raise SessionError(f"cannot create {self.path}: {e.strerror}") from None
        self._write("\t".join(self.columns) + "\n")
        fsync_dir(self.path.parent)

    @classmethod
    def reopen(cls, path: Path, columns: Iterable[str]) -> tuple["TsvLog", list[list[str]], int]:
        """Reopen an existing log to append to it (resuming a session).

        A last row cut off mid-write (no final newline) is removed first, so
        the next row starts on a line of its own. Returns the log, the complete
        rows already in it (as lists of strings) and the number of bytes removed.
        """
        path = Path(path)
        columns = list(columns)
        try:
            data = path.read_bytes()
        except OSError as e:
            raise SessionError(f"cannot read {path} to resume: {e.strerror}") from None
        cut = data.rfind(b"\n") + 1
        removed = len(data) - cut
        lines = data[:cut].decode("utf-8").split("\n")[:-1]
        if not lines or lines[0].split("\t") != columns:
            raise SessionError(f"{path} does not have the columns this experiment writes; "
                               "it cannot be resumed")
        log = cls.__new__(cls)
        log.path, log.columns = path, columns
        try:
            log._fd = os.open(path, os.O_WRONLY | os.O_APPEND | _BINARY)
            if removed:
                os.ftruncate(log._fd, cut)
                os.fsync(log._fd)
        except OSError as e:
            raise SessionError(f"cannot reopen {path}: {e.strerror}") from None
        return log, [ln.split("\t") for ln in lines[1:]], removed

    def truncate_rows(self, keep: int) -> None:
        """Keep the header and the first ``keep`` rows; drop the rest (fsync'd)."""
        data = self.path.read_bytes()
        pos = 0
        for _ in range(keep + 1):
            pos = data.index(b"\n", pos) + 1
        os.ftruncate(self._fd, pos)
        os.fsync(self._fd)

    def append(self, row: dict[str, Any]) -> None:
        unknown = set(row) - set(self.columns)
        if unknown:
            raise ValueError(f"columns not in the log: {sorted(unknown)}")
        self._write("\t".join(format_value(row.get(c)) for c in self.columns) + "\n")

    def append_many(self, rows: list[dict[str, Any]]) -> None:
        """Several rows with one ``write`` and one ``fsync`` (a live record's batch)."""
        if not rows:
            return
        unknown = set().union(*rows) - set(self.columns)
        if unknown:
            raise ValueError(f"columns not in the log: {sorted(unknown)}")
        self._write("".join("\t".join(format_value(r.get(c)) for c in self.columns) + "\n"
                            for r in rows))

    def _write(self, text: str) -> None:
        data = text.encode("utf-8")
        try:
            n = os.write(self._fd, data)
            if n != len(data):
                raise OSError(28, "short write (disk full?)")
            os.fsync(self._fd)
        except OSError as e:
            raise SessionError(f"cannot write to {self.path}: {e.strerror or e}; the session "
                               "stops here and every row written before is intact") from None

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def tmp_name(path: Path) -> Path:
    """Where :func:`write_json_atomic` stages ``path``: a hidden name, which BIDS ignores."""
    return path.with_name(f".{path.name}.tmp")


def write_json_atomic(path: Path, data: Any) -> None:
    path = Path(path)
    tmp = tmp_name(path)
    text = json.dumps(data, indent=2, ensure_ascii=False, default=str) + "\n"
    try:
        with open(tmp, "w", encoding="utf-8", newline="\n") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        replace_file(tmp, path)
        fsync_dir(path.parent)
    except OSError as e:
        raise SessionError(f"cannot write {path}: {e.strerror or e}") from None


def replace_file(src: Path, dst: Path) -> None:
    """``os.replace``; on Windows, tried again for up to a second while another program
    (a virus scanner, a reader of the record) has ``dst`` open, which Windows refuses."""
    if os.name != "nt":
        os.replace(src, dst)
        return
    import time
    deadline = time.monotonic() + 1.0
    while True:
        try:
            os.replace(src, dst)
            return
        except PermissionError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.02)


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 16), b""):
            h.update(chunk)
    return h.hexdigest()
