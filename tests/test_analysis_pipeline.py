"""The declared-analysis pipeline on trial tables made in the test (no device needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from vtexp.analysis.load import SessionData
from vtexp.analysis.pipeline import analyse_experiment
from vtexp.analysis.report import write_experiment_report
from vtexp.analysis.spec import AnalysisSpec
from vtexp.errors import InputError


def session(pid, factors, question, analysis=None):
    meta = {"format": "vtexp-session", "experiment": "whirl", "participant": pid,
            "session": 1, "status": "completed", "n_trials_planned": 0,
            "experiment_loaded": {"title": "Whirlpool ratings", "reference": "seed 002 §4",
                                  "factors": factors, "question": question,
                                  "analysis": analysis}}
    return SessionData(Path(f"/data/whirl/sub-{pid}/ses-1"), meta, pd.DataFrame())


def ratings_trials(n=8, seed=4):
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        for phantom in ("without", "with"):
            for j, hz in enumerate(("25", "40", "50")):
                for _ in range(3):
                    r = int(np.clip(round(1 + j * 0.8 + (phantom == "with") + rng.normal(0, .7)),
                                    0, 4))
                    rows.append({"experiment": "whirl", "participant": f"{i:02d}",
                                 "session": 1, "phantom": phantom, "frequency": hz,
                                 "answer": str(r), "correct": pd.NA, "correct_answer": None,
                                 "rt_s": 1.0, "replays": 0})
    t = pd.DataFrame(rows)
    t["correct"] = t["correct"].astype("Int64")
    return t


FACTORS = {"phantom": {"levels": ["without", "with"], "sets": "coding"},
           "frequency": {"levels": ["25", "40", "50"], "sets": "coding"}}
QUESTION = {"options": ["0", "1", "2", "3", "4"]}


def test_ratings_get_anova_and_rank_tests_side_by_side(tmp_path):
    spec = {"anova": [{"dv": "answer", "within": ["phantom", "frequency"]}],
            "ordinal": [{"factor": "frequency"}],
            "figure": {"x": "frequency", "trace": "phantom", "dv": "answer"}}
    trials = ratings_trials()
    sessions = [session(p, FACTORS, QUESTION, spec) for p in trials["participant"].unique()]
    a = analyse_experiment(trials, sessions, "whirl")
    assert a.spec_source == "the 'analysis:' section recorded in the sessions"
    assert list(a.tables["anova_1"]["effect"]) == ["phantom", "frequency", "phantom:frequency"]
    fr = a.tables["friedman_1"].iloc[0]
    assert fr["n"] == 8 and fr["k"] == 3 and fr["p"] < 0.05
    assert len(a.tables["wilcoxon_1"]) == 3
    assert any(s.startswith("Friedman test of frequency on the rating: χ²(2, N = 8)")
               for s in a.sentences)
    assert "rates_by_condition" not in a.tables          # unscored: no recognition rates
    files = write_experiment_report(a, tmp_path)
    html = files["html"].read_text()
    assert "Friedman test" in html and html.count("data:image/png;base64,") == 2


def test_default_analysis_and_bad_override():
    trials = ratings_trials()
    sessions = [session(p, FACTORS, QUESTION) for p in trials["participant"].unique()]
    a = analyse_experiment(trials, sessions, "whirl")
    assert "default" in a.spec_source and a.tables.get("anova_1") is None   # unscored
    with pytest.raises(InputError, match="analysis.posthoc\\[0\\].factor: 'shape' is not a "
                                         "factor"):
        analyse_experiment(trials, sessions, "whirl",
                           spec=AnalysisSpec.model_validate({"posthoc": [{"factor": "shape"}]}))


def test_measures_that_are_not_numbers_are_refused():
    trials = ratings_trials().assign(answer="circle")
    sessions = [session(p, FACTORS, QUESTION) for p in trials["participant"].unique()]
    with pytest.raises(InputError, match="answers are not numbers"):
        analyse_experiment(trials, sessions, "whirl", spec=AnalysisSpec.model_validate(
            {"anova": [{"dv": "answer"}]}))
