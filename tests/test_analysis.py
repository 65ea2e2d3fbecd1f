"""Analysis: reading sessions back and computing recognition rates."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from vtexp.analysis import load_sessions, recognition_rates
from vtexp.errors import InputError


def tidy(rows):
    df = pd.DataFrame(rows, columns=["participant", "a", "correct"])
    df["experiment"] = "x"
    df["correct"] = df["correct"].astype("Int64")
    return df


def test_rates_average_participants_equally():
    df = tidy([("1", "p", 1), ("1", "p", 1), ("1", "p", 0), ("1", "p", 1),   # 0.75
               ("2", "p", 0), ("2", "p", 1),                                   # 0.5
               ("1", "q", 0), ("2", "q", 0), ("2", "q", None)])                # unscored left out
    by = recognition_rates(df, ["a"]).set_index("a")
    assert by.loc["p", "rate"] == pytest.approx(0.625)
    assert by.loc["p", "n_trials"] == 6 and by.loc["p", "n_correct"] == 4
    assert by.loc["p", "se"] == pytest.approx(pd.Series([0.75, 0.5]).std() / 2 ** 0.5)
    assert by.loc["q", "rate"] == 0 and by.loc["q", "n_trials"] == 2
    per = recognition_rates(df, ["a"], per_participant=True)
    assert list(per["rate"]) == [0.75, 0.0, 0.5, 0.0]


def test_a_folder_without_sessions_is_refused(tmp_path):
    with pytest.raises(InputError, match="no vtexp sessions found"):
        load_sessions([tmp_path])


def test_a_foreign_session_json_is_refused(tmp_path):
    (tmp_path / "session.json").write_text(json.dumps({"hello": "world"}))
    with pytest.raises(InputError, match="not a vtexp session record"):
        load_sessions([tmp_path])


def test_cli_analyze_of_a_non_vtexp_file(cli, tmp_path):
    f = tmp_path / "notes.txt"
    f.write_text("hi")
    r = cli("analyze", str(f))
    assert r.returncode == 2 and "not a vtexp session folder" in r.stderr
    assert "Traceback" not in r.stderr
