"""Figure and ground where the experimenter meets them: ``vtexp encode`` on a photograph
(with the empty stage, or a still alone), a camera trial's frame against the empty stage
captured before it, ``vtexp live --background``, and the preview's outline of what was
taken for the object.

The scene behind the object is a photograph no one here took: matplotlib's sample of
Grace Hopper (tests/fuzz.py uses it too), so the background has the texture, edges and
shading of a real picture rather than a plain field."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from conftest import run_cli
from vtexp._cv2 import cv2
from vtexp.errors import InputError


def photograph() -> np.ndarray:
    import matplotlib

    from vtexp.stimuli import read_image
    return read_image(Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg",
                      colour=True)


def stage_and_scene(width: int = 480, height: int = 360, *, shift: float = 0.0):
    """The empty stage (the photograph, its light a little uneven) and the same with a
    flat card before it (a square turned 20 degrees, mid-grey with a printed texture),
    and the card's true mask."""
    cv = cv2()
    stage = cv.resize(photograph(), (width, height), interpolation=cv.INTER_AREA)
    yy, xx = np.mgrid[0:height, 0:width]
    light = 0.9 + 0.2 * xx / width
    stage = np.clip(stage * light[..., None], 0, 255).astype(np.uint8)
    mask = np.zeros((height, width), np.uint8)
    box = cv.boxPoints(((width * (0.45 + shift), height * 0.5), (height * 0.45, height * 0.45),
                        20.0)).astype(np.int32)
    cv.fillPoly(mask, [box], 1)
    card = np.full_like(stage, (90, 160, 210))
    card[(yy // 12 + xx // 12) % 2 == 0] = (70, 140, 190)
    scene = np.where(mask[..., None] == 1, card, stage)
    return stage, scene, mask


def iou(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a.astype(bool), b.astype(bool)
    return float((a & b).sum() / max((a | b).sum(), 1))


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    d = tmp_path_factory.mktemp("scene")
    stage, scene, mask = stage_and_scene()
    cv = cv2()
    cv.imwrite(str(d / "stage.png"), stage)
    cv.imwrite(str(d / "scene.jpg"), scene, [cv.IMWRITE_JPEG_QUALITY, 85])
    return d, mask


def test_encode_with_the_empty_stage_plays_the_object_and_draws_its_outline(photos):
    d, mask = photos
    out, png = d / "card.json", d / "card.png"
    r = run_cli("encode", str(d / "scene.jpg"), "--pipeline", "edge-trace", "--device",
                "vest_6x8", "--background", str(d / "stage.png"), "--json", str(out),
                "--png", str(png))
    assert r.returncode == 0, r.stderr
    assert "object: reference figure-ground" in r.stdout, r.stdout
    doc = json.loads(out.read_text())
    assert doc["schedule"] is not None and len(doc["pattern"]["points"]) >= 8
    # the drawing: the photograph with the outline found (magenta) beside the array
    img = cv2().imread(str(png))
    magenta = (img[..., 0] > 200) & (img[..., 1] < 80) & (img[..., 2] > 200)
    assert magenta.sum() > 100 and img.shape[1] > img.shape[0]


def test_encode_of_the_empty_stage_plays_nothing_and_says_why(photos):
    d, _ = photos
    png = d / "empty.png"
    r = run_cli("encode", str(d / "stage.png"), "--pipeline", "edge-trace", "--device",
                "vest_6x8", "--background", str(d / "stage.png"), "--png", str(png))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "nothing to play" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert png.is_file()                         # what vtexp looked at, drawn anyway


def test_encode_with_a_reference_of_another_size_is_one_message(photos, tmp_path):
    d, _ = photos
    cv = cv2()
    small = tmp_path / "small.png"
    cv.imwrite(str(small), cv.imread(str(d / "stage.png"))[:200, :300])
    r = run_cli("encode", str(d / "scene.jpg"), "--pipeline", "edge-trace", "--device",
                "vest_6x8", "--background", str(small))
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_a_generated_stimulus_is_encoded_as_it_is_by_default():
    r = run_cli("encode", "shape:shape=square", "--pipeline", "edge-trace", "--device",
                "vest_6x8")
    assert r.returncode == 0, r.stderr
    assert "object:" not in r.stdout             # a plain background by construction


def test_a_camera_frame_is_told_from_the_empty_stage(photos):
    from vtexp.experiment import load_experiment
    from vtexp.compile import enumerate_conditions
    from vtexp.live.trial import coded
    from vtexp.model import DeviceProfile

    root = Path(__file__).resolve().parents[1]
    lx = load_experiment(root / "experiments" / "duration_interval_grid.yaml")   # edge-trace
    condition = enumerate_conditions(lx)[0]
    profile = DeviceProfile.load(lx.experiment.device)
    stage, scene, mask = stage_and_scene()
    gray = cv2().cvtColor(scene, cv2().COLOR_BGR2GRAY)
    gstage = cv2().cvtColor(stage, cv2().COLOR_BGR2GRAY)
    with_stage, _ = coded(lx, condition, gray, profile, gstage)
    assert with_stage.points
    with pytest.raises(InputError, match="no object was found"):
        coded(lx, condition, gstage, profile, gstage)
    # the card pushed half out of the frame: said, nothing played
    _, cut, _ = stage_and_scene(shift=0.45)
    with pytest.raises(InputError, match="runs off the edge of the frame"):
        coded(lx, condition, cv2().cvtColor(cut, cv2().COLOR_BGR2GRAY), profile, gstage)


def test_capturing_the_empty_stage_needs_someone_to_clear_it(tmp_path):
    from vtexp.live.sources import VideoSource
    from vtexp.live.synthetic import write_video
    from vtexp.live.trial import capture_empty_stage

    video = tmp_path / "stage.avi"
    write_video(video, "rectangle", seconds=1.0, width=160, height=120)
    src = VideoSource(video)
    src.open()
    try:
        with pytest.raises(InputError, match="no one is at a terminal"):
            capture_empty_stage(src, None)
        asked = []
        stage = capture_empty_stage(src, asked.append, frames=5)
    finally:
        src.close()
    assert asked and "Clear the stage" in asked[0]
    assert stage.shape == (120, 160) and stage.dtype == np.uint8


def test_live_with_the_stage_learned_plays_nothing_until_the_object_comes(tmp_path):
    from vtexp.encoding.figure import BackgroundModel
    from vtexp.live import LiveSetup
    from vtexp.live.encoder import LiveEncoder

    stage, scene, _ = stage_and_scene(320, 240)
    cv = cv2()
    gstage = cv.cvtColor(stage, cv.COLOR_BGR2GRAY)
    gscene = cv.cvtColor(scene, cv.COLOR_BGR2GRAY)
    setup = LiveSetup.make("edge-trace")
    plain = LiveEncoder(setup)
    enc = LiveEncoder(setup, BackgroundModel(learn_frames=5))
    for _ in range(5):                           # learning: nothing plays
        e = enc.process(gstage)
        assert e.program is None and e.figure is not None and "learning" in e.figure.reason
    assert enc.process(gstage).program is None   # the empty stage: nothing
    e = enc.process(gscene)
    assert e.program is not None and not e.figure.empty
    # without the model, the photograph's own edges are what the pipeline finds
    assert plain.process(gstage).program is not None


def test_live_command_with_a_photograph_of_the_stage(tmp_path):
    from vtexp.live.synthetic import write_video

    stage, _, _ = stage_and_scene(320, 240)
    # the photograph dimmed, so that the light card (grey 210) stands out from all of it
    gstage = (cv2().cvtColor(stage, cv2().COLOR_BGR2GRAY) * 0.6).astype(np.uint8)
    video = tmp_path / "over-photo.avi"
    write_video(video, "rectangle", seconds=1.5, width=320, height=240, size=0.4,
                backdrop=gstage, empty_s=0.5)
    cv2().imwrite(str(tmp_path / "stage.png"), gstage)
    rec = tmp_path / "rec"
    r = run_cli("live", str(video), "--pipeline", "edge-trace", "--no-pace", "--background",
                str(tmp_path / "stage.png"), "--record", str(rec), timeout=120)
    assert r.returncode == 0, r.stderr
    import pandas as pd
    frames = pd.read_csv(rec / "frames.tsv", sep="\t")
    found = frames["centroid_row"].notna().to_numpy()
    # the empty half second before the object plays nothing; with it, the object plays
    assert not found[:10].any() and found[-20:].mean() > 0.8, found.astype(int)


def test_live_with_a_photograph_of_another_size_is_one_message(tmp_path):
    from vtexp.live.synthetic import write_video

    video = tmp_path / "v.avi"
    write_video(video, "rectangle", seconds=0.5, width=160, height=120)
    cv2().imwrite(str(tmp_path / "stage.png"), np.zeros((240, 320), np.uint8))
    r = run_cli("live", str(video), "--pipeline", "edge-trace", "--no-pace", "--background",
                str(tmp_path / "stage.png"), timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert "320x240 pixels, the frames 160x120" in r.stderr


def test_e_at_the_objects_prompt_captures_the_empty_stage_again(tmp_path):
    """The experimenter types 'e' at an object's prompt: the stage is captured again (the
    frames read for the prompt stop meanwhile), then the object is asked for again."""
    from types import SimpleNamespace

    from vtexp.live.sources import VideoSource
    from vtexp.live.synthetic import write_video
    from vtexp.live.trial import capture

    video = tmp_path / "v.avi"
    write_video(video, "rectangle", seconds=1.0, width=160, height=120)
    lx = SimpleNamespace(experiment=SimpleNamespace(stimuli={
        "card": SimpleNamespace(delay_s=None, object="the card")}))
    trial = SimpleNamespace(stimulus="card", number=3)
    said, recaptured = iter(["e", "E ", ""]), []
    asked = []

    def prompt(text):
        asked.append(text)
        return next(said)

    src = VideoSource(video)
    try:
        got = capture(lx, trial, tmp_path, prompt, src, "camera 0",
                      recapture=lambda: recaptured.append(1))
    finally:
        src.close()
    assert len(recaptured) == 2 and len(asked) == 3
    assert "'e' and Enter: capture the empty stage again" in asked[0]
    assert got.stim_file == "stim/trial-003.png" and (tmp_path / got.stim_file).is_file()
