"""Fitting the model participant: does ``vtexp observer fit`` recover known parameters, and
how long does a pilot take?

Recovery (Wilson & Collins 2019, rule 6). For each study, D simulated pilots (default
20) of N model participants (default 4) each answer every trial of the study's trial
list (``vtexp.simulate.simulate_participant``: the same answers a session with the
model responder logs). Each participant draws their own efficiency, decision noise,
lapse and rating bias from the default population (``protocols/observers/default.yaml``);
their percept parameters (two-point threshold, integration time, intensity levels) are
the population's typical ones, which is what the fit holds fixed: the fitted model is
the model that made the data. A percept parameter in ``--params`` (``integration_ms``,
``two_point_threshold_mm``) varies between participants as the default population
draws it (in 5 bins), and is fitted on its grid of percepts. Each participant is fitted back
(``vtexp observer fit``'s own path, the parameters of ``--params``), and each pilot's
population (``vtexp.observer.fit.population``). Reported per study and parameter:

- identified: the share of participants whose profile is not flat from bound to bound;
- bias and RMSE of the estimates against the truth (identified participants; on the
  log scale for efficiency and decision noise, as log10 ratios), median interval width;
- coverage: the share of 95 % profile intervals (identified or not) that hold the truth;
- the population's centre against the population's true median (log10 ratio).

Time. Fit time per participant (all profiles included) and per pilot in one process;
one pilot fitted with ``--workers`` processes, as ``vtexp observer fit --workers``
does (goal: a 4-participant pilot of the six-mode study in under a minute on 2
cores). Baseline in the same run: the time of one likelihood evaluation against the
same likelihood estimated by simulating the model's answers (2,000 draws per condition:
about 1 % error per probability, where the fit's quadrature is within 0.1-0.3 %).

Prints a table and writes JSON to bench/results/observer.json.
Usage: python bench/observer.py [--datasets D] [--participants N] [--studies a,b]
       [--params efficiency,lapse] [--workers W]
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
            "spreads": pop.spreads}


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
        centre = [p["population"].get(name) for p in pops if p["study"] == study]
        centre = [c for c in centre if c is not None]
        true_centre = pops[0]["true_centre"][name] if pops else float("nan")
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
                    else float("nan")})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--datasets", type=int, default=20)
    ap.add_argument("--participants", type=int, default=4)
    ap.add_argument("--studies", default="six_mode_ball,duration_interval_grid")
    ap.add_argument("--params", default="efficiency,lapse")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    names = args.params.split(",")
    studies = args.studies.split(",")
    t_all = time.perf_counter()
    results, summary, timing = [], [], []
    for study in studies:
        setup = setup_of(study, tuple(names))
        base = eval_baseline(study)
        # One pilot in one process; the same pilot's participants over the workers, as
        # vtexp observer fit --workers fits them (fresh processes: their start and the
        # experiment's preparation included); then the other pilots over the workers.
        t0 = time.perf_counter()
        one = pilot((study, 0, args.participants, names))
        serial = time.perf_counter() - t0
        t0 = time.perf_counter()
        with ProcessPoolExecutor(args.workers) as pool:
            list(pool.map(fit_one, [(study, 0, i, names) for i in range(args.participants)]))
        parallel = time.perf_counter() - t0
        t0 = time.perf_counter()
        with ProcessPoolExecutor(args.workers) as pool:
            rest = list(pool.map(pilot, [(study, d, args.participants, names)
                                         for d in range(1, args.datasets)]))
        pilots_s = time.perf_counter() - t0
        pilots = [one, *rest]
        params = setup.model.params
        true_centre = {n: float(getattr(params, n)) for n in names if hasattr(params, n)}
        if "two_point_threshold_mm" in names:
            true_centre["two_point_threshold_mm"] = params.two_point_threshold_mm[
                setup.model.site]
        pops = [{"study": study, "population": p["population"], "true_centre": true_centre}
                for p in pilots]
        rows = [r for p in pilots for r in p["rows"]]
        results.extend(rows)
        summary.extend(summarise(rows, pops, names, study))
        per = [r["seconds"] for r in rows if r["param"] == names[0]]
        timing.append({"study": study, "trials_per_participant": int(np.median(
                           [r["answers"] for r in rows])),
                       "participant_s_median": float(np.median(per)),
                       "participant_s_p95": float(np.percentile(per, 95)),
                       "pilot_s_one_process": serial, "pilot_s_on_workers": parallel,
                       "pilots_per_minute_on_workers": (args.datasets - 1) / pilots_s * 60
                       if args.datasets > 1 else float("nan"),
                       "workers": args.workers, **base})
    print(f"Recovery: {args.datasets} simulated pilots x {args.participants} participants per "
          f"study, fitting {', '.join(names)} (95 % profile-likelihood intervals)")
    print(f"{'study':24} {'param':11} {'ident.':>6} {'scale':>11} {'bias':>7} {'RMSE':>6} "
          f"{'width':>6} {'cover':>6} {'pop. bias':>9} {'pop. RMSE':>9}")
    for s in summary:
        print(f"{s['study']:24} {s['param']:11} {s['identified']:6.2f} {s['scale']:>11} "
              f"{s['bias']:+7.3f} {s['rmse']:6.3f} {s['median_width']:6.3f} "
              f"{s['coverage']:6.2f} {s['population_bias']:+9.3f} {s['population_rmse']:9.3f}")
    print("\nTime (fits of every participant, all profiles included):")
    print(f"{'study':24} {'trials':>6} {'s/participant':>13} {'p95':>6} {'pilot, 1 proc':>13} "
          f"{f'on {args.workers}':>6} {'lik. ms':>8} {'sim. 2000 ms':>12} {'ratio':>6}")
    for t in timing:
        print(f"{t['study']:24} {t['trials_per_participant']:6d} "
              f"{t['participant_s_median']:13.2f} {t['participant_s_p95']:6.2f} "
              f"{t['pilot_s_one_process']:13.1f} {t['pilot_s_on_workers']:6.1f} "
              f"{t['likelihood_ms']:8.2f} {t['simulated_2000_ms']:12.1f} {t['ratio']:6.0f}")
    six = [t for t in timing if t["study"] == "six_mode_ball"]
    if six:
        best = min(six[0]["pilot_s_one_process"], six[0]["pilot_s_on_workers"])
        print(f"goal: a {args.participants}-participant six-mode pilot in under 60 s on "
              f"{args.workers} cores: {best:.1f} s: {'met' if best < 60 else 'NOT met'}")
    print(f"total {time.perf_counter() - t_all:.0f} s")
    out = ROOT / "bench" / "results"
    out.mkdir(parents=True, exist_ok=True)
    (out / "observer.json").write_text(json.dumps({
        "datasets": args.datasets, "participants": args.participants, "params": names,
        "summary": summary, "timing": timing, "fits": results,
        "machine": {"python": platform.python_version(), "platform": platform.platform(),
                    "numpy": np.__version__}}, indent=2), encoding="utf-8")
    print(f"wrote {out / 'observer.json'}")


if __name__ == "__main__":
    main()
