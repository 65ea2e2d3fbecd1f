"""One test per class of report defect found in the demo's reports (issue 14, part 4).

Each failed before its fix: an undefined measure printed as a number, a crash on
a constant measure, a kappa interval beyond kappa's range, question rows counted
as trials, a figure caption naming another paper, the mixed model's SE headed
"sd", a missing value in a replicated cell averaged away without a word, and
the commands that existed only as Python functions.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from statsmodels.stats.inter_rater import cohens_kappa

from conftest import ROOT
from vtexp.analysis.confusion import agreement, information_transfer
from vtexp.analysis.report import html_table, md_table

DATA = ROOT / "tests" / "data"


def one_stimulus_trials():
    # the whirlpool study: one stimulus (the spiral), answers vary
    return pd.DataFrame({"correct_answer": ["spiral"] * 6,
                         "answer": ["spiral", "spiral", "spiral", "circle", "spiral", "circle"],
                         "cond": ["a"] * 6})


def test_undefined_information_transfer_and_kappa_are_not_applicable_with_the_reason():
    t = one_stimulus_trials()
    it = information_transfer(t).iloc[0]
    assert np.isnan(it["IT_bits"]) and np.isnan(it["relative_IT"])
    assert "only one stimulus" in it["not_applicable"]
    ag = agreement(t).iloc[0]
    assert np.isnan(ag["kappa"]) and np.isnan(ag["kappa_ci_low"])
    assert "kappa is not defined" in ag["not_applicable"]
    for render in (md_table, html_table):
        text = render("agreement", agreement(t))
        assert "n/a" in text and "-0.000" not in text and "0.000" not in text.split("n/a")[0][-30:]
    text = md_table("information_transfer", information_transfer(t))
    assert "2.000" not in text and "-0.000" not in text


def test_kappa_interval_stays_within_kappas_range():
    t = pd.DataFrame({"correct_answer": list("aabbaabb") * 2, "answer": list("aabbaabb") * 2})
    t.loc[0, "answer"] = "b"
    ag = agreement(t).iloc[0]
    assert -1 <= ag["kappa_ci_low"] <= ag["kappa"] <= ag["kappa_ci_high"] <= 1
    assert ag["kappa_ci_clipped"]


def test_weighted_kappa_equals_statsmodels():
    levels = ["0", "1", "2", "3", "4"]
    rng = np.random.default_rng(4)
    s = rng.integers(0, 5, 200)
    r = np.clip(s + rng.integers(-1, 2, 200), 0, 4)
    t = pd.DataFrame({"correct_answer": s.astype(str), "answer": r.astype(str)})
    m = pd.crosstab(t["correct_answer"], t["answer"]).reindex(index=levels, columns=levels,
                                                             fill_value=0).to_numpy()
    for w in ("linear", "quadratic"):
        ag = agreement(t, labels=levels, weights=w).iloc[0]
        ref = cohens_kappa(m, wt=w)
        assert ag["kappa"] == pytest.approx(ref.kappa, abs=1e-12)
        assert ag["kappa_se"] == pytest.approx(ref.std_kappa, abs=1e-12)


def test_constant_measure_is_not_applicable_not_a_traceback(cli, tmp_path):
    d = pd.read_csv(DATA / "grid_3x4.csv", dtype=str)
    d["score"] = "2"
    f = tmp_path / "constant.csv"
    d.to_csv(f, index=False)
    r = cli("stats", "rm-anova", str(f), "--dv", "score", "--within", "shape", "soa",
            "--subject", "participant")
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert "soa: F not applicable: the measure does not vary" in r.stdout
    assert "nan" not in r.stdout.lower().replace("n/a", "")


def test_sessions_table_counts_trials_not_question_rows():
    from vtexp.analysis.pipeline import _session_table
    trials = pd.DataFrame({"trial": [1, 1, 2, 2, 3, 3], "question": ["rating", "turns"] * 3})
    s = SimpleNamespace(meta={"participant": "01", "session": 1, "n_trials_planned": 3},
                        status="completed", trials=trials, checksum="ok", dir=Path("x"))
    row = _session_table([s]).iloc[0]
    assert row["trials"] == 3 and row["planned"] == 3


def test_figure_captions_name_no_other_papers_figures():
    import inspect

    from vtexp.analysis import report
    src = inspect.getsource(report.write_experiment_report) + repr(report._SECTIONS)
    assert "seed 000 Fig" not in src and "seed 001 Table" not in src


def test_mixed_model_table_heads_its_standard_errors_se():
    from vtexp.analysis.glmm import mixed_logit
    d = pd.read_csv(DATA / "trials_glmm.csv", dtype=str)
    m = mixed_logit(d, ["display"])
    assert "se" in m.columns and "sd" not in m.columns


def test_missing_value_in_a_replicated_cell_is_said(cli):
    f = DATA / "mixed_2b2w.csv"
    r = cli("stats", "rm-anova", str(f), "--dv", "rate", "--within", "shape", "timing",
            "--between", "group", "age", "--subject", "participant", "--json")
    assert r.returncode == 0, r.stderr
    assert "07: a missing value of 'rate' in square × slow" in r.stderr
    assert json.loads(r.stdout)["dropped"] == ["07"]


def test_stats_commands_for_what_was_only_python(cli, tmp_path):
    from vtexp.analysis.posthoc import pairwise_tests
    f = DATA / "mixed_group_soa.csv"
    r = cli("stats", "posthoc", str(f), "--dv", "score", "--within", "soa", "--between",
            "group", "--subject", "participant", "--factor", "soa", "--by", "group",
            "--error", "pooled", "--padjust", "sidak", "--json")
    assert r.returncode == 0, r.stderr
    got = pd.DataFrame(json.loads(r.stdout)["rows"])
    want = pairwise_tests(pd.read_csv(f, dtype=str), "score", "soa", "participant",
                          factor="soa", by="group", between="group", error="pooled",
                          padjust="sidak")
    assert np.allclose(got["p_adj"], want["p_adj"], rtol=0, atol=1e-12)
    # groups from a BIDS participants table instead of a column of the data
    d = pd.read_csv(f, dtype=str)
    d.drop(columns="group").to_csv(tmp_path / "scores.csv", index=False)
    g = d.groupby("participant")["group"].first().reset_index()
    g.insert(0, "participant_id", "sub-" + g.pop("participant"))
    g.to_csv(tmp_path / "participants.tsv", sep="\t", index=False)
    r2 = cli("stats", "rm-anova", str(tmp_path / "scores.csv"), "--dv", "score", "--within",
             "soa", "--between", "group", "--participants", str(tmp_path / "participants.tsv"),
             "--subject", "participant", "--json")
    r3 = cli("stats", "rm-anova", str(f), "--dv", "score", "--within", "soa", "--between",
             "group", "--subject", "participant", "--json")
    assert json.loads(r2.stdout)["effects"] == json.loads(r3.stdout)["effects"]
    for args in (["trend", str(f), "--dv", "score", "--within", "soa", "--subject",
                  "participant", "--factor", "soa"],
                 ["friedman", str(DATA / "ratings.csv"), "--dv", "rating", "--factor",
                  "frequency", "--subject", "participant"],
                 ["wilcoxon", str(DATA / "ratings.csv"), "--dv", "rating", "--factor",
                  "frequency", "--subject", "participant", "--padjust", "BH"],
                 ["kappa", str(DATA / "ratings.csv"), "--stimulus", "frequency", "--response",
                  "rating", "--weights", "linear"],
                 ["information-transfer", str(DATA / "trials_glmm.csv"), "--stimulus",
                  "display", "--response", "correct"],
                 ["mixed-logit", str(DATA / "trials_glmm.csv"), "--outcome", "correct",
                  "--factors", "display", "timing", "--subject", "participant"]):
        r = cli("stats", *args)
        assert r.returncode == 0 and "Traceback" not in r.stderr, (args, r.stderr)
        assert "|" in r.stdout
    r = cli("stats", "posthoc", str(f), "--dv", "score", "--within", "soa", "--subject",
            "participant", "--factor", "nope")
    assert r.returncode == 2 and "'nope'" in r.stderr and "Traceback" not in r.stderr
