"""Finding, verifying and reading session folders into one tidy trial table.

What is tolerated and what is refused (decided for issue 6):

- a **checksum mismatch** (a file changed after the session ended) is reported
  prominently: a warning on stderr, ``SessionData.checksum = "MISMATCH"``, a
  red box at the top of the report; the data are still analysed, because the
  analyst may have a reason (e.g. an anonymised copy), unless
  ``load_sessions(strict=True)`` (``vtexp analyze --strict``) refuses them;
- a **last row cut off mid-write** (no final newline) is dropped and reported;
- a session that **did not close** (``running``: killed, crashed) or ended
  **aborted/failed** keeps every trial it logged, and is reported; its files
  have no checksums to verify (``checksum = "not recorded"``);
- a file or folder that is **not a vtexp log** is refused with a message
  saying what was expected (a session record of format ``vtexp-session`` and a
  trial log with ``trial`` and ``answer`` columns).

Both layouts are read (issue 14): the BIDS dataset vtexp writes now (the record
``sourcedata/vtexp/sub-P/ses-N/*_session.json`` names the files from the dataset's
root, ``sub-P/ses-N/beh/``) and the layout before it (``sub-P/ses-N/session.json``
beside the logs, names from that folder); ``vtexp.analysis.pool`` reads many
datasets at once through DuckDB into the same table.

Decided for issue 13:

- a trial logged **twice** (two runs of one session at once, before sessions
  were locked) is refused, naming the session and the trials, unless
  ``duplicates="first"`` (``vtexp analyze --drop-duplicates``) keeps the first
  row of each and reports the rest; duplicated device events are reported;
- **model participants** (and scripted answers) are never pooled with people:
  a mix is analysed as the people alone, the simulated sessions listed as left
  out, unless ``include_simulated`` (``vtexp analyze --include-simulated``);
  folders of simulated sessions alone are analysed as they are.
"""

from __future__ import annotations

import io
import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import InputError
from ..log import NA, sha256_file


@dataclass
class SessionData:
    dir: Path
    meta: dict
    trials: pd.DataFrame
    warnings: list[str] = field(default_factory=list)
    checksum: str = "verified"          # verified | MISMATCH | not recorded | file missing
    mismatched: list[str] = field(default_factory=list)
    duplicated_trials: list[int] = field(default_factory=list)
    root: Path | None = None            # the dataset (the experiment's data folder)
    record: Path | None = None          # the session record (session.json)

    @property
    def status(self) -> str:
        return str(self.meta.get("status"))

    @property
    def simulated(self) -> bool:
        """Answered by a model participant or a script, not a person."""
        kind = self.meta.get("participant_kind")
        if kind is not None:
            return kind != "person"
        responder = str(self.meta.get("responder") or "")     # sessions before issue 13
        return responder.startswith(("model observer", "scripted"))

    @property
    def factors(self) -> list[str]:
        return list(self.levels)

    @property
    def levels(self) -> dict[str, list[str]]:
        """Each factor's levels in the order the experiment declared them."""
        factors = self.meta.get("experiment_loaded", {}).get("factors", {})
        return {name: list(f["levels"]) for name, f in factors.items()}


#: Where vtexp keeps its session records in a BIDS dataset (vtexp.bids.SOURCE).
SOURCE_PARTS = ("sourcedata", "vtexp")
#: The newest session record this reads: vtexp.session.files.FORMAT_VERSION (kept equal by
#: a test; importing the session package here would import the engine).
READS_FORMAT_VERSION = 2

_SESSION_FILES = ("_beh.tsv", "_events.tsv", "_beh.json", "_events.json")


def _is_record(path: Path) -> bool:
    """A session record: ``session.json`` (the layout before BIDS) or
    ``sourcedata/vtexp/sub-P/ses-N/*_session.json``."""
    if path.name == "session.json":
        return True
    return (path.name.endswith("_session.json") and len(path.parents) >= 4
            and path.parents[3].name == SOURCE_PARTS[0] and path.parents[2].name == SOURCE_PARTS[1])


def _records_in(folder: Path) -> list[Path]:
    """The session records of a session folder of either layout, or []."""
    if (folder / "session.json").is_file():
        return [folder / "session.json"]
    own = sorted(f for f in folder.glob("*_session.json") if _is_record(f))
    if own:
        return own
    # A BIDS session folder (sub-P/ses-N or sub-P/ses-N/beh): its record in sourcedata/.
    ses = folder.parent if folder.name == "beh" else folder
    if ses.name.startswith("ses-") and ses.parent.name.startswith("sub-"):
        rec = ses.parents[1].joinpath(*SOURCE_PARTS, ses.parent.name, ses.name)
        return sorted(f for f in rec.glob("*_session.json") if _is_record(f))
    return []


def find_sessions(paths: list[Path | str]) -> list[Path]:
    """Session records at or below each path (a dataset, a folder of datasets, a session
    folder of either layout, or a record), sorted."""
    found: list[Path] = []
    for p in map(Path, paths):
        if not p.exists():
            raise InputError("no such file or folder", path=str(p))
        if p.is_file():
            if _is_record(p):
                found.append(p)
                continue
            if p.name.endswith(_SESSION_FILES):
                raise InputError("this is one file of a session; give the session folder "
                                 f"({p.parent}) so that it can be checked against its "
                                 "record", path=str(p))
            raise InputError("not a vtexp session folder (expected a BIDS dataset written by "
                             "vtexp, a folder holding such datasets, or session folders "
                             "holding session.json)", path=str(p))
        own = _records_in(p)
        if own:
            found.extend(own)
            continue
        # Hidden folders hold no session: a session being started is staged in one.
        found.extend(sorted(q for q in p.rglob("*session.json")
                            if _is_record(q) and not any(
                                part.startswith(".") for part in q.parent.relative_to(p).parts)))
    seen, out = set(), []
    for d in found:
        r = d.resolve()
        if r not in seen:
            seen.add(r)
            out.append(d)
    return out


def _check_fields(meta: dict, path: Path) -> None:
    """The fields of a session record the analysis reads, of the kinds vtexp writes them:
    refused naming the field otherwise (a record edited by hand, or by another program)."""
    def bad(key: str, what: str):
        shown = repr(meta[key])[:80] if key in meta else "missing"
        return InputError(f"the session record's {key} is {shown}, not {what} (written by "
                          "another program or edited by hand?)", path=str(path))

    for key, what in (("experiment", "an experiment's name"),
                      ("participant", "a participant id")):
        if key in meta and not (isinstance(meta[key], str) and meta[key].strip()):
            raise bad(key, what)
    ses = meta.get("session")
    if "session" in meta and not (type(ses) is int and ses >= 1
                                  or isinstance(ses, str) and ses.isdigit() and int(ses) >= 1):
        raise bad("session", "a session number")
    if not isinstance(meta.get("files"), dict) or not all(
            isinstance(v, str) for v in meta["files"].values()):
        raise bad("files", "a table of the session's files")
    if meta.get("checksums") is not None and not (isinstance(meta["checksums"], dict) and all(
            isinstance(k, str) and isinstance(v, str) for k, v in meta["checksums"].items())):
        raise bad("checksums", "a table of file checksums")
    loaded = meta.get("experiment_loaded")
    if not isinstance(loaded, dict):
        raise bad("experiment_loaded", "the experiment the session ran")
    if not isinstance(loaded.get("title"), str):
        raise bad("experiment_loaded", "the experiment the session ran (no title)")
    factors = loaded.get("factors", {})
    if not (isinstance(factors, dict) and all(isinstance(k, str) and isinstance(f, dict)
                                              for k, f in factors.items())):
        raise bad("experiment_loaded", "the experiment the session ran (its factors are not "
                  "a table of factors)")
    for name, f in factors.items():
        levels = f.get("levels")
        if not (isinstance(levels, (list, dict)) and levels
                and all(isinstance(v, str) for v in levels)):
            raise bad("experiment_loaded", f"the experiment the session ran (the levels of "
                      f"factor {name[:40]!r} are not a list of level names)")
    if not isinstance(loaded.get("analysis") or {}, dict):
        raise bad("experiment_loaded", "the experiment the session ran (its analysis: is not "
                  "a table)")
    planned = meta.get("n_trials_planned")
    if not (type(planned) is int and planned >= 0):
        raise bad("n_trials_planned", "the number of trials planned")


def read_record(path: Path | str) -> SessionData:
    """A session's record and what it says of its files (checksums verified); the trial
    table is left empty (:func:`read_session` and the pooled reader fill it)."""
    path = Path(path)
    if path.is_dir():
        records = _records_in(path)
        if len(records) != 1:
            raise InputError("not a vtexp session folder (expected session.json, or a BIDS "
                             "session folder whose record is in sourcedata/vtexp/)"
                             if not records else "holds several sessions' records; give one",
                             path=str(path))
        path = records[0]
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as e:     # ValueError: JSON, huge ints
        raise InputError(f"cannot read the session record: {e}", path=str(path)) from None
    except RecursionError:
        raise InputError("cannot read the session record: nested too deeply (a record is a "
                         "few levels deep)", path=str(path)) from None
    if not isinstance(meta, dict) or meta.get("format") != "vtexp-session":
        raise InputError("not a vtexp session record (no 'format: vtexp-session')",
                         path=str(path))
    version = meta.get("format_version", 1)
    if type(version) is not int or version < 1:
        raise InputError(f"the session record's format_version is {version!r}, not a version "
                         "number (edited by hand?)", path=str(path))
    if version > READS_FORMAT_VERSION:
        raise InputError(f"the session record is of format_version {version}, newer than this "
                         f"vtexp reads (up to {READS_FORMAT_VERSION}); analyse it with the "
                         "vtexp that wrote it, or a newer one", path=str(path))
    _check_fields(meta, path)
    bids = meta.get("layout") == "bids"
    # The record names files from the dataset's root (BIDS) or from its own folder (before).
    base = path.parents[4] if bids else path.parent
    warnings: list[str] = []
    try:
        beh = base / meta["files"]["beh"]
        for key in ("experiment", "participant", "session"):
            meta[key]
    except (KeyError, TypeError) as e:
        raise InputError(f"the session record lacks {e} (written by another program or "
                         "edited by hand?)", path=str(path)) from None
    d = beh.parent if bids else path.parent
    status = meta.get("status")
    if status == "running":
        warnings.append(f"{d}: the session did not close (process killed or crashed); "
                        "using the trials it logged")
    elif status != "completed":
        warnings.append(f"{d}: session {status}"
                        + (f" ({meta['reason']})" if meta.get("reason") else ""))
    if not beh.is_file():
        raise InputError("the trial log named in the session record is missing", path=str(beh))
    checksums = meta.get("checksums") or {}
    checksum = "verified" if checksums else "not recorded"
    mismatched: list[str] = []
    for name, digest in checksums.items():
        f = base / name
        if not f.is_file():
            warnings.append(f"{f}: listed in the session record but missing")
            checksum = "file missing" if checksum == "verified" else checksum
        elif sha256_file(f) != digest:
            warnings.append(f"{f}: changed since the session ended (checksum differs)")
            mismatched.append(str(f))
            checksum = "MISMATCH"
    root = path.parents[4] if bids else path.parents[2] if len(path.parents) > 2 else None
    return SessionData(d, meta, pd.DataFrame(), warnings, checksum, mismatched, root=root,
                       record=path)


def beh_path(s: SessionData) -> Path:
    base = s.record.parents[4] if s.meta.get("layout") == "bids" else s.record.parent
    return base / s.meta["files"]["beh"]


def events_path(s: SessionData) -> Path | None:
    name = str((s.meta.get("files") or {}).get("events", ""))
    if not name:
        return None
    base = s.record.parents[4] if s.meta.get("layout") == "bids" else s.record.parent
    return base / name


def _check_log_columns(df: pd.DataFrame, s: SessionData, beh: Path) -> None:
    """The factor columns the session record declares are in its trial log."""
    factors = s.meta.get("experiment_loaded", {}).get("factors", {})
    missing = [f for f in factors if f not in df.columns]
    if missing:
        raise InputError(f"the trial log lacks the column(s) {', '.join(map(repr, missing))} of "
                         "the factors its session record declares; the log was changed since "
                         "vtexp wrote it", path=str(beh))


def typed_trials(df: pd.DataFrame, s: SessionData) -> pd.DataFrame:
    """A trial log's rows (all strings, n/a missing) as the tidy table's columns: numbers
    typed, duplicates found, experiment/participant/session in front."""
    beh = beh_path(s)
    header = list(df.columns)
    if "trial" not in header or "answer" not in header:
        raise InputError("not a vtexp trial log (no 'trial' and 'answer' columns)", path=str(beh))
    df = df.copy()
    _check_log_columns(df, s, beh)
    for col in ("trial", "repetition", "replays", "n_pulses", "practice", "correct",
                "rt_s", "stimulus_onset_ms", "stimulus_duration_ms"):
        if col not in df.columns:
            continue
        raw = df[col]
        num = pd.to_numeric(raw, errors="coerce")
        bad = raw.notna() & (num.isna() | ~np.isfinite(num.astype(float)))
        whole = col in ("trial", "repetition", "replays", "n_pulses")
        if col in ("practice", "correct"):
            bad |= num.notna() & ~num.isin([0, 1])
        elif col == "trial":
            bad |= raw.isna() | (num.notna() & ((num < 1) | (num % 1 != 0)))
        elif whole:
            bad |= num.notna() & ((num < 0) | (num % 1 != 0))
        if bad.any():
            i = int(bad.to_numpy().argmax())
            what = {"practice": "0 or 1", "correct": "0, 1 or n/a", "trial": "a trial number"}
            if whole and col != "trial":
                what[col] = "a whole number or n/a"
            value = raw.iloc[i] if raw.notna().iloc[i] else "n/a"
            raise InputError(f"line {i + 2}: {col} is {value!r}, not "
                             f"{what.get(col, 'a number or n/a')}"
                             + (f" ({int(bad.sum())} such rows)" if bad.sum() > 1 else "")
                             + "; the log was changed since vtexp wrote it", path=str(beh))
        df[col] = num.astype("Int64") if col in ("trial", "repetition", "replays", "n_pulses",
                                                  "practice", "correct") else num
    dup = df.duplicated(["trial", "question"], keep="first") if "question" in df.columns \
        else df.duplicated(["trial"], keep="first")
    duplicated = sorted({int(t) for t in df.loc[dup, "trial"].dropna()})
    if duplicated:
        s.warnings.append(f"{beh}: {int(dup.sum())} rows log a trial a second time (trials "
                          f"{_ranges(duplicated)}): two runs of the session wrote at once")
    s.duplicated_trials = duplicated
    events = events_path(s)
    if events is not None and events.is_file():
        lines = events.read_bytes().split(b"\n")[1:]
        lines = [ln for ln in lines if ln]
        extra = len(lines) - len(set(lines))
        if extra:
            s.warnings.append(f"{events}: {extra} device events are logged twice")
    meta = s.meta
    df.insert(0, "session", int(meta["session"]))
    df.insert(0, "participant", str(meta["participant"]))
    df.insert(0, "experiment", str(meta["experiment"]))
    return df


def read_session(d: Path | str) -> SessionData:
    """Read one session (its folder in either layout, or its record); problems that lose
    nothing become warnings."""
    s = read_record(d)
    beh = beh_path(s)
    text = beh.read_bytes().decode("utf-8", errors="replace")
    if text and not text.endswith("\n"):
        cut = text.rfind("\n") + 1
        s.warnings.append(f"{beh}: last row is incomplete (cut off mid-write) and was ignored")
        text = text[:cut]
    header = text.split("\n", 1)[0].split("\t")
    if "trial" not in header or "answer" not in header:
        raise InputError("not a vtexp trial log (no 'trial' and 'answer' columns)", path=str(beh))
    try:
        df = pd.read_csv(io.StringIO(text), sep="\t", dtype=str, na_values=[NA],
                         keep_default_na=False)
    except pd.errors.ParserError as e:      # a row with more cells than the header
        m = re.search(r"Expected (\d+) fields in line (\d+), saw (\d+)", str(e))
        what = (f"line {m[2]} has {m[3]} cells where the header has {m[1]}" if m
                else str(e).strip())
        raise InputError(f"not a trial log as vtexp writes it: {what} (a tab too many?)",
                         path=str(beh)) from None
    s.trials = typed_trials(df, s)
    return s


def _ranges(numbers: list[int]) -> str:
    """[1, 2, 3, 7] -> '1-3, 7'."""
    out, start = [], None
    for i, n in enumerate(numbers):
        if start is None:
            start = n
        if i + 1 == len(numbers) or numbers[i + 1] != n + 1:
            out.append(str(start) if start == n else f"{start}-{n}")
            start = None
    return ", ".join(out)


def load_sessions(paths: list[Path | str], *, include_practice: bool = False,
                  strict: bool = False, duplicates: str = "error",
                  include_simulated: bool = False, notes: list[str] | None = None
                  ) -> tuple[pd.DataFrame, list[SessionData]]:
    """Tidy trial table (one row per trial) of every session found under ``paths``.

    Practice trials are left out unless ``include_practice``; replays and
    reaction times are kept. With ``strict``, a file whose checksum differs
    from the one in its ``session.json`` is an error instead of a warning.
    A trial logged twice is an error unless ``duplicates="first"`` (its first
    row is kept). Simulated sessions found with people's are left out unless
    ``include_simulated``; what was left out is said in ``notes``.
    """
    dirs = find_sessions(paths)
    if not dirs:
        raise InputError("no vtexp sessions found (no session record below "
                         + ", ".join(map(str, paths)) + ")")
    sessions = [read_session(d) for d in dirs]
    notes = notes if notes is not None else []
    orphans = _logs_without_record(paths, sessions)
    if orphans:
        notes.append(f"{len(orphans)} trial log(s) without a session record, left out (a "
                     "record deleted or not copied? without it a log cannot be checked): "
                     + ", ".join(map(str, orphans[:5])) + (", ..." if len(orphans) > 5 else ""))
    return combine_sessions(sessions, include_practice=include_practice, strict=strict,
                            duplicates=duplicates, include_simulated=include_simulated,
                            notes=notes)


def _logs_without_record(paths: list[Path | str], sessions: list[SessionData]) -> list[Path]:
    """Trial logs (``*_beh.tsv``) below the folders given that no session read names."""
    named = {beh_path(s).resolve() for s in sessions}
    out = []
    for p in map(Path, paths):
        if not p.is_dir():
            continue
        for f in p.rglob("*_beh.tsv"):
            parts = f.relative_to(p).parts
            if any(x.startswith(".") for x in parts) or "derivatives" in parts:
                continue
            if f.resolve() not in named:
                out.append(f)
    return sorted(out)


def combine_sessions(sessions: list[SessionData], *, include_practice: bool = False,
                     strict: bool = False, duplicates: str = "error",
                     include_simulated: bool = False, notes: list[str] | None = None
                     ) -> tuple[pd.DataFrame, list[SessionData]]:
    """The tidy table of sessions already read (:func:`load_sessions`' second half)."""
    notes = notes if notes is not None else []
    seen: dict[tuple, SessionData] = {}
    for s in sessions:       # one session found in two folders: a copy (a backup) of it
        m = s.meta
        key = (str(m["experiment"]), str(m["participant"]), int(m["session"]),
               m.get("started_at"), m.get("seed"))
        if key in seen:
            raise InputError(f"session {key[2]} of participant {key[1]} of {key[0]} (started "
                             f"{key[3] or '?'}) is found twice: {seen[key].dir} and {s.dir} "
                             "(a copy, e.g. a backup folder?); give the folders so that each "
                             "session is found once")
        seen[key] = s
    twice = [s for s in sessions if s.duplicated_trials]
    if twice and duplicates != "first":
        raise InputError("trials logged twice (two runs of one session wrote at once): "
                         + "; ".join(f"{s.dir}: trials {_ranges(s.duplicated_trials)}"
                                     for s in twice)
                         + ". Nothing was analysed; --drop-duplicates keeps the first row "
                         "of each such trial")
    for s in twice:
        keep = ~s.trials.duplicated(["trial", "question"], keep="first")
        s.trials = s.trials[keep].reset_index(drop=True)
    people = [s for s in sessions if not s.simulated]
    models = [s for s in sessions if s.simulated]
    if people and models and not include_simulated:
        notes.append(f"{len(models)} simulated session(s) (model participants or scripted "
                     f"answers: {', '.join('sub-' + str(s.meta['participant']) for s in models)}"
                     ") left out, so that they are not pooled with people's; "
                     "--include-simulated pools them")
        sessions = people
    elif models:
        notes.append(f"{len(models)} of these sessions are simulated (model participants or "
                     "scripted answers), not people"
                     + (": pooled with people's as asked (--include-simulated)"
                        if people else ""))
    bad = [f for s in sessions for f in s.mismatched]
    if strict and bad:
        raise InputError("checksum mismatch: " + ", ".join(bad) + " changed since the session "
                         "ended (refused because of --strict)")
    df = pd.concat([s.trials for s in sessions], ignore_index=True)
    # Factor columns keep the declared order of their levels (tables read like the paper).
    order: dict[str, list[str]] = {}
    for s in sessions:
        for name, levels in s.levels.items():
            logged = s.trials[name].dropna().unique() if name in s.trials else []
            extra = sorted({str(v) for v in logged} - {str(v) for v in levels})
            if extra:
                notes.append(f"{s.dir}: factor {name!r}: the trial log holds "
                             f"{', '.join(map(repr, extra[:5]))}, which the session record "
                             f"does not declare as a level ({', '.join(map(str, levels[:8]))}); "
                             "analysed as a level of its own (the record or the log edited?)")
            known = order.setdefault(name, [])
            known.extend(lv for lv in levels if lv not in known)
    for name, levels in order.items():
        extra = [v for v in df[name].dropna().unique() if v not in levels]
        df[name] = pd.Categorical(df[name], categories=levels + sorted(extra), ordered=True)
    if not include_practice:
        df = df[df["practice"].fillna(0) == 0].reset_index(drop=True)
    return df, sessions
