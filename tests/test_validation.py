"""Experiment files: schema, references and safety; errors name file, line and key."""

from __future__ import annotations

from pathlib import Path

import pytest

from conftest import write_experiment
from vtexp.errors import InputError
from vtexp.compile import load_and_compile
from vtexp.experiment import load_experiment


def load(tmp_path, text):
    """Loaded, checked and compiled: every error a session would meet before it starts."""
    return load_and_compile(write_experiment(tmp_path, text))[0]


def error_of(tmp_path, text) -> InputError:
    with pytest.raises(InputError) as ei:
        load(tmp_path, text)
    return ei.value


def test_shipped_experiment_is_valid(grid_path):
    lx = load_experiment(grid_path)
    assert lx.experiment.name == "duration_interval_grid"
    assert lx.experiment.task_label == "durationIntervalGrid"


def test_minimal_is_valid(tmp_path, minimal_yaml):
    assert load(tmp_path, minimal_yaml).experiment.design.repetitions == 2


def test_unknown_key_names_line_and_key(tmp_path, minimal_yaml):
    text = minimal_yaml.replace("  repetitions: 2\n", "  repetitions: 2\n  repetitons: 3\n")
    e = error_of(tmp_path, text)
    assert e.line == text.splitlines().index("  repetitons: 3") + 1
    assert e.key == "design.repetitons" and "unknown key" in e.message
    assert str(e).startswith(f"{tmp_path / 'exp.yaml'}:{e.line}: design.repetitons:")


def test_unknown_top_level_key(tmp_path, minimal_yaml):
    e = error_of(tmp_path, minimal_yaml + "colour: red\n")
    assert e.key == "colour" and e.line == len(minimal_yaml.splitlines()) + 1


def test_wrong_type_says_what_is_expected(tmp_path, minimal_yaml):
    text = minimal_yaml.replace("repetitions: 2", "repetitions: many")
    e = error_of(tmp_path, text)
    assert e.key == "design.repetitions"
    assert "integer" in e.message and "'many'" in e.message
    assert e.line == text.splitlines().index("  repetitions: many") + 1


def test_out_of_range_value(tmp_path, minimal_yaml):
    e = error_of(tmp_path, minimal_yaml.replace("repetitions: 2", "repetitions: 0"))
    assert e.key == "design.repetitions" and "greater than or equal to 1" in e.message


def test_out_of_range_coding_parameter_points_at_it(tmp_path, minimal_yaml):
    text = minimal_yaml.replace("soa_ms: 200", "soa_ms: -5")
    e = error_of(tmp_path, text)
    assert e.key == "coding.params.soa_ms" and "greater than 0" in e.message
    assert e.line == text.splitlines().index("  params: {duration_ms: 200, soa_ms: -5}") + 1


def test_missing_key(tmp_path, minimal_yaml):
    text = minimal_yaml.replace("title: A minimal experiment\n", "")
    e = error_of(tmp_path, text)
    assert e.key == "title" and "required" in e.message


def test_yaml_syntax_error_has_line(tmp_path, minimal_yaml):
    text = minimal_yaml.replace("options: [square, circle]", "options: [square, circle")
    e = error_of(tmp_path, text)
    assert "YAML syntax error" in e.message and e.line is not None


def test_python_object_tags_are_refused(tmp_path, minimal_yaml):
    text = minimal_yaml.replace("title: A minimal experiment",
                                "title: !!python/object/apply:os.system ['echo pwned']")
    e = error_of(tmp_path, text)
    assert "not allowed" in e.message and e.line == 2


def test_duplicate_keys_are_refused(tmp_path, minimal_yaml):
    e = error_of(tmp_path, minimal_yaml + "title: again\n")
    assert "duplicate key 'title'" in e.message


def test_missing_stimulus_file(tmp_path, minimal_yaml):
    text = minimal_yaml.replace("square: {generator: shape, params: {shape: square}}",
                                "square: {file: images/square.png}")
    e = error_of(tmp_path, text)
    assert e.key == "stimuli.square.file" and "not found" in e.message
    assert e.line == 5


def test_unreadable_stimulus_file(tmp_path, minimal_yaml):
    (tmp_path / "square.png").write_bytes(b"not an image")
    text = minimal_yaml.replace("square: {generator: shape, params: {shape: square}}",
                                "square: {file: square.png}")
    e = error_of(tmp_path, text)
    assert e.key == "stimuli.square.file" and "not a readable image" in e.message


def test_stimulus_from_an_image_file(tmp_path, minimal_yaml):
    from vtexp._cv2 import cv2
    from vtexp.stimuli import render_shape
    cv2().imwrite(str(tmp_path / "square.png"), render_shape(shape="square"))
    text = minimal_yaml.replace("square: {generator: shape, params: {shape: square}}",
                                "square: {file: square.png}")
    assert load(tmp_path, text).experiment.stimuli["square"].file == "square.png"


def test_a_stimulus_file_outside_the_experiments_folder_is_said_and_recorded(
        tmp_path, minimal_yaml, cli):
    import hashlib
    import json

    from conftest import write_experiment
    from vtexp._cv2 import cv2
    from vtexp.stimuli import render_shape
    (tmp_path / "images").mkdir()
    (tmp_path / "exp").mkdir()
    image = (tmp_path / "images" / "square.png").resolve()
    cv2().imwrite(str(image), render_shape(shape="square"))
    (tmp_path / "exp" / "square.png").write_bytes(image.read_bytes())
    outside = write_experiment(tmp_path / "exp", minimal_yaml.replace(
        "square: {generator: shape, params: {shape: square}}",
        "square: {file: ../images/square.png}"), "outside.yaml")
    inside = write_experiment(tmp_path / "exp", minimal_yaml.replace(
        "square: {generator: shape, params: {shape: square}}",
        "square: {file: square.png}"), "inside.yaml")
    r = cli("validate", str(outside))
    assert r.returncode == 0, r.stderr
    assert f"{outside}:5: stimulus 'square': '../images/square.png' is outside the " \
           "experiment's folder" in r.stderr and str(image) in r.stderr
    r = cli("validate", str(inside))
    assert r.returncode == 0 and "note" not in r.stderr, r.stderr
    # a session says it too, and records which file it read
    r = cli("run", str(outside), "-p", "01", "--responder", "scripted:correct", "--data",
            str(tmp_path / "data"), "--quiet")
    assert r.returncode == 0 and "outside the experiment's folder" in r.stderr, r.stderr
    rec = json.loads(next((tmp_path / "data").rglob("*_session.json")).read_text())
    digest = hashlib.sha256(image.read_bytes()).hexdigest()
    assert rec["stimulus_files"] == {"square": {"path": str(image), "sha256": digest}}


@pytest.mark.parametrize("design, key, says", [
    ("repetitions: 10000\n  practice: 1000", "design.repetitions",
     "2 conditions x 10000 repetitions + 1000 practice = 21,000 trials in one session, "
     "more than a person can give (at most 20,000)"),
    ("repetitions: 2\n  iti_ms: 600000\n  practice: 100", "design.iti_ms",
     "104 trials with iti_ms 600000 pause 17.3 hours in one session (at most 12)"),
])
def test_a_session_no_person_could_sit_is_refused_before_it_runs(tmp_path, minimal_yaml,
                                                                   design, key, says):
    """Each passed validation, planning and the safety check as a session of days."""
    text = minimal_yaml.replace("repetitions: 2\n  iti_ms: 0", design)
    with pytest.raises(InputError) as e:
        load_and_compile(write_experiment(tmp_path, text))
    assert e.value.key == key and says in e.value.message, e.value.message


def test_unknown_device(tmp_path, minimal_yaml):
    e = error_of(tmp_path, minimal_yaml.replace("device: vest_6x8", "device: vest_9x9"))
    assert e.key == "device" and e.line == 3 and "known profiles" in e.message


def test_factor_level_that_is_no_stimulus(tmp_path, minimal_yaml):
    e = error_of(tmp_path, minimal_yaml.replace("levels: [square, circle]",
                                                "levels: [square, oval]"))
    assert e.key == "factors.shape.levels.1" and "'oval' is not a stimulus" in e.message


def test_correct_answer_must_be_an_option(tmp_path, minimal_yaml):
    e = error_of(tmp_path, minimal_yaml.replace('correct: "{shape}"', 'correct: "{shap}"'))
    assert e.key == "question.correct" and "names no factor" in e.message


def test_unsafe_stimulus_is_refused_at_validation(tmp_path, minimal_yaml):
    text = minimal_yaml.replace("params: {duration_ms: 200, soa_ms: 200}",
                                "params: {duration_ms: 200, soa_ms: 200, vertex_level: 7}")
    e = error_of(tmp_path, text)
    assert "unsafe stimulus" in e.message and "level 7 exceeds max_level 2" in e.message
    assert "actuator (row" in e.message


def test_unsafe_level_of_a_factor_points_at_that_level(tmp_path, minimal_yaml):
    text = minimal_yaml.replace("""design:""", """  timing:
    sets: coding
    levels:
      short: {duration_ms: 100}
      endless: {duration_ms: 9000}
design:""")
    e = error_of(tmp_path, text)
    assert e.key == "factors.timing.levels.endless"
    assert e.line == text.splitlines().index("      endless: {duration_ms: 9000}") + 1
    assert "max_on_ms" in e.message


def test_reserved_factor_name(tmp_path, minimal_yaml):
    text = minimal_yaml.replace("  shape:\n    sets", "  answer:\n    sets").replace(
        '"{shape}"', '"{answer}"')
    e = error_of(tmp_path, text)
    assert e.key == "factors.answer" and "reserved" in e.message


@pytest.mark.parametrize("mutation, needle", [
    (("repetitions: 2", "repetitions: 0"), "design.repetitions"),
    (("title: A minimal experiment", "title: [a"), "YAML syntax error"),
    (("iti_ms: 0", "itii_ms: 0"), "design.itii_ms: unknown key"),
    (("square: {generator: shape, params: {shape: square}}", "square: {file: nope.png}"),
     "stimuli.square.file"),
    (("square: {generator: shape, params: {shape: square}}", 'square: {file: ""}'),
     "stimuli.square.file: String should have at least 1 character"),     # was a TypeError
    (("soa_ms: 200}", "soa_ms: 1000000000}"),           # passed as within the device's limits
     "coding.params.soa_ms: Input should be less than or equal to 60000"),
    (("duration_ms: 200,", "duration_ms: .inf,"),
     "coding.params.duration_ms: Input should be less than or equal to 60000 (got inf)"),
])
def test_cli_validate_reports_one_clear_message(tmp_path, minimal_yaml, cli, mutation, needle):
    f = write_experiment(tmp_path, minimal_yaml.replace(*mutation))
    r = cli("validate", str(f))
    assert r.returncode == 2
    assert "Traceback" not in r.stderr and r.stdout == ""
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0] and str(f) in lines[0]


BOMB = "".join(f"{a}: &{a} [{', '.join([f'*{b}'] * 10)}]\n"
               for b, a in zip("abcdefgh", "bcdefghi"))


@pytest.mark.parametrize("make, needle, line", [
    (lambda t: t + "deep: " + "[" * 5000 + "]" * 5000 + "\n", "nested too deeply", False),
    (lambda t: t + "deep: " + "[" * 100 + "]" * 100 + "\n", "nested more than 64 levels",
     True),
    (lambda t: t + "a: &a [x, x, x, x, x, x, x, x, x, x]\n" + BOMB,
     "more than 100,000 values once its aliases", False),
    (lambda t: t.replace("title: A minimal", "title: A \x07minimal"),
     "a character YAML does not allow (U+0007", True),
    (lambda t: t + "# " + "x" * 1_100_000 + "\n", "over 1,000,000 bytes long", False),
])
def test_damaged_experiment_files_are_one_message(tmp_path, minimal_yaml, cli, make, needle,
                                                  line):
    """Deep nesting (RecursionError), aliases that repeat aliases (MemoryError after half a
    minute), a control character (ReaderError) and a file too long to be an experiment."""
    f = write_experiment(tmp_path, make(minimal_yaml))
    r = cli("validate", str(f), timeout=60)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0] and str(f) in lines[0], lines
    assert (f"{f}:" in lines[0] and lines[0].split(str(f) + ":")[1][:1].isdigit()) == line


def test_an_experiment_path_that_is_a_link_to_an_endless_device_is_refused(tmp_path, cli):
    link = tmp_path / "exp.yaml"
    link.symlink_to("/dev/zero")
    r = cli("validate", str(link), timeout=60)
    assert r.returncode == 2 and "over 1,000,000 bytes long" in r.stderr, r.stderr


def test_cli_run_reports_bad_input_without_traceback(tmp_path, minimal_yaml, cli):
    f = write_experiment(tmp_path, minimal_yaml.replace("repetitions: 2", "repetitions: -1"))
    r = cli("run", str(f), "-p", "01", "--responder", "scripted:correct",
            "--data", str(tmp_path / "d"))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "design.repetitions" in r.stderr
    assert not (tmp_path / "d").exists()


def test_cli_validate_ok(cli, grid_path):
    r = cli("validate", str(grid_path))
    assert r.returncode == 0, r.stderr
    assert "OK" in r.stdout and "96 trials per session" in r.stdout


SIX = Path(__file__).resolve().parents[1] / "experiments" / "six_mode_ball.yaml"


def test_six_mode_study_runs_its_six_listed_conditions():
    from vtexp.compile import compile_conditions
    lx = load_experiment(SIX)
    conds = compile_conditions(lx)
    assert [(c.levels["display"], c.levels["timing"], c.levels["intensity"]) for c in conds] == [
        ("static", "none", "linear"), ("static", "none", "nonlinear"),
        ("dynamic", "fixed", "linear"), ("dynamic", "fixed", "nonlinear"),
        ("dynamic", "varied", "linear"), ("dynamic", "varied", "nonlinear")]
    static = conds[0].schedule
    assert {p.duration_ms for p in static.pulses} == {4000}
    assert conds[4].pattern.params["n_lines"] == 3          # the ball: 3 lines (seed 000)


@pytest.mark.parametrize("condition, needle, key", [
    ("{display: static, timing: none}", "names no level of factor 'intensity'",
     "design.conditions.0"),
    ("{display: static, timing: none, intensity: loud}", "'loud' is not a level of 'intensity'",
     "design.conditions.0.intensity"),
    ("{display: static, timing: none, intensity: linear, mood: calm}", "'mood' is not a factor",
     "design.conditions.0.mood"),
])
def test_condition_lists_are_checked(tmp_path, condition, needle, key):
    text = SIX.read_text()
    start = text.index("  conditions:\n")
    end = text.index("\nquestion:")
    text = text[:start] + f"  conditions:\n    - {condition}\n" + text[end:]
    e = error_of(tmp_path, text)
    assert needle in e.message and e.key == key and e.line is not None


def test_rating_and_number_questions(tmp_path, minimal_yaml):
    rating = minimal_yaml.replace('''question:
  prompt: Which shape?
  options: [square, circle]
  correct: "{shape}"''', '''question:
  kind: rating
  prompt: Circle or square?
  low: -2
  high: 2
  labels: {-2: square, 2: circle}''')
    q = load(tmp_path, rating).experiment.question
    assert q.kind == "rating" and q.options == ["-2", "-1", "0", "1", "2"]
    assert q.scale == [-2, -1, 0, 1, 2] and q.labels[-2] == "square"
    e = error_of(tmp_path, rating.replace("low: -2", "low: 3"))
    assert e.key == "question" and "low < high" in e.message
    e = error_of(tmp_path, rating.replace("high: 2", "hihg: 2"))
    # The misspelt key leaves 'high' missing: both are reported, the missing one first.
    assert e.key == "question.high" and "required" in e.message and "1 more" in e.message
    number = minimal_yaml.replace('''question:
  prompt: Which shape?
  options: [square, circle]
  correct: "{shape}"''', '''question:
  kind: number
  prompt: How many turns?
  maximum: 10''')
    q = load(tmp_path, number).experiment.question
    assert q.kind == "number" and q.options[-1] == "10"
    e = error_of(tmp_path, number.replace("maximum: 10", "maximum: ten"))
    assert e.key == "question.maximum" and "integer" in e.message


def test_circle_vs_rectangle_study_validates():
    from vtexp.compile import compile_conditions
    lx = load_experiment(SIX.parent / "circle_vs_rectangle.yaml")
    conds = compile_conditions(lx)
    assert len(conds) == 4 and lx.experiment.question.kind == "rating"
    plain = next(c for c in conds if c.levels == {"shape": "rectangle", "corners": "plain"})
    emph = next(c for c in conds if c.levels == {"shape": "rectangle",
                                                  "corners": "emphasised"})
    assert max(p.train.pulse_width_ms for p in plain.schedule.pulses) == 1.0
    assert max(p.train.pulse_width_ms for p in emph.schedule.pulses) == 1.5    # Table 4


def test_letters_study_traces_every_letter():
    from vtexp.compile import compile_conditions
    lx = load_experiment(SIX.parent / "letters.yaml")
    conds = compile_conditions(lx)
    assert [c.stimulus for c in conds] == [chr(c) for c in range(ord("A"), ord("Z") + 1)]
    assert all(len(c.pattern.points) >= 3 for c in conds)
    assert lx.experiment.question.correct == "{letter}"


def test_several_questions_are_checked(tmp_path, minimal_yaml):
    both = minimal_yaml + """questions:
  - {prompt: "Which?", options: [square, circle]}
"""
    e = error_of(tmp_path, both)
    assert "'question' (one question) or 'questions'" in e.message
    twice = minimal_yaml.replace('''question:
  prompt: Which shape?
  options: [square, circle]
  correct: "{shape}"''', '''questions:
  - {prompt: "Which shape?", options: [square, circle], correct: "{shape}"}
  - {kind: rating, prompt: "How sure?", low: 1, high: 5}
  - {kind: number, name: rating, prompt: "How many?"}''')
    e = error_of(tmp_path, twice)
    assert "question names must differ" in e.message
    bad = twice.replace("name: rating, ", "")
    lx = load(tmp_path, bad)
    assert [q.name for q in lx.experiment.asked()] == ["response", "rating", "count"]
    wrong = bad.replace('correct: "{shape}"', 'correct: "{shap}"')
    e = error_of(tmp_path, wrong)
    assert e.key == "questions.0.correct"


def test_a_file_read_twice_gives_each_reader_its_own_data(tmp_path, minimal_yaml):
    """A command reads its experiment more than once; what one reader changes in the data
    is not what the next one reads, and an edited file is read anew."""
    from vtexp.yamlio import load_yaml
    p = write_experiment(tmp_path, minimal_yaml)
    first = load_yaml(p)
    first.data["stimuli"]["square"]["params"]["shape"] = "changed"
    first.lines.clear()
    again = load_yaml(p)
    assert again.data["stimuli"]["square"]["params"]["shape"] == "square"
    assert again.line_of(("stimuli", "square")) == 5
    p.write_text(minimal_yaml.replace("title: A minimal", "title: An edited"), encoding="utf-8")
    assert load_yaml(p).data["title"] == "An edited experiment"
