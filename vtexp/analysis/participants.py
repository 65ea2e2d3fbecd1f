"""Participants' properties (group, age, handedness...) from a participants table.

A between-participant factor is a property of the participant, not of a trial.
It comes either from a column of the trial table that is constant within a
participant, or from a participants table in the form of BIDS'
``participants.tsv``: a ``participant_id`` column (``sub-01``; the ``sub-``
prefix is optional here) and one column per property, ``n/a`` for a missing
value. :func:`join_participants` is the one place where the two meet: the
participants.tsv that vtexp writes at the root of each dataset (group, age,
handedness, vision and the experiment's ``participants:`` fields, asked at each
participant's first session; :mod:`vtexp.bids`) gives the analyses their
between-participant factors here.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from ..errors import InputError

__all__ = ["read_participants", "join_participants"]


def _bare(pid) -> str:
    s = str(pid)
    return s[4:] if s.startswith("sub-") else s


def read_participants(path) -> pd.DataFrame:
    """A BIDS ``participants.tsv`` as a table keyed by the bare id (``01`` for ``sub-01``)."""
    p = Path(path)
    if not p.is_file():
        raise InputError("no such participants table", path=str(p))
    try:
        t = pd.read_csv(p, sep="\t", dtype=str, keep_default_na=False, na_values=["n/a", ""],
                        encoding="utf-8")
    except UnicodeDecodeError:
        raise InputError("cannot read the participants table: not UTF-8 text",
                         path=str(p)) from None
    except (pd.errors.ParserError, pd.errors.EmptyDataError) as e:
        reason = str(e).strip().splitlines()[-1] if str(e).strip() else "no header"
        raise InputError(f"cannot read the participants table as tab-separated values: "
                         f"{reason}", path=str(p)) from None
    except OSError as e:
        raise InputError(f"cannot read the participants table: {e.strerror}",
                         path=str(p)) from None
    if "participant_id" not in t.columns:
        raise InputError("the participants table has no 'participant_id' column (BIDS "
                         f"participants.tsv); its columns are {', '.join(t.columns)}",
                         path=str(p))
    return t


def join_participants(trials: pd.DataFrame, participants: pd.DataFrame,
                      subject: str = "participant") -> pd.DataFrame:
    """``trials`` with every column of ``participants`` joined on the participant.

    Columns already in ``trials`` are kept from ``trials`` unless they are
    missing there. A participant of ``trials`` without a row in
    ``participants`` is refused with :class:`InputError` naming them.
    """
    if "participant_id" not in participants.columns:
        raise InputError("the participants table has no 'participant_id' column (BIDS "
                         f"participants.tsv); its columns are {', '.join(participants.columns)}")
    if subject not in trials.columns:
        raise InputError(f"no column {subject!r} in the table")
    p = participants.copy()
    p["_id"] = p["participant_id"].map(_bare)
    dup = p["_id"][p["_id"].duplicated()]
    if len(dup):
        raise InputError(f"participant {dup.iloc[0]} has two rows in the participants table")
    ids = trials[subject].map(_bare)
    unknown = sorted(set(ids.dropna()) - set(p["_id"]))
    if unknown:
        raise InputError(f"participant(s) {', '.join(unknown[:5])} of the data have no row in "
                         "the participants table")
    props = [c for c in p.columns if c not in ("participant_id", "_id")]
    joined = p.set_index("_id")[props].reindex(ids.to_numpy())
    out = trials.copy()
    for c in props:
        vals = joined[c].to_numpy()
        out[c] = vals if c not in out.columns else out[c].where(out[c].notna(), vals)
    return out
