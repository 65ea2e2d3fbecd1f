"""Printing for the command line: results on stdout, one-line errors on stderr."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path


def out(msg: str = "") -> None:
    """A line of the command's output (flushed, so that it shows before a prompt)."""
    print(msg, flush=True)


def err(msg: str) -> None:
    """An error as vtexp reports it: one line on stderr, no traceback."""
    print(f"vtexp: error: {msg}", file=sys.stderr, flush=True)


def note(msg: str) -> None:
    """Something accepted that the user should hear about: one line on stderr."""
    print(f"vtexp: note: {msg}", file=sys.stderr, flush=True)


def quote(arg: str) -> str:
    """``arg`` as a command line to paste: for a POSIX shell, or for Windows' ``cmd.exe``
    (which does not read single quotes)."""
    if sys.platform == "win32":
        import subprocess
        return subprocess.list2cmdline([arg])
    import shlex
    return shlex.quote(arg)


def program() -> str:
    """How to call vtexp again from any folder, the way it was called this time.

    ``vtexp`` if that is the command found on PATH, else the script's full path;
    ``python -m vtexp`` with this interpreter's full path when run that way.
    """
    argv0 = Path(sys.argv[0]) if sys.argv and sys.argv[0] else None
    if argv0 is None or argv0.name in ("__main__.py", "-c") or argv0.suffix == ".py":
        return f"{quote(sys.executable)} -m vtexp"
    found = shutil.which("vtexp")
    try:
        if found and Path(found).resolve() == argv0.resolve():
            return "vtexp"
    except OSError:
        pass
    return quote(str(argv0.resolve())) if argv0.exists() else \
        f"{quote(sys.executable)} -m vtexp"
