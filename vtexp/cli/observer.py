"""``vtexp observer fit``: the model participant's parameters from logged sessions."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from ..errors import InputError
from ._io import note, out


def register(sub) -> None:
    """Add ``vtexp observer fit`` to the ``vtexp`` parser."""
    s = sub.add_parser("observer", help="the model participant: fit it to logged sessions",
                       description="The model participant (vtexp simulate's).")
    ss = s.add_subparsers(dest="observer_command", metavar="COMMAND", required=True)
    f = ss.add_parser(
        "fit", help="estimate the model participant's parameters from logged sessions",
        description="Estimate each participant's parameters by maximum likelihood over their "
                    "answers (the percept of each trial from what the device reported "
                    "playing), with 95 %% profile-likelihood intervals; say which parameters "
                    "the data do not identify; write the population as an observer file for "
                    "vtexp simulate --observer.")
    f.add_argument("data", nargs="+", metavar="DATA",
                   help="datasets or session folders, as vtexp analyze takes them")
    f.add_argument("--params", default="efficiency,lapse", metavar="A,B",
                   help="parameters to fit, comma-separated (default efficiency,lapse; also "
                        "decision_noise, abstain_criterion, rating_bias, rating_step, "
                        "turns_sd, and one of integration_ms and two_point_threshold_mm)")
    f.add_argument("--observer", metavar="FILE",
                   help="the observer file whose other values are held fixed (default "
                        "protocols/observers/default.yaml)")
    f.add_argument("--out", metavar="FILE",
                   help="the fitted observer file (default observer-<experiment>.yaml)")
    f.add_argument("--json", metavar="FILE", help="also write every estimate as JSON")
    f.add_argument("--workers", type=int, default=1,
                   help="participants fitted at once, in processes (default 1)")
    f.add_argument("--include-simulated", action="store_true",
                   help="fit model participants' sessions with people's (as vtexp analyze)")
    f.set_defaults(func=cmd_fit)


def cmd_fit(args) -> int:
    from ..observer.fit import fit_all, observer_yaml, read_trials
    from ..resources import protocols_dir

    names = [n.strip() for n in args.params.split(",") if n.strip()]
    if args.workers < 1:
        raise InputError("give at least 1 worker", key="--workers")
    if args.observer is not None and not Path(args.observer).is_file():
        raise InputError("no such observer file", path=args.observer)
    data = read_trials(args.data, params_file=args.observer,
                       include_simulated=args.include_simulated)
    from ..observer.fit import check_names
    check_names(names, data.model)
    for n in data.notes:
        note(n)
    exp = data.model.lx.experiment
    n_answers = sum(len(t) for t in data.trials.values())
    print(f"{exp.name}: fitting {', '.join(names)} to {len(data.trials)} participant(s), "
          f"{n_answers} answers from {data.sessions} session(s)...", file=sys.stderr,
          flush=True)
    res = fit_all(data, names, workers=args.workers)
    for n in res.notes[len(data.notes):]:
        note(n)
    _print(res, names)
    base = Path(args.observer) if args.observer else protocols_dir() / "observers" / "default.yaml"
    target = Path(args.out) if args.out else Path(f"observer-{exp.name}.yaml")
    text = observer_yaml(base, res.population, res.fits, names,
                         source=", ".join(map(str, args.data)), experiment=exp.name,
                         site=data.model.site)
    try:
        target.write_text(text, encoding="utf-8")
    except OSError as e:
        raise InputError(f"cannot write: {e.strerror or e}", path=str(target)) from None
    from ..observer.params import load_params
    load_params(target)                  # what vtexp simulate --observer will read
    out(f"\nwrote {target}: vtexp simulate {data.model.lx.path} --observer {target}")
    if args.json:
        doc = {"experiment": exp.name, "data": list(map(str, args.data)), "params": names,
               "observer": str(base), "seconds": round(res.seconds, 2),
               "participants": [{"participant": f.participant, "answers": f.answers,
                                 "loglik": f.loglik, "seconds": round(f.seconds, 3),
                                 "evaluations": f.evaluations, "notes": f.notes,
                                 **{n: {"estimate": p.estimate, "low": p.low, "high": p.high,
                                        "identified": p.identified}
                                    for n, p in f.params.items()}} for f in res.fits],
               "population": {"values": res.population.values,
                              "spreads": res.population.spreads,
                              "participants": res.population.used,
                              "intervals": {k: list(v) for k, v in
                                            res.population.intervals.items()},
                              "not_identified": res.population.not_identified,
                              "notes": res.population.notes}}
        Path(args.json).write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
        print(f"wrote {args.json}", file=sys.stderr)
    return 0


def _print(res, names: list[str]) -> None:
    w = max(11, *(len(f.participant) for f in res.fits))
    head = f"{'participant':<{w}} {'answers':>7} {'log-lik':>9}  " + "  ".join(
        f"{n + ' [95% CI]':<26}" for n in names)
    out(head)
    for f in res.fits:
        out(f"{f.participant:<{w}} {f.answers:>7} {f.loglik:>9.2f}  " + "  ".join(
            f"{f.params[n].text():<26}" for n in names))
        for t in f.notes:
            out(f"{'':<{w}}   {t}")
    pop = res.population
    out(f"\npopulation ({len(res.fits)} participant(s); centre [95% profile-likelihood "
        f"interval]); in {res.seconds:.1f} s:")
    for n in names:
        used = pop.used.get(n, 0)
        if n == "rating_bias" and used:
            out(f"  {n}: centred on no bias (as the model draws it){_spread_text(n, pop.spreads)} "
                f"(from the {used} participant(s) whose data identify it)")
        elif n in pop.values:
            spread = _spread_text(n, pop.spreads)
            ci = pop.intervals.get(n)
            ci = f" [{ci[0]:.4g}, {ci[1]:.4g}]" if ci else " (centre not identified)"
            out(f"  {n}: {pop.values[n]:.4g}{ci}{spread} (from the {used} participant(s) "
                "whose data identify it)")
        else:
            out(f"  {n}: not identified by these data; the observer file keeps its value")
    for t in pop.notes:
        if "identified for no" not in t:
            out(f"  {t}")


def _spread_text(name: str, spreads: dict) -> str:
    from ..observer.fit import spec_of
    field = spec_of(name).spread
    if field is None or field not in spreads:
        return ""
    label = "CV" if field.endswith("_cv") else "SD" + (" of the logit" if "logit" in field
                                                      else "")
    return f", {label} {spreads[field]:.3g} across participants"
