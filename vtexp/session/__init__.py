"""Sessions: a plan of steps, an engine that plays, asks and emits records, and the
consumers of those records (the BIDS writer first).

::

    run_session(lx, device, responder, SessionOptions(...), consumers=(...))
      options.check_run   every check of the run, before anything is written or opened
      BidsWriter.open     a new session made, or one resumed: "my log holds N trials"
      plan.session_plan   the steps from trial N+1: Instructions, RunTrial | StoppedTrial,
                          Wait, Break, End (an adaptive track learns each trial's answer)
      engine.Engine       carries out each step and emits records.SessionStarted,
                          TrialStarted, PlayStarted, Answered, TrialDone, DevicePaused,
                          DeviceResumed, SessionEnded to the writer, the responder's
                          screens, then every other consumer (progress line, markers)

=================  ==============================================================
module             owns
=================  ==============================================================
``options``        :class:`SessionOptions`, :func:`check_run` (the early refusals)
``plan``           the steps and :func:`session_plan`
``engine``         :func:`run_session`, :class:`Engine`: play, ask, device faults
``records``        the record types; :func:`trial_rows`, the one maker of trial rows
``bids_writer``    :class:`BidsWriter`: the session's files, written from records
``resume``         reopening a session: its checks and what it rebuilds
``files``          the logs' columns, the sidecars, the session record's content
``store``          the sessions in a data folder: listed, read, marked when dead
``paths``          participant and session ids, :class:`SessionPaths`
``camera``         what camera trials need from the session
=================  ==============================================================

Every data folder is a BIDS dataset (:mod:`vtexp.bids`), one per experiment; a
session writes its BIDS files in ``sub-<P>/ses-<N>/beh/`` and vtexp's own record
in ``sourcedata/vtexp/sub-<P>/ses-<N>/``, where BIDS leaves room for it::

    DATA/<experiment>/
        dataset_description.json  README.md  participants.tsv  participants.json
        sub-<P>/ses-<N>/beh/
            sub-<P>_ses-<N>_task-<T>_beh.tsv      one row per trial and question (append + fsync)
            sub-<P>_ses-<N>_task-<T>_beh.json     every column described, TaskName, Instructions
            sub-<P>_ses-<N>_task-<T>_events.tsv   every pulse the device reported playing
                                                  (onset, duration in seconds first)
            sub-<P>_ses-<N>_task-<T>_events.json  every column described
        sourcedata/vtexp/sub-<P>/ses-<N>/
            sub-<P>_ses-<N>_task-<T>_session.json what produced the session, how it ended
            session.lock                          held while the session runs
            stim/                                 camera frames (camera stimuli)

The session record (``..._session.json``) is written with status ``running`` before
the first trial and rewritten at the end with the status (``completed``,
``aborted``, ``failed``), the end time and the SHA-256 of each file; a session
whose process died is marked ``interrupted`` by the next run that finds it
(:func:`mark_dead_sessions`).

A session exists when its record folder does. The record folder is made whole in a
hidden staging folder (``.ses-N.staging-PID``, holding the record and the lock) and
renamed into place, so a run killed while starting leaves either no session or one
that resumes; the BIDS files follow, each created exclusively, and a resume rebuilds
any that a kill left missing or cut short. The participant's row of
``participants.tsv`` is written before the participant's folder appears. While a
session runs, its ``session.lock`` is held (:mod:`vtexp.lock`): a second run of
the same session is refused, naming the process that holds it. Nothing is ever
overwritten.

An experiment with camera stimuli (``camera: N``, ``video: FILE``) also keeps the
frame taken at each such trial in the record folder's ``stim/`` (and a live trial's
record), named in the trial log's ``stim_file`` column (``vtexp.live.trial``).

Data folders of vtexp before the BIDS layout (``sub-<P>/ses-<N>/session.json``
beside the logs) are still read by :mod:`vtexp.analysis.load`; sessions are not
added to them.
"""

from __future__ import annotations

from .bids_writer import BidsWriter
from .engine import Engine, ResponderScreens, SessionResult, run_session
from .files import (EVENT_COLUMNS, FORMAT_VERSION, environment, events_sidecar, exact_level,
                    has_camera, log_columns, sidecar, task_fields, trial_columns)
from .options import DeviceFaultHandler, SessionOptions, SessionSetup, check_run
from .paths import (PARTICIPANT, SIMULATED_PREFIX, SessionPaths, check_participant,
                    check_participant_kind, check_session, device_kind, participant_kind)
from .plan import (Break, End, Instructions, RunTrial, Step, StoppedTrial, Wait,
                   session_plan)
from .records import (Answered, Consumer, DevicePaused, DeviceResumed, PlayStarted, Record,
                      SessionEnded, SessionStarted, TrialDone, TrialStarted, trial_rows)
from .store import legacy_sessions, list_sessions, mark_dead_sessions, record_of, recorded_run

__all__ = [
    "Answered", "BidsWriter", "Break", "Consumer", "DeviceFaultHandler", "DevicePaused",
    "DeviceResumed", "EVENT_COLUMNS", "End", "Engine", "FORMAT_VERSION", "Instructions",
    "PARTICIPANT", "PlayStarted", "Record", "ResponderScreens", "RunTrial",
    "SIMULATED_PREFIX", "SessionEnded", "SessionOptions", "SessionPaths", "SessionResult",
    "SessionSetup", "SessionStarted", "Step", "StoppedTrial", "TrialDone", "TrialStarted",
    "Wait", "check_participant", "check_participant_kind", "check_run", "check_session",
    "device_kind", "environment", "events_sidecar", "exact_level", "has_camera",
    "legacy_sessions", "list_sessions", "log_columns", "mark_dead_sessions",
    "participant_kind", "record_of", "recorded_run", "run_session", "session_plan",
    "sidecar", "task_fields", "trial_columns", "trial_rows",
]
