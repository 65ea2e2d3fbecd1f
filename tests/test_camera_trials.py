"""Camera trials end to end, with a video file standing in for the camera: the frame taken
at each trial saved in the session folder and named in the trial's row (stim_file), played
like any other stimulus (what was played is what that image encodes to), live trials felt
until the answer, the experimenter's prompt, resume, and the declarations refused."""

from __future__ import annotations

import time

import numpy as np
import pandas as pd
import pytest

from conftest import run_cli, write_experiment
from vtexp.compile import code, compile_conditions, encode
from vtexp.devices import open_device
from vtexp.errors import InputError, SessionError
from vtexp.experiment import load_experiment
from vtexp.live.record import load_record
from vtexp.live.synthetic import write_video
from vtexp.model import DeviceProfile
from vtexp.responders import make_responder
from vtexp.safety import check_schedule
from vtexp.session import SessionOptions, run_session
from vtexp.stimuli import read_image

VEST = DeviceProfile.load("vest_6x8")

EXPERIMENT = """\
name: camera_shapes
title: Objects before the camera
device: vest_6x8
stimuli:
  card: {{video: clip.avi, object: the rectangle card{card}}}
  moving: {{video: clip.avi, object: the rectangle card, delay_s: 0.3, live: true}}
encoding:
  pipeline: edge-trace
coding:
  protocol: sequential-trace
  params: {{duration_ms: 200, soa_ms: 150}}
factors:
  shape:
    sets: stimulus
    levels: [card, moving]
design:
  repetitions: 2
  iti_ms: 0
question:
  prompt: Which one?
  options: [card, moving]
  correct: "{{shape}}"
"""


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    path = tmp_path_factory.mktemp("clip") / "clip.avi"
    write_video(path, "rectangle", seconds=4.0, size=0.5)
    return path


def experiment(tmp_path, clip, card=", delay_s: 0.2"):
    (tmp_path / "clip.avi").write_bytes(clip.read_bytes())
    return write_experiment(tmp_path, EXPERIMENT.format(card=card))


class Slow:
    """A scripted participant who takes ``answer_s`` to answer (a live trial plays
    meanwhile)."""

    def __init__(self, inner, answer_s):
        self.inner, self.answer_s = inner, answer_s
        self.description = inner.description

    def ask(self, q, trial, replay):
        time.sleep(self.answer_s)
        return self.inner.ask(q, trial, replay)


def run(lx, tmp_path, device, *, answer_s=0.8, **kw):
    responder = Slow(make_responder("scripted:correct", "01", 1, lx), answer_s)
    return run_session(lx, device, responder,
                       SessionOptions(participant="01", data_dir=tmp_path / "data", **kw))


@pytest.mark.realtime          # a live trial plays on its thread while the answer takes real time
def test_a_camera_session_end_to_end_on_the_emulator(tmp_path, clip):
    lx = load_experiment(experiment(tmp_path, clip))
    conds = compile_conditions(lx, VEST)
    assert all(c.camera and c.schedule is None for c in conds)
    with open_device("emulator", VEST) as dev:
        res = run(lx, tmp_path, dev)
        assert dev.emulator.all_outputs_off()
    assert res.status == "completed"
    d = res.paths.record_dir               # camera frames are source data
    beh = pd.read_csv(res.paths.beh_tsv, sep="\t", na_values="n/a", keep_default_na=False)
    events = pd.read_csv(res.paths.events_tsv, sep="\t", na_values="n/a")
    assert list(beh.columns).index("stim_file") == list(beh.columns).index("stimulus") + 1
    assert sorted(beh["stim_file"]) == [f"stim/trial-00{k}.png" for k in range(1, 5)]
    for _, row in beh.iterrows():
        image = read_image(d / row["stim_file"])
        assert image.shape == (480, 640)
        if row["stimulus"] == "card":
            # what was played is exactly what the saved frame encodes to
            pattern = encode(lx, image, VEST, {})
            sched = code(lx, pattern, VEST, dict(lx.experiment.coding.params))
            check_schedule(sched, VEST)
            played = events[events["trial"] == row["trial"]]
            assert sorted(zip(played["row"], played["col"], played["scheduled_onset_ms"])) == \
                sorted((p.row, p.col, p.onset_ms) for p in sched.pulses)
            assert row["n_pulses"] == len(sched.pulses)
        else:
            # a live trial: played until the answer, recorded beside its frame
            live = load_record(d / row["stim_file"].replace(".png", "-live"))
            assert live.meta["status"] == "completed"
            assert len(live.frames) >= 5 and live.states()[-1][1] == {}
            assert any(state for _, state in live.states())
            assert row["stimulus_duration_ms"] >= 500
            assert events[events["trial"] == row["trial"]].empty
    sidecar = res.paths.beh_json.read_text()
    assert "stim_file" in sidecar


@pytest.mark.realtime          # a live trial plays on its thread while the answer takes real time
def test_the_experimenter_is_asked_to_place_the_named_object(tmp_path, clip):
    lx = load_experiment(experiment(tmp_path, clip, card=""))
    asked = []
    with open_device("sim", VEST) as dev:
        res = run(lx, tmp_path, dev, answer_s=0.3,
                  capture_prompt=lambda text: asked.append(text))
    assert res.status == "completed"
    cards = [r.trial for r in res.records if r.stimulus == "card"]
    assert asked == [f"Trial {k}: place the rectangle card in front of the camera, then "
                     "press Enter " for k in cards]


def test_without_anyone_to_ask_the_session_does_not_start(tmp_path, clip):
    lx = load_experiment(experiment(tmp_path, clip, card=""))
    with open_device("sim", VEST) as dev, pytest.raises(SessionError, match="delay_s"):
        run(lx, tmp_path, dev)
    assert not (tmp_path / "data").exists()


@pytest.mark.realtime          # a live trial plays on its thread while the answer takes real time
def test_a_camera_session_resumes_and_never_overwrites_a_frame(tmp_path, clip):
    lx = load_experiment(experiment(tmp_path, clip))
    with open_device("sim", VEST) as dev:
        first = run(lx, tmp_path, dev, answer_s=0.3, max_trials=2)
    assert first.status == "aborted"
    d = first.paths.record_dir
    (d / "stim" / "trial-003.png").write_bytes(b"left by a trial cut short")
    with open_device("sim", VEST) as dev:
        again = run(lx, tmp_path, dev, answer_s=0.3, resume=True)
    assert again.status == "completed"
    beh = pd.read_csv(again.paths.beh_tsv, sep="\t", keep_default_na=False)
    assert list(beh["trial"]) == [1, 2, 3, 4]
    assert beh["stim_file"][2] == "stim/trial-003-2.png"
    assert (d / "stim" / "trial-003.png").read_bytes() == b"left by a trial cut short"


@pytest.mark.realtime          # a live trial plays on its thread while the answer takes real time
def test_vtexp_run_with_a_video_standing_in_for_the_camera(tmp_path, clip):
    path = experiment(tmp_path, clip)
    r = run_cli("run", str(path), "-p", "07", "--responder", "scripted:correct",
                "--device", "emulator", "--data", str(tmp_path / "data"))
    assert r.returncode == 0, r.stderr
    assert "session completed: 4 trials" in r.stdout
    r = run_cli("plan", str(path), "-p", "07")
    assert r.returncode == 0 and "camera" in r.stdout


@pytest.mark.parametrize("stimulus, extra, message", [
    ("{video: clip.avi, live: true}", "  replays: 2\n", "cannot be felt again"),
    ("{video: nowhere.avi}", "", "stimulus video"),
    ("{camera: 0, params: {size: 2}}", "", "'params' apply to generators only"),
    ("{generator: shape, params: {shape: square}, delay_s: 1}", "",
     "'object', 'delay_s' and 'live' apply to 'camera' and 'video' only"),
    ("{camera: 0, video: clip.avi}", "", "give one of 'generator', 'file', 'camera'"),
])
def test_camera_declarations_are_checked(tmp_path, clip, stimulus, extra, message):
    (tmp_path / "clip.avi").write_bytes(clip.read_bytes())
    text = EXPERIMENT.format(card="").replace(
        "  card: {video: clip.avi, object: the rectangle card}", f"  card: {stimulus}") \
        .replace('  correct: "{shape}"\n', '  correct: "{shape}"\n' + extra)
    with pytest.raises(InputError, match=message):
        load_experiment(write_experiment(tmp_path, text))


def test_a_model_participant_cannot_feel_a_camera(tmp_path, clip):
    lx = load_experiment(experiment(tmp_path, clip))
    with pytest.raises(InputError, match="cannot feel a camera stimulus"):
        make_responder("model", "01", 1, lx)


def test_no_object_before_the_camera_is_one_message(tmp_path):
    from vtexp._cv2 import cv2

    w = cv2().VideoWriter(str(tmp_path / "clip.avi"), cv2().VideoWriter_fourcc(*"MJPG"), 30,
                          (320, 240), False)
    for _ in range(30):
        w.write(np.full((240, 320), 40, np.uint8))
    w.release()
    path = write_experiment(tmp_path, EXPERIMENT.format(card=", delay_s: 0.1")
                            .replace(", live: true", ""))
    r = run_cli("run", str(path), "-p", "01", "--responder", "scripted:correct",
                "--data", str(tmp_path / "data"))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "no object was found in the frame taken for stimulus" in r.stderr
