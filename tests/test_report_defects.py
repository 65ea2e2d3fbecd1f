"""One test per class of report defect found in the demo's reports (issue 14, part 4).

Each failed on the code before its fix (checked by running this file on a work
tree at the commit before issue 14's changes): an undefined measure printed as
a number, a crash on a constant measure, a kappa interval beyond kappa's range,
question rows counted as trials, a figure caption naming another paper's figure,
the mixed model's SE headed "sd", a missing value in a replicated cell averaged
away without a word, effect sizes without an interval, figures with text on
text, a letter matrix too small to read, a per-participant figure averaging
opposite ratings into a flat line, the whirlpool without a figure and its turns
called a rating, a legend over the data, and the commands that existed only as
Python functions. The figures are measured as they are saved
(``report_render.captured_figures``), not through vtexp's own overlap check.
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
from report_render import captured_figures
from vtexp.analysis.confusion import agreement, information_transfer
from vtexp.analysis.report import html_table, md_table

DATA = ROOT / "tests" / "data"


def study_analysis(name: str, trials: pd.DataFrame):
    """:func:`analyse_experiment` of ``trials`` as sessions of experiments/NAME.yaml
    would give them (its factors, questions and analysis: section recorded)."""
    from vtexp.analysis.load import SessionData
    from vtexp.analysis.pipeline import analyse_experiment
    from vtexp.experiment import load_experiment
    loaded = load_experiment(ROOT / "experiments" / f"{name}.yaml").experiment
    record = loaded.model_dump(mode="json")
    sessions = [SessionData(Path(f"/data/{name}/sub-{p}/ses-1"),
                            {"format": "vtexp-session", "experiment": name, "participant": p,
                             "session": 1, "status": "completed", "n_trials_planned": 0,
                             "experiment_loaded": record}, pd.DataFrame())
                for p in trials["participant"].unique()]
    return analyse_experiment(trials.assign(experiment=name), sessions, name)


def rating_trials(factors: dict[str, list[str]], answer, questions=("rating",), n=6):
    """One row per trial and question; ``answer(participant, question, **levels)``."""
    import itertools
    rows, trial = [], 0
    for p in range(n):
        for levels in itertools.product(*factors.values()):
            for rep in range(2):
                trial += 1
                at = dict(zip(factors, levels))
                for q in questions:
                    rows.append({"participant": f"{p + 1:02d}", "session": 1, "trial": trial,
                                 **at, "question": q, "answer": str(answer(p, q, **at)),
                                 "correct": pd.NA, "correct_answer": None, "rt_s": 1.0,
                                 "replays": 0})
    t = pd.DataFrame(rows)
    t["correct"] = t["correct"].astype("Int64")
    for f, lv in factors.items():
        t[f] = pd.Categorical(t[f], categories=lv)
    return t


def circle_rectangle_report(tmp_path):
    """Seed 002's circle and rectangle: every participant rates the circle +2 or +1 and
    the rectangle −2 or −1, more surely with corner emphasis."""
    t = rating_trials({"shape": ["circle", "rectangle"], "corners": ["plain", "emphasised"]},
                      lambda p, q, shape, corners: (1 if shape == "circle" else -1)
                      * (2 if corners == "emphasised" or p % 2 else 1))
    a = study_analysis("circle_vs_rectangle", t)
    from vtexp.analysis.report import write_experiment_report
    with captured_figures() as figs:
        files = write_experiment_report(a, tmp_path / "circle_vs_rectangle")
    return a, files, figs


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
    # every participant shows the same soa effect (no error variance: F infinite), the
    # shapes cancel over soa (F = 0/0), the interaction varies by participant
    # (before: decimal.InvalidOperation)
    soa = {v: i for i, v in enumerate(sorted(d["soa"].unique()))}
    shape = dict(zip(sorted(d["shape"].unique()), (1, -1, 0)))
    who = {v: i + 1 for i, v in enumerate(sorted(d["participant"].unique()))}
    d["score"] = [str(soa[s] + shape[h] * who[p] * (1 if soa[s] % 2 else -1))
                  for s, h, p in zip(d["soa"], d["shape"], d["participant"])]
    d.to_csv(f, index=False)
    r = cli("stats", "rm-anova", str(f), "--dv", "score", "--within", "shape", "soa",
            "--subject", "participant")
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert "soa: F not applicable: the error sum of squares is 0" in r.stdout
    assert "shape: F not applicable: the measure does not vary" in r.stdout
    assert "shape:soa: F(1, 13) = 45.00, p < .001" in r.stdout
    assert "inf" not in r.stdout.lower()


def test_sessions_table_counts_trials_not_question_rows():
    from vtexp.analysis.pipeline import _session_table
    trials = pd.DataFrame({"trial": [1, 1, 2, 2, 3, 3], "question": ["rating", "turns"] * 3})
    s = SimpleNamespace(meta={"participant": "01", "session": 1, "n_trials_planned": 3},
                        status="completed", trials=trials, checksum="ok", dir=Path("x"))
    row = _session_table([s]).iloc[0]
    assert row["trials"] == 3 and row["planned"] == 3


def test_figure_captions_name_no_other_papers_figures(tmp_path):
    import re
    # a seed 002 study: its report's headings and captions name no seed 000/001 figure
    _, files, _ = circle_rectangle_report(tmp_path)
    html = files["html"].read_text()
    md = files["markdown"].read_text()
    headings = re.findall(r"<h2>(.*?)</h2>", html) + re.findall(r"^## (.*)$", md, re.M)
    assert len(headings) > 5
    for h in headings:
        assert not re.search(r"seed 00[01]", h), h


def test_mixed_model_table_heads_its_standard_errors_se():
    from vtexp.analysis.glmm import mixed_logit
    d = pd.read_csv(DATA / "trials_glmm.csv", dtype=str)
    m = mixed_logit(d, ["display"])
    assert "se" in m.columns and "sd" not in m.columns


def test_missing_value_in_a_replicated_cell_is_said(cli):
    f = DATA / "mixed_2b2w.csv"
    # within factors only: participant 07's other value of square × slow was averaged
    # on its own before, silently; afex drops the participant
    r = cli("stats", "rm-anova", str(f), "--dv", "rate", "--within", "shape", "timing",
            "--subject", "participant", "--json")
    assert r.returncode == 0, r.stderr
    assert "07: a missing value of 'rate' in square × slow" in r.stderr
    assert json.loads(r.stdout)["dropped"] == ["07"]
    assert json.loads(r.stdout)["effects"][0]["n"] == 29
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


def test_effect_sizes_are_printed_with_their_interval(cli):
    # tables and sentences (the interval's values are checked against R in
    # tests/test_effect_sizes.py)
    r = cli("stats", "rm-anova", str(DATA / "grid_3x4.csv"), "--dv", "score", "--within",
            "shape", "soa", "--subject", "participant")
    assert r.returncode == 0, r.stderr
    assert "η²p 90% CI low" in r.stdout and "η²p 90% CI high" in r.stdout
    assert "shape: F(2, 26) = 14.91, p < .001, η²p = .53, 90% CI [.29, .68]" in r.stdout
    r = cli("stats", "posthoc", str(DATA / "grid_3x4.csv"), "--dv", "score", "--within",
            "shape", "soa", "--subject", "participant", "--factor", "soa", "--json")
    assert r.returncode == 0, r.stderr
    rows = pd.DataFrame(json.loads(r.stdout)["rows"])
    assert (rows["dz_ci95_low"] < rows["dz"]).all() and (rows["dz"] < rows["dz_ci95_high"]).all()


def test_the_overlap_measure_sees_text_on_text_and_only_that():
    import matplotlib
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    from report_render import text_overlaps
    fig, ax = plt.subplots(figsize=(4, 3))
    ax.text(0.5, 0.5, "first words", ha="center")
    ax.text(0.52, 0.51, "second words", ha="center")
    # parallel labels at 45°: their axis-aligned boxes intersect, their glyphs do not
    ax.set_xticks([0, 0.25, 0.5, 0.75], ["concave surface", "uneven surface", "ball",
                                         "plane circular"], rotation=45, ha="right")
    assert text_overlaps(fig) == [("first words", "second words")]
    fig, ax = plt.subplots(figsize=(4, 3))
    ax.set_xticks([0, 0.03], ["concave surface", "uneven surface"], rotation=45, ha="right")
    assert text_overlaps(fig) == [("concave surface", "uneven surface")]
    plt.close("all")


def test_report_figures_have_no_text_on_text_and_a_readable_letter_matrix():
    from vtexp.analysis import figures
    letters = [chr(65 + i) for i in range(26)]
    rows = [{"timing": t, "stimulus": s, "response": r,
             "proportion": (0.8 if s == r else 0.2 / 25)}
            for t in ("200/100 ms, long condition name", "300/500 ms, another long name")
            for s in letters for r in letters]
    with captured_figures() as figs:
        figures.confusion_heatmaps(pd.DataFrame(rows), ["timing"])
        four = [{"timing": t, "stimulus": s, "response": r, "proportion": 0.25}
                for t in [f"{a}/{b}" for a in (200, 300) for b in (100, 200, 300, 400)]
                for s in ("triangle", "circle", "square", "rectangle")
                for r in ("triangle", "circle", "square", "rectangle")]
        figures.confusion_heatmaps(pd.DataFrame(four), ["timing"])
        # seed 000's six modes, titled by three factors (the demo's overlapping titles)
        opts = ["plane circular", "ball", "uncertain", "concave surface", "uneven surface"]
        modes = [("static", "none", "linear"), ("static", "none", "nonlinear"),
                 ("dynamic", "fixed", "linear"), ("dynamic", "fixed", "nonlinear"),
                 ("dynamic", "varied", "linear"), ("dynamic", "varied", "nonlinear")]
        six = [{"display": d, "timing": t, "intensity": i, "stimulus": s, "response": r,
                "proportion": 0.6 if s == r else 0.1}
               for d, t, i in modes for s in opts for r in opts]
        figures.confusion_heatmaps(pd.DataFrame(six), ["display", "timing", "intensity"])
    letters_fig, four_fig, six_fig = figs
    assert letters_fig["overlaps"] == [] and four_fig["overlaps"] == []
    assert six_fig["overlaps"] == []
    # a 26 x 26 matrix gets at least 20 px of the PNG per cell (before: 250 px in all)
    panels = [ax for ax in letters_fig["axes"] if ax["images"]]
    assert len(panels) == 2
    assert all(ax["width_px"] / 26 >= 20 and ax["height_px"] / 26 >= 20 for ax in panels)


def test_per_participant_figure_keeps_opposite_ratings_apart(tmp_path):
    # every participant rates the circle above +1 and the rectangle below −1:
    # averaging over shape drew each of them as a line at 0
    a, _, figs = circle_rectangle_report(tmp_path)
    per = [f for f in figs if any(label.startswith("sub-") for ax in f["axes"]
                                  for label, _ in ax["lines"])]
    assert len(per) == 1
    lines = [y for ax in per[0]["axes"] for label, y in ax["lines"] if label.startswith("sub-")]
    assert len(lines) == 2 * 6                        # a panel per shape, a line per person
    assert all(abs(v) >= 1 for y in lines for v in y), lines
    assert all(f["overlaps"] == [] for f in figs)


def test_rate_figure_legend_is_outside_the_axes(tmp_path):
    _, _, figs = circle_rectangle_report(tmp_path)
    rate = next(f for f in figs if any("mean ± SE" in ax["ylabel"] for ax in f["axes"]))
    (ax,) = rate["axes"]
    (legend,) = rate["legends"]
    assert not legend.overlaps(ax["box"]), (legend, ax["box"])


def test_whirlpool_has_figures_and_its_turns_are_not_a_rating(tmp_path):
    from vtexp.analysis.report import write_experiment_report
    t = rating_trials({"phantom": ["without", "with"], "frequency": ["25Hz", "40Hz", "50Hz"]},
                      lambda p, q, phantom, frequency: (
                          (p + 2 * (phantom == "with") + int(frequency[:2]) // 10) % 5
                          if q == "sensation" else
                          3 + p * (phantom == "with") + (p + int(frequency[:2])) % 4),
                      questions=("sensation", "turns"))
    a = study_analysis("whirlpool", t)
    with captured_figures() as figs:
        files = write_experiment_report(a, tmp_path / "whirlpool")
    html = files["html"].read_text()
    assert html.count("data:image/png;base64,") == 4         # rates and participants, twice
    assert "Sensation rating by frequency and phantom (mean ± SE" in html
    assert "Number of turns by frequency and phantom (mean ± SE" in html
    turns = [s for s in a.sentences if "turns" in s.lower()]
    assert len(turns) == 3 and all(s.startswith("Number of turns, phantom × frequency")
                                   for s in turns)
    assert not any(s.startswith("Rating") for s in a.sentences)
    ylabels = {ax["ylabel"] for f in figs for ax in f["axes"] if ax["ylabel"]}
    assert {"number of turns (mean ± SE)", "number of turns"} <= ylabels
    assert not any("rating" in y for y in ylabels if "turns" in y)
    assert all(f["overlaps"] == [] for f in figs)
