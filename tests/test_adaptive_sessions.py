"""Adaptive studies through whole sessions, in process: a stimulus parameter in actuator
pitches (the two-point threshold by QUEST), exact resume, practice trials, the model
participant, the procedures' own estimates in the report, plan and validate."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from conftest import ROOT, session_record
from vtexp.cli import main

TWO = ROOT / "experiments" / "two_point_quest.yaml"
STAIR = ROOT / "experiments" / "shape_soa_staircase.yaml"
QPLUS = ROOT / "experiments" / "apparent_motion_questplus.yaml"
PSY = "scripted:psychometric:threshold=2,slope=3.5,lapse=0.02"


def _variant(tmp_path, src, old, new):
    text = src.read_text(encoding="utf-8")
    assert old in text
    p = tmp_path / "bad.yaml"
    p.write_text(text.replace(old, new), encoding="utf-8")
    return p


def _beh(data, exp, pid):
    f = next((data / exp / f"sub-{pid}" / "ses-1" / "beh").glob("*_beh.tsv"))
    return f, pd.read_csv(f, sep="\t", dtype=str, keep_default_na=False)


def _run(*args) -> int:
    return main(["run", *map(str, args), "--quiet"])


# --------------------------------------------------------------------------- pitches

def test_two_point_levels_land_on_actuators_whole_pitches_apart():
    from vtexp.compile import load_and_compile

    _, conds = load_and_compile(TWO)
    (c,) = conds
    assert sorted(c.patterns) == [1, 2, 3, 4, 5, 6, 7]
    for s, pattern in c.patterns.items():
        cells = sorted((int(p.row), int(p.col)) for p in pattern.points)
        assert len(cells) == 2 and cells[0][1] == cells[1][1]
        assert cells[1][0] - cells[0][0] == s                  # pitches on the array
        pulses = c.schedules[s].pulses
        assert {p.onset_ms for p in pulses} == {0.0} and len(pulses) == 2   # together


@pytest.mark.parametrize("old,new,words,key", [
    ("values: {min: 1, max: 7, step: 1}", "values: {min: 1, max: 8, step: 1}",
     "separation_pitches = 8 does not fit on vest_6x8", "adaptive.values"),
    ("params: {axis: vertical}", "params: {axis: horizontal}",
     "separation_pitches = 6 does not fit on vest_6x8", "adaptive.values"),
    ("values: {min: 1, max: 7, step: 1}", "values: {min: 1, max: 7, step: 0.5}",
     "whole actuator pitches", "adaptive.values"),
    ("variable: separation_pitches", "variable: separation_mm",
     "'separation_mm' is not a parameter of generator 'two_point'", "adaptive.variable"),
    ("params: {axis: vertical}", "params: {axis: vertical, separation_pitches: 3}",
     "which the adaptive procedure sets", "stimuli.points.params.separation_pitches"),
    ("  sets: stimulus ", "  sets: coding ", "not a parameter of coding 'contour-modes'",
     "adaptive.variable"),
])
def test_pitches_that_do_not_fit_are_refused_with_file_line_and_key(tmp_path, old, new, words,
                                                                    key):
    from vtexp.errors import InputError
    from vtexp.experiment import load_experiment

    with pytest.raises(InputError) as e:
        load_experiment(_variant(tmp_path, TWO, old, new))
    assert words in e.value.message and e.value.key == key and e.value.line, str(e.value)
    assert str(e.value).startswith(str(tmp_path / "bad.yaml") + ":")


# --------------------------------------------------------------------------- QUEST, end to end

def test_quest_two_point_study_runs_resumes_exactly_and_is_analysed(tmp_path, capsys):
    from vtexp.adaptive import Quest

    data, other = tmp_path / "data", tmp_path / "other"
    assert _run(TWO, "-p", "01", "--responder", PSY, "--data", other) == 0
    assert _run(TWO, "-p", "01", "--responder", PSY, "--data", data, "--max-trials", 9) == 0
    assert _run(TWO, "-p", "01", "--session", 1, "--resume", "--data", data) == 0
    f, beh = _beh(data, "two_point_quest", "01")
    _, whole = _beh(other, "two_point_quest", "01")
    cols = ["trial", "practice", "proposed", "presented", "answer"]
    pd.testing.assert_frame_equal(beh[cols], whole[cols])       # as text: every digit
    assert beh["proposed"].str.len().max() > 12                 # logged with repr
    assert set(beh["presented"]) <= {f"{v}.0" for v in range(1, 8)}
    record = json.loads(session_record(f.parent).read_text(encoding="utf-8"))
    assert record["adaptive_levels"] == "exact"

    # Practice trials play QUEST's first proposal and teach it nothing (documented).
    practice, main_ = beh[beh["practice"] == "1"], beh[beh["practice"] == "0"]
    assert len(practice) == 2 and len(main_) == 40
    assert set(practice["proposed"]) == {main_["proposed"].iloc[0]}

    # QUEST fed by hand with the main trials gives each logged proposal, bit for bit.
    q = Quest(_quest_rule())
    for row in main_.itertuples():
        assert float(row.proposed) == q.propose()
        q.update(float(row.presented), row.answer == "two")

    out = tmp_path / "out"
    assert main(["analyze", str(data / "two_point_quest"), "--out", str(out)]) == 0
    est = pd.read_csv(out / "two_point_quest" / "procedure_estimates.csv")
    assert len(est) == 1 and est["procedure"][0] == "quest" and est["n_trials"][0] == 40
    assert est["threshold"][0] == pytest.approx(q.estimate(), abs=1e-12)
    assert est["threshold_sd"][0] == pytest.approx(q.sd(), abs=1e-12)
    assert abs(est["threshold"][0] - 2) < 0.75
    fit = pd.read_csv(out / "two_point_quest" / "psychometric_fit.csv")
    assert len(fit) == 1 and fit["n_trials"][0] == 40
    assert fit["n_levels"][0] == main_["presented"].nunique()
    md = (out / "two_point_quest" / "report.md").read_text(encoding="utf-8")
    assert "QUEST's posterior mean of the threshold of separation_pitches" in md
    assert ("may be poorly determined" in md) == (fit["n_levels"][0] < 3)
    assert "threshold of separation_pitches" in capsys.readouterr().out


def _quest_rule():
    from vtexp.adaptive import QuestRule
    from vtexp.adaptive.spec import grid
    from vtexp.experiment import load_experiment

    p = load_experiment(TWO).experiment.adaptive.procedure
    return QuestRule(thresholds=tuple(grid(p.thresholds)), slope=p.slope, guess=p.guess,
                     lapse=p.lapse, function=p.function, prior_mean=p.prior_mean,
                     prior_sd=p.prior_sd, method=p.method)


def test_resume_refuses_a_proposal_changed_in_its_last_digit_and_reads_older_logs(tmp_path,
                                                                                  capsys):
    data = tmp_path / "data"
    assert _run(TWO, "-p", "01", "--responder", PSY, "--data", data, "--max-trials", 8) == 0
    f, beh = _beh(data, "two_point_quest", "01")
    text = f.read_text(encoding="utf-8")
    lines = text.splitlines(keepends=True)
    i = beh.columns.get_loc("proposed")
    cells = lines[6].split("\t")                               # trial 6
    digits = cells[i]
    cells[i] = digits[:-1] + ("1" if digits[-1] != "1" else "2")
    assert float(cells[i]) != float(digits)
    f.write_text("".join(lines[:6] + ["\t".join(cells)] + lines[7:]), encoding="utf-8")
    capsys.readouterr()
    assert _run(TWO, "-p", "01", "--session", 1, "--resume", "--data", data) != 0
    err = capsys.readouterr().err
    assert "trial 6" in err and "does not follow from the answers" in err

    # A log written before proposals kept every digit: 6 decimals, no 'adaptive_levels'.
    old = [lines[0]]
    for ln in lines[1:]:
        c = ln.rstrip("\n").split("\t")
        c[i] = repr(round(float(c[i]), 6))
        old.append("\t".join(c) + "\n")
    f.write_text("".join(old), encoding="utf-8")
    sj = session_record(f.parent)
    record = json.loads(sj.read_text(encoding="utf-8"))
    del record["adaptive_levels"]
    sj.write_text(json.dumps(record), encoding="utf-8")
    assert _run(TWO, "-p", "01", "--session", 1, "--resume", "--data", data,
                "--max-trials", 5) == 0                  # new rows with every digit
    assert _run(TWO, "-p", "01", "--session", 1, "--resume", "--data", data) == 0
    _, done = _beh(data, "two_point_quest", "01")
    assert len(done) == 42 and (done["status"] == "ok").all()


# --------------------------------------------------------------------------- model participant

def test_the_model_participant_answers_a_yes_no_threshold_question_with_templates(tmp_path,
                                                                                   capsys):
    data = tmp_path / "data"
    assert _run(TWO, "-p", "sim01", "--responder", "model", "--data", data) == 0
    _, beh = _beh(data, "two_point_quest", "sim01")
    assert len(beh) == 42 and set(beh["answer"]) == {"one", "two"}
    assert (beh["status"] == "ok").all()
    # Without templates for its answers (no observer: section) it is refused at once.
    capsys.readouterr()
    assert _run(QPLUS, "-p", "sim01", "--responder", "model", "--data", data) == 2
    err = capsys.readouterr().err
    assert "add observer.templates.moving" in err and "Traceback" not in err
    assert not (data / "apparent_motion_questplus").exists()


# --------------------------------------------------------------------------- estimates

def test_replayed_staircase_estimate_is_the_mean_of_its_last_reversals():
    from vtexp.adaptive.spec import StaircaseSpec
    from vtexp.adaptive.track import replay_estimate

    p = StaircaseSpec(kind="staircase", start=4, steps=[1], n_up=1, n_down=1)
    values = [float(v) for v in range(0, 9)]
    # 1-up-1-down from 4: yes yes no yes no no yes -> levels 4 3 2 3 2 3 4, reversals at
    # 2 (down->up), 3 (up->down), 2 (down->up), 4 (up->down)
    levels = [4, 3, 2, 3, 2, 3, 4]
    yes = [True, True, False, True, False, False, True]
    est = replay_estimate(p, values, levels, yes)
    assert est["n_reversals"] == 4 and est["reversals_used"] == 2   # all but the first, even
    assert est["threshold"] == pytest.approx((2 + 4) / 2)
    assert est["threshold_sd"] == pytest.approx(np.std([2, 4], ddof=1))
    p8 = StaircaseSpec(kind="staircase", start=4, steps=[1], estimate_reversals=3)
    assert replay_estimate(p8, values, levels, yes)["threshold"] == pytest.approx(3.0)


# --------------------------------------------------------------------------- plan, validate

def test_plan_and_validate_give_the_trials_each_track_may_play_and_a_time_range(tmp_path,
                                                                                 capsys):
    from vtexp.compile import load_and_compile

    bad = _variant(tmp_path, QPLUS, "    guess: 0.0\n", "    guess: 0.0\n    stop: {trials: 20}\n")
    assert main(["validate", str(bad)]) == 0
    said = capsys.readouterr().out
    _, (c,) = load_and_compile(bad)
    d = [s.duration_ms for s in c.schedules.values()]
    lo, hi = 20 * min(d) / 60000, 20 * max(d) / 60000
    assert "1 track of at most 20 trials" in said and "at most 20 of the 60 planned" in said
    assert f"{lo:.1f} min to {hi:.1f} min of stimulation" in said
    assert main(["plan", str(bad), "-p", "01", "--format", "tsv"]) == 0
    rows = [ln.split("\t") for ln in capsys.readouterr().out.splitlines()[1:]]
    assert [r[-1] for r in rows[:20]] == [f"{min(d):.0f}-{max(d):.0f}"] * 20
    assert {r[-1] for r in rows[20:]} == {"stopped"} and len(rows) == 60
    assert main(["validate", str(STAIR)]) == 0
    said = capsys.readouterr().out
    assert "2 tracks of at most 40 trials (or fewer: a track stops after 10 reversals)" in said
