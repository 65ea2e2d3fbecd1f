"""A session run in a child process, slowed down so that a test can kill it mid-way.

Usage: python session_child.py EXPERIMENT DATA PARTICIPANT DELAY_S [resume]
Prints "logged N" after trial N is on disk, and "done" at the end.

The tests start it with :func:`forked.start` (tests/forked.py): a process forked from
one that has vtexp imported already, so that each of the many runs a kill test makes
does not import vtexp again; ``main`` is what both ways run.
"""

from __future__ import annotations

import sys
import time
from typing import Callable

from vtexp.devices import open_device
from vtexp.experiment import load_experiment
from vtexp.model import DeviceProfile
from vtexp.responders import make_responder
from vtexp.session import SessionOptions, TrialDone, run_session


def main(argv: list[str], say: Callable[[str], None]) -> None:
    exp_path, data, participant, delay = argv[0], argv[1], argv[2], float(argv[3])
    lx = load_experiment(exp_path)
    responder = make_responder("scripted:accuracy=0.75", participant, 1)
    inner = responder.ask

    def slow_ask(q, t, replay):
        time.sleep(delay)
        return inner(q, t, replay)

    responder.ask = slow_ask

    def announce(record):
        if isinstance(record, TrialDone):
            for rec in record.rows:
                say(f"logged {rec.trial}")

    with open_device("sim", DeviceProfile.load(lx.experiment.device)) as dev:
        run_session(lx, dev, responder,
                    SessionOptions(participant=participant, data_dir=data,
                                   resume=len(argv) > 4 and argv[4] == "resume"),
                    consumers=(announce,))
    say("done")


if __name__ == "__main__":
    main(sys.argv[1:], lambda line: print(line, flush=True))
