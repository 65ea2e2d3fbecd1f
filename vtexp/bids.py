"""The dataset around the sessions: what makes a data folder a valid BIDS dataset.

Every data folder vtexp writes (``DATA/<experiment>/``) is a BIDS dataset from its
first session on, and stays one as sessions are added::

    DATA/<experiment>/
        dataset_description.json    BIDSVersion, Name, DatasetType raw, GeneratedBy vtexp
        README.md                   what the dataset is and how vtexp laid it out
        participants.tsv            participant_id, group, age, handedness, vision, and
        participants.json           the experiment's own fields (described in the .json)
        sub-<P>/ses-<N>/beh/        the BIDS files of a session (vtexp.session)
        sourcedata/vtexp/sub-<P>/ses-<N>/   vtexp's record of the session, its lock and
                                    camera frames (BIDS leaves sourcedata/ to the lab)
        derivatives/vtexp/          reports of ``vtexp analyze`` (a derivative dataset)

This module owns the dataset-level files; :mod:`vtexp.session` the session's.
Files are written whole and renamed into place (a temporary file whose name starts
with a dot, which BIDS ignores), so a run killed at any instant leaves each file
either as it was or complete.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
from pathlib import Path
from typing import Any, Iterator

from . import __version__
from .errors import InputError
from .lock import exclusive
from .log import NA, fsync_dir, write_json_atomic

BIDS_VERSION = "1.10.0"
CODE_URL = "https://github.com/vtexp/vtexp"
PARTICIPANTS = "participants.tsv"
SOURCE = Path("sourcedata") / "vtexp"
DERIVATIVE = Path("derivatives") / "vtexp"

#: What every dataset asks of each participant, unless the experiment redefines a field.
BUILTIN_FIELDS: dict[str, dict] = {
    "group": {"description": "the participant's group, e.g. blind or sighted (a between-"
                             "participant factor of the analyses)", "type": "text"},
    "age": {"description": "age of the participant at the first session", "type": "number",
            "units": "year", "minimum": 0, "maximum": 120},
    "handedness": {"description": "handedness of the participant as reported",
                   "type": "text", "levels": ["left", "right", "ambidextrous"]},
    "vision": {"description": "vision status of the participant: sighted (normal or "
                              "corrected to normal), low-vision, or blind",
               "type": "text", "levels": ["sighted", "low-vision", "blind"]},
}
_HANDS = {"l": "left", "r": "right", "a": "ambidextrous", "ambi": "ambidextrous"}
_WORD = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.\-]*$")


# ------------------------------------------------------------------------- the dataset

def dataset_description(name: str, title: str) -> dict:
    """The raw dataset's ``dataset_description.json``."""
    return {"Name": title or name, "BIDSVersion": BIDS_VERSION, "DatasetType": "raw",
            "GeneratedBy": [{"Name": "vtexp", "Version": __version__, "CodeURL": CODE_URL,
                             "Description": f"sessions of experiment {name!r}"}]}


def derivative_description(source_name: str) -> dict:
    """``derivatives/vtexp/dataset_description.json``: the reports are a derivative."""
    return {"Name": f"vtexp reports: {source_name}", "BIDSVersion": BIDS_VERSION,
            "DatasetType": "derivative",
            "GeneratedBy": [{"Name": "vtexp", "Version": __version__, "CodeURL": CODE_URL,
                             "Description": "vtexp analyze: recognition rates, statistics, "
                                            "figures and reports"}]}


def is_dataset(folder: Path | str) -> bool:
    """A folder vtexp laid out as a BIDS dataset (or any BIDS dataset)."""
    return (Path(folder) / "dataset_description.json").is_file()


def readme(name: str, title: str, reference: str) -> str:
    return (f"# {title or name}\n\n"
            f"Behavioural sessions of the vtexp experiment `{name}`"
            + (f", reproducing {reference}" if reference else "") + ".\n\n"
            "Written by vtexp (tactile shape displays) as the sessions ran:\n\n"
            "- `participants.tsv` (+ `.json`): one row per participant, asked at their first "
            "session.\n"
            "- `sub-<P>/ses-<N>/beh/`: per session, `_beh.tsv` (one row per trial and "
            "question), `_events.tsv` (every pulse the device reported playing; onset in "
            "seconds from the session's first stimulus), each with a `.json` describing its "
            "columns.\n"
            "- `sourcedata/vtexp/sub-<P>/ses-<N>/`: vtexp's record of each session (the "
            "experiment file, seed, device, status, checksums), its lock and camera frames.\n"
            "- `derivatives/vtexp/`: reports made by `vtexp analyze`.\n")


def ensure_dataset(root: Path | str, name: str, title: str, reference: str = "") -> None:
    """Make ``root`` a BIDS dataset if it is not one yet (files already there are kept).
    Under the dataset's lock: participants started at once in a new data folder would
    otherwise stage the same files under the same temporary names."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    with _dataset_lock(root):
        desc = root / "dataset_description.json"
        if not desc.exists():
            write_json_atomic(desc, dataset_description(name, title))
        if not any((root / f).exists() for f in ("README", "README.md", "README.rst",
                                                 "README.txt")):
            write_text_atomic(root / "README.md", readme(name, title, reference))


def ensure_derivative(out: Path | str, source_name: str) -> None:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if not (out / "dataset_description.json").exists():
        write_json_atomic(out / "dataset_description.json", derivative_description(source_name))


def write_text_atomic(path: Path, text: str) -> None:
    """Replace ``path`` with ``text`` whole (a hidden temporary file renamed into place)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w", encoding="utf-8", newline="\n") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    fsync_dir(path.parent)


# ------------------------------------------------------------------ participant fields

def participant_fields(declared: dict | None = None) -> dict[str, dict]:
    """Every field asked of a participant: the built-in ones, then the experiment's
    (``participants:`` of the experiment file; a field of a built-in's name replaces it)."""
    fields = {k: dict(v) for k, v in BUILTIN_FIELDS.items()}
    for name, f in (declared or {}).items():
        spec = f.model_dump(exclude_none=True) if hasattr(f, "model_dump") else dict(f)
        fields[name] = spec
    return fields


def parse_info(text: str | None, where: str = "--participant-info") -> dict[str, str]:
    """``group=blind,age=34`` -> ``{"group": "blind", "age": "34"}``."""
    info: dict[str, str] = {}
    for part in (text or "").split(","):
        part = part.strip()
        if not part:
            continue
        key, eq, value = part.partition("=")
        if not eq or not key.strip():
            raise InputError(f"{part!r} is not FIELD=VALUE (e.g. group=blind,age=34)",
                             key=where)
        info[key.strip()] = value.strip()
    return info


def check_value(name: str, field: dict, value: Any) -> str:
    """The value as written to participants.tsv; ValueError with the reason if wrong."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return NA
    text = str(value).strip()
    if text in ("", NA):
        return NA
    if field.get("type") == "number":
        try:
            x = float(text)
        except ValueError:
            raise ValueError(f"{name} is a number" + (f" in {field['units']}s"
                                                      if field.get("units") else "")
                             + f", got {text!r}") from None
        if not math.isfinite(x) or (field.get("minimum") is not None and x < field["minimum"]) \
                or (field.get("maximum") is not None and x > field["maximum"]):
            raise ValueError(f"{name} must be from {field.get('minimum', '-inf'):g} to "
                             f"{field.get('maximum', 'inf'):g}, got {text}")
        return f"{x:g}"
    if name == "handedness":
        text = _HANDS.get(text.lower(), text.lower())
    levels = field.get("levels")
    if levels:
        match = next((lv for lv in levels if lv.lower() == text.lower()), None)
        if match is None:
            raise ValueError(f"{name} is one of {', '.join(levels)}, got {text!r}")
        return match
    if not _WORD.match(text):
        raise ValueError(f"{name} is one word of letters, digits, '-', '_' or '.', got {text!r}")
    return text


def check_info(info: dict[str, Any], fields: dict[str, dict],
               where: str = "--participant-info") -> dict[str, str]:
    """Every value checked against its field; unknown fields refused, naming the known."""
    out = {}
    for name, value in info.items():
        if name not in fields:
            raise InputError(f"unknown participant field {name!r}; the fields are "
                             f"{', '.join(fields)} (an experiment declares more under "
                             "'participants:')", key=where)
        try:
            out[name] = check_value(name, fields[name], value)
        except ValueError as e:
            raise InputError(str(e), key=where) from None
    return out


def participants_sidecar(fields: dict[str, dict], columns: list[str],
                         old: dict | None = None) -> dict:
    """``participants.json``: every column described (what was there is kept)."""
    doc = dict(old or {})
    doc.setdefault("participant_id", {"Description": "unique participant identifier"})
    for name in columns:
        if name == "participant_id" or name in doc:
            continue
        f = fields.get(name, {"description": "a property of the participant"})
        entry: dict[str, Any] = {"Description": f["description"]}
        if f.get("levels"):
            entry["Levels"] = {lv: lv for lv in f["levels"]}
        if f.get("units"):
            entry["Units"] = f["units"]
        doc[name] = entry
    return doc


# ------------------------------------------------------------------ participants.tsv

def read_table(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    """A participants.tsv as its columns and rows; InputError naming the file if unreadable."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise InputError("cannot read the participants table: not UTF-8 text",
                         path=str(path)) from None
    except OSError as e:
        raise InputError(f"cannot read the participants table: {e.strerror}",
                         path=str(path)) from None
    lines = [ln for ln in text.split("\n") if ln.strip()]
    if not lines:
        raise InputError("the participants table is empty (it needs a header "
                         "'participant_id ...')", path=str(path))
    columns = lines[0].rstrip("\r").split("\t")
    if columns[0] != "participant_id":
        raise InputError("the participants table's first column is not participant_id "
                         f"(its header: {' '.join(columns)})", path=str(path), line=1)
    rows = []
    for i, ln in enumerate(lines[1:], start=2):
        cells = ln.rstrip("\r").split("\t")
        if len(cells) != len(columns):
            raise InputError(f"row has {len(cells)} values for {len(columns)} columns",
                             path=str(path), line=i)
        rows.append(dict(zip(columns, cells)))
    return columns, rows


@contextlib.contextmanager
def _dataset_lock(root: Path) -> Iterator[None]:
    """One writer of the dataset's files at a time (sessions of several participants may
    start at once in one data folder); :func:`vtexp.lock.exclusive` says how on each
    platform."""
    folder = root / SOURCE
    folder.mkdir(parents=True, exist_ok=True)
    with exclusive(folder / ".dataset.lock", what=f"the dataset {root}"):
        yield


def known_participant(root: Path | str, participant: str) -> dict[str, str] | None:
    """The participant's row of participants.tsv, or None (no row, or no table yet)."""
    path = Path(root) / PARTICIPANTS
    if not path.is_file():
        return None
    _, rows = read_table(path)
    return next((r for r in rows if r["participant_id"] == f"sub-{participant}"), None)


def _refuse_contradiction(path: Path, row: dict[str, str], info: dict[str, str]) -> None:
    """A value given that contradicts the participant's row: what was given at the first
    session is kept."""
    for name, value in info.items():
        was = row.get(name, NA)
        if was not in (NA, "") and value != NA and was != value:
            raise InputError(f"{path} already says {name}={was} for {row['participant_id']}, "
                             f"not {value}; what was given at the first session is kept (edit "
                             "participants.tsv to correct it)", key="--participant-info")


def check_participant_info(root: Path | str, participant: str, info: dict[str, str]) -> None:
    """Refuse, before anything is written, a value that contradicts the participant's row
    of participants.tsv (:func:`record_participant` checks again as it writes)."""
    row = known_participant(root, participant)
    if row is not None:
        _refuse_contradiction(Path(root) / PARTICIPANTS, row, info)


def record_participant(root: Path | str, participant: str, info: dict[str, str],
                       fields: dict[str, dict]) -> dict[str, str]:
    """Add the participant to participants.tsv (before their first session's folder
    appears), or fill the values that row lacks; a value that contradicts the row is
    refused. Returns the row."""
    root = Path(root)
    path = root / PARTICIPANTS
    with _dataset_lock(root):
        columns, rows = read_table(path) if path.is_file() else (["participant_id"], [])
        for name in [*fields, *info]:
            if name not in columns:
                columns.append(name)
        pid = f"sub-{participant}"
        row = next((r for r in rows if r["participant_id"] == pid), None)
        if row is None:
            row = {"participant_id": pid}
            rows.append(row)
        _refuse_contradiction(path, row, info)
        for name, value in info.items():
            if value != NA:
                row[name] = value
        text = "\t".join(columns) + "\n" + "".join(
            "\t".join(r.get(c, NA) or NA for c in columns) + "\n" for r in rows)
        if not path.is_file() or path.read_text(encoding="utf-8") != text:
            write_text_atomic(path, text)
        side = root / "participants.json"
        try:
            old = json.loads(side.read_text(encoding="utf-8")) if side.is_file() else {}
        except (OSError, ValueError):
            old = {}
        doc = participants_sidecar(fields, columns, old if isinstance(old, dict) else {})
        if doc != old:
            write_json_atomic(side, doc)
        return {c: row.get(c, NA) for c in columns}


# ------------------------------------------------------------------------ sidecars

EVENTS_SIDECAR = {
    "onset": {"LongName": "pulse onset",
              "Description": "onset of the pulse in seconds from the session's first stimulus "
                             "(the start of the acquisition). Within one run of the session "
                             "pulses are timed by the device's clock; a resumed run is placed "
                             "at the wall-clock time of its first stimulus",
              "Units": "s"},
    "duration": {"LongName": "pulse duration",
                 "Description": "how long the actuator was driven, as the device reported",
                 "Units": "s"},
    "trial": {"Description": "trial number in the session (the row of _beh.tsv with the "
                             "same trial)"},
    "play": {"Description": "which play of the trial's stimulus: 0 the first, 1 the first "
                            "replay (feel it again), ...; a play the device stopped part-way "
                            "(a device fault) lists the pulses it played, and the plays of "
                            "the trial played again after it follow with the next numbers"},
    "row": {"Description": "actuator row on the array, from 0 at the top"},
    "col": {"Description": "actuator column on the array, from 0 at the left"},
    "scheduled_onset_ms": {"Description": "onset the schedule asked for, from the start of "
                                          "the stimulus", "Units": "ms"},
    "onset_ms": {"Description": "device clock at the pulse's onset, as the device reported "
                                "it (the clock restarts with each run of the session)",
                 "Units": "ms"},
    "duration_ms": {"Description": "how long the actuator was driven", "Units": "ms"},
    "level": {"Description": "drive level of a vibration motor (the profile's duty levels), "
                             "n/a for a pulse train"},
    "amplitude_v": {"Description": "pulse-train amplitude (SMA pins), n/a for a motor",
                    "Units": "V"},
    "frequency_hz": {"Description": "pulse-train frequency (SMA pins), n/a for a motor",
                     "Units": "Hz"},
    "pulse_width_ms": {"Description": "width of each pulse of a pulse train, n/a for a motor",
                       "Units": "ms"},
}
