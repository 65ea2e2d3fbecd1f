"""`vtexp analyze` end to end: reading any mix of sessions, integrity, the report."""

from __future__ import annotations

import json
import re
import shutil

import pandas as pd
import pytest

from conftest import GRID, ROOT, write_experiment, session_record
from vtexp.analysis.pipeline import apa_anova, format_p

APA = re.compile(r"F\(\d+(\.\d\d)?, \d+(\.\d\d)?\) = \d+\.\d\d, p (< \.001|= \.\d{3}), η²p = "
                 r"-?\.\d\d, 90% CI \[(0|\.\d\d), (1|\.\d\d)\]")


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """Three participants of the duration/interval study on the simulator."""
    from conftest import run_cli
    root = tmp_path_factory.mktemp("grid")
    for p, acc in (("01", 0.9), ("02", 0.7), ("03", 0.5)):
        r = run_cli("run", str(GRID), "-p", p, "--responder", f"scripted:accuracy={acc}",
                    "--data", str(root), "--quiet")
        assert r.returncode == 0, r.stderr
    return root / "duration_interval_grid"


def test_apa_sentence_has_the_papers_form():
    row = pd.Series({"df1": 1.0, "df2": 14.0, "F": 28.775, "p": 4e-5, "pes": 0.6727,
                     "mauchly_p": float("nan"), "eps_gg": 1.0, "eps_hf": 1.0, "p_gg": 4e-5,
                     "p_hf": 4e-5, "mauchly_W": float("nan")})
    # η²p's 90 % interval from the noncentral F on the df printed (R: see
    # tests/test_effect_sizes.py; F_to_eta2(28.775, 1, 14) gives [.386, .806])
    assert apa_anova(row)[0] == "F(1, 14) = 28.78, p < .001, η²p = .67, 90% CI [.39, .81]"
    row2 = row.copy()
    row2.update({"df1": 3.0, "df2": 33.0, "F": 3.0035, "p": 0.0443, "mauchly_p": 0.0004,
                 "eps_gg": 0.45694, "p_gg": 0.0940, "pes": 0.2145})
    s, used = apa_anova(row2)
    assert used == "GG" and s == ("F(1.37, 15.08) = 3.00, p = .094, η²p = .21, 90% CI [0, .47], "
                                  "ε = .46 (Greenhouse–Geisser)")
    assert apa_anova(row2, "none")[0].startswith("F(3, 33) = 3.00, p = .044")
    assert format_p(0.0005) == "p < .001" and format_p(0.5) == "p = .500"


def test_analyze_a_mix_of_folders_writes_a_self_contained_report(cli, data, tmp_path):
    # a study folder and one session folder given directly (overlapping: read once)
    out = tmp_path / "out"
    r = cli("analyze", str(data), str(data / "sub-02" / "ses-1"), "--out", str(out))
    assert r.returncode == 0, r.stderr
    rep = out / "duration_interval_grid"
    html = (rep / "report.html").read_text()
    assert html.count("data:image/png;base64,") == 3            # rates, participants, confusion
    assert not re.search(r"""src=['"](?!data:)""", html)          # nothing outside the file
    assert "3 participant(s), 288 trials" in html
    md = (rep / "report.md").read_text()
    assert "(figure_rates.png)" in md and (rep / "figure_rates.png").is_file()
    # Seed 001 Table 1 layout: one row per duration/interval, a column per shape and the mean
    t1 = pd.read_csv(rep / "recognition_table.csv", dtype={"timing": str})
    assert list(t1.columns) == ["timing", "triangle", "circle", "square", "rectangle", "mean"]
    assert list(t1["timing"]) == ["200/100", "200/200", "200/300", "200/400", "300/200",
                                  "300/300", "300/400", "300/500"]
    trials = pd.read_csv(out / "trials.csv", dtype=str)
    scored = trials[trials["timing"] == "300/200"]
    assert t1.set_index("timing").loc["300/200", "mean"] == pytest.approx(
        scored["correct"].astype(float).mean())
    # the declared two-way ANOVA, with an APA sentence per effect
    anova = pd.read_csv(rep / "anova_1.csv")
    assert list(anova["effect"]) == ["shape", "timing", "shape:timing"]
    assert (anova["df2"] == anova["df1"] * 2).all()            # 3 participants: df × (n − 1)
    sentences = [line for line in r.stdout.splitlines() if ": effect of" in line]
    assert len(sentences) == 3 and all(APA.search(s) for s in sentences)
    simple = pd.read_csv(rep / "simple_effects_1.csv")
    assert set(simple["method"]) == {"separate", "pooled"} and len(simple) == 16
    assert len(pd.read_csv(rep / "posthoc_1.csv")) == 28         # 8 timings: 28 pairs
    it = pd.read_csv(rep / "information_transfer.csv")
    assert len(it) == 8 and (it["bias_bits"] > 0).all()
    assert "Mixed-effects logistic regression" in html and "Laplace approximation" in html


def test_checksum_mismatch_is_reported_prominently_or_refused(cli, data, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(data, copy)
    beh = next((copy / "sub-01" / "ses-1" / "beh").glob("*_beh.tsv"))
    beh.write_text(beh.read_text().replace("\t1\t", "\t0\t", 1))   # someone edited a value
    r = cli("analyze", str(copy), "--out", str(tmp_path / "out"))
    assert r.returncode == 0
    assert "WARNING: CHECKSUM MISMATCH" in r.stderr and beh.name in r.stderr
    html = (tmp_path / "out" / "duration_interval_grid" / "report.html").read_text()
    assert "<div class='alarm'><h2>Checksum mismatch</h2>" in html
    sessions = pd.read_csv(tmp_path / "out" / "duration_interval_grid" / "sessions.csv",
                           dtype=str)
    assert sessions.set_index("participant").loc["01", "checksum"] == "MISMATCH"
    r = cli("analyze", str(copy), "--strict", "--out", str(tmp_path / "out2"))
    assert r.returncode == 2 and "checksum mismatch" in r.stderr and "Traceback" not in r.stderr


def test_unclosed_session_with_a_cut_row_is_kept_and_reported(cli, data, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(data, copy)
    d = copy / "sub-03" / "ses-1"
    meta = json.loads(session_record(d).read_text())
    meta.update(status="running", checksums=None)                  # as a killed session
    session_record(d).write_text(json.dumps(meta))
    beh = next(d.glob("beh/*_beh.tsv"))
    lines = beh.read_text().splitlines(keepends=True)
    beh.write_text("".join(lines[:41]) + lines[41][:9])              # 40 trials + a cut row
    r = cli("analyze", str(copy), "--out", str(tmp_path / "out"))
    assert r.returncode == 0, r.stderr
    assert "did not close" in r.stderr and "last row is incomplete" in r.stderr
    s = pd.read_csv(tmp_path / "out" / "duration_interval_grid" / "sessions.csv", dtype=str)
    row = s.set_index("participant").loc["03"]
    assert (row["status"], row["trials"], row["checksum"]) == ("running", "40", "not recorded")


@pytest.mark.parametrize("make, needle", [
    (lambda p: p.joinpath("rates.csv").write_text("a,b\n1,2\n") and p / "rates.csv",
     "not a vtexp session folder"),
    (lambda p: p.joinpath("session.json").write_text('{"format": "psychopy"}') and p,
     "not a vtexp session record"),
    (lambda p: p, "no vtexp sessions found"),
])
def test_files_that_are_not_vtexp_logs_are_refused(cli, tmp_path, make, needle):
    r = cli("analyze", str(make(tmp_path)))
    assert r.returncode == 2 and needle in r.stderr and "Traceback" not in r.stderr


@pytest.mark.parametrize("version, says", [
    (999, "format_version 999, newer than this vtexp reads (up to 2)"),
    ("2", "format_version is '2', not a version number"),
    (None, "format_version is None, not a version number"),
])
def test_a_session_record_of_a_newer_or_unknown_format_is_refused(cli, data, tmp_path,
                                                                   version, says):
    copy = tmp_path / "copy"
    shutil.copytree(data, copy)
    rec = session_record(copy / "sub-02" / "ses-1")
    meta = json.loads(rec.read_text())
    meta["format_version"] = version
    rec.write_text(json.dumps(meta))
    r = cli("analyze", str(copy), "--out", str(tmp_path / "out"))
    assert r.returncode == 2 and says in r.stderr and str(rec) in r.stderr, r.stderr
    assert "Traceback" not in r.stderr


def test_analysis_reads_the_format_sessions_write():
    from vtexp.analysis.load import READS_FORMAT_VERSION
    from vtexp.session import FORMAT_VERSION
    assert READS_FORMAT_VERSION == FORMAT_VERSION


def _edit(**changes):
    return lambda m: m.update(changes)


@pytest.mark.parametrize("damage, says", [
    (_edit(session="abc"), "session is 'abc', not a session number"),
    (_edit(experiment=5), "experiment is 5, not an experiment's name"),
    (_edit(participant=[1]), "participant is [1], not a participant id"),
    (lambda m: m.pop("experiment_loaded"), "experiment_loaded is missing"),
    (_edit(experiment_loaded={"name": 3}), "experiment the session ran (no title)"),
    (lambda m: m["experiment_loaded"].update(factors="x"), "its factors are not a table"),
    (lambda m: next(iter(m["experiment_loaded"]["factors"].values()))["levels"].__setitem__(
        0, {"a": None}), "are not a list of level names"),        # found by tests/fuzz.py
    (_edit(checksums="abc"), "checksums is 'abc', not a table of file checksums"),
    # found by tests/fuzz.py: an analysis: section nested in lists (AttributeError), the
    # planned trial count gone (the sessions table changed without a word)
    (lambda m: m["experiment_loaded"].update(analysis=[[{"a": 1}]]),
     "its analysis: is not a table"),
    (lambda m: m.pop("n_trials_planned"), "n_trials_planned is missing, not the number of "
                                          "trials planned"),
    ("nested", "nested too deeply"),
    ("digits", "Exceeds the limit (4300 digits)"),
    ("tab", "line 4 has 19 cells where the header has 18 (a tab too many?)"),
], ids=["session", "experiment", "participant", "no-experiment", "no-title", "factors",
        "levels", "checksums", "analysis-list", "no-planned", "nested", "digits", "tab"])
def test_a_damaged_session_record_or_log_is_one_message(cli, data, tmp_path, damage, says):
    """What analyze met with a traceback (ValueError, StopIteration, KeyError,
    AttributeError, LinAlgError, RecursionError, ParserError)."""
    copy = tmp_path / "copy"
    shutil.copytree(data, copy)
    rec = session_record(copy / "sub-02" / "ses-1")
    beh = next((copy / "sub-02" / "ses-1" / "beh").glob("*_beh.tsv"))
    if damage == "nested":
        rec.write_text(rec.read_text().rstrip()[:-1] + ', "x": ' + "[" * 100_000
                       + "]" * 100_000 + "}")
    elif damage == "digits":
        rec.write_text(rec.read_text().rstrip()[:-1] + ', "x": ' + "9" * 5000 + "}")
    elif damage == "tab":
        lines = beh.read_text().splitlines(keepends=True)
        lines[3] = lines[3].rstrip("\n") + "\textra\n"
        beh.write_text("".join(lines))
    else:
        meta = json.loads(rec.read_text())
        damage(meta)
        rec.write_text(json.dumps(meta))
    r = cli("analyze", str(copy), "--out", str(tmp_path / "out"))
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert says in r.stderr and str(beh if damage == "tab" else rec) in r.stderr, r.stderr


def test_a_pilot_of_one_finished_and_one_unfinished_session_gets_its_report(cli, tmp_path):
    """It exited 2 ("1 participant(s) with a value in every cell ...") and wrote no report:
    the tables, figures and report are written, and each test that cannot run is named
    as skipped, with why."""
    data = tmp_path / "data"
    for p, more in (("01", []), ("02", ["--max-trials", "5"])):
        r = cli("run", str(GRID), "-p", p, "--responder", "scripted:accuracy=0.8", "--data",
                str(data), "--quiet", *more)
        assert r.returncode == 0, r.stderr
    out = tmp_path / "out"
    r = cli("analyze", str(data / "duration_interval_grid"), "--out", str(out))
    assert r.returncode == 0, r.stderr
    d = out / "duration_interval_grid"
    assert (d / "report.html").is_file() and (d / "figure_rates.png").is_file()
    assert (d / "rates_by_condition.csv").is_file()
    md = (d / "report.md").read_text(encoding="utf-8")
    reason = ("1 participant(s) with a value in every cell; a repeated-measures ANOVA needs "
              "at least 2")
    assert f"The ANOVA of the recognition rate: skipped ({reason})" in md
    assert f"The paired comparisons of timing: skipped ({reason})" in md
    assert not list(d.glob("anova_*.csv"))


def test_log_values_a_record_does_not_declare_as_levels_are_said(cli, data, tmp_path):
    """A record whose factor's first level was edited: the tables changed (the log's
    level analysed as one of its own) and nothing was said (found by tests/fuzz.py)."""
    copy = tmp_path / "copy"
    shutil.copytree(data, copy)
    rec = session_record(copy / "sub-02" / "ses-1")
    meta = json.loads(rec.read_text())
    name, factor = next(iter(meta["experiment_loaded"]["factors"].items()))
    levels = factor["levels"]
    first = next(iter(levels))
    if isinstance(levels, dict):
        levels["edited"] = levels.pop(first)
    else:
        levels[0] = "edited"
    rec.write_text(json.dumps(meta))
    r = cli("analyze", str(copy), "--out", str(tmp_path / "out"))
    assert r.returncode == 0, r.stderr
    assert f"factor {name!r}: the trial log holds {first!r}, which the session record " \
           "does not declare as a level" in r.stderr, r.stderr
    assert f"vtexp: note: {copy / 'sub-02' / 'ses-1'}" in r.stderr, r.stderr


def test_a_dataset_copied_into_a_backup_folder_is_not_counted_twice(cli, data, tmp_path):
    """Every session was counted twice (one participant with 192 trials), or the model
    could not be fitted: each session found in two folders is named."""
    root = tmp_path / "data"
    shutil.copytree(data, root / "duration_interval_grid")
    shutil.copytree(data, root / "backup" / "duration_interval_grid")
    r = cli("analyze", str(root), "--out", str(tmp_path / "out"))
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert "session 1 of participant 01 of duration_interval_grid" in r.stderr
    assert "is found twice" in r.stderr and str(root / "backup") in r.stderr
    r = cli("analyze", str(root / "duration_interval_grid"), "--out", str(tmp_path / "out"))
    assert r.returncode == 0, r.stderr


def _cells(col, value, rows=None):
    """Set column ``col`` of the data rows ``rows`` (all if None) of a trial log."""
    def edit(text):
        lines = text.split("\n")
        i = lines[0].split("\t").index(col)
        for k in range(1, len(lines)):
            if lines[k] and (rows is None or k - 1 in rows):
                cells = lines[k].split("\t")
                cells[i] = value
                lines[k] = "\t".join(cells)
        return "\n".join(lines)
    return edit


def _without(col):
    def edit(text):
        lines = text.split("\n")
        i = lines[0].split("\t").index(col)
        return "\n".join("\t".join(c for j, c in enumerate(ln.split("\t")) if j != i)
                         if ln else ln for ln in lines)
    return edit


@pytest.mark.parametrize("damage, says", [
    (_cells("trial", "", [2]), "line 4: trial is '', not a trial number"),
    (_cells("trial", "x", [2]), "line 4: trial is 'x', not a trial number"),
    (_cells("correct", "maybe"), "line 2: correct is 'maybe', not 0, 1 or n/a (96 such rows)"),
    (_without("shape"), "lacks the column(s) 'shape' of the factors its session record"),
    # found by tests/fuzz.py (OverflowError, TypeError)
    (_cells("repetition", "inf", [1]), "line 3: repetition is 'inf', not a whole number"),
    (_cells("replays", "1.5", [0]), "line 2: replays is '1.5', not a whole number or n/a"),
    (_cells("rt_s", "-inf", [0]), "line 2: rt_s is '-inf', not a number or n/a"),
], ids=["trial-blank", "trial-x", "correct-maybe", "no-factor-column", "repetition-inf",
        "replays-fraction", "rt-infinite"])
def test_a_trial_log_changed_by_hand_is_refused_not_analysed(cli, data, tmp_path, damage, says):
    """Each was analysed without a word: a trial without its number, a participant whose
    every answer was neither right nor wrong (gone from the rates, still in the counts),
    trials without their condition."""
    copy = tmp_path / "copy"
    shutil.copytree(data, copy)
    beh = next((copy / "sub-02" / "ses-1" / "beh").glob("*_beh.tsv"))
    beh.write_text(damage(beh.read_text()))
    r = cli("analyze", str(copy), "--out", str(tmp_path / "out"))
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert says in r.stderr and str(beh) in r.stderr, r.stderr


def test_a_session_whose_record_was_deleted_is_said_to_be_left_out(cli, data, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(data, copy)
    session_record(copy / "sub-03" / "ses-1").unlink()
    beh = next((copy / "sub-03" / "ses-1" / "beh").glob("*_beh.tsv"))
    r = cli("analyze", str(copy), "--out", str(tmp_path / "out"))
    assert r.returncode == 0, r.stderr
    assert "1 trial log(s) without a session record, left out" in r.stderr
    assert str(beh) in r.stderr
    s = pd.read_csv(tmp_path / "out" / "duration_interval_grid" / "sessions.csv", dtype=str)
    assert sorted(s["participant"]) == ["01", "02"]


def test_a_trial_log_given_alone_points_to_its_session_folder(cli, data):
    beh = next((data / "sub-01" / "ses-1" / "beh").glob("*_beh.tsv"))
    r = cli("analyze", str(beh))
    assert r.returncode == 2 and "give the session folder" in r.stderr


def test_experiment_file_overrides_the_recorded_analysis(cli, data, tmp_path):
    text = GRID.read_text()
    head = text.split("\nanalysis:")[0]
    f = write_experiment(tmp_path, head + "\nanalysis:\n  posthoc:\n    - {factor: shape, "
                         "padjust: bonferroni}\n", name="grid.yaml")
    r = cli("analyze", str(data), "--experiment", str(f), "--out", str(tmp_path / "out"))
    assert r.returncode == 0, r.stderr
    rep = tmp_path / "out" / "duration_interval_grid"
    ph = pd.read_csv(rep / "posthoc_1.csv")
    assert len(ph) == 6 and set(ph["padjust"]) == {"bonferroni"}
    assert not (rep / "anova_1.csv").exists()
    assert "the experiment file given with --experiment" in (rep / "report.md").read_text()


def test_analysis_names_must_be_factors(cli, tmp_path):
    text = GRID.read_text().replace("{effect: shape, by: timing", "{effect: shape, by: timing_ms")
    f = write_experiment(tmp_path, text, name="grid.yaml")
    r = cli("validate", str(f))
    assert r.returncode == 2
    assert "analysis.simple_effects[0].by: 'timing_ms' is not a factor" in r.stderr
    f = write_experiment(tmp_path, GRID.read_text().replace("pooled: true}", "pooled: true, "
                                                            "style: apa}"), name="g2.yaml")
    r = cli("validate", str(f))
    assert r.returncode == 2 and "analysis.table.style" in r.stderr


def test_stats_rm_anova_cli_json_equals_the_library(cli):
    from conftest import ROOT
    from vtexp.analysis.anova import rm_anova
    f = ROOT / "tests" / "data" / "grid_3x4.csv"
    r = cli("stats", "rm-anova", str(f), "--dv", "score", "--within", "shape", "soa",
            "--subject", "participant", "--json")
    assert r.returncode == 0, r.stderr
    got = pd.DataFrame(json.loads(r.stdout)["effects"])
    want = rm_anova(pd.read_csv(f, dtype=str), "score", ["shape", "soa"], "participant")
    assert list(got["effect"]) == list(want["effect"])
    assert (got["F"] - want["F"]).abs().max() < 1e-12
    r = cli("stats", "rm-anova", str(f), "--dv", "score", "--within", "shape", "soa",
            "--subject", "participant")
    assert ("soa: F(1.66, 21.60) = 6.02, p = .011, η²p = .32, 90% CI [.05, .52], ε = .55 "
            "(Greenhouse–Geisser)") in r.stdout


def test_stats_cli_errors_name_the_file_and_column(cli, tmp_path):
    from conftest import ROOT
    f = ROOT / "tests" / "data" / "missing_cell.csv"
    r = cli("stats", "rm-anova", str(f), "--dv", "correct", "--within", "shape", "timing",
            "--subject", "participant", "--missing", "error")
    assert r.returncode == 2 and str(f) in r.stderr and "04: no square × 300/500" in r.stderr
    r = cli("stats", "rm-anova", str(tmp_path / "nope.csv"), "--dv", "y", "--within", "a",
            "--subject", "s")
    assert r.returncode == 2 and "no such file" in r.stderr and "Traceback" not in r.stderr
    r = cli("stats", "simple-effects", str(f), "--dv", "correct", "--within", "shape", "timing",
            "--subject", "participant", "--effect", "timing", "--by", "shape", "--method",
            "pooled", "--json")
    assert r.returncode == 0 and len(json.loads(r.stdout)["rows"]) == 2


def test_stats_reads_what_spreadsheets_write_and_refuses_an_empty_file(cli, tmp_path):
    from conftest import ROOT
    f = ROOT / "tests" / "data" / "grid_3x4.csv"
    args = ["--dv", "score", "--within", "shape", "soa", "--subject", "participant", "--json"]
    want = cli("stats", "rm-anova", str(f), *args)
    assert want.returncode == 0, want.stderr
    excel = tmp_path / "excel.csv"            # a byte-order mark and CRLF line ends
    excel.write_bytes(b"\xef\xbb\xbf" + f.read_bytes().replace(b"\r\n", b"\n")
                      .replace(b"\n", b"\r\n"))
    got = cli("stats", "rm-anova", str(excel), *args)
    assert got.returncode == 0, got.stderr
    assert json.loads(got.stdout)["effects"] == json.loads(want.stdout)["effects"]
    for name, text in (("empty.csv", b""), ("blank.csv", b"\n\n"), ("one.csv", b"a\n1\n")):
        (tmp_path / name).write_bytes(text)
        r = cli("stats", "rm-anova", str(tmp_path / name), *args)
        assert r.returncode == 2 and name in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_stats_refuses_an_infinite_value_naming_it(cli, tmp_path):
    # every F was "n/a" with the reason "the measure does not vary across these cells"
    from conftest import ROOT
    rows = (ROOT / "tests" / "data" / "grid_3x4.csv").read_text().splitlines()
    head = rows[0].split(",")
    cells = rows[5].split(",")
    cells[head.index("score")] = "inf"
    f = tmp_path / "inf.csv"
    f.write_text("\n".join(rows[:5] + [",".join(cells)] + rows[6:]) + "\n")
    r = cli("stats", "rm-anova", str(f), "--dv", "score", "--within", "shape", "soa",
            "--subject", "participant")
    assert r.returncode == 2 and "column 'score' holds an infinite value 'inf' (row 4)" in \
        r.stderr and "Traceback" not in r.stderr, r.stderr


def test_reanalysis_script_shows_where_the_papers_df_come_from(data, tmp_path):
    import subprocess
    import sys
    from conftest import ROOT
    r = subprocess.run([sys.executable, str(ROOT / "analysis" / "duration_interval_grid.py"),
                        str(data), "--out", str(tmp_path / "t1.csv")], capture_output=True,
                       text=True)
    assert r.returncode == 0, r.stderr
    # 3 participants: repeated measures gives F(7, 14) for timing (uncorrected df), the
    # between-participants reading of seed 001 gives F(7, 96 - 32 = 64).
    assert "C(timing): F(7, 64)" in r.stdout
    assert "timing: F(" in r.stdout and "η²p" in r.stdout
    assert len(pd.read_csv(tmp_path / "t1.csv", index_col=0)) == 8


def test_groups_from_the_participants_table_give_a_mixed_anova(cli, data, tmp_path):
    import shutil as sh
    root = tmp_path / "grid"
    sh.copytree(data, root)
    text = GRID.read_text()
    head = text.split("\nanalysis:")[0]
    f = write_experiment(tmp_path, head + "\nanalysis:\n  anova:\n    - {within: [shape], "
                         "between: [group]}\n  posthoc:\n    - {factor: group, between: "
                         "[group], within: [shape], error: pooled}\n", name="grid.yaml")
    r = cli("analyze", str(root), "--experiment", str(f), "--out", str(tmp_path / "out"))
    # vtexp wrote participants.tsv at the first sessions, without groups (scripted runs).
    assert r.returncode == 2 and "participants.tsv: group is n/a for participant(s) sub-01" \
        in r.stderr and "Traceback" not in r.stderr
    (root / "participants.tsv").write_text("participant_id\tgroup\nsub-01\tblind\n"
                                           "sub-02\tblind\nsub-03\tsighted\n")
    r = cli("analyze", str(root), "--experiment", str(f), "--out", str(tmp_path / "out"))
    assert r.returncode == 0, r.stderr
    rep = tmp_path / "out" / "duration_interval_grid"
    anova = pd.read_csv(rep / "anova_1.csv")
    assert list(anova["effect"]) == ["group", "shape", "group:shape"]
    assert (anova["df2"] == anova["df1"] * 1).all()            # 3 participants − 2 groups
    assert len(pd.read_csv(rep / "posthoc_1.csv")) == 1


STUDIES = sorted((ROOT / "experiments").glob("*.yaml"))


@pytest.mark.parametrize("study", STUDIES, ids=[p.stem for p in STUDIES])
def test_a_pilot_of_two_with_a_condition_everyone_got_right_analyses(cli, tmp_path, study):
    """What a lab analyses first: one participant who stopped early and one who answered
    every question right (where a question has no right answer, the same answer
    throughout), in each study. The tables,
    figures and report are written; what cannot be tested is named as skipped, with why;
    no effect size or interval is a crash."""
    from vtexp.experiment import load_experiment
    data = tmp_path / "data"
    asked = load_experiment(study).experiment.asked()
    if all(q.correct is not None for q in asked):
        first, second = "scripted:accuracy=0.7", "scripted:correct"
    else:           # a rating, or a percept with no right answer: one answer throughout
        (tmp_path / "same.txt").write_text("".join(f"{q.options[0]}\n" for q in asked) * 16)
        first, second = "scripted:random", f"scripted:answers={tmp_path / 'same.txt'}"
    for p, responder, more in (("01", first, ["--max-trials", "8"]),
                               ("02", second, ["--max-trials", "16"])):
        r = cli("run", str(study), "-p", p, "--responder", responder, "--data", str(data),
                "--quiet", *more)
        assert r.returncode == 0, r.stderr
    out = tmp_path / "out"
    r = cli("analyze", *data.iterdir(), "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    report = next(out.rglob("report.md")).read_text(encoding="utf-8")
    assert (next(out.rglob("report.html"))).stat().st_size > 1000
    assert "2 participant" in report or "participants: 2" in report or "| 2 |" in report, \
        report[:1500]
