"""Pooled reanalysis: many labs' BIDS datasets read at once through DuckDB.

``vtexp analyze --pool 'labs/*/'`` reads every dataset the glob matches. The
session records (small JSON files) are read and verified as
:func:`~vtexp.analysis.load.load_sessions` does; every trial log of every
dataset is read by one DuckDB query (``read_csv`` over the list of files,
``union_by_name``, ``n/a`` as missing), split back per session and typed by the
same function, so the table is :func:`load_sessions`' with a ``dataset``
column in front. DuckDB is the optional ``pool`` extra.

For the statistics, :func:`for_analysis` joins each dataset's
``participants.tsv`` (so that groups come from each lab's own table) and keeps
participants apart when two datasets use the same id.
"""

from __future__ import annotations

import glob
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import InputError
from ..log import NA
from .load import (SessionData, beh_path, combine_sessions, find_sessions, read_record,
                   read_session, typed_trials)
from .participants import join_participants, read_participants

__all__ = ["load_pooled", "for_analysis", "expand_datasets"]


def _duckdb():
    try:
        import duckdb
    except ImportError:
        raise InputError("reading a glob of datasets (--pool) needs DuckDB, vtexp's 'pool' "
                         "extra: pip install 'vtexp[pool]' (or pip install duckdb)",
                         key="--pool") from None
    return duckdb


def expand_datasets(patterns: list[str]) -> list[Path]:
    """The dataset folders the globs match, sorted; an error naming a glob that matches
    no folder."""
    out: list[Path] = []
    for pattern in patterns:
        matched = sorted(Path(p) for p in glob.glob(pattern) if Path(p).is_dir())
        if not matched:
            raise InputError(f"the glob {pattern!r} matches no folder (from "
                             f"{Path.cwd()})", key="--pool")
        out += [p for p in matched if p not in out]
    return out


def dataset_label(folder: Path) -> str:
    """How a dataset is named in the ``dataset`` column: its path as the glob matched it."""
    return Path(folder).as_posix().rstrip("/") or "."


def load_pooled(patterns: list[str] | str, *, include_practice: bool = False,
                strict: bool = False, duplicates: str = "error",
                include_simulated: bool = False, notes: list[str] | None = None
                ) -> tuple[pd.DataFrame, list[SessionData]]:
    """Every session of every dataset matched by ``patterns``: the tidy table of
    :func:`load_sessions` with a ``dataset`` column first, and the sessions (each with
    ``dataset`` in its ``meta``)."""
    duckdb = _duckdb()
    patterns = [patterns] if isinstance(patterns, str) else list(patterns)
    sessions: list[SessionData] = []
    for folder in expand_datasets(patterns):
        records = find_sessions([folder])
        if not records:
            raise InputError("no vtexp sessions in this folder (a BIDS dataset written by "
                             "vtexp, with sourcedata/vtexp/ records, or sessions of the "
                             "layout before)", path=str(folder))
        for r in records:
            s = read_record(r)
            s.meta["dataset"] = dataset_label(folder)
            sessions.append(s)
    whole, cut = [], []
    for s in sessions:
        f = beh_path(s)
        with open(f, "rb") as fh:
            fh.seek(0, 2)
            size = fh.tell()
            fh.seek(max(0, size - 1))
            (whole if size and fh.read(1) == b"\n" else cut).append(s)
    if whole:
        files = [str(beh_path(s)) for s in whole]
        con = duckdb.connect()
        try:
            # Every value as text (typed afterwards as load_sessions does); n/a missing.
            table = con.execute(
                "SELECT * FROM read_csv(?, delim = '\t', header = true, all_varchar = true, "
                "union_by_name = true, filename = true, nullstr = ?, quote = '', "
                "escape = '')", [files, NA]).df()
        except duckdb.Error as e:
            raise InputError(f"DuckDB could not read the trial logs: {e}") from None
        finally:
            con.close()
        table = table.astype(object).where(table.notna(), np.nan)
        for s in whole:
            f = beh_path(s)
            header = f.read_text(encoding="utf-8", errors="replace").split("\n", 1)[0]
            rows = table[table["filename"] == str(f)]
            # The text dtype pandas gives read_csv(dtype=str), missing values kept.
            df = rows[header.split("\t")].reset_index(drop=True).astype(str)
            s.trials = typed_trials(df, s)
    for s in cut:                       # a last row cut off mid-write: read as one session
        again = read_session(s.record)
        again.meta["dataset"] = s.meta["dataset"]
        s.trials, s.warnings = again.trials, again.warnings
        s.duplicated_trials = again.duplicated_trials
    for s in sessions:
        s.trials.insert(0, "dataset", s.meta["dataset"])
    return combine_sessions(sessions, include_practice=include_practice, strict=strict,
                            duplicates=duplicates, include_simulated=include_simulated,
                            notes=notes)


def for_analysis(trials: pd.DataFrame, sessions: list[SessionData],
                 notes: list[str] | None = None) -> pd.DataFrame:
    """The pooled table ready for the statistics: each dataset's participants.tsv
    joined (its columns, where the trial table lacks them), and participants of
    different datasets kept apart (``dataset/id``) when an id occurs in several."""
    parts = []
    for label in trials["dataset"].unique():
        sub = trials[trials["dataset"] == label]
        root = next((s.root for s in sessions if s.meta.get("dataset") == label), None)
        table = root / "participants.tsv" if root is not None else None
        if table is not None and table.is_file():
            sub = join_participants(sub, read_participants(table), "participant")
        parts.append(sub)
    out = pd.concat(parts, ignore_index=True)
    for c in trials.columns:            # keep the categories of the factors
        if isinstance(trials[c].dtype, pd.CategoricalDtype):
            out[c] = pd.Categorical(out[c], categories=trials[c].cat.categories, ordered=True)
    owners = out.groupby("participant", observed=True)["dataset"].nunique()
    shared = sorted(owners[owners > 1].index)
    if shared:
        out["participant"] = out["dataset"].astype(str) + "/" + out["participant"].astype(str)
        if notes is not None:
            notes.append(f"participant id(s) {', '.join(shared[:5])} occur in several datasets; "
                         "they are different people, named dataset/id in the analysis")
    return out
