"""``vtexp analyze``: statistics, figures and a report from logged sessions.

The report of a dataset goes to its ``derivatives/vtexp/`` (a BIDS derivative
dataset with its own dataset_description.json); ``--pool GLOB`` reads many labs'
datasets at once through DuckDB (the ``pool`` extra, :mod:`vtexp.analysis.pool`).
"""

from __future__ import annotations

import sys
from pathlib import Path

from ..errors import InputError
from ._io import out


def cmd_analyze(args) -> int:
    from ..analysis import load_sessions, recognition_rates
    from ..analysis.report import markdown_table, write_reports

    from .. import bids

    notes: list[str] = []
    if not args.dirs and not args.pool:
        raise InputError("give the data: dataset or session folders (DIR ...), or --pool GLOB")
    options = dict(strict=args.strict, duplicates="first" if args.drop_duplicates else "error",
                   include_simulated=args.include_simulated, notes=notes)
    if args.pool:
        from ..analysis.pool import for_analysis, load_pooled

        patterns = list(args.pool) + list(args.dirs)
        trials, sessions = load_pooled(patterns, **options)
        out(f"pooled {trials['dataset'].nunique()} dataset(s) through DuckDB: "
            + ", ".join(map(str, trials["dataset"].unique())))
        trials = for_analysis(trials, sessions, notes)
    else:
        trials, sessions = load_sessions(args.dirs, **options)
    for note in notes:
        print(f"vtexp: note: {note}", file=sys.stderr)
    for s in sessions:
        for w in s.warnings:
            kind = "WARNING: CHECKSUM MISMATCH" if "checksum differs" in w else "warning"
            print(f"vtexp: {kind}: {w}", file=sys.stderr)
    specs = {}
    if args.experiment:
        from ..experiment import load_experiment
        exp = load_experiment(args.experiment).experiment
        if exp.analysis is None:
            raise InputError("has no 'analysis:' section to use", path=args.experiment)
        specs[exp.name] = exp.analysis
    roots = {s.root for s in sessions if s.root is not None and bids.is_dataset(s.root)}
    if args.out:
        out_dir = Path(args.out)
    elif not args.pool and len(roots) == 1:
        out_dir = next(iter(roots)) / bids.DERIVATIVE     # BIDS: reports are derivatives
    elif not args.pool and not roots:
        first = Path(args.dirs[0])                        # the layout before BIDS
        out_dir = (first if not (first / "session.json").exists() else Path(".")) / "report"
    else:
        out_dir = Path("report")
    if out_dir.resolve() in {(r / bids.DERIVATIVE).resolve() for r in roots}:
        bids.ensure_derivative(out_dir, next(iter(roots)).name)
    rep, full = write_reports(trials, sessions, out_dir, specs=specs)
    for exp in sorted(trials["experiment"].unique()):
        sub = trials[trials["experiment"] == exp]
        factors = next(s.factors for s in sessions if s.meta["experiment"] == exp)
        if sub["correct"].notna().any():
            per = recognition_rates(sub, factors, per_participant=True)
            wide = per.pivot_table(index=factors, columns="participant", values="rate",
                                   observed=True)
            wide.columns = [f"sub-{c}" for c in wide.columns]
            wide["mean"] = recognition_rates(sub, factors).set_index(factors)["rate"]
            out(f"\n{exp}: recognition rate per condition (rows) and participant (columns)")
            out(markdown_table(wide.reset_index()))
        a = full[exp]["analysis"]
        for w in a.warnings:
            print(f"vtexp: warning: {exp}: {w}", file=sys.stderr)
        if a.sentences:
            out(f"\n{exp}: results")
            for line in a.sentences:
                out(f"  {line}")
        out(f"\n{exp}: report {full[exp]['html']} (+ report.md and CSV tables in "
            f"{full[exp]['html'].parent}/)")
    out(f"\n{len(sessions)} session(s), {len(trials)} trials. Tables and report in {out_dir}/ "
        f"(report: {rep.markdown})")
    return 0


def register(sub) -> None:
    """Add ``vtexp analyze`` to the ``vtexp`` parser."""
    s = sub.add_parser("analyze", help="statistics and reports from logged sessions")
    s.add_argument("dirs", nargs="*", metavar="DIR",
                   help="datasets (DATA/<experiment>), session folders, or folders holding "
                        "them (any mix; the layout before BIDS too)")
    s.add_argument("--pool", action="append", metavar="GLOB",
                   help="pool every dataset the glob matches (quote it: --pool 'labs/*/'), "
                        "read through DuckDB (the 'pool' extra) with a dataset column; "
                        "each dataset's participants.tsv gives its participants' groups")
    s.add_argument("--out", help="folder for the tables and report (default: the dataset's "
                                 "derivatives/vtexp/; ./report for several datasets)")
    s.add_argument("--experiment", metavar="FILE",
                   help="use this experiment file's 'analysis:' section instead of the one "
                        "recorded in the sessions")
    s.add_argument("--strict", action="store_true",
                   help="refuse sessions whose files changed since they ended (checksum "
                        "mismatch) instead of warning")
    s.add_argument("--drop-duplicates", action="store_true",
                   help="a trial logged twice (two runs of one session at once) keeps its "
                        "first row, reported, instead of being refused")
    s.add_argument("--include-simulated", action="store_true",
                   help="pool simulated sessions (model participants, scripted answers) with "
                        "people's; by default they are left out when people's are present")
    s.set_defaults(func=cmd_analyze)
