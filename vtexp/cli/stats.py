"""``vtexp stats``: the statistics on any tidy CSV, so labs can use them on their own data.

    vtexp stats rm-anova FILE.csv --dv COL --within COL [COL...] [--between COL...] --subject COL
    vtexp stats simple-effects FILE.csv --dv COL --within A B --subject COL --effect A --by B
    vtexp stats posthoc FILE.csv --dv COL --within A --between G --subject COL --factor A --by G
    vtexp stats trend FILE.csv --dv COL --within SOA --subject COL --factor SOA
    vtexp stats friedman | wilcoxon FILE.csv --dv COL --factor A --subject COL
    vtexp stats kappa | information-transfer FILE.csv --stimulus COL --response COL [--by COL]
    vtexp stats mixed-logit FILE.csv --outcome COL --factors A B --subject COL [--items COL]

A between-participant factor is a column of the tidy table that is constant within a
participant (their group). ``--participants participants.tsv`` takes the groups from a
participants table instead (BIDS ``participants.tsv``: a ``participant_id`` column,
``sub-`` prefix optional, one column per property), joined on the subject column.

Registered in ``vtexp.cli.build_parser`` with :func:`register`.
"""

from __future__ import annotations

import argparse
import csv
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
    if p.stat().st_size == 0:
        raise InputError("the file is empty; expected a tidy CSV or TSV with a header row",
                         path=str(p))
    try:
        # utf-8-sig: a byte-order mark (what spreadsheet programs write) is not part of
        # the first column's name
        df = pd.read_csv(p, sep=sep, engine="python", dtype=str, keep_default_na=False,
                         na_values=["", "NA", "n/a", "NaN"], encoding="utf-8-sig")
    except (pd.errors.ParserError, UnicodeDecodeError, ValueError, csv.Error) as e:
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


def with_participants(df, path: str | None, subject: str):
    """The tidy table with the participants table's columns joined on ``subject``.

    ``path`` is a BIDS ``participants.tsv`` (or any CSV/TSV) with a
    ``participant_id`` column (``sub-01`` or ``01``) and one column per
    property (group, age, handedness...). A participant of the data without a
    row in the table is refused, naming them.
    """
    if not path:
        return df
    from ..analysis.participants import join_participants
    try:
        return join_participants(df, read_table(path), subject)
    except InputError as e:
        raise InputError(e.message, path=path) from None


def _run(fn, args, **kw):
    from ..analysis.anova import MissingCellsWarning

    df = with_participants(read_table(args.file), getattr(args, "participants", None),
                           args.subject)
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

    t = _run(rm_anova, args, between=args.between, observed=args.observed)
    if args.json:
        print(json.dumps({"file": args.file, "dv": args.dv, "within": args.within,
                          "between": args.between, "observed": args.observed,
                          "subject": args.subject, "dropped": [str(s) for s in t.attrs["dropped"]],
                          "group_sizes": t.attrs["group_sizes"],
                          "effects": _records(t)}, indent=2, ensure_ascii=False))
        return 0
    kind = "Mixed" if args.between else "Repeated-measures"
    factors = " × ".join(args.between + args.within)
    groups = (", groups " + ", ".join(f"{k}: {v}" for k, v in t.attrs["group_sizes"].items())
              if args.between else "")
    print(f"{kind} ANOVA of {args.dv} on {factors} ({int(t['n'].iloc[0])} participants"
          f"{groups}; type 3 sums of squares)" if args.between else
          f"{kind} ANOVA of {args.dv} on {factors} ({int(t['n'].iloc[0])} participants)")
    _print_table(t)
    print()
    for _, row in t.iterrows():
        sentence, _ = apa_anova(row, args.correction)
        print(f"{row['effect']}: {sentence}")
    return 0


def cmd_simple_effects(args) -> int:
    from ..analysis.anova import simple_effects

    t = _run(simple_effects, args, effect=args.effect, by=args.by, method=args.method,
             between=args.between)
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


def cmd_posthoc(args) -> int:
    from ..analysis.posthoc import pairwise_tests

    t = _run(pairwise_tests, args, factor=args.factor, by=args.by or None,
             padjust=args.padjust, between=args.between, error=args.error)
    return _emit(args, t, f"Comparisons of the levels of {args.factor}"
                 + (f" within each level of {' × '.join(args.by)}" if args.by else "")
                 + f" ({args.error} error; p adjusted: {args.padjust})")


def cmd_trend(args) -> int:
    from ..analysis.posthoc import trend_contrasts

    scores = None
    if args.scores:
        try:
            scores = [float(x) for x in args.scores]
        except ValueError:
            raise InputError(f"--scores must be numbers, got {' '.join(args.scores)}") from None
    t = _run(trend_contrasts, args, factor=args.factor, by=args.by or None,
             between=args.between, error=args.error, scores=scores)
    return _emit(args, t, f"Polynomial trends of {args.dv} across {args.factor} (scores "
                 f"{', '.join(f'{v:g}' for v in t.attrs['scores'])}; {args.error} error)")


def _emit(args, t, title: str) -> int:
    if args.json:
        for c in t.columns:
            if str(t[c].dtype) == "category":
                t[c] = t[c].astype(str)
        print(json.dumps({"file": args.file, "rows": _records(t), **{
            k: v for k, v in t.attrs.items() if isinstance(v, (str, int, float, list, dict))
            and k not in ("dropped",)}}, indent=2, ensure_ascii=False, default=str))
        return 0
    print(title)
    from ..analysis.report import md_table
    print(md_table("stats", t))
    return 0


def _table_only(args):
    return with_participants(read_table(args.file), getattr(args, "participants", None),
                             args.subject) if getattr(args, "subject", None) else \
        read_table(args.file)


def _call(fn, args, *a, **kw):
    from ..analysis.anova import MissingCellsWarning
    df = _table_only(args)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            t = fn(df, *a, **kw)
        except InputError as e:
            raise InputError(e.message, path=args.file, key=e.key) from None
    for w in caught:
        if issubclass(w.category, (MissingCellsWarning, UserWarning)):
            print(f"vtexp: warning: {args.file}: {w.message}", file=sys.stderr)
    return t


def cmd_friedman(args) -> int:
    from ..analysis.ordinal import friedman
    t = _call(friedman, args, args.dv, args.factor, args.subject, missing=args.missing)
    return _emit(args, t, f"Friedman test of {args.factor} on {args.dv}")


def cmd_wilcoxon(args) -> int:
    from ..analysis.ordinal import wilcoxon_pairwise
    t = _call(wilcoxon_pairwise, args, args.dv, args.factor, args.subject,
              padjust=args.padjust, missing=args.missing)
    return _emit(args, t, f"Wilcoxon signed-rank tests between the levels of {args.factor} "
                          f"(p adjusted: {args.padjust})")


def _labels(args):
    return list(args.labels) if args.labels else None


def cmd_kappa(args) -> int:
    from ..analysis.confusion import agreement
    t = _call(agreement, args, args.by, stimulus=args.stimulus, response=args.response,
              labels=_labels(args), weights=args.weights)
    return _emit(args, t, f"Cohen's kappa between {args.stimulus} and {args.response}"
                 + (f" ({args.weights} weights)" if args.weights else ""))


def cmd_information_transfer(args) -> int:
    from ..analysis.confusion import information_transfer
    t = _call(information_transfer, args, args.by, stimulus=args.stimulus,
              response=args.response, labels=_labels(args))
    return _emit(args, t, f"Information transferred from {args.stimulus} to {args.response} "
                          "(bits)")


def cmd_mixed_logit(args) -> int:
    from ..analysis.glmm import mixed_logit
    t = _call(mixed_logit, args, args.factors, outcome=args.outcome, subject=args.subject,
              items=args.items, interactions=args.interactions, n_quad=args.n_quad,
              on_failure="error" if args.strict else "warn")
    return _emit(args, t, f"Mixed logistic model {t.attrs['formula']}: {t.attrs['method']}; "
                          f"deviance {t.attrs['deviance']:.4f}")


def _common(s, within_required: bool = True) -> None:
    s.add_argument("file", metavar="FILE.csv", help="tidy table: one row per observation "
                   "(several per cell are averaged)")
    s.add_argument("--dv", required=True, metavar="COL", help="dependent variable column")
    s.add_argument("--within", nargs="*", default=[], metavar="COL",
                   help="within-participant factor columns")
    s.add_argument("--between", nargs="+", default=[], metavar="COL",
                   help="between-participant factor columns (constant within a participant: "
                        "their group)")
    s.add_argument("--participants", metavar="TSV",
                   help="take participants' groups from this participants table (BIDS "
                        "participants.tsv: participant_id and one column per property)")
    s.add_argument("--subject", required=True, metavar="COL", help="participant column")
    s.add_argument("--missing", choices=["drop", "error"], default="drop",
                   help="participants lacking a cell: drop them with a warning (default, as "
                        "afex) or stop with an error")
    s.add_argument("--json", action="store_true", help="print JSON instead of a table")


def _confusion_args(s) -> None:
    s.add_argument("file", metavar="FILE.csv", help="tidy table: one row per trial")
    s.add_argument("--stimulus", required=True, metavar="COL", help="what was presented")
    s.add_argument("--response", required=True, metavar="COL", help="what was answered")
    s.add_argument("--by", nargs="+", default=[], metavar="COL", help="one result per level")
    s.add_argument("--labels", nargs="+", metavar="LABEL",
                   help="the categories in order (the order weighted kappa uses)")
    s.add_argument("--json", action="store_true", help="print JSON instead of a table")


def register(subparsers) -> None:
    """Add ``vtexp stats`` and its subcommands to the ``vtexp`` parser."""
    from ..analysis.spec import PADJUST_METHODS
    st = subparsers.add_parser(
        "stats", help="statistics on any tidy CSV (ANOVA, post hoc, rank tests, kappa, "
                      "information transfer, mixed logit)",
        description="Statistics on a tidy CSV/TSV table (one row per observation).")
    sub = st.add_subparsers(dest="stats_command", metavar="ANALYSIS", required=True)
    fmt = argparse.ArgumentDefaultsHelpFormatter
    _register_anova(sub, fmt, PADJUST_METHODS)
    _register_ranks_and_agreement(sub, fmt, PADJUST_METHODS)
    _register_mixed_logit(sub, fmt)


def _register_anova(sub, fmt, padjust_methods) -> None:
    """rm-anova, simple-effects, posthoc and trend: the ANOVA family."""
    s = sub.add_parser("rm-anova", help="repeated-measures or mixed ANOVA (type 3, Mauchly, "
                       "GG/HF, η²p, η²G)", formatter_class=fmt)
    _common(s)
    s.add_argument("--observed", nargs="+", default=[], metavar="COL",
                   help="factors measured rather than manipulated (changes η²G only)")
    s.add_argument("--correction", choices=["auto", "none", "GG", "HF"], default="auto",
                   help="which p the sentences give (auto: GG when Mauchly's p < .05)")
    s.set_defaults(func=cmd_rm_anova)
    s = sub.add_parser("simple-effects", help="simple effects of one factor at each level "
                       "of another (separate or pooled error term)", formatter_class=fmt)
    _common(s)
    s.add_argument("--effect", required=True, metavar="COL")
    s.add_argument("--by", required=True, metavar="COL")
    s.add_argument("--method", choices=["separate", "pooled"], default="separate")
    s.set_defaults(func=cmd_simple_effects)
    s = sub.add_parser("posthoc", help="pairwise comparisons of a factor's levels (within or "
                       "across groups), corrected", formatter_class=fmt)
    _common(s)
    s.add_argument("--factor", required=True, metavar="COL", help="the factor compared")
    s.add_argument("--by", nargs="+", default=[], metavar="COL",
                   help="compare within each level of these factors")
    s.add_argument("--padjust", choices=padjust_methods, default="holm")
    s.add_argument("--error", choices=["paired", "pooled"], default="paired",
                   help="paired: per-participant t tests; pooled: the ANOVA model's error "
                        "(emmeans)")
    s.set_defaults(func=cmd_posthoc)
    s = sub.add_parser("trend", help="polynomial trend contrasts across a graded factor "
                       "(intensity, frequency, SOA)", formatter_class=fmt)
    _common(s)
    s.add_argument("--factor", required=True, metavar="COL")
    s.add_argument("--by", nargs="+", default=[], metavar="COL")
    s.add_argument("--scores", nargs="+", metavar="X",
                   help="the levels' values (default: the levels read as numbers)")
    s.add_argument("--error", choices=["paired", "pooled"], default="paired")
    s.set_defaults(func=cmd_trend)


def _register_ranks_and_agreement(sub, fmt, padjust_methods) -> None:
    """friedman and wilcoxon (rank tests), kappa and information-transfer (confusions)."""
    for name, fn, hlp in (("friedman", cmd_friedman, "Friedman's rank test with Kendall's W"),
                          ("wilcoxon", cmd_wilcoxon, "Wilcoxon signed-rank tests between "
                           "every two levels, corrected")):
        s = sub.add_parser(name, help=hlp, formatter_class=fmt)
        s.add_argument("file", metavar="FILE.csv")
        s.add_argument("--dv", required=True, metavar="COL")
        s.add_argument("--factor", required=True, metavar="COL")
        s.add_argument("--subject", required=True, metavar="COL")
        s.add_argument("--missing", choices=["drop", "error"], default="drop")
        if name == "wilcoxon":
            s.add_argument("--padjust", choices=padjust_methods, default="holm")
        s.add_argument("--json", action="store_true")
        s.set_defaults(func=fn)
    s = sub.add_parser("kappa", help="Cohen's kappa (weighted for ordered answers) between "
                       "stimulus and response", formatter_class=fmt)
    _confusion_args(s)
    s.add_argument("--weights", choices=["linear", "quadratic"],
                   help="weighted kappa for ordered categories (in --labels order)")
    s.set_defaults(func=cmd_kappa)
    s = sub.add_parser("information-transfer", help="information transmitted from stimulus "
                       "to response (bits)", formatter_class=fmt)
    _confusion_args(s)
    s.set_defaults(func=cmd_information_transfer)


def _register_mixed_logit(sub, fmt) -> None:
    s = sub.add_parser("mixed-logit", help="mixed logistic model of a 0/1 outcome, maximum "
                       "likelihood as lme4::glmer", formatter_class=fmt)
    s.add_argument("file", metavar="FILE.csv", help="tidy table: one row per trial")
    s.add_argument("--outcome", required=True, metavar="COL", help="0/1 column")
    s.add_argument("--factors", nargs="+", required=True, metavar="COL")
    s.add_argument("--subject", required=True, metavar="COL")
    s.add_argument("--items", metavar="COL", help="crossed random intercept per item")
    s.add_argument("--interactions", action="store_true")
    s.add_argument("--n-quad", type=int, default=1,
                   help="1 = Laplace; more = adaptive Gauss–Hermite nodes (nAGQ)")
    s.add_argument("--strict", action="store_true",
                   help="refuse (exit 2) instead of warning when the fit does not converge")
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=cmd_mixed_logit)
