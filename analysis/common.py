"""Shared by the per-study scripts: load one study's sessions, print the paper's tables
and the analyses its experiment file declares."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from vtexp.analysis import load_sessions  # noqa: E402
from vtexp.analysis.pipeline import analyse_experiment  # noqa: E402
from vtexp.errors import VtexpError  # noqa: E402


def paper_table(trials: pd.DataFrame, rows: str | list[str], columns: str | None, dv: str,
                question: str | None = None) -> pd.DataFrame:
    """Mean per cell over all trials of all participants: ``rate`` in % correct, or the
    numeric ``answer`` (ratings, counts) of ``question``."""
    sub = trials if question is None else trials[trials["question"] == question]
    if dv == "rate":
        sub = sub[sub["correct"].notna()].assign(value=lambda d: 100 * d["correct"].astype(float))
    else:
        sub = sub.assign(value=pd.to_numeric(sub["answer"], errors="coerce"))
    t = sub.pivot_table(index=rows, columns=columns, values="value", aggfunc="mean",
                        observed=True)
    return t.round(2)


def main(experiment: str, tables: list[tuple[str, str | list[str], str | None, str,
                                            str | None]], doc: str) -> int:
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("data_dir", type=Path)
    ap.add_argument("--out", type=Path, help="folder for the tables as CSV")
    args = ap.parse_args()
    try:
        trials, sessions = load_sessions([args.data_dir])
        trials = trials[trials["experiment"] == experiment]
        if trials.empty:
            raise VtexpError(f"no {experiment} sessions under {args.data_dir}")
        n = trials["participant"].nunique()
        for i, (title, rows, columns, dv, question) in enumerate(tables, start=1):
            t = paper_table(trials, rows, columns, dv, question)
            print(f"{title} ({n} participants)")
            print(t.to_string())
            print()
            if args.out:
                args.out.mkdir(parents=True, exist_ok=True)
                t.to_csv(args.out / f"{experiment}_table_{i}.csv")
        res = analyse_experiment(trials, sessions, experiment)
        print("Analyses declared in the experiment file:")
        for line in res.sentences + res.notes:
            print(f"  {line}")
    except VtexpError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0
