"""Resuming a session: whether its record allows it, and reopening its files.

What a run killed at any instant can leave is rebuilt from what exists: a session.json
that is missing or unreadable (from its staged copy, else anew from the experiment,
noted under ``rebuilt``), a missing sidecar, a trial or events log that is missing or
was cut off in its header. A trial log's rows are never invented: a log of events with
no trial log to match is refused. A row cut off mid-write, the rows of a trial cut short
between its questions and the events of a trial without its rows are removed; what
remains must be exactly the planned trials, in order (an adaptive session's levels
exactly what its procedure proposes from the answers before them).
"""

from __future__ import annotations

import sys
from pathlib import Path

from ..clock import Clock, iso
from ..errors import SessionError
from ..log import TsvLog, tmp_name, write_json_atomic
from .files import EVENT_COLUMNS, events_sidecar, log_columns, new_record, process, sidecar
from .paths import device_kind
from .store import read_record


def check_resumable(record: dict, setup, backend: str | None) -> None:
    """Refuse to continue the session of ``record`` with this run (``setup``: a
    :class:`~vtexp.session.options.SessionSetup`) on a device of ``backend`` (None: not
    known yet) if the experiment, the coding, the trial list, the kind of device or the
    kind of participant is not the one it started with, or if it is complete."""
    paths, lx = setup.paths, setup.lx
    if record.get("status") == "completed":
        raise SessionError(f"session in {paths.dir} is already completed; nothing to resume")
    if record.get("experiment_file", {}).get("sha256") != lx.sha256:
        raise SessionError(f"the experiment file {lx.path} is not the one session {paths.dir} "
                           "started with (its SHA-256 differs); resume with that file, or "
                           "start a new session")
    was = ((record.get("experiment_loaded") or {}).get("coding") or {}).get("source") or {}
    now = lx.experiment.coding.model_dump(mode="json").get("source") or {}
    if was.get("sha256") != now.get("sha256"):
        raise SessionError(f"the coding file {now.get('file') or was.get('file')} is not the one "
                           f"session {paths.dir} started with (its SHA-256 differs); restore "
                           "it, or start a new session")
    if record.get("seed") != setup.seed or record.get("trial_order") != \
            [t.condition.index for t in setup.trials]:
        raise SessionError(f"the trial list of {paths.dir} cannot be rebuilt (seed or order "
                           "differ); it cannot be resumed")
    if backend is not None:
        _check_device_kind(record, setup, backend)
    was_kind, kind = record.get("participant_kind"), setup.run_info["participant_kind"]
    if was_kind and was_kind != kind and "model" in (was_kind, kind):
        raise SessionError(f"session {paths.dir} was answered by a {was_kind}, and cannot be "
                           f"continued by a {kind}; start a new session")


def _recorded_device(record: dict) -> str | None:
    return record.get("device_spec") or (record.get("device") or {}).get("backend")


def _check_device_kind(record: dict, setup, backend: str) -> None:
    recorded = _recorded_device(record)
    if device_kind(recorded) == backend or setup.options.force_device:
        return
    given = setup.run_info["device_spec"]
    raise SessionError(
        f"session {setup.paths.dir} ran on {recorded} ({_device_words(record.get('device'))}), "
        f"but the device given is {given} ({backend}): the participant would "
        f"{_what_they_feel(backend)}. Resume on a {device_kind(recorded)} device (--device "
        f"{_device_hint(recorded)}), or add --force-device to continue on {given} anyway.")


def _device_words(info: dict | None) -> str:
    info = info or {}
    backend = info.get("backend", "?")
    if backend == "serial":
        return (f"a tactile array on {info.get('port') or 'a serial port'}, firmware "
                f"{info.get('firmware') or '?'}")
    return {"sim": "the simulator, which drives nothing", "emulator":
            "the emulator, which drives nothing"}.get(backend, backend)


def _what_they_feel(backend: str) -> str:
    return ("feel nothing" if backend in ("sim", "emulator")
            else "feel a device the session did not start on")


def _device_hint(recorded: str | None) -> str:
    return recorded if device_kind(recorded) != "serial" or ":" in (recorded or "") \
        else "serial:PORT"


def reopen(setup, info, responder, clock: Clock) -> tuple[dict, TsvLog, TsvLog, int]:
    """Check that the session can be resumed (under its lock, with the device open:
    ``info``) and reopen its logs; return its record, the logs, and how many trials it
    holds."""
    paths = setup.paths
    rebuilt: list[str] = []
    record = _record_or_rebuilt(setup, info, responder, clock, rebuilt)
    check_resumable(record, setup, info.backend)
    _rebuild_files(setup, rebuilt)
    beh, done, cut_beh = _reopen_trials(setup, record)
    try:
        events, erows, cut_ev = TsvLog.reopen(paths.events_tsv, EVENT_COLUMNS)
    except BaseException:
        beh.close()
        raise
    keep = sum(1 for r in erows if int(r[EVENT_COLUMNS.index("trial")]) <= done)
    if keep < len(erows):
        events.truncate_rows(keep)          # events of the trial that was cut short
    removed = {"beh_bytes": cut_beh, "event_rows": len(erows) - keep, "event_bytes": cut_ev}
    _note_resume(record, setup, info, done, removed, rebuilt, clock)
    write_json_atomic(paths.session_json, record)
    return record, beh, events, done


def _record_or_rebuilt(setup, info, responder, clock: Clock, rebuilt: list[str]) -> dict:
    """The session record as it stands, or made anew from the experiment (noted)."""
    paths = setup.paths
    record = read_record(paths)
    for f in (paths.beh_json, paths.events_json):      # a sidecar's write cut short
        tmp_name(f).unlink(missing_ok=True)
    if record is None:
        record = new_record(setup, info, responder, clock)
        record["started_at"] = None                 # not known any more
        rebuilt.append(f"{paths.session_json.name} (missing or unreadable; made anew from the "
                       "experiment)")
    tmp_name(paths.session_json).unlink(missing_ok=True)
    return record


def _rebuild_files(setup, rebuilt: list[str]) -> None:
    """Sidecars that are missing, logs that are missing or cut off in their header."""
    paths, lx = setup.paths, setup.lx
    paths.dir.mkdir(parents=True, exist_ok=True)
    if not paths.beh_json.is_file():
        write_json_atomic(paths.beh_json, sidecar(lx))
        rebuilt.append(paths.beh_json.name)
    if not paths.events_json.is_file():
        write_json_atomic(paths.events_json, events_sidecar(lx))
        rebuilt.append(paths.events_json.name)
    if _needs_header(paths.beh_tsv):
        if _has_rows(paths.events_tsv):
            raise SessionError(f"{paths.beh_tsv} is missing but {paths.events_tsv.name} holds "
                               "played trials: the answers are lost and the session cannot be "
                               "resumed; start a new session (the folder is left as it is)")
        _write_header(paths.beh_tsv, log_columns(lx))
        rebuilt.append(paths.beh_tsv.name)
    if _needs_header(paths.events_tsv):
        _write_header(paths.events_tsv, EVENT_COLUMNS)
        rebuilt.append(paths.events_tsv.name)


def _reopen_trials(setup, record: dict) -> tuple[TsvLog, int, int]:
    """The trial log reopened: its rows checked against the plan (and an adaptive
    procedure), a trial cut short between its questions removed. Returns the log, the
    trials it holds and the bytes of a cut-off row removed."""
    paths, exp = setup.paths, setup.lx.experiment
    cols = log_columns(setup.lx)
    beh, rows, cut = TsvLog.reopen(paths.beh_tsv, cols)
    per_trial = len(exp.asked())          # one row per question
    try:
        _check_rows(setup, rows, cols, per_trial)
        done = len(rows) // per_trial
        if setup.adaptive is not None:
            _check_adaptive(setup, rows[:done * per_trial], cols,
                            exact=record.get("adaptive_levels") == "exact")
    except BaseException:
        beh.close()
        raise
    if len(rows) % per_trial:                        # a trial cut short between questions
        beh.truncate_rows(done * per_trial)
    return beh, done, cut


def _check_rows(setup, rows: list[list[str]], cols: list[str], per_trial: int) -> None:
    trials, factors = setup.trials, list(setup.lx.experiment.factors)
    for i, row in enumerate(rows):
        k = i // per_trial + 1
        t = trials[k - 1] if k <= len(trials) else None
        if t is None or row[cols.index("trial")] != str(k) or \
                any(row[cols.index(f)] != t.levels[f] for f in factors):
            raise SessionError(f"row {i + 1} of {setup.paths.beh_tsv} does not match the "
                               f"planned trial {k}; the log cannot be resumed")


def _check_adaptive(setup, rows: list[list[str]], cols: list[str], exact: bool) -> None:
    """Replay the logged answers through the procedure (which so learns them); refused,
    with no hint to resume, at the first row whose level it would not have proposed.
    ``exact``: the log holds every digit; else (older sessions) 6 decimals."""
    adaptive = setup.adaptive
    for i, row in enumerate(rows):
        d = dict(zip(cols, row, strict=False))
        if d.get("question") != adaptive.question:
            continue
        trial = setup.trials[int(d["trial"]) - 1]
        problem = adaptive.replay(trial, d, exact=exact)
        if problem:
            refusal = SessionError(
                f"{setup.paths.beh_tsv}: row {i + 1} (trial {trial.number}): {problem}. The "
                "log does not follow from the answers it holds (it was changed, or the "
                "experiment's procedure differs), so the session cannot be resumed; start a "
                "new session (the folder is left as it is)")
            refusal.final = True                 # no "to continue it" hint after this
            raise refusal


def _note_resume(record: dict, setup, info, done: int, removed: dict, rebuilt: list[str],
                 clock: Clock) -> None:
    """The record says running again, and lists this resume."""
    recorded, run_info = _recorded_device(record), setup.run_info
    record.setdefault("resumes", []).append({
        "at": iso(clock), "trials_done": done, "device": info.model_dump(mode="json"),
        "device_spec": run_info["device_spec"], "responder_spec": run_info["responder_spec"],
        "forced_device": bool(setup.options.force_device and
                              device_kind(recorded) != info.backend),
        "process": process(), "command": setup.options.command or sys.argv,
        "removed": removed, "rebuilt": rebuilt,
        "previous_status": record.get("status"), "previous_reason": record.get("reason")})
    record.update(status="running", reason=None, ended_at=None, checksums=None,
                  n_trials_logged=done, process=process())
    for key in ("device_spec", "responder_spec", "data_dir", "participant_kind"):
        if run_info.get(key) is not None:
            record[key] = run_info[key]


def _needs_header(path: Path) -> bool:
    """A log that is missing, or was created and cut off before its header was whole."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return True
    return b"\n" not in data


def _has_rows(path: Path) -> bool:
    try:
        return path.read_bytes().count(b"\n") > 1
    except OSError:
        return False


def _write_header(path: Path, columns: list[str]) -> None:
    path.unlink(missing_ok=True)
    TsvLog(path, columns).close()
