"""Figure and ground (issue 20): the object found in photographs, and every pipeline
rendering only the object it is given.

The scenes are composites of photographs no one here took or drew: matplotlib's
sample of Grace Hopper (always available) and, where installed, scikit-image's
brick, grass and gravel with its horse silhouette textured by its photographs (the
research note's probe scenes). Light gradients, noise and JPEG are applied here.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import matplotlib
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from vtexp._cv2 import cv2
from vtexp.encoding import PIPELINES
from vtexp.encoding.figure import (MIN_CONFIDENCE, SHADOW_REACH, BackgroundModel, Figure,
                                   cast_shadow, figure_from_reference, figure_from_still,
                                   fit_light, grow_by_colour, median, settle_rim,
                                   shadow_rim, without_specks)
from vtexp.encoding.height_contours import reflectance
from vtexp.encoding.snake import SnakeTracker
from vtexp.errors import InputError
from vtexp.live.trial import mean_frame
from vtexp.stimuli import render_shape
from vtexp.stimuli.spiral import render_whirlpool
from vtexp.stimuli.surfaces import render_surface, surface_height

cv = cv2()
W, H = 640, 480


def photograph() -> np.ndarray:
    """Grace Hopper, BGR, 600 x 512."""
    path = Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg"
    return cv.imread(str(path))


def light(lo: float, hi: float, *, corner: bool = False, shape=(H, W)) -> np.ndarray:
    """A light gradient from left to right (or from the bottom left to the top right)."""
    x = np.linspace(0, 1, shape[1])[None, :]
    y = np.linspace(0, 1, shape[0])[:, None]
    ramp = (x + (1 - y)) / 2 if corner else x + 0 * y
    return (lo + (hi - lo) * ramp)[:, :, None]


def shoot(scene: np.ndarray, gain, seed: int, noise: float = 3.0) -> np.ndarray:
    """What a camera records: the scene under ``gain`` (a number or a light), with noise."""
    rng = np.random.default_rng(seed)
    out = scene.astype(np.float64) * gain + rng.normal(0, noise, scene.shape)
    return np.clip(out, 0, 255).astype(np.uint8)


def jpeg(img: np.ndarray, quality: int = 75) -> np.ndarray:
    return cv.imdecode(cv.imencode(".jpg", img, [cv.IMWRITE_JPEG_QUALITY, quality])[1],
                       cv.IMREAD_UNCHANGED)


def iou(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a > 0, b > 0
    return float((a & b).sum() / max((a | b).sum(), 1))


def photo_scene(shape: str = "triangle", **place) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(stage, scene, true mask): the photograph as the stage, and on it a shape cut out
    of the photograph's flag (an object with a photograph's texture).

    Where the object has the colours of the stage behind it, nothing tells them apart:
    a shape cut from the photograph turned upside down, over her face, was found with
    IoU 0.34-0.72, and the flag's dark blue over her navy suit 0.76 (docs/decisions.md).
    The shapes here lie over her face, hat and the sky.
    """
    photo = photograph()
    stage = cv.resize(photo, (W, H), interpolation=cv.INTER_AREA)
    flag = cv.resize(photo[:300, :200], (W, H), interpolation=cv.INTER_LINEAR)
    mask = (render_shape(shape=shape, width=W, height=H, **place) > 125).astype(np.uint8)
    scene = np.where(mask[:, :, None] > 0, flag, stage)
    return stage, scene, mask


# --------------------------------------------------------------------------- with a reference


@pytest.mark.parametrize("shape, place", [("triangle", {"size": 0.4, "center_x": 0.35}),
                                          ("circle", {"size": 0.3, "center_y": 0.4})])
def test_a_reference_finds_the_object_though_the_light_changed(shape, place):
    stage, scene, truth = photo_scene(shape, **place)
    reference = shoot(stage, light(0.8, 1.15), 1)
    frame = shoot(scene, light(1.05, 1.35, corner=True), 2)
    fig = figure_from_reference(frame, reference)
    assert not fig.empty and fig.method == "reference"
    assert fig.mask.shape == truth.shape and fig.mask.dtype == np.uint8
    assert set(np.unique(fig.mask)) <= {0, 1}
    assert iou(fig.mask, truth) >= 0.8
    # gray frames and JPEG (the camera's) too
    gray = figure_from_reference(cv.cvtColor(jpeg(frame), cv.COLOR_BGR2GRAY),
                                 cv.cvtColor(jpeg(reference), cv.COLOR_BGR2GRAY))
    assert not gray.empty and iou(gray.mask, truth) >= 0.8


def test_an_empty_stage_is_an_empty_figure_with_its_reason():
    stage, _, _ = photo_scene()
    reference = shoot(stage, light(0.8, 1.15), 1)
    for frame in (shoot(stage, light(0.8, 1.15), 3),                   # noise only
                  shoot(stage, light(1.05, 1.35, corner=True), 4),     # the light changed
                  jpeg(shoot(stage, 0.6, 5), 60)):                     # exposure, JPEG
        fig = figure_from_reference(frame, reference)
        assert fig.empty and not fig.mask.any(), fig.reason
        assert fig.reason and "no object" in fig.reason


def _card_scene(stage: np.ndarray, *, size: float, center_x: float, center_y: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(frame, reference, true mask): a flat grey card over ``stage``, both blurred by
    the lens (1 pixel) and shot with their own noise."""
    cover = render_shape(shape="square", width=W, height=H, size=size, center_x=center_x,
                         center_y=center_y, rotation_deg=10, background=0,
                         foreground=255) / 255.0
    card = np.array([180, 182, 178], np.float32)
    scene = stage * (1 - cover[:, :, None]) + card * cover[:, :, None]
    lens = [cv.GaussianBlur(np.asarray(x, np.float32), (0, 0), 1.0) for x in (scene, stage)]
    return shoot(lens[0], 1.0, 2), shoot(lens[1], 1.0, 1), (cover >= 0.5).astype(np.uint8)


@pytest.mark.parametrize("ground", ["plain", "photograph"])
def test_the_figure_ends_where_the_card_covers_half_a_pixel(ground):
    # The change past the noise starts where the card's blurred edge covers a small part
    # of a pixel; the figure's rim is settled where it covers half (docs/decisions.md).
    # Over the photograph's blue background the card is found whole (before the score
    # was taken in grey levels and the light as a gain: IoU 0.60, 39 % of it missed).
    if ground == "plain":
        stage = np.broadcast_to(np.float32([40, 45, 42]), (H, W, 3))
    else:
        stage = cv.resize(photograph(), (W, H), interpolation=cv.INTER_AREA)
    frame, reference, truth = _card_scene(stage, size=0.4, center_x=0.8, center_y=0.45)
    fig = figure_from_reference(frame, reference)
    got, want = fig.mask > 0, truth > 0
    assert not fig.empty and iou(fig.mask, truth) >= 0.95
    assert (got & ~want).sum() <= 0.02 * want.sum()        # what is not the card
    assert (want & ~got).sum() <= 0.03 * want.sum()        # the card missed


def test_the_light_is_a_quadratic_surface_fitted_past_an_object_and_the_dark():
    h, w = 120, 160
    y = (np.arange(h) / h - 0.5)[:, None]
    x = (np.arange(w) / w - 0.5)[None, :]
    light = 0.1 + 0.2 * x - 0.3 * y + 0.4 * x * x - 0.5 * x * y + 0.6 * y * y
    ratio = light + np.random.default_rng(0).normal(0, 0.01, (h, w))
    ratio[20:70, 30:90] += 0.8                    # an object: a third of the frame
    valid = np.ones((h, w), bool)
    valid[:, :20] = False                         # too dark for a ratio: left out
    ratio[:, :20] = 0.0
    kept = valid.copy()
    fit = fit_light(ratio, valid=valid)
    assert np.abs(fit - light).max() < 0.02
    assert (valid == kept).all()                  # the caller's mask is not written


@pytest.mark.parametrize("frames", [1, 10])
@pytest.mark.parametrize("size, centre_x, tone", [(0.5, 0.72, (26, 30, 27)),
                                                  (0.4, 0.65, (30, 34, 28))])
def test_the_light_on_a_dark_ground_is_fitted_over_the_whole_frame(frames, size, centre_x,
                                                                   tone):
    # A dark plain ground lit 0.72-1.11 from the left, a card on its brighter right side,
    # the reference one frame or the mean of ten (as vtexp captures the empty stage).
    # Fitted to the pixels of at least 32 grey levels only, the light fell on the right
    # side, where the card is: the surface extrapolated over the left, and 70-88 % of the
    # frame was taken for changed, refused as another stage (docs/decisions.md).
    ramp = light(0.72, 1.11)
    stage = np.broadcast_to(np.float32(tone), (H, W, 3))
    cover = render_shape(shape="rectangle", width=W, height=H, size=size, center_x=centre_x,
                         rotation_deg=8, background=0, foreground=255) / 255.0
    scene = stage * (1 - cover[:, :, None]) + np.float32([70, 74, 66]) * cover[:, :, None]
    frame = jpeg(shoot(scene, ramp, 2), 70)
    reference = mean_frame(jpeg(shoot(stage, ramp, 10 + k), 70) for k in range(frames))
    fig = figure_from_reference(frame, reference)
    assert not fig.empty, fig.reason
    assert iou(fig.mask, cover >= 0.5) >= 0.98


def test_the_light_is_weighted_by_each_pixels_precision():
    # Noise of 3 grey levels moves the log-ratio of a pixel at 5 grey levels by 0.5, at
    # 200 by 0.015: weighted by R + 1, the dark half's noise does not decide the surface.
    h, w = 120, 160
    x = (np.arange(w) / w - 0.5)[None, :] + np.zeros((h, 1))
    level = np.where(x > 0, 200.0, 5.0)
    truth = 0.05 + 0.1 * x
    ratio = truth + np.random.default_rng(3).normal(0, 1, (h, w)) * 3 / (level + 1)
    weighted = np.abs(fit_light(ratio, weight=level + 1) - truth).max()
    alike = np.abs(fit_light(ratio) - truth).max()            # every pixel alike: 0.12
    assert weighted < 0.04 and weighted < alike / 3


@given(arrays(st.sampled_from([np.float32, np.float64]), st.integers(1, 300),
              elements=st.floats(-1e6, 1e6, width=32)))
def test_the_fast_median_is_numpys_to_the_last_bit(values):
    # A live frame's figure takes about twenty medians; numpy's own cost 5-10 times one
    # partition, and the figure must not move by a bit for the speed.
    got, want = median(values), np.median(values)
    assert got == want and np.asarray(got).dtype == np.asarray(want).dtype


def test_a_shadow_lies_beside_its_object_and_what_reaches_farther_is_the_object():
    changed = np.zeros((240, 320), bool)
    shadow = np.zeros_like(changed)
    changed[40:120, 40:100] = True                 # the object's part that is no shadow
    reach = int(SHADOW_REACH * 320)
    changed[40:100, 100:100 + reach - 4] = shadow[40:100, 100:100 + reach - 4] = True
    changed[170:220, 40:200] = shadow[170:220, 40:200] = True    # touches nothing
    changed[120:140, 40:260] = shadow[120:140, 40:260] = True    # reaches 160 px away
    cast = cast_shadow(changed, shadow)
    assert cast[40:100, 100:100 + reach - 4].all()          # beside it: its shadow
    assert cast[170:220, 40:200].all()              # alone (a shadow from outside the frame)
    assert not cast[120:140, 40:260].any()          # the object (a card over a pale sky)
    assert not cast[~shadow].any()


@pytest.mark.parametrize("shape, centre, offset", [("square", (0.5, 0.45), (15, -20)),
                                                   ("circle", (0.45, 0.5), (-18, 14)),
                                                   ("triangle", (0.55, 0.5), (16, 16))])
def test_the_shadow_is_told_from_the_ground_up_to_the_object_edge(shape, centre, offset):
    # A grey card casting a soft shadow (blur 6 px, half the light) on the photograph.
    # The shadow keeps the ground's texture; compared over a window that also held the
    # card's pixels, it did not, and a crescent of shadow 5-10 px wide stayed in the
    # figure beside the card (2.6-4.6 % of the card's area; docs/decisions.md).
    stage = cv.resize(photograph(), (W, H), interpolation=cv.INTER_AREA).astype(np.float32)
    cover = render_shape(shape=shape, width=W, height=H, size=0.4, center_x=centre[0],
                         center_y=centre[1], rotation_deg=10, background=0,
                         foreground=255) / 255.0
    moved = cv.warpAffine(cover.astype(np.float32), np.float32([[1, 0, offset[0]],
                                                                [0, 1, offset[1]]]), (W, H))
    shade = cv.GaussianBlur(moved, (0, 0), 6.0)
    card = np.array([180, 182, 178], np.float32)
    scene = (stage * (1 - 0.5 * shade)[:, :, None] * (1 - cover[:, :, None])
             + card * cover[:, :, None])
    lens = [cv.GaussianBlur(x, (0, 0), 1.0) for x in (scene, stage)]
    fig = figure_from_reference(shoot(lens[0], 1.0, 2), shoot(lens[1], 1.0, 1))
    truth = cover >= 0.5
    shadow = (shade > 0.2) & ~truth
    assert iou(fig.mask, truth) >= 0.93
    assert (shadow & (fig.mask > 0)).sum() <= 0.025 * truth.sum()


@pytest.mark.parametrize("shape", ["circle", "square", "triangle"])
def test_a_card_over_a_texture_of_its_own_grey_is_found_by_the_texture_it_hides(shape):
    # A grey card (150) across a textured ground, dark (70) on the left and of the card's
    # own grey on the right (texture SD 12). Where it lies over its own grey it changes
    # the grey levels by about the texture's contrast, under the threshold, and was left
    # out (IoU 0.67-0.80); it hides the texture, though.
    noise = cv.GaussianBlur(np.random.default_rng(7).normal(0, 1, (H, W)).astype(np.float32),
                            (0, 0), 2.0)
    ground = np.where(np.arange(W)[None, :] < 0.55 * W, 70.0, 150.0) + 12 * noise / noise.std()
    stage = np.repeat(ground[:, :, None], 3, axis=2).astype(np.float32)
    cover = render_shape(shape=shape, width=W, height=H, size=0.45, rotation_deg=10,
                         background=0, foreground=255) / 255.0
    scene = stage * (1 - cover[:, :, None]) + np.float32(150) * cover[:, :, None]
    lens = [cv.GaussianBlur(x, (0, 0), 1.0) for x in (scene, stage)]
    reference = shoot(lens[1], 1.0, 1)
    fig = figure_from_reference(shoot(lens[0], 1.0, 2), reference)
    assert not fig.empty and iou(fig.mask, cover >= 0.5) >= 0.9
    assert figure_from_reference(shoot(lens[1], 1.0, 3), reference).empty


def card_with_shadow(photo: np.ndarray, *, tone: float, size: float, centre: tuple,
                     offset: tuple, blur: float, dark: float, lens: float, noise: float,
                     seed: int, light: np.ndarray | None = None):
    """A grey card (``tone``, a circle of ``size`` at ``centre``) on ``photo`` (BGR,
    resized to W x H), its shadow moved by ``offset``, blurred by ``blur`` pixels and
    darkening by ``dark``, through a camera (``light`` across, blur ``lens``, noise,
    JPEG 70): ``(frame, reference, truth, shadow, empty frame)``."""
    photo = cv.resize(photo, (W, H), interpolation=cv.INTER_AREA).astype(np.float32)
    cover = render_shape(shape="circle", width=W, height=H, size=size, center_x=centre[0],
                         center_y=centre[1], background=0, foreground=255) / 255.0
    dx, dy = offset
    moved = cv.warpAffine(cover.astype(np.float32), np.float32([[1, 0, dx], [0, 1, dy]]),
                          (W, H))
    shade = cv.GaussianBlur(moved, (0, 0), blur)
    scene = (photo * (1 - dark * shade)[:, :, None] * (1 - cover[:, :, None])
             + np.float32(tone) * cover[:, :, None])

    def camera(x, seed):
        if light is not None:
            x = x * light
        x = cv.GaussianBlur(x, (0, 0), lens) + np.random.default_rng(seed).normal(
            0, noise, x.shape)
        return jpeg(np.clip(np.round(x), 0, 255).astype(np.uint8), 70)

    truth = cover >= 0.5
    return camera(scene, seed), camera(photo, 1), truth, (shade > 0.2) & ~truth, camera(photo, 3)


def pale_wall(tone: float, seed: int = 2):
    """A light grey circle (``tone``) with a soft shadow, on scikit-image's astronaut,
    half over the pale wall behind her (:func:`card_with_shadow`)."""
    from skimage import data

    return card_with_shadow(cv.cvtColor(data.astronaut(), cv.COLOR_RGB2BGR)[64:448],
                            tone=tone, size=0.37, centre=(0.557, 0.383), offset=(-18, 19),
                            blur=8.0, dark=0.5, lens=0.75, noise=3.5, seed=seed)


@pytest.mark.parametrize("tone", [180, 190])
def test_a_grey_card_over_a_pale_wall_is_not_taken_for_its_shadow(tone):
    # Over the pale wall the card is a darker patch of the wall's colour on a ground
    # without texture, as a shadow is, beside the rest of the card, and was taken for the
    # card's shadow (IoU 0.55-0.58). No shadow beside its object is that thick with edges
    # that sharp; the shadow itself stays out, and the empty stage is still empty.
    frame, reference, truth, shadow, empty = pale_wall(tone)
    fig = figure_from_reference(frame, reference)
    assert iou(fig.mask, truth) >= 0.9
    assert (shadow & (fig.mask > 0)).sum() <= 0.025 * truth.sum()
    assert figure_from_reference(empty, reference).empty


@pytest.mark.parametrize("tone", [200, 210, 215, 220])
def test_a_card_whose_change_on_a_pale_wall_is_faint_is_found_by_its_colour(tone):
    # Lighter cards on the same wall: over it they change the frame by less than the
    # threshold the photograph's texture sets (6-14 grey levels, median), or pass for
    # their own shadow; only the half over the astronaut was found (IoU 0.55-0.60).
    # Where it was found the card says what colour it is, and GrabCut finds the rest of
    # it by that colour (IoU 0.90-0.98), over all that changed by a tenth of the
    # threshold: from a third, 0.75-0.81 where the change is 6-8 grey levels.
    frame, reference, truth, shadow, _ = pale_wall(tone)
    fig = figure_from_reference(frame, reference)
    assert iou(fig.mask, truth) >= 0.85
    assert (shadow & (fig.mask > 0)).sum() <= 0.025 * truth.sum()


def test_the_specks_that_settling_the_rim_leaves_apart_are_dropped():
    # A card (a change of 100 grey levels) and, joined to it by a neck of 2 pixels that
    # changed by 20 (the faint rim of a shadow), a speck of 5 x 5 farther out. Settling
    # the rim cuts the neck where it meets the card; what it leaves apart, a speck, no
    # longer stretches the figure's box (it did by 22 pixels).
    relit = np.full((240, 320, 1), 100.0, np.float32)
    image = relit.copy()
    mask = np.zeros((240, 320), np.uint8)
    for part, level in (((slice(60, 180), slice(80, 240)), 200.0),       # the card
                        ((slice(119, 121), slice(240, 257)), 120.0),     # the neck
                        ((slice(117, 122), slice(257, 262)), 200.0)):    # the speck
        image[part], mask[part] = level, 1
    settled = settle_rim(Figure(mask, 1.0, "reference"), image, relit)
    assert settled.mask[117:122, 257:262].all()                  # left apart
    assert not settled.mask[119:121, 240].any()                  # the neck cut
    clean = without_specks(settled).mask
    assert clean[62:178, 82:238].all()                           # the card stays
    assert not clean[:, 242:].any()                              # the speck goes


def on_grass(dx: float, dy: float, seed: int = 2):
    """A grey card (190) on the grass of scikit-image's cameraman, its shadow moved by
    (dx, dy) and blurred by 7 pixels, light from 0.85 to 1.15 across
    (:func:`card_with_shadow`)."""
    from skimage import data

    light = (0.85 + 0.3 * np.arange(W, dtype=np.float32) / W)[None, :, None]
    return card_with_shadow(cv.cvtColor(data.camera(), cv.COLOR_GRAY2BGR), tone=190,
                            size=0.4, centre=(0.7, 0.75), offset=(dx, dy), blur=7.0,
                            dark=0.425, lens=1.0, noise=3.0, seed=seed, light=light)


@pytest.mark.parametrize("dx,dy", [(23, -15), (18, 18), (-15, 22), (24, 8)])
def test_the_soft_edge_of_a_shadow_on_grass_is_not_joined_to_the_card(dx, dy):
    # In the shadow's soft edge the light changes across the texture window, which hid
    # the grass's correlation: fringes of the shadow 24-28 pixels deep were joined to the
    # card (IoU 0.87-0.94, 4-13 % of the card's area in shadow). The detail of the grass,
    # without that gradient, is the reference's: IoU 0.94-0.96, 2-5 %.
    frame, reference, truth, shadow, empty = on_grass(dx, dy)
    fig = figure_from_reference(frame, reference)
    assert iou(fig.mask, truth) >= 0.93
    assert (shadow & (fig.mask > 0)).sum() <= 0.05 * truth.sum()
    assert figure_from_reference(empty, reference).empty


def on_fur(dx: float, dy: float, seed: int = 2):
    """A white card (225) on the fur of scikit-image's chelsea, its shadow moved by
    (dx, dy) and blurred by 6 pixels (:func:`card_with_shadow`)."""
    from skimage import data

    return card_with_shadow(cv.cvtColor(data.chelsea(), cv.COLOR_RGB2BGR), tone=225,
                            size=0.45, centre=(0.5, 0.6), offset=(dx, dy), blur=6.0,
                            dark=0.45, lens=0.75, noise=3.0, seed=seed)


@pytest.mark.parametrize("dx,dy", [(-12, -14), (14, -12), (0, -16), (6, 16)])
def test_the_shadow_of_the_grounds_colour_beside_a_card_of_another_is_left_out(dx, dy):
    # Beside the card the shadow's soft edge on fur fails the texture tests, and bumps of
    # it were joined to the card (1.1-1.7 % of its area, its box 10-14 pixels too tall or
    # wide). They are of the fur's colour in shadow; the white card is not: 0.4-0.7 %.
    frame, reference, truth, shadow, empty = on_fur(dx, dy)
    fig = figure_from_reference(frame, reference)
    assert iou(fig.mask, truth) >= 0.98
    assert (shadow & (fig.mask > 0)).sum() <= 0.01 * truth.sum()
    assert figure_from_reference(empty, reference).empty


def test_a_gray_frame_has_no_colour_to_tell_a_shadow_by():
    # A card and, along its right side, 2 pixels darker than the ground and of its grey:
    # a shadow, or the card's own dark edge. In colour, beside a blue card, the shadow.
    relit = np.full((60, 80, 1), 100.0, np.float32)
    image = relit.copy()
    image[20:40, 20:40] = 200.0
    image[20:40, 40:42] = 60.0
    mask = np.zeros((60, 80), np.uint8)
    mask[20:40, 20:42] = 1
    fig = Figure(mask, 1.0, "reference")
    assert shadow_rim(fig, image, relit) is fig
    colour = np.repeat(image, 3, axis=2)
    colour[20:40, 20:40] = (250.0, 200.0, 90.0)
    rim = shadow_rim(fig, colour, np.repeat(relit, 3, axis=2)).mask
    # (the column next to the card is, in its 3 x 3 mean, not of the ground's colour)
    assert not rim[22:38, 41].any() and rim[20:40, 20:41].all()


def test_the_cut_is_the_same_whatever_drew_on_opencvs_random_generator_before():
    # GrabCut's colour models start from k-means++ on OpenCV's random generator; drawn
    # on by anything before, it moved the figure of this scene by 36-104 pixels.
    frame, reference, *_ = pale_wall(220)
    first = figure_from_reference(frame, reference).mask
    for seed in (1, 7920, 15839, 23758):
        cv.setRNGSeed(seed)
        assert (figure_from_reference(frame, reference).mask == first).all()


def test_growing_by_colour_takes_the_objects_colour_and_never_shrinks_the_figure():
    # A card (150) found but for its right quarter; that quarter and a patch of ground
    # of another colour (70, 110, 150) beside it both changed a little. The figure grows
    # over the card and not over the patch; without faint pixels it stays as it was.
    rng = np.random.default_rng(3)
    image = np.full((120, 160, 3), 200.0, np.float32)
    image[30:90, 20:100] = 150.0                               # the card
    image[30:90, 104:150] = (70.0, 110.0, 150.0)               # something else
    image += rng.normal(0, 2.0, image.shape).astype(np.float32)
    found = np.zeros((120, 160), np.uint8)
    found[30:90, 20:80] = 1
    faint = np.zeros((120, 160), bool)
    faint[30:90, 80:150] = True
    grown = grow_by_colour(Figure(found, 1.0, "reference"), image, faint).mask > 0
    card = np.zeros_like(faint)
    card[30:90, 20:100] = True
    assert iou(grown, card) >= 0.95
    assert not grown[:, 104:].any()
    nothing = grow_by_colour(Figure(found, 1.0, "reference"), image, np.zeros_like(faint))
    assert (nothing.mask == found).all()


def test_a_change_of_exposure_is_absorbed():
    stage, scene, truth = photo_scene("square", size=0.35, rotation_deg=20)
    reference = shoot(stage, 1.0, 1)
    fig = figure_from_reference(shoot(scene, 0.6, 2), reference)
    assert not fig.empty and iou(fig.mask, truth) >= 0.8


def test_a_moved_camera_asks_for_the_empty_stage_again():
    stage, scene, _ = photo_scene()
    reference = shoot(stage, 1.0, 1)
    for moved in (np.roll(scene, 12, axis=1), np.roll(stage, -5, axis=0)):
        fig = figure_from_reference(shoot(moved, 1.0, 2), reference)
        assert fig.empty and "the stage changed" in fig.reason
        assert "capture the empty stage again" in fig.reason


def test_another_stage_altogether_is_refused():
    stage, _, _ = photo_scene()
    other = stage[:, ::-1]                    # the same camera, another scene
    fig = figure_from_reference(shoot(other, 1.0, 2), shoot(stage, 1.0, 1))
    assert fig.empty and "stage changed" in fig.reason


def test_a_reference_of_another_size_or_colour_mode_is_an_input_error():
    stage, scene, _ = photo_scene()
    with pytest.raises(InputError, match=r"320x240 pixels but the image is 640x480.*"
                                         r"capture the empty stage again"):
        figure_from_reference(scene, cv.resize(stage, (320, 240)))
    with pytest.raises(InputError, match=r"reference \(empty stage\) is gray but the image is "
                                         r"colour.*capture the empty stage again"):
        figure_from_reference(scene, cv.cvtColor(stage, cv.COLOR_BGR2GRAY))
    with pytest.raises(InputError, match="gray .* or BGR"):
        figure_from_reference(scene[:, :, :2], stage[:, :, :2])


def test_a_mean_of_empty_frames_is_a_reference():
    stage, scene, truth = photo_scene("circle", size=0.3)
    mean = np.mean([shoot(stage, 1.0, s) for s in range(4)], axis=0)      # float
    fig = figure_from_reference(shoot(scene, 1.0, 9), mean)
    assert not fig.empty and iou(fig.mask, truth) >= 0.8


@pytest.fixture(scope="module")
def skimage_data():
    import skimage.data                   # the test extra installs it: a photograph's source
    return skimage.data


def horse_scene(data, ground: str, texture: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The research note's probe scenes: scikit-image's horse silhouette textured by one of
    its photographs, on one of its textures, 640 x 480."""
    def bgr(img):
        img = np.dstack([img] * 3) if img.ndim == 2 else img[:, :, ::-1]
        return cv.resize(img, (W, H), interpolation=cv.INTER_LINEAR)
    horse = (~data.horse()).astype(np.uint8)
    s = 0.45 * H / horse.shape[0]
    horse = cv.resize(horse, None, fx=s, fy=s, interpolation=cv.INTER_NEAREST)
    mask = np.zeros((H, W), np.uint8)
    y0, x0 = (H - horse.shape[0]) // 2 + 20, (W - horse.shape[1]) // 2 - 40
    mask[y0:y0 + horse.shape[0], x0:x0 + horse.shape[1]] = horse
    stage = bgr(getattr(data, ground)())
    scene = np.where(mask[:, :, None] > 0, bgr(getattr(data, texture)()), stage)
    return stage, scene, mask


@pytest.mark.parametrize("ground, texture", [("brick", "astronaut"), ("grass", "chelsea"),
                                             ("gravel", "coffee")])
def test_a_reference_on_brick_grass_and_gravel(skimage_data, ground, texture):
    stage, scene, truth = horse_scene(skimage_data, ground, texture)
    reference = shoot(stage, 1.0, 1)
    fig = figure_from_reference(shoot(scene, light(1.05, 1.35, corner=True), 2), reference)
    assert not fig.empty and iou(fig.mask, truth) >= 0.8
    empty = figure_from_reference(jpeg(shoot(stage, light(0.8, 1.15), 3)), reference)
    assert empty.empty, empty.reason


# --------------------------------------------------------------------------- live camera


def test_the_background_model_learns_then_holds_a_stopped_object():
    small = (320, 240)
    stage, scene, truth = (cv.resize(a, small, interpolation=cv.INTER_NEAREST)
                           for a in photo_scene("circle", size=0.35, center_x=0.4))
    model = BackgroundModel(learn_frames=10)
    for i in range(10):
        fig = model.update(shoot(stage, 1.0 + 0.02 * np.sin(i), 100 + i))
        assert fig.empty and fig.method == "model" and "learning the background" in fig.reason
    assert not model.learning
    for i in range(40):                   # the object stops; a free-running MOG2 absorbs it
        fig = model.update(shoot(scene, 1.0, 200 + i))
    assert not fig.empty and iou(fig.mask, truth) >= 0.8
    # the light changes slowly: the stage is still empty, the object still found
    assert model.update(shoot(stage, light(0.85, 1.2, shape=stage.shape[:2]), 300)).empty
    lit = model.update(shoot(scene, light(0.85, 1.2, shape=stage.shape[:2]), 301))
    assert not lit.empty and iou(lit.mask, truth) >= 0.8
    moved = model.update(shoot(np.roll(stage, 6, axis=1), 1.0, 302))
    assert moved.empty and "learn it again" in moved.reason
    model.relearn()
    assert model.learning and "learning" in model.update(stage).reason


def test_the_background_model_learns_a_flickering_part_of_the_stage():
    small = (320, 240)
    stage, scene, truth = (cv.resize(a, small, interpolation=cv.INTER_NEAREST)
                           for a in photo_scene("circle", size=0.35, center_x=0.6))
    screen = np.zeros(stage.shape[:2] + (1,))
    screen[10:60, 220:310] = 1                   # a screen in view, +-50 % from frame to frame

    def frame(scene, i):
        return shoot(scene, 1 + 0.5 * screen * np.sin(1.7 * i), 100 + i)
    model = BackgroundModel(learn_frames=20)
    for i in range(20):
        model.update(frame(stage, i))
    for i in range(20, 26):
        empty = model.update(frame(stage, i))
        assert empty.empty, empty.reason
    fig = model.update(frame(scene, 26))
    assert not fig.empty and iou(fig.mask, truth) >= 0.8


def test_the_background_model_finds_a_flat_grey_object_on_grey_brick(skimage_data):
    # MOG2 alone: IoU 0.76 (parts of the object lie within its 4 sigma of the brick)
    stage, _, _ = horse_scene(skimage_data, "brick", "astronaut")
    stage = cv.resize(stage, (320, 240), interpolation=cv.INTER_AREA)
    truth = (render_shape(shape="triangle", size=0.5, center_x=0.45) > 125).astype(np.uint8)
    scene = np.where(truth[:, :, None] > 0, np.uint8(128), stage)
    model = BackgroundModel(learn_frames=10)
    for i in range(10):
        model.update(shoot(stage, 1 + 0.02 * np.sin(i), i))
    fig = model.update(shoot(scene, 1.0, 50))
    assert not fig.empty and iou(fig.mask, truth) >= 0.9


def test_a_background_model_from_one_captured_empty_frame():
    small = (320, 240)
    stage, scene, truth = (cv.resize(a, small, interpolation=cv.INTER_NEAREST)
                           for a in photo_scene("square", size=0.4, center_x=0.6))
    model = BackgroundModel.from_reference(shoot(stage, 1.0, 1))
    assert not model.learning
    assert model.update(shoot(stage, 1.0, 2)).empty
    fig = model.update(shoot(scene, 1.0, 3))
    assert not fig.empty and iou(fig.mask, truth) >= 0.8


# --------------------------------------------------------------------------- one still image


@pytest.mark.parametrize("kw", [{"shape": "triangle", "noise_sd": 4, "rotation_deg": 20},
                                {"shape": "circle", "size": 0.4, "center_x": 0.3},
                                {"shape": "square", "background": 210, "foreground": 50},
                                {"shape": "rectangle", "background": 100, "foreground": 140,
                                 "noise_sd": 5, "size": 0.3, "center_x": 0.7}])
def test_a_still_image_of_a_vtexp_stimulus_gives_the_shape(kw):
    img = render_shape(**kw)
    clean = render_shape(**{**kw, "noise_sd": 0})
    truth = (np.abs(clean.astype(int) - kw.get("background", 40))
             > abs(kw.get("foreground", 210) - kw.get("background", 40)) / 2)
    fig = figure_from_still(img)
    assert fig.method == "still" and not fig.empty, fig.reason
    assert fig.confidence >= 0.8 and iou(fig.mask, truth) >= 0.9


def test_a_still_image_without_an_object_is_refused():
    uniform = figure_from_still(np.full((240, 320, 3), 90, np.uint8))
    assert uniform.empty and "uniform" in uniform.reason
    # a photograph: its figure touches the border, and the rest is the border's colours
    photo = figure_from_still(photograph())
    assert photo.empty and photo.reason
    sky = figure_from_still(photograph()[:300, 380:])
    assert sky.empty and "nothing inside the image differs from its border" in sky.reason


def test_still_images_of_empty_textures_are_refused(skimage_data):
    for ground in ("brick", "grass", "gravel"):
        stage, _, _ = horse_scene(skimage_data, ground, "astronaut")
        fig = figure_from_still(jpeg(shoot(stage, light(0.8, 1.15), 3)))
        assert fig.empty, (ground, fig.confidence)


def test_a_figure_is_empty_below_min_confidence():
    mask = np.ones((4, 4), np.uint8)
    assert Figure(mask, MIN_CONFIDENCE - 0.01, "still", "low").empty
    assert not Figure(mask, MIN_CONFIDENCE, "still", None).empty
    assert Figure(mask * 0, 1.0, "reference", None).empty


# --------------------------------------------------------------------------- the pipelines


FLAG = (slice(0, 300), slice(0, 200))
SUIT = (slice(300, 600), slice(0, 512))     # her uniform, shirt, name tag and ribbons
SKY = (slice(0, 300), slice(380, 512))      # light blue, brighter than a ball's rim


def on_photo(stimulus: np.ndarray, mask: np.ndarray, region=FLAG) -> np.ndarray:
    """``stimulus`` where ``mask`` is, elsewhere a part of the (gray) photograph."""
    gray = cv.cvtColor(photograph()[region], cv.COLOR_BGR2GRAY)
    ground = cv.resize(gray, stimulus.shape[::-1], interpolation=cv.INTER_AREA)
    return np.where(mask > 0, stimulus, ground).astype(np.uint8)


def cells(pattern) -> np.ndarray:
    return np.array([(p.row, p.col) for p in pattern.points], float).reshape(-1, 2)


def farthest(a: np.ndarray, b: np.ndarray) -> float:
    """Hausdorff distance between two sets of cells, in pitches (inf if one is empty)."""
    if not len(a) or not len(b):
        return np.inf
    d = np.sqrt(((a[:, None] - b[None]) ** 2).sum(axis=2))
    return float(max(d.min(axis=1).max(), d.min(axis=0).max()))


SQUARE = {"shape": "square", "rotation_deg": 10, "size": 0.5, "center_x": 0.45}
# (pipeline, params, rows, cols, tolerance in pitches): a cell, or for the snake one step
# of its grid of pins and phantom points
CASES = [("covered-cells", {}, 8, 6, 1.0), ("covered-cells", {"fit": "object"}, 8, 6, 1.0),
         ("edge-trace", {"mode": "region"}, 8, 6, 1.0),
         ("edge-trace", {"mode": "outline"}, 8, 6, 1.0),
         ("edge-trace", {"mode": "edges"}, 8, 6, 1.0),
         ("edge-trace", {"mode": "edges", "fit": "frame"}, 8, 6, 1.0),
         ("snake-corners", {}, 5, 5, 0.5), ("snake-corners", {"fit": "frame"}, 5, 5, 0.5)]


@pytest.mark.parametrize("pipeline, params, rows, cols, tolerance", CASES)
def test_with_the_mask_a_pipeline_renders_the_object_not_the_photograph(
        pipeline, params, rows, cols, tolerance):
    fn, _ = PIPELINES[pipeline]
    plain = render_shape(**SQUARE)
    mask = (plain > 125).astype(np.uint8)
    scene = on_photo(plain, mask, SUIT)
    want = cells(fn(plain, rows, cols, **params))
    got = cells(fn(scene, rows, cols, mask=mask, **params))
    assert len(want) and farthest(want, got) <= tolerance
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        blind = cells(fn(scene, rows, cols, **params))        # without it, the photograph
    assert farthest(want, blind) > tolerance


def test_with_the_mask_the_skeleton_is_the_lines(pipeline="edge-trace"):
    fn, _ = PIPELINES[pipeline]
    plain = render_whirlpool(turns=1.0)
    mask = (plain > 125).astype(np.uint8)
    scene = on_photo(plain, mask)
    want = cells(fn(plain, 8, 8, mode="skeleton"))
    assert farthest(want, cells(fn(scene, 8, 8, mode="skeleton", mask=mask))) <= 1.0
    assert farthest(want, cells(fn(scene, 8, 8, mode="skeleton"))) > 1.0


def test_with_the_mask_the_spiral_path_follows_the_line():
    fn, _ = PIPELINES["spiral-path"]
    plain = render_whirlpool(turns=1.5, width=320, height=240)
    mask = (plain > 125).astype(np.uint8)
    scene = on_photo(plain, mask, (slice(0, 250), slice(0, 130)))     # the flag, closer
    want = fn(plain, 5, 5)
    got = fn(scene, 5, 5, mask=mask)
    assert farthest(cells(want), cells(got)) <= 0.5
    assert len(got.points) == len(want.points)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        blind = fn(scene, 5, 5)
    assert farthest(cells(want), cells(blind)) > 0.5


@pytest.mark.parametrize("surface, region", [("ball", FLAG), ("vase", FLAG), ("ball", SKY),
                                             ("vase", SKY), ("uneven", SKY)])
def test_with_the_mask_height_contours_stay_on_the_object(surface, region):
    fn, _ = PIPELINES["height-contours"]
    plain = render_surface(surface=surface, size=0.6, center_x=0.4, noise_sd=2)
    _, inside = surface_height(surface=surface, size=0.6, center_x=0.4)
    mask = inside.astype(np.uint8)
    scene = on_photo(plain, mask, region)
    want = fn(plain, 20, 20)
    got = fn(scene, 20, 20, mask=mask)
    # the object's cells on the array: where its pixels land (params["to_array"])
    rows, cols = np.nonzero(mask)
    (rs, r0), (cs, c0) = got.params["to_array"]["row"], got.params["to_array"]["col"]
    footprint = {(int(round(r * rs + r0)), int(round(c * cs + c0))) for r, c in zip(rows, cols)}

    def off_object(p):
        return sum(all((q.row + dr, q.col + dc) not in footprint
                       for dr in (-1, 0, 1) for dc in (-1, 0, 1)) for q in p.points)
    assert got.params["n_lines"] == want.params["n_lines"] == 3
    assert off_object(got) == 0 and farthest(cells(want), cells(got)) <= 1.0
    if region is FLAG:
        assert off_object(fn(scene, 20, 20)) > 10          # without it, the flag's lines


def test_with_the_mask_the_brightness_is_the_objects_on_a_light_background():
    # The sky is brighter than the ball's rim: its median is no level of zero reflectance.
    plain = render_surface(surface="ball", size=0.6, center_x=0.4, noise_sd=2)
    _, inside = surface_height(surface="ball", size=0.6, center_x=0.4)
    scene = on_photo(plain, inside.astype(np.uint8), SKY)
    assert np.median(scene[~inside]) > 100
    e_plain, m_plain = reflectance(plain, size=(80, 60))
    e_mask, m_mask = reflectance(scene, size=(80, 60), mask=inside)
    assert np.array_equal(m_plain, m_mask)
    assert np.abs(e_plain - e_mask)[m_plain].mean() < 0.05


@pytest.mark.parametrize("shape, corners", [("square", 4), ("triangle", 3), ("circle", 0)])
def test_with_the_mask_the_snake_keeps_to_the_objects_outline_and_corners(shape, corners):
    from vtexp.encoding.snake import find_outline
    plain = render_shape(shape=shape, size=0.5, rotation_deg=10, center_x=0.45)
    mask = (plain > 125).astype(np.uint8)
    edge = np.argwhere(cv.morphologyEx(mask, cv.MORPH_GRADIENT, np.ones((3, 3), np.uint8)))
    for region in (FLAG, SUIT):
        res = find_outline(on_photo(plain, mask, region), mask=mask)
        off = np.sqrt(((res.points[:, None] - edge[None]) ** 2).sum(axis=2)).min(axis=1)
        assert off.mean() <= 1.5 and res.corner.sum() == corners


def test_the_tracker_takes_the_mask():
    plain = render_shape(**SQUARE)
    mask = (plain > 125).astype(np.uint8)
    scene = on_photo(plain, mask, SUIT)
    want = cells(SnakeTracker(fit="frame").pattern(plain, 5, 5))
    tracker = SnakeTracker(fit="frame")
    for _ in range(2):                                     # started, then carried
        got = tracker.pattern(scene, 5, 5, mask=mask)
        assert farthest(want, cells(got)) <= 0.5
    assert got.params["snake_init"] == "carried"


@pytest.mark.parametrize("pipeline", sorted(PIPELINES))
def test_an_all_zero_mask_is_an_empty_pattern_and_a_wrong_one_an_input_error(pipeline):
    fn, _ = PIPELINES[pipeline]
    img = render_shape(shape="circle")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")                    # snake and spiral warn: no object
        pat = fn(img, 5, 5, mask=np.zeros(img.shape, np.uint8))
    assert pat.points == [] and pat.pipeline == pipeline
    with pytest.raises(InputError, match="mask has shape .* give a mask of the image's"):
        fn(img, 5, 5, mask=np.ones((10, 10), np.uint8))


def test_mask_is_a_run_time_argument_not_a_parameter_an_experiment_may_declare():
    from pydantic import ValidationError

    from vtexp.compile import checked_encoding_params
    for name, (_, model) in PIPELINES.items():
        assert "mask" not in model.model_fields, name
        with pytest.raises(ValidationError, match="mask"):
            checked_encoding_params(name, {"mask": [[1]]})
