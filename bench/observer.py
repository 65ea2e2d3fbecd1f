"""Fitting the model participant: does ``vtexp observer fit`` recover known parameters, how
long does a pilot take, and what did the model's new structure do to each study's power?

Recovery (Wilson & Collins 2019, rule 6). For each study, D simulated pilots (default
20) of N model participants (default 4) each answer every trial of the study's trial
list (``vtexp.simulate.simulate_participant``: the same answers a session with the
model responder logs). Each participant draws their own efficiency, decision noise,
lapse and rating bias from the default population (``protocols/observers/default.yaml``);
their percept parameters (two-point threshold, integration time, intensity levels) are
the population's typical ones, which is what the fit holds fixed: the fitted model is
the model that made the data. By default each study is fitted for every decision
parameter its answers depend on (``STUDY_PARAMS``: efficiency, decision noise and lapse
everywhere; the abstain criterion where a question has an abstain option; the rating
step and bias where one is rated; the turns' SD where turns are counted). A percept
parameter in ``--params`` (``integration_ms``, ``two_point_threshold_mm``) varies between
participants as the default population draws it (in 5 bins), and is fitted on its grid
of percepts. Each participant is fitted back
(``vtexp observer fit``'s own path, the parameters of ``--params``), and each pilot's
population (``vtexp.observer.fit.population``). Reported per study and parameter:

- identified: the share of participants whose profile is not flat from bound to bound;
- bias and RMSE of the estimates against the truth (identified participants; on the
  log scale for efficiency and decision noise, as log10 ratios), median interval width;
- coverage: the share of 95 % profile intervals (identified or not) that hold the truth;
- the population's centre against the population's true median (log10 ratio), and
  the coverage of its 95 % interval (the ``fitted:`` section ``vtexp observer fit``
  writes): the share of pilots whose interval holds the true centre, over the pilots
  whose centre is identified (a pilot whose centre is not identified keeps the observer
  file's value, which is the truth here); the centre's interval as ``vtexp observer
  fit`` cuts it (``centre_cut``: the t interval's cut for the participants who estimate
  the spread) and, beside it ("chi2 cover"), cut at the large-sample 3.84 / 2.

Time. Fit time per participant (all profiles included) and per pilot in one process;
one pilot fitted with ``--workers`` processes, as ``vtexp observer fit --workers``
does (goal: a 4-participant pilot of the six-mode study in under a minute on 2
cores). Baseline in the same run: the time of one likelihood evaluation against the
same likelihood estimated by simulating the model's answers (2,000 draws per condition:
about 1 % error per probability, where the fit's quadrature is within 0.1-0.3 %).

Power before and after (``--power M``): M simulated studies (``vtexp.simulate.run_power``,
seed 0, as ``vtexp simulate``) of each study at its paper's N (``PAPER_N``), with the
model participant before the structure of 2026-11-27 (``protocols/observers/
structure_off.yaml``: answers rendered through the pipeline, no low-speed prior, no
SMA pin heating) and after (the default observer): each declared effect's power.

Prints tables and writes JSON to bench/results/observer.json (``--json`` elsewhere).
Usage: python bench/observer.py [--datasets D] [--participants N] [--studies a,b]
       [--params study|efficiency,lapse] [--workers W] [--power M] [--first D0]
       [--json FILE]
       python bench/observer.py --merge A.json B.json [--json FILE]
``--datasets 0`` skips recovery and timing. One long run split over processes: pilots
numbered from ``--first`` in each (e.g. ``--datasets 100 --first 0`` and ``--datasets 100
--first 100``), then ``--merge`` their JSON files for the table of all of them.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vtexp.observer.fit import (  # noqa: E402
    PERCEPT_PARAMS, _fit_one, population, simulated_trials, spec_of)
from vtexp.observer.likelihood import Likelihood, decision_values  # noqa: E402
from vtexp.observer.model import question_columns  # noqa: E402
from vtexp.simulate import Setup, simulate_participant  # noqa: E402

#: The decision parameters each study's answers depend on (``--params study``).
STUDY_PARAMS = {
    "six_mode_ball": "efficiency,decision_noise,lapse,abstain_criterion",
    "duration_interval_grid": "efficiency,decision_noise,lapse",
    "letters": "efficiency,decision_noise,lapse",
    "whirlpool": "efficiency,decision_noise,lapse,rating_step,rating_bias,turns_sd",
    "circle_vs_rectangle": "efficiency,decision_noise,lapse,rating_step,rating_bias",
}
#: Each paper's number of participants (docs/model-predictions.md).
PAPER_N = {"six_mode_ball": 15, "duration_interval_grid": 10, "letters": 10, "whirlpool": 7,
           "circle_vs_rectangle": 7}
BEFORE = ROOT / "protocols" / "observers" / "structure_off.yaml"
SAME_SKIN = {"population": {"two_point_threshold_cv": 0.0, "integration_cv": 0.0,
                            "intensity_levels_sd": 0.0}}
SEED = 20261127
_SETUPS: dict[str, Setup] = {}


def setup_of(study: str, names: tuple = ()) -> Setup:
    """The study's model; its participants' percepts all typical, except the percept
    parameter being fitted (``names``), which varies as the default population has it."""
    key = (study, tuple(n for n in names if n in PERCEPT_PARAMS))
    if key not in _SETUPS:
        varied = {PERCEPT_PARAMS[n].spread for n in key[1]}
        spread = {k: v for k, v in SAME_SKIN["population"].items() if k not in varied}
        _SETUPS[key] = Setup.load(ROOT / "experiments" / f"{study}.yaml",
                                  overrides={"population": spread})
    return _SETUPS[key]


def truth_of(who, name: str) -> float:
    if name in ("abstain_criterion", "rating_step", "turns_sd"):
        return float("nan")          # one value for everyone: filled in by the caller
    return float(getattr(who, name))


def fit_one(args) -> tuple[list[dict], object]:
    """Participant ``i`` of pilot ``d``: simulated, fitted back; their rows and fit."""
    study, d, i, names = args
    setup = setup_of(study, tuple(names))
    m = setup.model
    fixed = decision_values(m)
    skin = m.participant(0, "fit", typical=True)
    pid = f"d{d}p{i + 1}"
    who = m.participant(SEED, pid)
    t0 = time.perf_counter()
    # vtexp observer fit's own path (a percept parameter on its grid of percepts)
    f = _fit_one((m, skin, simulated_trials(setup, simulate_participant(setup, SEED, pid)), names,
                  fixed, pid))
    dt = time.perf_counter() - t0
    rows = []
    for name in names:
        p = f.params[name]
        truth = truth_of(who, name)
        if truth != truth:
            truth = float(fixed[name])
        rows.append({"study": study, "dataset": d, "participant": pid, "param": name,
                     "truth": truth, "estimate": p.estimate, "low": p.low, "high": p.high,
                     "identified": p.identified, "seconds": dt, "answers": f.answers})
    return rows, f


def pilot(args) -> dict:
    """One simulated pilot: its participants fitted back, and its population."""
    study, d, n, names = args
    got = [fit_one((study, d, i, names)) for i in range(n)]
    pop = population([f for _, f in got], names, setup_of(study, tuple(names)).model.params)
    return {"rows": [r for rows, _ in got for r in rows], "population": pop.values,
            "spreads": pop.spreads, "intervals": {k: list(v) for k, v in pop.intervals.items()},
            "chi2_intervals": {k: list(v) for k, v in pop.chi2_intervals.items()},
            "not_identified": list(pop.not_identified), "dataset": d}


def eval_baseline(study: str, seconds: float = 3.0) -> dict:
    """One likelihood evaluation of a participant, against simulating the answers."""
    setup = setup_of(study)
    m = setup.model
    skin = m.participant(0, "fit", typical=True)
    lik = Likelihood(m, skin, simulated_trials(setup, simulate_participant(setup, SEED, "base")))
    v = decision_values(m)
    k, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds / 2 or k < 5:
        lik(v)
        k += 1
    ours = (time.perf_counter() - t0) / k
    rng = np.random.default_rng(1)
    qs = m.lx.experiment.asked()
    k, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds / 2 or k < 2:
        for q in qs:
            for c, p in zip(setup.conditions, setup.played, strict=True):
                m.answers(q, c, p, skin, rng.random((2000, question_columns(q))),
                          played_key=("condition", c.index))
        k += 1
    sim = (time.perf_counter() - t0) / k
    return {"likelihood_ms": ours * 1e3, "simulated_2000_ms": sim * 1e3, "ratio": sim / ours}


def summarise(rows: list[dict], pops: list[dict], names: list[str], study: str) -> list[dict]:
    out = []
    for name in names:
        rs = [r for r in rows if r["study"] == study and r["param"] == name]
        spec = spec_of(name)
        ident = [r for r in rs if r["identified"]]

        def err(r):
            if spec.log:
                return math.log10(r["estimate"] / r["truth"])
            return r["estimate"] - r["truth"]
        errs = np.array([err(r) for r in ident]) if ident else np.array([])
        cover = np.mean([r["low"] - 1e-12 <= r["truth"] <= r["high"] + 1e-12 for r in rs])
        widths = [(math.log10(r["high"] / max(r["low"], 1e-12)) if spec.log
                   else r["high"] - r["low"]) for r in ident]
        mine = [p for p in pops if p["study"] == study]
        centre = [p["population"].get(name) for p in mine]
        centre = [c for c in centre if c is not None]
        true_centre = mine[0]["true_centre"].get(name, float("nan")) if mine else float("nan")
        def cover_width(key):
            held = [p[key][name] for p in mine if name in p.get(key, {})]
            if not held:
                return held, float("nan"), float("nan")
            return (held,
                    float(np.mean([lo - 1e-9 <= true_centre <= hi + 1e-9 for lo, hi in held])),
                    float(np.median([math.log10(hi / lo) if spec.log and lo > 0 else hi - lo
                                     for lo, hi in held])))
        held, pop_cover, pop_width = cover_width("intervals")
        held2, pop_cover2, pop_width2 = cover_width("chi2_intervals")
        if centre and true_centre and spec.log:
            cerr = np.array([math.log10(c / true_centre) for c in centre])
        else:
            cerr = np.array([c - true_centre for c in centre])
        out.append({"study": study, "param": name, "fits": len(rs),
                    "identified": len(ident) / max(len(rs), 1),
                    "scale": "log10 ratio" if spec.log else "units",
                    "bias": float(errs.mean()) if len(errs) else float("nan"),
                    "rmse": float(np.sqrt((errs ** 2).mean())) if len(errs) else float("nan"),
                    "median_width": float(np.median(widths)) if widths else float("nan"),
                    "coverage": float(cover),
                    "population_pilots": len(centre),
                    "population_bias": float(cerr.mean()) if len(cerr) else float("nan"),
                    "population_rmse": float(np.sqrt((cerr ** 2).mean())) if len(cerr)
                    else float("nan"),
                    "true_centre": true_centre,
                    "population_intervals": len(held),
                    "population_identified": len(held) / max(len(mine), 1),
                    "population_median_width": pop_width,
                    "population_coverage": pop_cover,
                    "population_identified_chi2": len(held2) / max(len(mine), 1),
                    "population_median_width_chi2": pop_width2,
                    "population_coverage_chi2": pop_cover2})
    return out


def true_centres(setup: Setup, names: list[str]) -> dict[str, float]:
    """The population's true centre of each parameter (its median; rating bias: none)."""
    params = setup.model.params
    fixed = decision_values(setup.model)
    out = {n: float(fixed[n]) for n in names if n in fixed and n != "rating_bias"}
    if "two_point_threshold_mm" in names:
        out["two_point_threshold_mm"] = float(params.two_point_threshold_mm[setup.model.site])
    if "integration_ms" in names:
        out["integration_ms"] = float(params.integration_of(setup.model.site))
    return out


def recovery(study: str, names: list[str], args) -> tuple[list[dict], list[dict], dict]:
    """D pilots of the study fitted back: their rows, the summary, the timing."""
    setup = setup_of(study, tuple(names))
    base = eval_baseline(study)
    # One pilot in one process; with several workers the same pilot's participants over
    # them, as vtexp observer fit --workers fits them (fresh processes: their start and
    # the experiment's preparation included); then the other pilots.
    t0 = time.perf_counter()
    one = pilot((study, args.first, args.participants, names))
    serial = time.perf_counter() - t0
    parallel = float("nan")
    jobs = [(study, d, args.participants, names)
            for d in range(args.first + 1, args.first + args.datasets)]
    t0 = time.perf_counter()
    if args.workers > 1:
        with ProcessPoolExecutor(args.workers) as pool:
            list(pool.map(fit_one, [(study, args.first, i, names)
                                    for i in range(args.participants)]))
        parallel = time.perf_counter() - t0
        t0 = time.perf_counter()
        with ProcessPoolExecutor(args.workers) as pool:
            rest = list(pool.map(pilot, jobs))
    else:
        rest = []
        for k, j in enumerate(jobs):
            rest.append(pilot(j))
            if (k + 2) % 20 == 0:
                print(f"  {study}: {k + 2} of {args.datasets} pilots, "
                      f"{time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    pilots_s = time.perf_counter() - t0
    pilots = [one, *rest]
    centres = true_centres(setup, names)
    pops = [{"study": study, "dataset": p["dataset"], "population": p["population"],
             "intervals": p["intervals"], "chi2_intervals": p["chi2_intervals"],
             "true_centre": centres} for p in pilots]
    rows = [r for p in pilots for r in p["rows"]]
    per = [r["seconds"] for r in rows if r["param"] == names[0]]
    timing = {"study": study, "params": names,
              "trials_per_participant": int(np.median([r["answers"] for r in rows])),
              "participant_s_median": float(np.median(per)),
              "participant_s_p95": float(np.percentile(per, 95)),
              "participant_s_mean": float(np.mean(per)),
              "pilot_s_one_process": serial, "pilot_s_on_workers": parallel,
              "pilots_per_minute": (args.datasets - 1) / pilots_s * 60
              if args.datasets > 1 else float("nan"),
              "workers": args.workers, **base}
    return rows, summarise(rows, pops, names, study), timing, pops


def power_before_after(study: str, studies: int) -> list[dict]:
    """Each declared effect's power at the paper's N, before and after the structure."""
    from vtexp.simulate import run_power
    path = ROOT / "experiments" / f"{study}.yaml"
    n = PAPER_N[study]
    out: dict[str, dict] = {}
    for label, params_file in (("before", str(BEFORE)), ("after", None)):
        res = run_power(path, n, studies, workers=1, params_file=params_file)
        for r in res.table.to_dict("records"):
            row = out.setdefault(r["effect"], {"study": study, "effect": r["effect"], "n": n,
                                               "studies": studies})
            row[label] = r["power"]
            row[f"{label}_ci"] = [r["ci_low"], r["ci_high"]]
            row[f"{label}_seconds"] = res.seconds
    return list(out.values())


def print_recovery(summary, timing, args) -> None:
    print(f"Recovery: {args.datasets} simulated pilots x {args.participants} participants per "
          "study (95 % profile-likelihood intervals; scale parameters in log10 ratios)")
    print(f"{'study':22} {'param':22} {'ident.':>6} {'bias':>7} {'RMSE':>6} {'width':>6} "
          f"{'cover':>6} | {'centre bias':>11} {'RMSE':>6} {'ident.':>6} {'width':>6} "
          f"{'cover':>6} {'chi2 cover':>10}")
    for s in summary:
        print(f"{s['study']:22} {s['param']:22} {s['identified']:6.2f} {s['bias']:+7.3f} "
              f"{s['rmse']:6.3f} {s['median_width']:6.3f} {s['coverage']:6.2f} | "
              f"{s['population_bias']:+11.3f} {s['population_rmse']:6.3f} "
              f"{s['population_identified']:6.2f} {s['population_median_width']:6.3f} "
              f"{s['population_coverage']:6.2f} {s['population_coverage_chi2']:10.2f}")
    print("\nTime (fits of every participant, all profiles included):")
    print(f"{'study':22} {'trials':>6} {'params':>6} {'s/participant':>13} {'p95':>6} "
          f"{'pilot, 1 proc':>13} {f'on {args.workers}':>6} {'pilots/min':>10} "
          f"{'lik. ms':>8} {'sim. 2000 ms':>12} {'ratio':>6}")
    for t in timing:
        print(f"{t['study']:22} {t['trials_per_participant']:6d} {len(t['params']):6d} "
              f"{t['participant_s_median']:13.2f} {t['participant_s_p95']:6.2f} "
              f"{t['pilot_s_one_process']:13.1f} {t['pilot_s_on_workers']:6.1f} "
              f"{t['pilots_per_minute']:10.1f} "
              f"{t['likelihood_ms']:8.2f} {t['simulated_2000_ms']:12.1f} {t['ratio']:6.0f}")
    six = [t for t in timing if t["study"] == "six_mode_ball"]
    if six:
        best = np.nanmin([six[0]["pilot_s_one_process"], six[0]["pilot_s_on_workers"]])
        print(f"goal: a {args.participants}-participant six-mode pilot in under 60 s on "
              f"2 cores: {best:.1f} s ({args.workers} process(es)): "
              f"{'met' if best < 60 else 'NOT met'}")


def print_power(power: list[dict]) -> None:
    studies = power[0]["studies"]
    print(f"\nPower at the papers' N ({studies} studies each, seed 0), before "
          f"({BEFORE.name}) and after (default.yaml):")
    print(f"{'study':22} {'N':>3} {'effect':48} {'before':>7} {'after':>7}")
    for r in power:
        before, after = r.get("before", float("nan")), r.get("after", float("nan"))
        print(f"{r['study']:22} {r['n']:3d} {r['effect']:48} {before:7.3f} {after:7.3f}")


def write_json(path: str, doc: dict) -> None:
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(doc, indent=2), encoding="utf-8")
    print(f"wrote {out}")


def merge(args) -> None:
    """Runs split over processes (``--first``), summarised as one."""
    docs = [json.loads(Path(f).read_text(encoding="utf-8")) for f in args.merge]
    fits = [r for d in docs for r in d["fits"]]
    pilots = [p for d in docs for p in d.get("pilots", [])]
    keys = [(p["study"], p["dataset"]) for p in pilots]
    if len(set(keys)) != len(keys):
        raise SystemExit("the runs share pilots: give each its own --first")
    summary = []
    for study in dict.fromkeys(r["study"] for r in fits):
        names = list(dict.fromkeys(r["param"] for r in fits if r["study"] == study))
        summary.extend(summarise(fits, pilots, names, study))
    timing = [t for d in docs for t in d["timing"]]
    args.datasets = len(pilots) // max(len({p["study"] for p in pilots}), 1)
    args.participants = docs[0]["participants"]
    print_recovery(summary, timing, args)
    write_json(args.json, {
        "datasets": args.datasets, "participants": args.participants,
        "params": docs[0]["params"], "merged": list(map(str, args.merge)),
        "summary": summary, "timing": timing, "power": [], "fits": fits, "pilots": pilots,
        "machine": docs[0]["machine"]})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--datasets", type=int, default=20)
    ap.add_argument("--participants", type=int, default=4)
    ap.add_argument("--studies", default=",".join(STUDY_PARAMS))
    ap.add_argument("--params", default="study",
                    help="parameters to fit, or 'study': each study's STUDY_PARAMS")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--power", type=int, default=0, metavar="M",
                    help="also the power before/after from M simulated studies per study")
    ap.add_argument("--first", type=int, default=0, metavar="D0",
                    help="number the pilots from D0 (to split one run over processes)")
    ap.add_argument("--merge", nargs="+", metavar="JSON",
                    help="summarise the fits of these runs' JSON files together (pilots "
                         "numbered apart with --first) and write --json")
    ap.add_argument("--json", default=str(ROOT / "bench" / "results" / "observer.json"))
    args = ap.parse_args()
    studies = args.studies.split(",")
    t_all = time.perf_counter()
    if args.merge:
        return merge(args)
    results, summary, timing, power, pilots = [], [], [], [], []
    for study in studies:
        if args.datasets > 0:
            names = (STUDY_PARAMS[study] if args.params == "study" else args.params).split(",")
            rows, summ, tim, pops = recovery(study, names, args)
            results.extend(rows)
            pilots.extend(pops)
            summary.extend(summ)
            timing.append(tim)
        if args.power > 0 and study in PAPER_N:
            power.extend(power_before_after(study, args.power))
    if summary:
        print_recovery(summary, timing, args)
    if power:
        print_power(power)
    print(f"total {time.perf_counter() - t_all:.0f} s")
    write_json(args.json, {
        "datasets": args.datasets, "participants": args.participants, "params": args.params,
        "first": args.first, "summary": summary, "timing": timing, "power": power,
        "fits": results, "pilots": pilots,
        "machine": {"python": platform.python_version(), "platform": platform.platform(),
                    "numpy": np.__version__}})


if __name__ == "__main__":
    main()
