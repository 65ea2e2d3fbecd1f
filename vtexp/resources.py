"""Where shipped resources (device profiles, codings, experiments, firmware) live.

In a source checkout or an editable install they are the top-level
``protocols/``, ``experiments/`` and ``firmware/`` folders; a wheel carries copies
under ``vtexp/_shipped/``. ``VTEXP_PROTOCOLS`` overrides the protocols folder.
"""

from __future__ import annotations

import os
from pathlib import Path

_PKG = Path(__file__).resolve().parent


def _first_existing(*candidates: Path) -> Path:
    for c in candidates:
        if c.is_dir():
            return c
    return candidates[0]


def protocols_dir() -> Path:
    env = os.environ.get("VTEXP_PROTOCOLS")
    if env:
        return Path(env)
    return _first_existing(_PKG / "_shipped" / "protocols", _PKG.parent / "protocols")


def experiments_dir() -> Path:
    return _first_existing(_PKG / "_shipped" / "experiments", _PKG.parent / "experiments")


def devices_dir() -> Path:
    return protocols_dir() / "devices"


def codings_dir() -> Path:
    """Coding-protocol files (``protocols/codings/NAME.yaml``), named by an experiment's
    ``coding: {ref: NAME}``."""
    return protocols_dir() / "codings"


def firmware_dir() -> Path:
    """The reference firmware's sources (``firmware/``: C, a Makefile)."""
    return _first_existing(_PKG / "_shipped" / "firmware", _PKG.parent / "firmware")
