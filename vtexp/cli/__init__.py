"""The ``vtexp`` command line: one module per command group.

=====================  ==================================================
module                 commands
=====================  ==================================================
``experiment``         ``validate``, ``schema``, ``plan``
``run``                ``run`` (the experimenter's prompts: ``prompts``)
``analyze``            ``analyze``
``stats``              ``stats ...`` on any tidy table
``demo``               ``demo``
``simulate``           ``simulate``
``observer``           ``observer fit``
``encode``             ``encode``
``device``             ``device list|check|monitor|emulate``
``live``               ``live`` (a camera felt live), ``live-replay``
``firmware``           ``firmware build|flash|vectors``
=====================  ==================================================

Each module has a ``register(sub)`` that adds its parsers, and imports what a
command needs only when it runs, so that ``vtexp --help`` stays fast. Imports go
one way: this package uses the rest of vtexp, nothing in vtexp imports it.

Every input mistake ends in one message on stderr naming the file, line and
key (no traceback) and a non-zero exit status: 2 for bad input, 3 for device
faults, 4 for a broken installation, 130 when interrupted.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys

from .. import __version__
from ..errors import VtexpError
from . import (analyze, demo, device, encode, experiment, firmware, live, observer, run,
               simulate, stats)
from ._io import err

#: The command groups, in the order ``vtexp --help`` lists them.
GROUPS = (experiment, run, analyze, stats, encode, live, device, firmware, demo, simulate,
          observer)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="vtexp", description="Psychophysics experiments on tactile shape displays.")
    p.add_argument("--version", action="version", version=f"vtexp {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for group in GROUPS:
        group.register(sub)
    return p


def _sigterm(signum, frame):
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    signal.signal(signal.SIGTERM, _sigterm)     # turn the actuators off on 'kill' too
    if hasattr(signal, "SIGBREAK"):             # Windows: Ctrl-Break would end us at once
        signal.signal(signal.SIGBREAK, _sigterm)
    try:
        return args.func(args)
    except VtexpError as e:
        err(str(e))
        if not getattr(e, "final", False):      # e.g. a log that cannot be resumed
            _after_error(args)
        return e.exit_code
    except KeyboardInterrupt:
        err("interrupted; every actuator was turned off and completed trials are kept")
        _after_error(args)
        return 130
    except BrokenPipeError:                     # e.g. 'vtexp plan ... | head'
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except BaseException:                       # a bug: its traceback, and how to go on
        _after_error(args)
        raise


def _after_error(args) -> None:
    """What a command set to say after it failed (``vtexp run``: how to continue)."""
    hint = getattr(args, "after_error", None)
    try:
        text = hint() if callable(hint) else None
    except Exception:           # the hint must never hide the error itself
        text = None
    if text:
        print(text, file=sys.stderr, flush=True)


if __name__ == "__main__":
    sys.exit(main())
