"""The sessions already in a data folder: listed, read, and marked when their process died.

Reads session records (``..._session.json``) and probes locks; the one thing it writes is
the status ``interrupted`` of a session whose process died (:func:`mark_dead_sessions`).
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

from .. import bids
from ..clock import REAL, Clock, iso
from ..errors import SessionError
from ..lock import LOCK_NAME, SessionBusy, SessionLock
from ..log import tmp_name, write_json_atomic
from .paths import SessionPaths


def record_of(folder: Path) -> Path | None:
    """The session record in a record folder (``*_session.json``), or None."""
    found = sorted(Path(folder).glob("*_session.json")) if Path(folder).is_dir() else []
    return found[0] if found else None


def legacy_sessions(root: Path | str) -> list[Path]:
    """Sessions in the layout of vtexp before BIDS (``sub-*/ses-*/session.json``)."""
    return sorted(Path(root).glob("sub-*/ses-*/session.json"))


def read_record(paths: SessionPaths) -> dict | None:
    """session.json, or its staged copy left by a write cut short; None if neither reads."""
    for f in (paths.session_json, tmp_name(paths.session_json)):
        try:
            data = json.loads(f.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        if isinstance(data, dict) and data.get("format") == "vtexp-session":
            return data
    return None


def _read_json(path: Path | None) -> dict:
    try:
        meta = json.loads(path.read_text(encoding="utf-8")) if path else {}
    except (OSError, ValueError):
        meta = {}
    return meta if isinstance(meta, dict) else {}


def list_sessions(data, experiment: str, participant: str) -> list[dict]:
    """The sessions of ``participant`` already in the data folder, by number: each a dict
    with ``session``, ``status`` (from the session record, or ``unreadable``), ``logged``,
    ``planned``, ``started`` and ``reason``."""
    found = []
    root = Path(data) / experiment
    folder = root / bids.SOURCE / f"sub-{participant}"
    old = [(sj.parent, sj) for sj in root.glob(f"sub-{participant}/ses-*/session.json")]
    for d, record in [(d, record_of(d)) for d in (folder.glob("ses-*") if folder.is_dir()
                                                   else ())] + old:
        m = re.fullmatch(r"ses-(\d+)", d.name)
        if not (m and d.is_dir()):
            continue
        meta = _read_json(record)
        found.append({"session": int(m[1]), "status": meta.get("status") or "unreadable",
                      "logged": meta.get("n_trials_logged"),
                      "planned": meta.get("n_trials_planned"),
                      "started": meta.get("started_at") or "", "reason": meta.get("reason"),
                      "device": meta.get("device_spec") or (meta.get("device") or {}).get(
                          "backend"),
                      "responder": meta.get("responder_spec"),
                      "held_by": SessionLock.probe(d) if (d / LOCK_NAME).exists() else None})
    return sorted(found, key=lambda x: x["session"])


def _remove_dead_staging(source: Path) -> None:
    """Staging folders left by a run killed while starting (no trial was played)."""
    for staging in source.glob("sub-*/.ses-*.staging-*"):
        try:
            lock = SessionLock.acquire(staging)
        except SessionError:
            continue                        # still being made by a live run
        lock.release()
        shutil.rmtree(staging, ignore_errors=True)


def _mark_if_dead(sj: Path, clock: Clock) -> dict | None:
    """Mark the session of record ``sj`` interrupted if it says running and no one holds
    its lock; what was marked, or None."""
    d = sj.parent
    try:
        lock = SessionLock.acquire(d)
    except (SessionBusy, SessionError):
        return None                         # really running, in another process
    try:
        meta = _read_json(sj)               # read again, under the lock
        if meta.get("status") != "running":
            return None
        who = lock.stale or meta.get("process") or {}
        reason = ("the vtexp process that ran it"
                  + (f" (pid {who['pid']} on {who.get('host', '?')})" if who.get("pid") else "")
                  + " ended without closing it: killed, crashed or the power failed; "
                  f"found at {iso(clock)[:19].replace('T', ' ')}")
        logged = _trials_in_log(d, meta)
        if logged is not None:                # the record counts only what a run closed
            meta["n_trials_logged"] = logged
        meta.update(status="interrupted", reason=reason)
        write_json_atomic(sj, meta)
        return {"participant": meta.get("participant"), "session": meta.get("session"),
                "logged": meta.get("n_trials_logged"), "planned": meta.get("n_trials_planned"),
                "dir": d, "record": sj, "reason": reason}
    finally:
        lock.release()


def _trials_in_log(record_dir: Path, meta: dict) -> int | None:
    """The whole trials the trial log of a session holds, counted as a resume counts them
    (complete rows, one per question asked; a trial cut short between its questions is not
    one); None if the log cannot be found or read."""
    exp = meta.get("experiment_loaded")
    if not isinstance(exp, dict):
        return None
    asked = 1 if exp.get("question") is not None else len(exp.get("questions") or [])
    ses, sub = record_dir.name, record_dir.parent.name
    if record_dir.parents[1].parts[-2:] == bids.SOURCE.parts:
        beh_dir = record_dir.parents[3] / sub / ses / "beh"
    else:                                   # the layout before BIDS: the log beside it
        beh_dir = record_dir
    logs = sorted(beh_dir.glob("*_beh.tsv"))
    if not logs or asked < 1:
        return None
    try:
        lines = logs[0].read_bytes().split(b"\n")[1:-1]   # after the header, whole lines
    except OSError:
        return None
    return sum(1 for ln in lines if ln.strip()) // asked


def mark_dead_sessions(data, experiment: str, clock: Clock = REAL) -> list[dict]:
    """Sessions of ``experiment`` that say ``running`` but whose process has died (no one
    holds their lock) are marked ``interrupted``; staging folders left by a run killed
    while starting (no trial was played) are removed. Returns what was marked: dicts with
    ``participant``, ``session``, ``logged``, ``planned``, ``dir`` (the record folder),
    ``record`` (the record file), ``reason``."""
    source = Path(data) / experiment / bids.SOURCE
    if not source.is_dir():
        return []
    _remove_dead_staging(source)
    marked = []
    for sj in sorted(source.glob("sub-*/ses-*/*_session.json")):
        try:
            meta = json.loads(sj.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        if isinstance(meta, dict) and meta.get("status") == "running":
            found = _mark_if_dead(sj, clock)
            if found is not None:
                marked.append(found)
    return marked


def recorded_run(where) -> dict:
    """How a session was run, from its record: ``device`` (the --device spec, or the
    backend for sessions recorded before specs were), ``responder`` (the --responder spec,
    or None), ``data`` (the data folder), ``participant_kind``. Empty if unreadable.
    ``where`` is a :class:`SessionPaths`, a record file or a record folder."""
    if isinstance(where, SessionPaths):
        record = where.session_json
    else:
        where = Path(where)
        record = where if where.is_file() else (record_of(where) or where / "session.json")
    try:
        meta = json.loads(record.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    if not isinstance(meta, dict):
        return {}
    return {"device": meta.get("device_spec") or (meta.get("device") or {}).get("backend"),
            "device_info": meta.get("device") or {},
            "responder": meta.get("responder_spec"),
            "data": meta.get("data_dir"), "participant_kind": meta.get("participant_kind"),
            "status": meta.get("status")}


def refuse_existing(paths: SessionPaths, who: str):
    """A new session whose record folder exists: running now elsewhere, or to resume."""
    holder = SessionLock.probe(paths.record_dir)
    if holder is not None:
        from ..lock import describe_holder
        raise SessionBusy(f"{who} is running now in another vtexp process "
                          f"({describe_holder(holder)}); nothing was touched.", holder)
    raise SessionError(f"{who} already exists in {paths.root}; nothing was overwritten. "
                       "Use --resume to continue it, or another --session number.")


def check_new_place(paths: SessionPaths, who: str) -> None:
    """Nothing of a new session may exist yet: neither its record nor its BIDS folder."""
    if paths.record_dir.exists():
        refuse_existing(paths, who)
    if paths.dir.parent.exists():
        raise SessionError(f"{paths.dir.parent} exists but vtexp has no record of it "
                           f"(expected {paths.session_json}); nothing was overwritten. Use "
                           "another --session number, or move that folder away")


def check_resume_place(paths: SessionPaths, who: str) -> None:
    """A session to resume exists: its record folder does."""
    rd = paths.record_dir
    if not rd.is_dir():
        raise SessionError(f"there is no {who} in {paths.root} to resume"
                           + (" (a run was stopped while creating it, before any trial; "
                              "start it without --resume)"
                              if list(rd.parent.glob(f".{rd.name}.staging-*")) else ""))
