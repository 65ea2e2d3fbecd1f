"""``vtexp simulate``: the power of an experiment's analyses, from model participants."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

from ..errors import InputError


def register(sub) -> None:
    """Add ``vtexp simulate`` to the ``vtexp`` parser."""
    s = sub.add_parser(
        "simulate", help="run whole studies of model participants: power of each effect",
        description="Run M simulated studies of N model participants each through the "
                    "experiment's real pipeline and declared analyses, and report for each "
                    "effect the share of studies with p < alpha (power, 95 % Wilson "
                    "interval) and the predicted mean of every condition.")
    s.add_argument("file", metavar="EXPERIMENT")
    s.add_argument("--participants", "-n", type=int, default=15, metavar="N",
                   help="participants per study (default 15)")
    s.add_argument("--studies", "-m", type=int, default=200, metavar="M",
                   help="simulated studies (default 200)")
    s.add_argument("--alpha", type=float, default=0.05, help="significance level (0.05)")
    s.add_argument("--target-power", type=float, metavar="P",
                   help="also find, for each effect, the smallest N whose power reaches P")
    s.add_argument("--max-participants", type=int, default=200, metavar="N",
                   help="give up the --target-power search above N (default 200)")
    s.add_argument("--seed", type=int, default=0, help="simulation seed (default 0)")
    s.add_argument("--observer", metavar="FILE",
                   help="observer parameters (default protocols/observers/default.yaml; a file "
                        "vtexp observer fit wrote also gives power over the fitted "
                        "parameters' 95 %% intervals, each at either end), or "
                        "a stated design (kind: stated): each participant's measure per "
                        "condition drawn from stated means, SDs and correlations, whose "
                        "power is known exactly (see --exact)")
    s.add_argument("--exact", action="store_true",
                   help="with a stated design (--observer FILE of kind: stated): also print "
                        "each ANOVA effect's exact power (noncentral F, as Superpower's "
                        "ANOVA_exact) beside the simulated one, and with --target-power "
                        "the exact smallest N")
    s.add_argument("--workers", type=int, default=0,
                   help="processes (default: one per core)")
    s.add_argument("--executor", default="local", metavar="SPEC",
                   help="where the studies run: local (processes on this computer, the "
                        "default) or dask://HOST:PORT (a Dask scheduler and its workers, "
                        "each with vtexp and the 'cluster' extra; they receive the "
                        "experiment's text, not a path)")
    s.add_argument("--connect-timeout", type=float, default=5.0, metavar="S",
                   help="with --executor dask://: give up reaching the scheduler after S "
                        "seconds (default 5)")
    s.add_argument("--sweep", metavar="FILE",
                   help="a sweep file: lists of participants per study and of experiment "
                        "values (design.repetitions, coding.params.duration_ms, ...); prints "
                        "the power of every effect at every combination (the power surface)")
    s.add_argument("--out", metavar="FILE",
                   help="with --sweep: also write the surface, one row per point, N and "
                        "effect, as CSV (.csv) or JSON (.json)")
    s.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    s.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    s.set_defaults(func=cmd_simulate)


def _progress(total: int, quiet: bool, label: str):
    """A rich progress bar on stderr; returns (advance, stop)."""
    if quiet:
        return (lambda k: None), (lambda: None)
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    bar = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                   TimeElapsedColumn(), TimeRemainingColumn(),
                   console=Console(stderr=True), transient=False)
    task = bar.add_task(label, total=total)
    bar.start()
    return (lambda k: bar.advance(task, k)), bar.stop


def _print_power(res, out=print) -> None:
    out(f"\nPower at N = {res.n} ({res.studies} studies, alpha = {res.alpha}; "
        f"{res.seconds:.1f} s):")
    if res.table.empty:
        out("  the experiment declares no test (no anova: or ordinal: under analysis:), so "
            "there is no power to estimate; the predicted means follow")
        return
    out(f"  {'effect':<58} {'power':>6}  {'95% CI':<13} {'median p':>9} {'mean η²p':>9}")
    for _, r in res.table.iterrows():
        pes = "" if r["mean_pes"] != r["mean_pes"] else f"{r['mean_pes']:.3f}"
        out(f"  {r['effect']:<58} {r['power']:6.3f}  [{r['ci_low']:.3f}, {r['ci_high']:.3f}]"
            f" {r['median_p']:9.3g} {pes:>9}")


def _n_text(n, power: float, n_max: int) -> str:
    found = n is not None and n == n
    return (f"N = {int(n)} (power {power:.3f})" if found
            else f"not reached by N = {n_max} (power {power:.3f})")


def _print_exact(res, exact, out=print) -> None:
    """The exact power of each ANOVA effect beside the simulated one and its interval."""
    out(f"\nExact power at N = {res.n} (noncentral F from the stated means, SDs and "
        "correlations; uncorrected F, Lakens & Caldwell 2021):")
    out(f"  {'effect':<58} {'exact':>6}  {'simulated [95% CI]':<24} in CI")
    sim = res.table.set_index("effect")
    corrected = False
    for _, r in exact.iterrows():
        s = sim.loc[r["effect"]] if r["effect"] in sim.index else None
        mark = ""
        if r["df1"] > 1 and r["correction"] != "none":
            mark, corrected = " *", True
        if s is None:
            out(f"  {r['effect']:<58} {r['exact_power']:6.3f}{mark}")
            continue
        inside = "yes" if s["ci_low"] <= r["exact_power"] <= s["ci_high"] else "no"
        out(f"  {r['effect']:<58} {r['exact_power']:6.3f}  {s['power']:.3f} "
            f"[{s['ci_low']:.3f}, {s['ci_high']:.3f}]{'':<4} {inside}{mark}")
    if corrected:
        out("  * the declared ANOVA corrects this effect for sphericity (correction: auto, GG "
            "or HF), the exact value is for the uncorrected F: the simulated power can be "
            "a little lower")


def _print_means(res, factors: list[str], out=print, stated: bool = False) -> None:
    out("\nMean per condition (all simulated participants' stated measures):" if stated
        else "\nPredicted mean per condition (all simulated trials):")
    t = res.means
    for (q, meas), g in t.groupby(["question", "measure"], sort=False):
        out(f"  {q} ({meas}):")
        for _, r in g.iterrows():
            lv = ", ".join(f"{f}={r[f]}" for f in factors if f in r and r[f] == r[f])
            out(f"    {lv:<58} {r['predicted']:.3f}")


def cmd_simulate(args) -> int:
    from ..compile import load_and_compile

    if not 0 < args.alpha < 1:
        raise InputError("alpha must be between 0 and 1", key="--alpha")
    if args.target_power is not None and not 0 < args.target_power < 1:
        raise InputError("the target power must be between 0 and 1", key="--target-power")
    if args.out and not args.sweep:
        raise InputError("writes a sweep's surface; give --sweep FILE (or --json for one N)",
                         key="--out")
    if args.out and Path(args.out).suffix.lower() not in (".csv", ".json"):
        raise InputError(f"{args.out!r}: name a .csv or .json file", key="--out")
    if args.sweep and args.target_power is not None:
        raise InputError("--target-power searches one design; with --sweep, list the Ns "
                         "under participants:", key="--target-power")
    lx, _ = load_and_compile(args.file)        # clear errors before any worker starts
    stated = None
    if args.observer is not None:
        from ..observer.stated import stated_kind
        if stated_kind(args.observer):
            from ..simulate import StatedSetup
            stated = StatedSetup.load(lx, args.observer)
    if args.exact and stated is None:
        raise InputError("gives the exact power of a stated design: pass --observer FILE "
                         "with kind: stated (e.g. protocols/observers/"
                         "circle_vs_rectangle_stated.yaml)", key="--exact")
    if args.exact and args.sweep:
        raise InputError("prints the exact power of one design; leave it out with --sweep",
                         key="--exact")
    args.stated = stated
    if lx.experiment.adaptive is not None:
        raise InputError("vtexp simulate plays the fixed levels of a design; this experiment "
                         "chooses its levels adaptively. Run sessions with --responder "
                         "scripted:psychometric:threshold=T (or see bench/adaptive.py for the "
                         "procedures' convergence)", path=str(args.file), key="adaptive")
    sweep = None
    if args.sweep:
        from ..sweep import load_sweep, sweep_points
        spec, doc = load_sweep(args.sweep)
        sweep = (spec, sweep_points(args.file, spec, doc, params_file=args.observer))
    client = None
    if args.executor not in ("local", ""):
        from ..cluster import connect, threads
        client = connect(args.executor, timeout_s=args.connect_timeout)   # before any study
    try:
        if client is not None:
            workers, executor = threads(client), client.get_executor(pure=False)
            where = f"{workers} worker threads of {client.scheduler.address}"
        else:
            workers, executor = args.workers or os.cpu_count() or 1, None
            where = f"{workers} processes"
        if sweep is not None:
            return _sweep(args, lx, *sweep, workers, executor, where)
        return _one_n(args, lx, workers, executor, where)
    finally:
        if client is not None:
            client.close()


def _one_n(args, lx, workers, executor, where) -> int:
    from ..simulate import run_power

    factors = list(lx.experiment.factors)
    who = "model participants" if args.stated is None else \
        f"participants drawn from the stated design {args.observer}"
    print(f"{lx.experiment.name}: {args.studies} studies of {args.participants} {who}, "
          f"{where}", file=sys.stderr)
    advance, stop = _progress(args.studies, args.quiet, f"N = {args.participants}")
    try:
        res = run_power(args.file, args.participants, args.studies, alpha=args.alpha,
                        seed=args.seed, workers=workers, params_file=args.observer,
                        progress=advance, executor=executor)
    finally:
        stop()
    _print_power(res)
    runs, unknown = ([], []) if args.stated is not None else \
        _fitted(args, lx)
    ranged = []
    if runs:
        ranged = _power_runs(args, runs, workers, executor, res)
    if unknown:
        print(f"  {', '.join(unknown)}: not identified by the fit; held at the observer "
              "file's value" + (", outside this range" if runs else ""))
    exact = None
    if args.exact:
        exact = args.stated.exact(res.n, res.alpha)
        _print_exact(res, exact)
    _print_means(res, factors, stated=args.stated is not None)
    from ..session import environment
    doc = {"experiment": lx.experiment.name, "experiment_file": str(lx.path),
           "experiment_sha256": lx.sha256, "environment": environment(),
           "participants": res.n, "studies": res.studies, "alpha": res.alpha,
           "seed": args.seed, "observer": args.observer or "protocols/observers/default.yaml",
           "seconds": round(res.seconds, 2), "workers": workers, "executor": args.executor,
           "power": res.table.to_dict(orient="records"),
           **({} if exact is None else {"exact_power": exact.to_dict(orient="records")}),
           "predicted": res.means.astype(object).where(res.means.notna(), None)
           .to_dict(orient="records")}
    if runs:
        from ..simulate import power_range
        rng = power_range(res.table, [(r, t.table) for r, t in ranged])
        doc["power_range"] = {
            "method": "each fitted parameter at its interval's low and high end, the others "
                      "at the centre; the range is min..max over these runs and the centre's",
            "studies_per_run": args.studies, "not_identified": unknown,
            "runs": [{"param": r.param, "end": r.end, "value": r.value,
                      "centre": r.centre, "power": t.table.to_dict(orient="records")}
                     for r, t in ranged],
            "effects": rng.to_dict(orient="records")}
    if args.target_power is not None:
        _target_power(args, workers, executor, runs, doc)
    if args.json:
        Path(args.json).write_text(json.dumps(doc, indent=2, default=str) + "\n",
                                   encoding="utf-8")
        print(f"\nwrote {args.json}", file=sys.stderr)
    return 0


def _target_power(args, workers, executor, runs, doc: dict) -> None:
    """--target-power: the smallest N for each effect (with --exact, the exact one beside
    it; with a fitted file, its range over the fitted intervals), printed and put in
    ``doc``."""
    from ..simulate import smallest_n

    print(f"\nSearching the smallest N with power >= {args.target_power} "
          f"({args.studies} studies per N)...", file=sys.stderr)

    def step(n, r):
        if not args.quiet:
            print(f"  N = {n}: " + ", ".join(f"{p:.2f}" for p in r.table["power"])
                  + f"  ({r.seconds:.1f} s)", file=sys.stderr)

    table, _ = smallest_n(args.file, args.target_power, args.studies, alpha=args.alpha,
                          seed=args.seed, n_max=args.max_participants, workers=workers,
                          params_file=args.observer, on_step=step, executor=executor)
    exact_n = None
    if args.exact:
        exact_n = args.stated.exact_smallest_n(args.target_power, args.alpha,
                                               args.max_participants) \
            .set_index("effect")
    print(f"\nSmallest N for power >= {args.target_power}"
          + (" (simulated; exact)" if exact_n is not None else "") + ":")
    for _, r in table.iterrows():
        n = _n_text(r["smallest_n"], r["power"], args.max_participants)
        if exact_n is not None and r["effect"] in exact_n.index:
            e = exact_n.loc[r["effect"]]
            n += f";  exact {_n_text(e['smallest_n'], e['power'], args.max_participants)}"
        print(f"  {r['effect']:<58} {n}")
    doc["target_power"] = args.target_power
    doc["smallest_n"] = table.astype(object).where(table.notna(), None) \
        .to_dict(orient="records")
    if runs:
        doc["smallest_n_range"] = _n_runs(args, runs, workers, executor, table)
    if exact_n is not None:
        t = exact_n.reset_index()
        doc["exact_smallest_n"] = t.astype(object).where(t.notna(), None) \
            .to_dict(orient="records")


def _fitted(args, lx):
    """The runs over the observer file's fitted intervals (none without a fitted: section)."""
    if args.observer is None:
        return [], []
    from ..observer.model import ObserverModel
    from ..simulate import fitted_runs
    model = ObserverModel.for_experiment(lx, params_file=args.observer)
    runs, unknown = fitted_runs(args.observer, model.site)
    held = sorted({r.param for r in runs if r.param in model.spec.params})
    if held:
        print(f"  {', '.join(held)}: set by the experiment's observer.params, which overrides "
              "the observer file; left out of the range", file=sys.stderr)
    return [r for r in runs if r.param not in held], unknown


def _run_label(r) -> str:
    return f"{r.param} = {r.value:.4g} ({r.end})"


def _power_runs(args, runs, workers, executor, centre):
    """Power with each fitted parameter at each end of its interval; the range printed."""
    from ..simulate import power_range, run_power
    params = sorted({r.param for r in runs})
    print(f"\nPower over the fitted parameters' 95 % intervals ({', '.join(params)}): "
          f"{len(runs)} more run{'' if len(runs) == 1 else 's'} of {args.studies} studies "
          f"({len(runs) * args.studies} "
          f"studies more; {len(runs) + 1} times the centre's cost in all)...", file=sys.stderr)
    out = []
    for r in runs:
        advance, stop = _progress(args.studies, args.quiet, _run_label(r))
        try:
            t = run_power(args.file, args.participants, args.studies, alpha=args.alpha,
                          seed=args.seed, workers=workers, params_file=args.observer,
                          overrides=r.overrides, progress=advance, executor=executor)
        finally:
            stop()
        out.append((r, t))
    if centre.table.empty:
        return out
    rng = power_range(centre.table, [(r, t.table) for r, t in out])
    print(f"\nPower over the fitted parameters' 95 % intervals at N = {centre.n} (each "
          "parameter at its interval's low and high end, the others at the centre; the "
          f"same simulated participants in every run; {len(runs) + 1} runs of "
          f"{args.studies} studies):")
    print(f"  {'effect':<58} {'centre':>6}  {'range':<14}")
    for _, e in rng.iterrows():
        print(f"  {e['effect']:<58} {e['centre']:6.3f}  {e['low']:.3f} .. {e['high']:.3f}")
        for r, t in out:
            row = t.table.set_index("effect").loc[e["effect"]]
            print(f"      {_run_label(r):<40} {row['power']:.3f} "
                  f"[{row['ci_low']:.3f}, {row['ci_high']:.3f}]")
    return out


def _n_runs(args, runs, workers, executor, centre) -> list[dict]:
    """The smallest N with each fitted parameter at each end of its interval."""
    from ..simulate import smallest_n
    print(f"\nSearching the smallest N over the fitted intervals: {len(runs)} more "
          f"searches of {args.studies} studies per N ({len(runs) + 1} times the centre's "
          "search in all)...", file=sys.stderr)
    found = []
    for r in runs:
        table, res = smallest_n(args.file, args.target_power, args.studies, alpha=args.alpha,
                                seed=args.seed, n_max=args.max_participants,
                                workers=workers, params_file=args.observer,
                                overrides=r.overrides, executor=executor)
        print(f"  {_run_label(r)}: {len(res)} Ns simulated", file=sys.stderr)
        found.append((r, table.set_index("effect")))
    inf = float("inf")

    def n_of(x):
        return inf if x is None or x != x else int(x)

    def text(x):
        return f"> {args.max_participants}" if x == inf else str(x)
    print(f"\nSmallest N for power >= {args.target_power} over the fitted parameters' 95 % "
          f"intervals ({len(runs) + 1} searches):")
    rows = []
    for _, c in centre.iterrows():
        ns = {"centre": n_of(c["smallest_n"])}
        each = []
        for r, t in found:
            n = n_of(t.loc[c["effect"], "smallest_n"]) if c["effect"] in t.index else inf
            each.append({"param": r.param, "end": r.end, "value": r.value,
                         "smallest_n": None if n == inf else n})
            ns[_run_label(r)] = n
        lo, hi = min(ns.values()), max(ns.values())
        at = text(ns["centre"])
        print(f"  {c['effect']:<58} N {at if at.startswith('>') else '= ' + at} at the "
              f"centre; {text(lo)} .. {text(hi)} over the intervals")
        print("      " + "; ".join(f"{k}: {text(v)}" for k, v in ns.items() if k != "centre"))
        rows.append({"effect": c["effect"],
                     "centre": None if ns["centre"] == inf else ns["centre"],
                     "low": None if lo == inf else lo, "high": None if hi == inf else hi,
                     "runs": each})
    return rows


def _sweep(args, lx, spec, points, workers, executor, where) -> int:
    """The power surface of a sweep (``vtexp.sweep``)."""
    from concurrent.futures import ProcessPoolExecutor

    from ..sweep import run_sweep, surface_lines

    studies = spec.studies or args.studies
    keys = list(spec.vary)
    total = len(points) * len(spec.participants)
    print(f"{lx.experiment.name}: sweep of {len(points)} design"
          f"{'' if len(points) == 1 else 's'} x {len(spec.participants)} N = {total} points, "
          f"{studies} studies each, {where}", file=sys.stderr)
    pool = None
    if executor is None and workers > 1:
        pool = executor = ProcessPoolExecutor(workers)     # one pool for every point
    advance, stop = _progress(total * studies, args.quiet, "sweep")

    def point(p, n, res):
        advance(studies)

    try:
        table = run_sweep(points, spec.participants, studies, alpha=args.alpha,
                          seed=args.seed, workers=workers, executor=executor, on_point=point)
    finally:
        stop()
        if pool is not None:
            pool.shutdown(cancel_futures=True)
    print(f"\nPower surface ({studies} studies per point, alpha = {args.alpha}):")
    for line in surface_lines(table, keys):
        print(f"  {line}")
    if args.out:
        out = Path(args.out)
        if out.suffix.lower() == ".csv":
            table.to_csv(out, index=False)
        else:
            doc = {"experiment": lx.experiment.name, "experiment_sha256": lx.sha256,
                   "sweep": str(args.sweep), "studies": studies, "alpha": args.alpha,
                   "seed": args.seed, "executor": args.executor,
                   "points": [{"setting": p.setting, "sha256": p.source.sha256}
                              for p in points],
                   "power": table.astype(object).where(table.notna(), None)
                   .to_dict(orient="records")}
            out.write_text(json.dumps(doc, indent=2, default=str) + "\n", encoding="utf-8")
        print(f"\nwrote {out}", file=sys.stderr)
    return 0
