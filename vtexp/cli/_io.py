"""Printing for the command line: results on stdout, one-line errors on stderr."""

from __future__ import annotations

import sys


def out(msg: str = "") -> None:
    """A line of the command's output (flushed, so that it shows before a prompt)."""
    print(msg, flush=True)


def err(msg: str) -> None:
    """An error as vtexp reports it: one line on stderr, no traceback."""
    print(f"vtexp: error: {msg}", file=sys.stderr, flush=True)
