"""``vtexp stats``: the statistics on any tidy CSV, so labs can use them on their own data.

    vtexp stats rm-anova FILE.csv --dv COL --within COL [COL...] --subject COL [--json]
    vtexp stats simple-effects FILE.csv --dv COL --within A B --subject COL --effect A --by B

Registered in ``vtexp.cli.build_parser`` with :func:`register`.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import warnings
from pathlib import Path

from ..errors import InputError


def read_table(path: str):
    """A CSV or TSV (by extension, or sniffed) read with every column as text first."""
    import pandas as pd

    p = Path(path)
    if not p.is_file():
        raise InputError("no such file", path=str(p))
    sep = "\t" if p.suffix.lower() in (".tsv", ".tab") else None
    try:
        df = pd.read_csv(p, sep=sep, engine="python", dtype=str, keep_default_na=False,
                         na_values=["", "NA", "n/a", "NaN"])
    except (pd.errors.ParserError, UnicodeDecodeError, ValueError) as e:
        raise InputError(f"cannot read as a table (CSV or TSV): {e}", path=str(p)) from None
    if df.shape[1] < 2:
        raise InputError("found fewer than 2 columns; expected a tidy CSV or TSV with a header "
                         "row (one row per observation)", path=str(p))
    return df


def _records(df) -> list[dict]:
    out = []
    for row in df.to_dict(orient="records"):
        out.append({k: (None if isinstance(v, float) and math.isnan(v) else
                        (v.item() if hasattr(v, "item") else v)) for k, v in row.items()})
    return out


def _print_table(df) -> None:
    from ..analysis.report import md_table
    print(md_table("anova", df))


def _run(fn, args, **kw):
    from ..analysis.anova import MissingCellsWarning

    df = read_table(args.file)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", MissingCellsWarning)
        try:
            t = fn(df, args.dv, args.within, args.subject, missing=args.missing, **kw)
        except InputError as e:
            raise InputError(e.message, path=args.file, key=e.key) from None
    for w in caught:
        print(f"vtexp: warning: {args.file}: {w.message}", file=sys.stderr)
    return t


def cmd_rm_anova(args) -> int:
    from ..analysis.anova import rm_anova
    from ..analysis.pipeline import apa_anova

    t = _run(rm_anova, args)
    if args.json:
        print(json.dumps({"file": args.file, "dv": args.dv, "within": args.within,
                          "subject": args.subject, "dropped": [str(s) for s in t.attrs["dropped"]],
                          "effects": _records(t)}, indent=2, ensure_ascii=False))
        return 0
    print(f"Repeated-measures ANOVA of {args.dv} on {' × '.join(args.within)} "
          f"({int(t['n'].iloc[0])} participants)")
    _print_table(t)
    print()
    for _, row in t.iterrows():
        sentence, _ = apa_anova(row, args.correction)
        print(f"{row['effect']}: {sentence}")
    return 0


def cmd_simple_effects(args) -> int:
    from ..analysis.anova import simple_effects

    t = _run(simple_effects, args, effect=args.effect, by=args.by, method=args.method)
    if args.json:
        t = t.astype({args.by: str})
        print(json.dumps({"file": args.file, "effect": args.effect, "by": args.by,
                          "method": args.method, "rows": _records(t)}, indent=2,
                         ensure_ascii=False))
        return 0
    print(f"Simple effects of {args.effect} at each level of {args.by} ({args.method} error "
          "term)")
    _print_table(t)
    return 0


def _common(s) -> None:
    s.add_argument("file", metavar="FILE.csv", help="tidy table: one row per observation "
                   "(several per cell are averaged)")
    s.add_argument("--dv", required=True, metavar="COL", help="dependent variable column")
    s.add_argument("--within", required=True, nargs="+", metavar="COL",
                   help="within-participant factor columns")
    s.add_argument("--subject", required=True, metavar="COL", help="participant column")
    s.add_argument("--missing", choices=["drop", "error"], default="drop",
                   help="participants lacking a cell: drop them with a warning (default, as "
                        "afex) or stop with an error")
    s.add_argument("--json", action="store_true", help="print JSON instead of a table")


def register(subparsers) -> None:
    """Add ``vtexp stats`` and its subcommands to the ``vtexp`` parser."""
    st = subparsers.add_parser(
        "stats", help="statistics on any tidy CSV (rm-anova, simple-effects)",
        description="Statistics on a tidy CSV/TSV table (one row per observation).")
    sub = st.add_subparsers(dest="stats_command", metavar="ANALYSIS", required=True)
    s = sub.add_parser("rm-anova", help="repeated-measures ANOVA (Mauchly, GG/HF, η²p, η²G)",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    _common(s)
    s.add_argument("--correction", choices=["auto", "none", "GG", "HF"], default="auto",
                   help="which p the sentences give (auto: GG when Mauchly's p < .05)")
    s.set_defaults(func=cmd_rm_anova)
    s = sub.add_parser("simple-effects", help="simple effects of one factor at each level "
                       "of another (separate or pooled error term)")
    _common(s)
    s.add_argument("--effect", required=True, metavar="COL")
    s.add_argument("--by", required=True, metavar="COL")
    s.add_argument("--method", choices=["separate", "pooled"], default="separate")
    s.set_defaults(func=cmd_simple_effects)
