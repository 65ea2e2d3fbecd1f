"""Power over a fitted observer file's intervals: the ``fitted:`` section that ``vtexp
observer fit`` writes, how ``vtexp simulate`` reads it, and what it refuses."""

from __future__ import annotations

import json

import pytest
import yaml
from conftest import ROOT

from vtexp.cli import main
from vtexp.observer.params import load_params
from vtexp.simulate import Setup, fitted_runs

#: the quickest study to simulate (4 conditions)
CVR = ROOT / "experiments" / "circle_vs_rectangle.yaml"
DEFAULT = ROOT / "protocols" / "observers" / "default.yaml"
SECTION = {"by": "vtexp observer fit", "participants": 4,
           "params": {"efficiency": {"centre": 0.1, "low": 0.03, "high": 0.4},
                      "lapse": {"centre": 0.02, "low": 0.02, "high": 0.2}},
           "not_identified": ["decision_noise"]}


def _observer(tmp_path, fitted=None, name="fitted.yaml"):
    data = yaml.safe_load(DEFAULT.read_text(encoding="utf-8"))
    data["efficiency"], data["lapse"] = 0.1, 0.02
    if fitted is not None:
        data["fitted"] = fitted
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


def test_each_end_of_each_interval_is_one_run_of_the_model_with_that_value(tmp_path):
    """Two runs per fitted parameter, none for an end that is the centre; a run's model
    participant has the end's value and the centre's others."""
    f = _observer(tmp_path, SECTION)
    runs, unknown = fitted_runs(f)
    assert [(r.param, r.end, r.value) for r in runs] == [
        ("efficiency", "low", 0.03), ("efficiency", "high", 0.4), ("lapse", "high", 0.2)]
    assert unknown == ["decision_noise"]
    for r in runs:
        p = Setup.load(CVR, params_file=f, overrides=r.overrides).model.params
        assert getattr(p, r.param) == r.value
        other = "lapse" if r.param == "efficiency" else "efficiency"
        assert getattr(p, other) == SECTION["params"][other]["centre"]
    assert fitted_runs(_observer(tmp_path, None, "plain.yaml")) == ([], [])


def test_simulate_prints_the_range_and_the_runs_it_cost(tmp_path, capsys):
    f = _observer(tmp_path, SECTION)
    assert main(["simulate", str(CVR), "--observer", str(f), "-n", "2", "-m", "2",
                 "--workers", "1", "-q", "--json", str(tmp_path / "s.json")]) == 0
    cap = capsys.readouterr()
    assert "3 more runs of 2 studies (6 studies more; 4 times the centre's cost" in cap.err
    assert "efficiency = 0.03 (low)" in cap.out and "lapse = 0.2 (high)" in cap.out
    assert "decision_noise: not identified by the fit" in cap.out
    doc = json.loads((tmp_path / "s.json").read_text(encoding="utf-8"))
    centre = {r["effect"]: r["power"] for r in doc["power"]}
    got = {r["effect"]: r for r in doc["power_range"]["effects"]}
    assert set(got) == set(centre)
    for e, r in got.items():
        each = [x["power"] for run in doc["power_range"]["runs"] for x in run["power"]
                if x["effect"] == e]
        assert len(each) == 3
        assert r["centre"] == centre[e]
        assert r["low"] == min(each + [centre[e]]) and r["high"] == max(each + [centre[e]])
        assert r["low"] <= r["centre"] <= r["high"]


def test_a_file_without_the_section_prints_no_range(tmp_path, capsys):
    f = _observer(tmp_path, None, "plain.yaml")
    assert main(["simulate", str(CVR), "--observer", str(f), "-n", "2", "-m", "2",
                 "--workers", "1", "-q", "--json", str(tmp_path / "s.json")]) == 0
    cap = capsys.readouterr()
    assert "Power at N = 2" in cap.out
    assert "fitted" not in cap.out and "more runs" not in cap.err
    assert "power_range" not in json.loads((tmp_path / "s.json").read_text(encoding="utf-8"))


@pytest.mark.parametrize("case,key,words", [
    ("reversed", "fitted.params.efficiency", "does not hold the centre"),
    ("outside", "fitted.params.lapse.high", "not a value of lapse"),
    ("unknown", "fitted.params.sharpness", "no parameter 'sharpness'"),
    ("text", "fitted.params.efficiency.low", "valid number"),
    ("not-identified", "fitted.not_identified", "no parameter 'speed'"),
])
def test_bad_section_values_are_one_message_naming_the_file_and_key(tmp_path, capsys, case,
                                                                   key, words):
    sec = json.loads(json.dumps(SECTION))
    p = sec["params"]
    if case == "reversed":
        p["efficiency"].update(low=0.2, high=0.05)
    elif case == "outside":
        p["lapse"]["high"] = 1.5
    elif case == "unknown":
        p["sharpness"] = {"centre": 1, "low": 0, "high": 2}
    elif case == "text":
        p["efficiency"]["low"] = "low"
    else:
        sec["not_identified"] = ["speed"]
    f = _observer(tmp_path, sec, "bad.yaml")
    with pytest.raises(Exception) as e:
        load_params(f)
    assert key in str(e.value) and str(f) in str(e.value)
    code = main(["simulate", str(CVR), "--observer", str(f), "-n", "2", "-m", "2",
                 "--workers", "1", "-q"])
    err = capsys.readouterr().err
    errors = [ln for ln in err.splitlines() if ln.startswith("vtexp: error:")]
    assert code == 2 and len(errors) == 1 and "Traceback" not in err, err
    assert str(f) in errors[0] and f"{key}:" in errors[0] and words in errors[0]


def test_a_parameter_the_experiment_sets_is_left_out_of_the_range(tmp_path, capsys):
    """The experiment's observer.params overrides the observer file, in the centre's run
    too: varying that parameter over the file's interval would not be the centre's model."""
    text = CVR.read_text(encoding="utf-8").replace(
        "observer:\n", "observer:\n  params: {efficiency: 0.2}\n", 1)
    exp = tmp_path / "cvr.yaml"
    exp.write_text(text, encoding="utf-8")
    f = _observer(tmp_path, SECTION)
    assert main(["simulate", str(exp), "--observer", str(f), "-n", "2", "-m", "2",
                 "--workers", "1", "-q"]) == 0
    cap = capsys.readouterr()
    assert "efficiency: set by the experiment's observer.params" in cap.err
    assert "1 more run of 2 studies" in cap.err and "lapse = 0.2 (high)" in cap.out
    assert "efficiency = 0.03" not in cap.out
