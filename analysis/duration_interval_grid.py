"""Seed 001, Table 1: recognition rate by shape and duration/interval, from logged data.

Usage: python analysis/duration_interval_grid.py DATA_DIR [--out FILE.csv]

DATA_DIR is any folder holding sessions of `duration_interval_grid`
(e.g. data/duration_interval_grid or data/demo). The table has the paper's
layout: one row per duration/interval pair, one column per shape, and the
mean identification rate; rates are pooled over trials of all participants,
as the paper's percentages are.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from vtexp.analysis import load_sessions  # noqa: E402
from vtexp.errors import VtexpError  # noqa: E402

SHAPES = ["triangle", "circle", "square", "rectangle"]


def table_1(data_dir: Path):
    trials, _ = load_sessions([data_dir])
    trials = trials[trials["experiment"] == "duration_interval_grid"]
    if trials.empty:
        raise VtexpError(f"no duration_interval_grid sessions under {data_dir}")
    scored = trials[trials["correct"].notna()].assign(correct=lambda d: d["correct"].astype(float))
    t = scored.pivot_table(index="timing", columns="shape", values="correct", aggfunc="mean")
    t = t.reindex(columns=[s for s in SHAPES if s in t.columns])
    t["mean"] = scored.groupby("timing")["correct"].mean()
    t.index.name = "duration/interval (ms)"
    return t, trials["participant"].nunique()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data_dir", type=Path)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    try:
        t, n = table_1(args.data_dir)
    except VtexpError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"Recognition rate by shape and duration/interval ({n} participants)")
    print((t * 100).round(1).to_string())
    if args.out:
        t.to_csv(args.out)
        print(f"written: {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
