"""Held out: the model participant fitted on one table of a paper, predicting the others.

The papers publish cell rates, not trials. Each table (``protocols/published/*.yaml``)
gives each cell's rate(s) and its number of answers (participants x trials per
participant in the cell); the model's probability of each answer in each cell is
computed from the percept of what the experiment plays on the simulated device
(``vtexp.observer.published``), and the cells' counts are fitted by maximum likelihood
(binomial, or multinomial where the paper gives more than one answer's rate), with 95 %
profile-likelihood intervals. The fitted parameters are those of the population-typical
participant:

- ``efficiency`` (how much of the percept's information the decision uses) and
  ``lapse``: the two decision parameters that set a rate's level and ceiling, and that
  nothing in the literature fixes for these displays;
- ``integration_ms``, the back's (and the fingertips') integration time: assumed at 40 ms
  from the hands; docs/model-predictions.md names it the first parameter to measure. It
  is fitted on its grid of 17 percepts (10-400 ms), the decision parameters maximised at
  each.

Every other parameter keeps its value of ``protocols/observers/default.yaml``; none is set
by hand to a held-out number. The held-out cells are then predicted at the estimate
and at each parameter's interval ends (the other parameters maximised there): the range
printed beside each prediction.

Cases: seed 001 Table 1 fitted on its 0.3 s rows, predicting the 0.2 s rows, and the
other way; seed 001's letters (82 %, abstract) predicted from all of Table 1's cells;
seed 000's static modes predicting its dynamic modes. Seed 002 reports figures and
prose only, so it has no cells to fit.

Baselines in the same run: the model at the observer file's values (no fit), and no
model at all (every held-out cell predicted at the fitted cells' pooled rate). The goal
(issue 21): the sign of every effect the paper reports as significant, and the held-out
cells within 10 points (RMSE).

Prints the tables and writes JSON to bench/results/heldout.json.
Usage: python bench/heldout.py [--cases a,b] [--params efficiency,lapse,integration_ms]
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vtexp.observer.likelihood import decision_values  # noqa: E402
from vtexp.observer.published import (  # noqa: E402
    OTHER,
    Setting,
    fit_published,
    load_published,
    predicted_cells,
    rmse_points,
)
from vtexp.simulate import Setup  # noqa: E402

GOAL_POINTS = 10.0
#: A model difference smaller than this (points) has no sign: the quadrature's error is
#: about 0.1 point.
NO_SIGN = 0.5
_SETUPS: dict = {}
_TABLES: dict = {}


def setup_of(study: str) -> Setup:
    if study not in _SETUPS:
        _SETUPS[study] = Setup.load(ROOT / "experiments" / f"{study}.yaml")
    return _SETUPS[study]


def table_of(name: str, study: str):
    if name not in _TABLES:
        _TABLES[name] = load_published(ROOT / "protocols" / "published" / f"{name}.yaml",
                                       setup_of(study).lx)
    return _TABLES[name]


def mean(xs) -> float:
    return float(np.mean(list(xs)))


# --------------------------------------------------------------------------- effects

@dataclass
class Effect:
    """An effect a paper reports as significant, as a difference of cell rates (points)."""

    name: str
    reported: str
    of: callable          # rates by cell name (proportions) -> difference in points


def _row(r, duration: str, soas: list[str], shapes=("triangle", "circle", "square",
                                                    "rectangle")) -> float:
    return mean(r[f"{s} {duration}/{a}"] for s in shapes for a in soas)


SEED001_EFFECTS = [
    Effect("timing: 0.2/0.1 below the other 0.2 s cells", "F(7,288) = 42.62",
           lambda r: 100 * (_row(r, "0.2", ["0.2", "0.3", "0.4"]) - _row(r, "0.2", ["0.1"]))),
]


def _m(r, *names) -> float:
    return mean(r[n] for n in names)


SEED000_EFFECTS = [
    Effect("dynamic > static", "F(1,14) = 28.78",
           lambda r: 100 * (_m(r, "dynamic, fixed, linear", "dynamic, fixed, nonlinear",
                                "dynamic, varied, linear", "dynamic, varied, nonlinear")
                            - _m(r, "static, linear", "static, nonlinear"))),
    Effect("varied > fixed (dynamic)", "F(1,14) = 9.79",
           lambda r: 100 * (_m(r, "dynamic, varied, linear", "dynamic, varied, nonlinear")
                            - _m(r, "dynamic, fixed, linear", "dynamic, fixed, nonlinear"))),
    Effect("linear > nonlinear (dynamic)", "F(1,14) = 5.53",
           lambda r: 100 * (_m(r, "dynamic, fixed, linear", "dynamic, varied, linear")
                            - _m(r, "dynamic, fixed, nonlinear", "dynamic, varied, nonlinear"))),
    Effect("timing x intensity: linear - nonlinear larger at varied", "F(1,14) = 4.82",
           lambda r: 100 * ((r["dynamic, varied, linear"] - r["dynamic, varied, nonlinear"])
                            - (r["dynamic, fixed, linear"] - r["dynamic, fixed, nonlinear"]))),
    Effect("linear > nonlinear at varied (simple effect)", "F(1,14) = 12.04",
           lambda r: 100 * (r["dynamic, varied, linear"] - r["dynamic, varied, nonlinear"])),
]


def sign(x: float) -> str:
    return "0" if abs(x) < NO_SIGN else ("+" if x > 0 else "-")


# --------------------------------------------------------------------------- cases

@dataclass
class Case:
    name: str
    study: str
    table: str
    fit: dict             # levels selecting the fitted cells (table.select)
    held: dict | None     # levels selecting the held-out cells of the same table
    predict: tuple | None = None   # (study, table) of held-out cells of another experiment
    effects: tuple = ()
    scan: tuple | None = None      # (where, answer) for most_often


CASES = {
    "vest_03_to_02": Case("seed 001 Table 1: fitted on the 0.3 s rows, predicting the 0.2 s rows",
                          "duration_interval_grid", "seed001_table1",
                          {"timing": ("300/200", "300/300", "300/400", "300/500")},
                          {"timing": ("200/100", "200/200", "200/300", "200/400")},
                          effects=tuple(SEED001_EFFECTS)),
    "vest_02_to_03": Case("seed 001 Table 1: fitted on the 0.2 s rows, predicting the 0.3 s rows",
                          "duration_interval_grid", "seed001_table1",
                          {"timing": ("200/100", "200/200", "200/300", "200/400")},
                          {"timing": ("300/200", "300/300", "300/400", "300/500")},
                          effects=tuple(SEED001_EFFECTS)),
    "letters": Case("seed 001: fitted on all of Table 1, predicting the letters' 82 %",
                    "duration_interval_grid", "seed001_table1", {}, None,
                    predict=("letters", "seed001_letters")),
    "pad_static_to_dynamic": Case("seed 000: fitted on the static modes, predicting the "
                                  "dynamic modes", "six_mode_ball", "seed000_modes",
                                  {"display": "static"}, {"display": "dynamic"},
                                  effects=tuple(SEED000_EFFECTS),
                                  scan=({"display": "static"}, "plane circular")),
}

NO_NUMBERS = ("seed 002 (whirlpool; circle vs rectangle): the paper reports its results in "
              "Figs. 12-17 and 19-20 and in prose only (no rate, rating or count is printed "
              "in the text), so there are no cells to fit or predict; "
              "docs/model-predictions.md compares its prose.")


def most_often(study: str, table: str, where: dict, answer: str) -> dict:
    """The most often the model gives ``answer`` in the cells ``where``, without lapses,
    over a grid of efficiency, decision noise, abstain criterion and integration time:
    whether any value of these parameters makes the answer a choice, not a guess."""
    from vtexp.observer.fit import with_percept
    from vtexp.observer.published import CellRates
    setup = setup_of(study)
    t = table_of(table, study)
    cells = t.select(**where)
    who = setup.model.participant(0, "fit", typical=True)
    best = {"rate": -1.0}
    for integ in (10.0, 40.0, 400.0):
        rates = CellRates(setup.model, with_percept(who, "integration_ms", integ), t, cells,
                          setup.conditions, setup.played)
        for eff in np.geomspace(1e-3, 1.0, 13):
            for noise in (0.05, 1.0, 10.0):
                for crit in (0.0, 1.0, 10.0):
                    v = {**decision_values(setup.model), "efficiency": float(eff),
                         "lapse": 0.0, "decision_noise": noise, "abstain_criterion": crit}
                    got = rates.predicted(v)
                    r = max(x.get(answer, 0.0) for x in got.values())
                    if r > best["rate"]:
                        best = {"rate": r, "integration_ms": integ, "efficiency": float(eff),
                                "decision_noise": noise, "abstain_criterion": crit}
    return {"answer": answer, "cells": [c.name for c in cells], "grid": {
        "integration_ms": [10, 40, 400], "efficiency": "13 values, 0.001-1 (log)",
        "decision_noise": [0.05, 1, 10], "abstain_criterion": [0, 1, 10], "lapse": 0},
        "most": best}


def flat(pred: dict) -> dict[str, float]:
    """Rates of the correct answer by cell name (where the cell names it)."""
    return {k: v["correct"] for k, v in pred.items() if "correct" in v}


def run_case(key: str, case: Case, names: list[str]) -> dict:
    t0 = time.perf_counter()
    setup = setup_of(case.study)
    model = setup.model
    table = table_of(case.table, case.study)
    who = model.participant(0, "fit", typical=True)
    fixed = decision_values(model)
    fit_cells = table.select(**case.fit)
    if case.predict is None:
        held_cells = table.select(**case.held)
        held_setup, held_table = setup, table
    else:
        held_setup = setup_of(case.predict[0])
        held_table = table_of(case.predict[1], case.predict[0])
        held_cells = held_table.cells
    pf = fit_published(model, who, table, fit_cells, setup.conditions, setup.played, names, fixed)
    t_fit = time.perf_counter() - t0

    default = Setting("observer file", dict(fixed), None)

    def predict(setting: Setting, on: str) -> dict:
        if on == "fit":
            return predicted_cells(model, who, table, table.cells, setup.conditions,
                                   setup.played, setting, pf.percept)
        hm = held_setup.model
        hwho = hm.participant(0, "fit", typical=True)
        return predicted_cells(hm, hwho, held_table, held_cells, held_setup.conditions,
                               held_setup.played, setting, pf.percept)

    # All cells of the fitted table at every setting (the held-out ones among them when
    # they are of the same table), and the other experiment's cells when there are any.
    at = {}
    for s in [*pf.settings, default]:
        own = predict(s, "fit")
        other = predict(s, "held") if case.predict is not None else {}
        at[s.label] = {**own, **other}
    est = at["estimate"]
    pooled = (sum(c.rate("correct") * c.n for c in fit_cells)
              / sum(c.n for c in fit_cells))
    const = {c.name: {g: (pooled if g == "correct" else float("nan")) for g in c.groups}
             for c in held_cells}
    rmse = {"estimate": rmse_points(held_cells, est),
            "range": [min(rmse_points(held_cells, at[s.label]) for s in pf.settings),
                      max(rmse_points(held_cells, at[s.label]) for s in pf.settings)],
            "fitted_cells": rmse_points(fit_cells, est),
            "observer_file": rmse_points(held_cells, at["observer file"]),
            "no_model": rmse_points([c for c in held_cells if "correct" in c.groups], const)}
    cells = []
    held_names = {c.name for c in held_cells}
    for c in [*fit_cells, *held_cells]:
        for g in c.groups:
            if g == OTHER:
                continue
            vals = [at[s.label][c.name][g] for s in pf.settings]
            cells.append({"cell": c.name, "answer": g, "n": c.n, "paper": c.rate(g),
                          "predicted": est[c.name][g], "low": min(vals), "high": max(vals),
                          "observer_file": at["observer file"][c.name][g],
                          "role": "held out" if c.name in held_names else "fitted"})
    effects = []
    for e in case.effects:
        paper = e.of(flat({c.name: dict(zip(c.groups, c.rates)) for c in table.cells}))
        vals = [e.of(flat(at[s.label])) for s in pf.settings]
        model_e = e.of(flat(est))
        effects.append({"effect": e.name, "reported": e.reported, "paper_points": paper,
                        "model_points": model_e, "model_low": min(vals),
                        "model_high": max(vals),
                        "observer_file_points": e.of(flat(at["observer file"])),
                        "paper_sign": sign(paper), "model_sign": sign(model_e),
                        "signs_over_intervals": "".join(sorted({sign(v) for v in vals})),
                        "agrees": sign(paper) == sign(model_e)})
    scan = None if case.scan is None else most_often(case.study, case.table, *case.scan)
    params = {n: {"estimate": p.estimate, "low": p.low, "high": p.high,
                  "identified": p.identified} for n, p in pf.fit.params.items()}
    return {"case": key, "title": case.name, "study": case.study, "table": case.table,
            "fitted_cells": len(fit_cells), "held_out_cells": len(held_cells),
            "fitted_answers": sum(c.n for c in fit_cells), "params": params,
            "loglik": pf.fit.loglik, "notes": pf.notes,
            "settings": [{"label": s.label, "values": {k: s.values[k] for k in names
                                                        if k in s.values},
                          "percept": s.percept, "loglik": s.loglik} for s in pf.settings],
            "cells": cells, "rmse_points": rmse, "effects": effects, "scan": scan,
            "seconds": time.perf_counter() - t0, "fit_seconds": t_fit}


# --------------------------------------------------------------------------- printing

def show(r: dict) -> None:
    print(f"\n== {r['title']}")
    print(f"   fitted: {r['fitted_cells']} cells ({r['fitted_answers']:.0f} answers); "
          f"held out: {r['held_out_cells']} cells; {r['seconds']:.0f} s")
    for n, p in r["params"].items():
        est = "not identified" if not p["identified"] else f"{p['estimate']:.3g}"
        print(f"   {n:15} {est:>15}  95 % [{p['low']:.3g}, {p['high']:.3g}]")
    for note in r["notes"]:
        print(f"   note: {note}")
    print(f"   {'cell':28} {'answer':15} {'paper':>6} {'model':>6} {'range':>13} "
          f"{'defaults':>8}  role")
    for c in r["cells"]:
        print(f"   {c['cell']:28} {c['answer']:15} {100 * c['paper']:6.1f} "
              f"{100 * c['predicted']:6.1f} {100 * c['low']:6.1f}-{100 * c['high']:<6.1f} "
              f"{100 * c['observer_file']:8.1f}  {c['role']}")
    m = r["rmse_points"]
    verdict = "met" if m["estimate"] <= GOAL_POINTS else "NOT met"
    print(f"   held-out RMSE {m['estimate']:.1f} points (over the intervals' ends "
          f"{m['range'][0]:.1f}-{m['range'][1]:.1f}); goal {GOAL_POINTS:g}: {verdict}")
    print(f"   baselines: observer file's values {m['observer_file']:.1f}, no model (the fitted "
          f"cells' pooled rate) {m['no_model']:.1f}; fitted cells' RMSE {m['fitted_cells']:.1f}")
    if r["scan"]:
        sc, b = r["scan"], r["scan"]["most"]
        print(f"   the most often the model answers {sc['answer']!r} in {', '.join(sc['cells'])} "
              f"without lapses, over efficiency 0.001-1, decision noise 0.05-10, abstain "
              f"criterion 0-10, integration 10-400 ms: {100 * b['rate']:.1f} % (efficiency "
              f"{b['efficiency']:.3g}, noise {b['decision_noise']:g}, criterion "
              f"{b['abstain_criterion']:g}, {b['integration_ms']:g} ms)")
    if r["effects"]:
        print(f"   {'effect':56} {'reported':>16} {'paper':>6} {'model':>6} {'range':>13} "
              f"{'sign':>5}")
        for e in r["effects"]:
            print(f"   {e['effect']:56} {e['reported']:>16} {e['paper_points']:+6.1f} "
                  f"{e['model_points']:+6.1f} {e['model_low']:+6.1f}..{e['model_high']:<+6.1f} "
                  f"{e['paper_sign']}/{e['model_sign']} {'ok' if e['agrees'] else 'WRONG'}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--params", default="efficiency,lapse,integration_ms")
    args = ap.parse_args()
    names = args.params.split(",")
    t_all = time.perf_counter()
    results = []
    for key in args.cases.split(","):
        r = run_case(key, CASES[key], names)
        show(r)
        results.append(r)
    print(f"\n{NO_NUMBERS}")
    print(f"\ntotal {time.perf_counter() - t_all:.0f} s")
    out = ROOT / "bench" / "results"
    out.mkdir(parents=True, exist_ok=True)
    (out / "heldout.json").write_text(json.dumps({
        "params": names, "goal_rmse_points": GOAL_POINTS, "no_sign_below_points": NO_SIGN,
        "cases": results, "seed002": NO_NUMBERS,
        "machine": {"python": platform.python_version(), "platform": platform.platform(),
                    "numpy": np.__version__}}, indent=2), encoding="utf-8")
    print(f"wrote {out / 'heldout.json'}")


if __name__ == "__main__":
    main()
