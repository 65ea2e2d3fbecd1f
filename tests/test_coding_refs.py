"""Coding protocols by reference to a file (``coding: {ref: NAME}``): resolution,
overrides, the session record, the schema, and one clear error per mistake."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest
import yaml

from conftest import ROOT, write_experiment
from vtexp.compile import compile_conditions, enumerate_conditions, load_and_compile
from vtexp.devices import open_device
from vtexp.errors import InputError
from vtexp.experiment import available_codings, load_coding_file, load_experiment
from vtexp.model import DeviceProfile
from vtexp.resources import codings_dir
from vtexp.responders import make_responder
from vtexp.session import SessionOptions, run_session

EXPERIMENTS = sorted((ROOT / "experiments").glob("*.yaml"))
SHIPPED = sorted((ROOT / "protocols" / "codings").glob("*.yaml"))
INLINE = "coding:\n  protocol: sequential-trace\n  params: {duration_ms: 200, soa_ms: 200}\n"
GOOD_FILE = """\
name: mine
description: a pilot's timing
reference: our pilot, 2024
protocol: sequential-trace
params: {duration_ms: 250, soa_ms: 150, vertex_level: 2}
"""


def with_coding(minimal_yaml: str, coding: str) -> str:
    assert INLINE in minimal_yaml
    return minimal_yaml.replace(INLINE, coding)


def error_of(path: Path) -> InputError:
    with pytest.raises(InputError) as ei:
        load_experiment(path)
    return ei.value


def line_of(text: str, start: str) -> int:
    return next(i for i, s in enumerate(text.splitlines(), 1) if s.startswith(start))


def without_source(dump: dict) -> dict:
    coding = dump["coding"]
    return {**dump, "coding": {"protocol": coding["protocol"], "params": coding["params"]}}


# ---------------------------------------------------------------- resolution

@pytest.mark.parametrize("path", EXPERIMENTS, ids=lambda p: p.stem)
def test_every_shipped_experiment_validates(path):
    lx, _ = load_and_compile(path)              # with every stimulus checked for safety
    assert lx.experiment.coding.protocol is not None


@pytest.mark.parametrize("path", [p for p in EXPERIMENTS if "ref:" in p.read_text()],
                         ids=lambda p: p.stem)
def test_a_reference_loads_as_the_inline_form(tmp_path, path):
    lx = load_experiment(path)
    src = lx.experiment.coding.source
    cf, sha = load_coding_file(src.file)
    data = yaml.safe_load(path.read_text())
    assert set(data["coding"]) == {"ref"}
    data["coding"] = {"protocol": cf.protocol, "params": cf.params}
    inline = load_experiment(write_experiment(tmp_path, yaml.safe_dump(data, sort_keys=False)))
    assert lx.experiment.coding.protocol == inline.experiment.coding.protocol
    assert lx.experiment.coding.params == inline.experiment.coding.params
    assert without_source(lx.experiment.model_dump(mode="json")) == \
        without_source(inline.experiment.model_dump(mode="json"))
    assert [(c.levels, c.coding_params) for c in enumerate_conditions(lx)] == \
        [(c.levels, c.coding_params) for c in enumerate_conditions(inline)]
    assert src.ref == data_ref(path) and Path(src.file) == codings_dir().resolve() / \
        f"{src.ref}.yaml"
    assert src.sha256 == sha == hashlib.sha256(Path(src.file).read_bytes()).hexdigest()
    assert inline.experiment.coding.source is None


def data_ref(path: Path) -> str:
    return yaml.safe_load(path.read_text())["coding"]["ref"]


def test_same_schedules_as_inline(tmp_path, minimal_yaml):
    ref = load_experiment(write_experiment(tmp_path, with_coding(
        minimal_yaml, "coding:\n  ref: seed001_table1_best_trace\n"), "ref.yaml"))
    inline = load_experiment(write_experiment(tmp_path, with_coding(
        minimal_yaml, "coding:\n  protocol: sequential-trace\n  params: {duration_ms: 300, "
                      "soa_ms: 200, loops: 1, level: 1, vertex_level: 2}\n"), "inline.yaml"))
    a, b = compile_conditions(ref), compile_conditions(inline)
    assert [c.schedule for c in a] == [c.schedule for c in b]


def test_params_beside_ref_override_the_file(tmp_path, minimal_yaml):
    lx = load_experiment(write_experiment(tmp_path, with_coding(
        minimal_yaml, "coding:\n  ref: seed001_table1_best_trace\n  params: {duration_ms: 250}\n")))
    assert lx.experiment.coding.params == {"duration_ms": 250, "soa_ms": 200, "loops": 1,
                                           "level": 1, "vertex_level": 2}


def test_factor_levels_override_the_file_too(tmp_path, minimal_yaml):
    text = with_coding(minimal_yaml, "coding:\n  ref: seed001_table1_best_trace\n").replace(
        "design:", "  timing:\n    sets: coding\n    levels:\n      fast: {soa_ms: 100}\n"
                   "      slow: {soa_ms: 400}\ndesign:")
    conds = enumerate_conditions(load_experiment(write_experiment(tmp_path, text)))
    assert {c.levels["timing"]: c.coding_params["soa_ms"] for c in conds} == {"fast": 100,
                                                                               "slow": 400}
    assert all(c.coding_params["duration_ms"] == 300 for c in conds)


def test_a_relative_path_resolves_against_the_experiment_folder(tmp_path, minimal_yaml,
                                                                monkeypatch):
    folder = tmp_path / "study"
    (folder / "codings").mkdir(parents=True)
    (folder / "codings" / "mine.yaml").write_text(GOOD_FILE)
    f = write_experiment(folder, with_coding(minimal_yaml, "coding:\n  ref: codings/mine.yaml\n"))
    monkeypatch.chdir(tmp_path)                   # not the experiment's folder
    coding = load_experiment(f).experiment.coding
    assert coding.protocol == "sequential-trace" and coding.params["duration_ms"] == 250
    assert coding.source.file == str((folder / "codings" / "mine.yaml").resolve())


def test_names_are_found_where_the_profiles_are(tmp_path, minimal_yaml, monkeypatch):
    # VTEXP_PROTOCOLS moves protocols/ (devices and codings) as a wheel's copy would.
    shipped = ROOT / "protocols"
    moved = tmp_path / "protocols"
    (moved / "codings").mkdir(parents=True)
    (moved / "devices").symlink_to(shipped / "devices")
    (moved / "codings" / "mine.yaml").write_text(GOOD_FILE)
    monkeypatch.setenv("VTEXP_PROTOCOLS", str(moved))
    assert available_codings() == ["mine"]
    lx = load_experiment(write_experiment(tmp_path, with_coding(minimal_yaml,
                                                               "coding:\n  ref: mine\n")))
    assert lx.experiment.coding.source.file == str((moved / "codings" / "mine.yaml").resolve())


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem)
def test_shipped_coding_files_cite_their_paper(path):
    cf, _ = load_coding_file(path)
    assert cf.name == path.stem and cf.description
    assert cf.reference.startswith("seed 00") and "Table" in cf.reference


def test_every_shipped_coding_is_used_by_an_experiment():
    used = {data_ref(p) for p in EXPERIMENTS if "ref:" in p.read_text()}
    assert used == {p.stem for p in SHIPPED}


# ---------------------------------------------------------------- the record

def test_session_json_records_the_coding_file_and_its_hash(tmp_path, minimal_yaml):
    f = write_experiment(tmp_path, with_coding(minimal_yaml,
                                               "coding:\n  ref: seed001_table1_best_trace\n"))
    lx = load_experiment(f)
    responder = make_responder("scripted:correct", "01", 1)
    with open_device("sim", DeviceProfile.load(lx.experiment.device)) as dev:
        res = run_session(lx, dev, responder,
                          SessionOptions(participant="01", data_dir=tmp_path / "data"))
    meta = json.loads(res.paths.session_json.read_text())
    coding = meta["experiment_loaded"]["coding"]
    file = ROOT / "protocols" / "codings" / "seed001_table1_best_trace.yaml"
    assert coding["protocol"] == "sequential-trace" and coding["params"]["duration_ms"] == 300
    assert coding["source"] == {"ref": "seed001_table1_best_trace", "file": str(file.resolve()),
                                "sha256": hashlib.sha256(file.read_bytes()).hexdigest()}


def test_schema_accepts_the_shipped_experiments(cli, tmp_path):
    import jsonschema
    out = tmp_path / "schema.json"
    assert cli("schema", "--out", str(out)).returncode == 0
    schema = json.loads(out.read_text())
    validator = jsonschema.Draft202012Validator(schema)
    for path in EXPERIMENTS:
        errors = list(validator.iter_errors(yaml.safe_load(path.read_text())))
        assert not errors, (path.name, errors[0].message)
    coding = schema["$defs"]["CodingSpec"]
    assert "source" not in coding["properties"]              # filled in, never written
    assert set(coding["properties"]["ref"]["examples"]) == {p.stem for p in SHIPPED}
    bad = yaml.safe_load(EXPERIMENTS[0].read_text())
    bad["coding"] = {"ref": "seed002_table3_pulses", "protocol": "pulse-trains"}
    assert list(validator.iter_errors(bad))                  # both: refused


# ---------------------------------------------------------------- errors

def test_unknown_name_lists_the_known_ones(tmp_path, minimal_yaml):
    text = with_coding(minimal_yaml, "coding:\n  ref: seed001_nope\n")
    e = error_of(write_experiment(tmp_path, text))
    assert e.path == str(tmp_path / "exp.yaml") and e.key == "coding.ref"
    assert e.line == line_of(text, "  ref:")
    assert "unknown coding 'seed001_nope'" in e.message
    for name in ("seed000_table2_modes", "seed002_table3_pulses"):
        assert name in e.message


def test_missing_relative_file(tmp_path, minimal_yaml):
    e = error_of(write_experiment(tmp_path, with_coding(minimal_yaml,
                                                        "coding:\n  ref: codings/gone.yaml\n")))
    assert e.key == "coding.ref" and "gone.yaml" in e.message and "not found" in e.message


def test_protocol_and_ref_together(tmp_path, minimal_yaml):
    text = with_coding(minimal_yaml, "coding:\n  protocol: sequential-trace\n"
                                     "  ref: seed001_table1_trace\n")
    e = error_of(write_experiment(tmp_path, text))
    assert e.key == "coding.ref" and e.line == line_of(text, "  ref:")
    assert "not both" in e.message


def test_neither_protocol_nor_ref(tmp_path, minimal_yaml):
    e = error_of(write_experiment(tmp_path, with_coding(minimal_yaml,
                                                        "coding:\n  params: {loops: 1}\n")))
    assert e.key == "coding" and "'protocol'" in e.message and "'ref'" in e.message


@pytest.mark.parametrize("key", ["parms", "source"])
def test_unknown_key_beside_ref(tmp_path, minimal_yaml, key):
    text = with_coding(minimal_yaml, f"coding:\n  ref: seed001_table1_trace\n  {key}: {{}}\n")
    e = error_of(write_experiment(tmp_path, text))
    assert e.key == f"coding.{key}" and "unknown key" in e.message
    assert e.line == line_of(text, f"  {key}:")


def test_a_bad_override_points_at_the_experiment(tmp_path, minimal_yaml):
    text = with_coding(minimal_yaml, "coding:\n  ref: seed001_table1_trace\n"
                                     "  params: {soa_ms: -1}\n")
    e = error_of(write_experiment(tmp_path, text))
    assert e.path == str(tmp_path / "exp.yaml") and e.key == "coding.params.soa_ms"
    assert "greater than 0" in e.message


@pytest.mark.parametrize("content, line, key, words", [
    (GOOD_FILE.replace("duration_ms: 250", "duration_ms: -1"), 5, "params.duration_ms",
     "greater than 0"),
    (GOOD_FILE.replace("vertex_level: 2", "vertex_levle: 2"), 5, "params.vertex_levle",
     "unknown key"),
    (GOOD_FILE.replace("sequential-trace", "sequential-trail"), 4, "protocol",
     "unknown coding protocol 'sequential-trail'"),
    (GOOD_FILE.replace("reference: our pilot, 2024\n", ""), 1, "reference",
     "required key is missing"),
    (GOOD_FILE.replace("name: mine", "name: yours"), 1, "name", "'yours' differs"),
    (GOOD_FILE.replace("params: {", "params: [{"), 6, None, "YAML syntax error"),
    ("- a list\n", 1, None, "expected a mapping"),
])
def test_a_broken_coding_file_is_named_with_its_line_and_key(tmp_path, minimal_yaml, content,
                                                             line, key, words):
    (tmp_path / "mine.yaml").write_text(content)
    text = with_coding(minimal_yaml, "coding:\n  ref: mine.yaml\n")
    e = error_of(write_experiment(tmp_path, text))
    assert e.path == str(tmp_path / "mine.yaml")
    assert e.line == line and e.key == key and words in e.message
    # ... and says which experiment line referred to it
    assert f"coding file of {tmp_path / 'exp.yaml'}:{line_of(text, '  ref:')}" in e.message


def test_an_unreadable_coding_file(tmp_path, minimal_yaml):
    (tmp_path / "mine.yaml").write_bytes(b"name: mine\nreference: \xff\n")
    e = error_of(write_experiment(tmp_path, with_coding(minimal_yaml,
                                                        "coding:\n  ref: mine.yaml\n")))
    assert e.path == str(tmp_path / "mine.yaml") and "not UTF-8" in e.message


def test_the_cli_prints_one_line(cli, tmp_path, minimal_yaml):
    (tmp_path / "mine.yaml").write_text(GOOD_FILE.replace("duration_ms: 250", "duration_ms: -1"))
    f = write_experiment(tmp_path, with_coding(minimal_yaml, "coding:\n  ref: mine.yaml\n"))
    r = cli("validate", str(f))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    lines = (r.stdout + r.stderr).strip().splitlines()
    assert len(lines) == 1 and f"{tmp_path / 'mine.yaml'}:5: params.duration_ms:" in lines[0]
