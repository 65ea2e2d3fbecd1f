"""A session run in a child process, slowed down so that a test can kill it mid-way.

Usage: python session_child.py EXPERIMENT DATA PARTICIPANT DELAY_S [resume]
Prints "logged N" after trial N is on disk.
"""

import sys
import time

from vtexp.devices import open_device
from vtexp.experiment import load_experiment
from vtexp.model import DeviceProfile
from vtexp.responders import make_responder
from vtexp.session import SessionOptions, TrialDone, run_session

exp_path, data, participant, delay = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4])
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
            print(f"logged {rec.trial}", flush=True)


with open_device("sim", DeviceProfile.load(lx.experiment.device)) as dev:
    run_session(lx, dev, responder,
                SessionOptions(participant=participant, data_dir=data,
                               resume=len(sys.argv) > 5 and sys.argv[5] == "resume"),
                consumers=(announce,))
print("done", flush=True)
