"""``vtexp encode`` as a user runs it, and the drawings it makes."""

from __future__ import annotations

import json
import os

import numpy as np
from PIL import Image

from vtexp.draw import draw_pattern, schedule_frames
from vtexp.encoding import edge_trace
from vtexp.model import DeviceProfile, Pattern, PatternPoint, Schedule
from vtexp.stimuli import render_shape


def test_encode_a_generated_ball_for_the_pad(cli, tmp_path):
    out = {k: tmp_path / f"ball.{k}" for k in ("json", "png", "gif")}
    r = cli("encode", "surface:surface=ball", "--pipeline", "height-contours", "--device",
            "pad_20x20", "--json", str(out["json"]), "--png", str(out["png"]), "--gif",
            str(out["gif"]))
    assert r.returncode == 0, r.stderr
    assert "3 line(s)" in r.stdout and "within pad_20x20's safety limits" in r.stdout
    data = json.loads(out["json"].read_text())
    pattern, schedule = Pattern(**data["pattern"]), Schedule(**data["schedule"])
    assert pattern.lines() == [1, 2, 3] and schedule.device == "pad_20x20"
    png = np.asarray(Image.open(out["png"]))
    assert png.std() > 10                                  # not blank
    gif = Image.open(out["gif"])
    assert gif.n_frames > 10


def test_encode_an_image_file_for_the_vest(cli, tmp_path):
    from vtexp._cv2 import cv2
    f = tmp_path / "square.png"
    cv2().imwrite(str(f), render_shape(shape="square", width=640, height=480))
    r = cli("encode", str(f), "--pipeline", "edge-trace", "--device", "vest_6x8",
            "--coding-param", "soa_ms=200", "--coding-param", "duration_ms=300",
            "--json", str(tmp_path / "o.json"))
    assert r.returncode == 0, r.stderr
    assert "1 closed" in r.stdout
    sched = json.loads((tmp_path / "o.json").read_text())["schedule"]
    assert sched["params"]["soa_ms"] == 200


def test_encode_errors_are_clear(cli, tmp_path):
    blank = tmp_path / "blank.png"
    from vtexp._cv2 import cv2
    cv2().imwrite(str(blank), np.full((240, 320), 128, np.uint8))
    cases = [
        (["nope.png", "--pipeline", "edge-trace", "--device", "vest_6x8"], "image file not found"),
        ([str(tmp_path), "--pipeline", "edge-trace", "--device", "vest_6x8"], "image"),
        (["shape:shape=hexagon", "--pipeline", "edge-trace", "--device", "vest_6x8"], "shape"),
        (["shape:shape=square", "--pipeline", "magic", "--device", "vest_6x8"],
         "unknown pipeline 'magic'"),
        (["shape:shape=square", "--pipeline", "edge-trace", "--device", "vest_9x9"],
         "unknown device profile"),
        (["shape:shape=square", "--pipeline", "edge-trace", "--device", "vest_6x8",
          "--coding-param", "vertex_level=9"], "level 9 exceeds max_level 2"),
        (["shape:shape=square", "--pipeline", "edge-trace", "--device", "vest_6x8",
          "--param", "mode=bogus"], "--param mode"),
    ]
    for args, needle in cases:
        r = cli("encode", *args)
        assert r.returncode == 2, (args, r.stdout, r.stderr)
        assert needle in r.stderr and "Traceback" not in r.stderr, (args, r.stderr)
    # a uniform picture: nothing to play, and why (what vtexp looked at is drawn anyway)
    r = cli("encode", str(blank), "--pipeline", "edge-trace", "--device", "vest_6x8",
            "--png", str(tmp_path / "b.png"))
    assert r.returncode == 2 and "nothing to play" in r.stderr and "uniform" in r.stderr
    assert (tmp_path / "b.png").is_file()
    # told to use the pipeline's own threshold: an empty pattern, with a warning
    r = cli("encode", str(blank), "--pipeline", "edge-trace", "--device", "vest_6x8",
            "--background", "none")
    assert r.returncode == 0 and "no shape found" in r.stderr
    assert "0 points" in r.stdout


def test_images_no_one_can_read_are_one_message(cli, tmp_path):
    """A PNG that declares more pixels than OpenCV reads (cv2.error), a file name over the
    system's limit (OSError), a file that cannot be read: one message each, naming it."""
    import struct
    import zlib

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(
            ">I", zlib.crc32(kind + data) & 0xFFFFFFFF)
    huge = tmp_path / "huge.png"
    huge.write_bytes(b"\x89PNG\r\n\x1a\n"
                     + chunk(b"IHDR", struct.pack(">IIBBBBB", 40000, 40000, 8, 0, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(b"\0" * 10)) + chunk(b"IEND", b""))
    locked = tmp_path / "locked.png"
    locked.write_bytes(huge.read_bytes())
    locked.chmod(0)
    cases = [(huge, "more pixels than OpenCV reads"),
             (tmp_path / ("x" * 300 + ".png"), "cannot read the image file: File name too long")]
    if os.geteuid() != 0:                   # root reads a file whatever its mode
        cases.append((locked, "cannot read the image file: Permission denied"))
    for path, says in cases:
        r = cli("encode", str(path), "--pipeline", "edge-trace", "--device", "vest_6x8")
        assert r.returncode == 2 and says in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_camera_absent_is_a_clear_error(cli):
    r = cli("encode", "camera:7", "--pipeline", "edge-trace", "--device", "vest_6x8")
    assert r.returncode == 2 and "no camera at index 7" in r.stderr


def test_drawings_mark_lines_order_and_vertices():
    pat = edge_trace(render_shape(shape="square"), 8, 6)
    img = draw_pattern(pat)
    red = (img[..., 2] > 200) & (img[..., 0] < 50) & (img[..., 1] < 50)
    assert red.sum() > 0                                    # vertex rings drawn
    phantom = Pattern(rows=5, cols=5, points=[PatternPoint(row=0.5, col=1.5, order=0)])
    assert draw_pattern(phantom).std() > 0
    frames = schedule_frames(
        Schedule(device="vest_6x8", pulses=[]), DeviceProfile.load("vest_6x8"))
    assert len(frames) == 1
