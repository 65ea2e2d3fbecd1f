"""Published cell rates as data for the model (vtexp.observer.published, bench/heldout.py):
the aggregate likelihood, recovery of known parameters from cell rates, bad tables."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.stats import binom, multinomial

from vtexp.errors import InputError
from vtexp.observer.likelihood import Likelihood, Trial, decision_values
from vtexp.observer.published import (
    AggregateLikelihood,
    CellRates,
    fit_published,
    load_published,
    published_table,
)
from vtexp.simulate import Setup

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def grid():
    setup = Setup.load(ROOT / "experiments" / "duration_interval_grid.yaml")
    return setup, setup.model.participant(0, "fit", typical=True)


def _table(setup, cells: dict, **extra):
    return published_table({"name": "t", "experiment": "duration_interval_grid",
                            "reference": "test", "cells": cells, **extra}, setup.lx)


CELLS = {f"{s} {t}": {"where": {"shape": s, "timing": t}, "n": 40, "rates": {"correct": r}}
         for s, t, r in [("triangle", "200/100", 0.3), ("triangle", "300/200", 0.9),
                         ("square", "200/100", 0.125), ("square", "300/200", 0.95)]}


def test_aggregate_likelihood_is_the_sum_of_binomial_log_probabilities(grid):
    setup, who = grid
    table = _table(setup, CELLS)
    rates = CellRates(setup.model, who, table, table.cells, setup.conditions, setup.played)
    v = {**decision_values(setup.model), "efficiency": 0.05, "lapse": 0.03}
    p = rates.predicted(v)
    by_hand = sum(binom.logpmf(round(c.rate("correct") * c.n), c.n, p[c.name]["correct"])
                  for c in table.cells)
    assert AggregateLikelihood(rates)(v) == pytest.approx(by_hand, abs=1e-9)
    # each cell's rate is the trial likelihood's probability of the answer in its condition
    q = setup.lx.experiment.asked()[0]
    for c in table.cells:
        cond = setup.conditions[c.conditions[0]]
        one = Likelihood(setup.model, who, [Trial(q.name, cond, setup.played[cond.index],
                                                  c.where["shape"])])
        full = one.probabilities(v, full=True)[0][0]
        assert p[c.name]["correct"] == pytest.approx(full[q.options.index(c.where["shape"])])
        assert p[c.name]["other"] == pytest.approx(1 - p[c.name]["correct"])


def test_a_cell_with_several_answers_is_multinomial(grid):
    setup, who = grid
    table = _table(setup, {"tri": {"where": {"shape": "triangle", "timing": "200/100"},
                                   "n": 20, "rates": {"correct": 0.5, "circle": 0.3}}})
    rates = CellRates(setup.model, who, table, table.cells, setup.conditions, setup.played)
    v = {**decision_values(setup.model), "efficiency": 0.02}
    p = rates(v)[0]
    assert table.cells[0].groups == ("correct", "circle", "other")
    assert p.sum() == pytest.approx(1.0)
    want = multinomial.logpmf([10, 6, 4], 20, p)
    assert AggregateLikelihood(rates)(v) == pytest.approx(want, abs=1e-9)


def test_a_pooled_cell_is_the_mean_of_its_conditions(grid):
    setup, who = grid
    shapes = ("triangle", "circle", "square", "rectangle")
    cells = {s: {"where": {"shape": s, "timing": "200/100"}, "n": 25,
                 "rates": {"correct": 0.2}} for s in shapes}
    table = _table(setup, {"0.2/0.1": {"where": {"timing": "200/100"}, "n": 100,
                                       "rates": {"correct": 0.237}}, **cells})
    rates = CellRates(setup.model, who, table, table.cells, setup.conditions, setup.played)
    p = rates.predicted({**decision_values(setup.model), "efficiency": 0.05})
    assert len(table.cell("0.2/0.1").conditions) == 4
    assert p["0.2/0.1"]["correct"] == pytest.approx(np.mean([p[s]["correct"] for s in shapes]),
                                                    abs=1e-12)


def test_fitting_rates_the_model_made_recovers_its_parameters(grid):
    setup, who = grid
    truth = {**decision_values(setup.model), "efficiency": 0.04, "lapse": 0.06}
    table = _table(setup, CELLS)
    made = CellRates(setup.model, who, table, table.cells, setup.conditions,
                     setup.played).predicted(truth)
    cells = {name: {**spec, "n": 5000, "rates": {"correct": made[name]["correct"]}}
             for name, spec in CELLS.items()}
    table = _table(setup, cells)
    fit = fit_published(setup.model, who, table, table.cells, setup.conditions,
                        setup.played, ["efficiency", "lapse"], decision_values(setup.model))
    for n in ("efficiency", "lapse"):
        p = fit.fit.params[n]
        assert p.identified
        assert p.low <= truth[n] <= p.high, (n, p)
        assert p.estimate == pytest.approx(truth[n], rel=0.1)
    est = fit.settings[0]
    assert est.label == "estimate"
    assert est.values["efficiency"] == pytest.approx(fit.fit.params["efficiency"].estimate)
    # the interval's ends are settings too, the other parameter maximised there
    assert {s.label for s in fit.settings} >= {"efficiency low", "efficiency high",
                                               "lapse low", "lapse high"}


@pytest.mark.parametrize("cell, words", [
    ({"where": {"shape": "hexagon", "timing": "200/100"}, "n": 10, "rates": {"correct": 0.5}},
     ["factor 'shape' has no level 'hexagon'", "cells.bad.where.shape"]),
    ({"where": {"shpae": "triangle"}, "n": 10, "rates": {"correct": 0.5}},
     ["no factor 'shpae'", "cells.bad.where.shpae"]),
    ({"where": {"shape": "triangle"}, "n": 10, "rates": {"correct": 82}},
     ["proportion in [0, 1]", "cells.bad.rates.correct"]),
    ({"where": {"shape": "triangle"}, "n": 10, "rates": {"correct": -0.1}},
     ["proportion in [0, 1]"]),
    ({"where": {"shape": "triangle"}, "n": 10, "rates": {"correct": 0.7, "circle": 0.5}},
     ["sum to 1.2, more than 1"]),
    ({"where": {"shape": "triangle"}, "n": 10, "rates": {"hexagon": 0.5}},
     ["neither 'correct' nor an option"]),
    ({"where": {"shape": "triangle"}, "n": 10, "rates": {"correct": 0.5, "triangle": 0.2}},
     ["name the same answer"]),
    ({"where": {"shape": "triangle"}, "n": -3, "rates": {"correct": 0.5}},
     ["n must be the number of answers"]),
    ({"where": {"shape": "triangle"}, "n": 10, "rate": {"correct": 0.5}},
     ["unknown key 'rate'"]),
])
def test_a_bad_table_is_one_clear_message(grid, cell, words):
    setup, _ = grid
    with pytest.raises(InputError) as e:
        _table(setup, {"bad": cell})
    for w in words:
        assert w in str(e.value)


def test_a_table_of_another_experiment_is_refused(grid):
    setup, _ = grid
    with pytest.raises(InputError, match="of experiment 'letters', not 'duration_interval_grid'"):
        published_table({"experiment": "letters", "cells": CELLS}, setup.lx)


def test_a_table_file_names_the_line(grid, tmp_path):
    setup, _ = grid
    f = tmp_path / "t.yaml"
    f.write_text("name: t\nexperiment: duration_interval_grid\ncells:\n"
                 "  a: {where: {shape: triangle}, n: 10, rates: {correct: 0.5}}\n"
                 "  b: {where: {shape: triangle}, n: 10, rates: {correct: 1.5}}\n",
                 encoding="utf-8")
    with pytest.raises(InputError) as e:
        load_published(f, setup.lx)
    assert str(e.value).startswith(f"{f}:5: cells.b.rates.correct: a rate is a proportion")


def test_a_cell_without_n_is_predicted_not_fitted(grid):
    setup, who = grid
    table = _table(setup, {"all": {"where": {}, "rates": {"correct": 0.82}}})
    rates = CellRates(setup.model, who, table, table.cells[:0], setup.conditions, setup.played)
    assert rates(decision_values(setup.model)) == []
    with pytest.raises(InputError, match="can be predicted, not fitted"):
        AggregateLikelihood(CellRates(setup.model, who, table, table.cells, setup.conditions,
                                      setup.played))


def test_the_shipped_tables_read(grid):
    setup, _ = grid
    t = load_published(ROOT / "protocols" / "published" / "seed001_table1.yaml", setup.lx)
    assert len(t.cells) == 32 and sum(c.n for c in t.cells) == 852
    assert t.cell("square 0.2/0.1").rate("correct") == pytest.approx(0.115)
    assert len(t.select(timing=("300/200", "300/300", "300/400", "300/500"))) == 16
    # every printed rate is a whole number of answers over the cell's n, to 0.1 %
    for c in t.cells:
        k = c.rate("correct") * c.n
        assert abs(round(k) / c.n - c.rate("correct")) < 0.00051, c.name
