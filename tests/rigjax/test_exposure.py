"""Exposure, white balance and vignetting fitted in the overlaps (rigjax.calibration.exposure):
images of a scene at infinity photographed through known gains (Hugin's model, applied here with
the test's own formula), fitted back from a neutral start."""

import dataclasses

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

from test_pto_photometry import hugin_vignetting

import rigjax
from rigjax import synthetic
from rigjax.calibration.exposure import fit_exposure, format_exposure
from rigjax.calibration.motion import frames_project
from rigjax.calibration.template import PhotometryConfig
from rigjax.camera.rotation import world_from_cam

NEUTRAL = dict(
    exposure_value=0.0,
    white_balance_red=1.0,
    white_balance_blue=1.0,
    vignetting_b=0.0,
    vignetting_c=0.0,
    vignetting_d=0.0,
)
LENS = dict(vignetting_b=-0.3, vignetting_c=0.1, vignetting_d=-0.05)


def vignetting(image, x, y):
    """Hugin's V(r) of ``image`` at pixels ``x``, ``y`` (test_pto_photometry's reference)."""
    return hugin_vignetting(
        (image.vignetting_a, image.vignetting_b, image.vignetting_c, image.vignetting_d),
        (image.vignetting_x, image.vignetting_y),
        (image.width, image.height),
        np.stack([x, y], axis=-1),
    )


def photographed(truth):
    """What each camera of ``truth`` records of a procedural scene: its light times the camera's gain."""
    neutral = truth.replace(images=tuple(dataclasses.replace(im, **NEUTRAL) for im in truth.images))
    light = synthetic.render_images(neutral, synthetic.procedural_environment(2048, seed=0))
    out = []
    for image, pixels in zip(truth.images, light):
        y, x = np.mgrid[: image.height, : image.width].astype(float)
        gain = vignetting(image, x, y)[..., None] * 2.0**-image.exposure_value
        gain = gain * np.array([image.white_balance_red, 1.0, image.white_balance_blue])
        out.append(np.clip(np.round(pixels * gain), 0, 255).astype(np.uint8))
    return out, neutral


def with_photometry(rig, seed):
    rng = np.random.default_rng(seed)
    images = []
    for k, image in enumerate(rig.images):
        values = (
            {}
            if k == 0
            else dict(
                exposure_value=rng.uniform(-0.5, 0.5),
                white_balance_red=rng.uniform(0.9, 1.1),
                white_balance_blue=rng.uniform(0.9, 1.1),
            )
        )
        images.append(dataclasses.replace(image, **LENS, **values, links={"Vb": 0, "Vc": 0, "Vd": 0} if k else {}))
    return rig.replace(images=tuple(images))


def test_a_ring_of_six_gives_each_exposure_white_balance_and_the_lens_vignetting():
    truth = with_photometry(synthetic.ring_rig(6, width=480, height=360, projection=3, hfov=123.0, b=-0.01), seed=1)
    images, start = photographed(truth)
    fit = fit_exposure(start, images)
    assert fit.held == ()
    for got, want in zip(fit.project.images, truth.images):
        assert got.exposure_value == pytest.approx(want.exposure_value, abs=0.005)  # EV; the issue asks 0.05
        assert got.white_balance_red == pytest.approx(want.white_balance_red, rel=0.003)
        assert got.white_balance_blue == pytest.approx(want.white_balance_blue, rel=0.003)
        y, x = np.mgrid[: got.height : 12, : got.width : 12].astype(float)
        np.testing.assert_allclose(vignetting(got, x, y), vignetting(want, x, y), atol=0.005)  # the issue asks 2 %
    assert np.all(fit.exposure_sd[1:] < 0.01) and np.isnan(fit.exposure_sd[0])  # the anchor: held
    assert np.all(fit.vignetting_sd < 0.005) and 0.0 < fit.rms < 0.1
    assert "exposure and vignetting (" in format_exposure(fit)


def test_a_dual_fisheyes_ring_gives_the_exposure_and_holds_the_vignetting():
    rig = synthetic.rig_from_orientations(
        [(0, 0, 0), (180, 0, 0)], width=720, height=720, projection=2, hfov=191.0, b=0.0
    )
    truth = rig.replace(
        images=(
            dataclasses.replace(rig.images[0], **LENS),
            dataclasses.replace(
                rig.images[1], **LENS, exposure_value=0.3, white_balance_red=1.05, links={"Vb": 0, "Vc": 0, "Vd": 0}
            ),
        )
    )
    images, start = photographed(truth)
    fit = fit_exposure(start, images)
    # Both lenses see the seam ring at one radius: V there trades with the exposure, and the same
    # lens at the same radius cancels from the ratio, so the exposure difference stands.
    assert len(fit.held) == 1 and fit.held[0].startswith("image 0's vignetting: its overlaps cannot tell it")
    assert np.isnan(fit.vignetting_sd).all()
    assert fit.project.images[1].vignetting_b == 0.0  # held where it started
    assert fit.project.images[1].exposure_value == pytest.approx(0.3, abs=0.01)
    assert fit.project.images[1].white_balance_red == pytest.approx(1.05, rel=0.01)


def test_overlaps_that_show_other_surfaces_at_the_same_directions_hold_every_letter():
    """A dual camera whose second lens sees another scene than the first at the seam's directions
    (what near content seen with parallax, or a misplaced rim, gives): no gains explain the samples,
    and the fit is not kept. The same camera seeing one scene is fitted as before."""
    rig = synthetic.rig_from_orientations([(0, 0, 0), (180, 0, 0)], width=360, height=360, projection=2, hfov=191.0)
    truth = rig.replace(images=(rig.images[0], dataclasses.replace(rig.images[1], exposure_value=0.3)))
    images, start = photographed(truth)
    kept = fit_exposure(start, images, max_rms=0.5)
    assert kept.rms < 0.1 and kept.project.images[1].exposure_value == pytest.approx(0.3, abs=0.01)
    elsewhere = synthetic.render_images(start, synthetic.procedural_environment(2048, seed=5))[1]
    other = [images[0], np.clip(np.round(elsewhere * 2.0**-0.3), 0, 255).astype(np.uint8)]
    held = fit_exposure(start, other, max_rms=0.5)
    assert held.rms > 0.5 and held.held[-1].startswith(f"the overlaps disagree by {held.rms:.2f} stops")
    assert held.project == start and np.isnan(held.exposure_sd).all() and np.isnan(held.white_balance_sd).all()
    assert fit_exposure(start, other).project != start  # without the limit, the fit is taken as it comes
    with pytest.raises(rigjax.RigjaxError, match="max_rms_stops: expected stops"):
        PhotometryConfig(fit=True, max_rms_stops=0.0)
    assert PhotometryConfig(fit=True, max_rms_stops=None).max_rms_stops is None  # no limit
    with pytest.raises(rigjax.RigjaxError, match="max_rms must be > 0"):
        fit_exposure(start, images, max_rms=-1.0)


def _dual_frames(turn_deg: float, count: int, seed: int):
    """A dual fisheye (two 191-degree lenses, 360 px, -1 stop at the circle's rim) turning by
    ``turn_deg`` a frame (yaw, with a pitch and roll wobble), every image its own exposure and white
    balance (the camera's automatic exposure), vignetting linked to frame 0's lens; as photographed."""
    rig = synthetic.rig_from_orientations([(0, 0, 0), (180, 0, 0)], width=360, height=360, projection=2, hfov=191.0)
    rng = np.random.default_rng(seed)
    turns = np.stack([np.asarray(world_from_cam(f * turn_deg, *rng.uniform(-2.0, 2.0, 2))) for f in range(count)])
    frames = frames_project(rig, turns, [[f"f{f}-left.png", f"f{f}-right.png"] for f in range(count)])
    # V = 1 - 0.9 r^2 - 0.4 r^4 + 0.1 r^6: 0.50 at the circle's rim (r = 0.707 half diagonals)
    lens = dict(vignetting_b=-0.9, vignetting_c=-0.4, vignetting_d=0.1)
    images = []
    for k, image in enumerate(frames.images):
        values = {} if k == 0 else dict(exposure_value=rng.uniform(-0.5, 0.5), white_balance_red=rng.uniform(0.9, 1.1))
        links = {} if k < 2 else {letter: k % 2 for letter in ("Vb", "Vc", "Vd")}
        images.append(dataclasses.replace(image, **lens, **values, links=links))
    return frames.replace(images=tuple(images))


def test_a_turning_dual_fisheye_gives_its_lenses_vignetting_and_each_frames_exposure():
    """Hugin's recipe for these cameras: the same lens sees a direction at one radius in one frame
    and at another in the next, which one frame's seam ring (above) cannot tell."""
    truth = _dual_frames(turn_deg=8.0, count=5, seed=4)
    images, start = photographed(truth)
    fit = fit_exposure(start, images)
    assert fit.held == ()
    for got, want in zip(fit.project.images, truth.images):
        assert got.exposure_value == pytest.approx(want.exposure_value, abs=0.05)  # the 0.05 EV
        assert got.white_balance_red == pytest.approx(want.white_balance_red, rel=0.01)
    for lens in range(2):  # over the lens's circle (within 95 % of its radius): the 2 %
        got, want = fit.project.images[lens], truth.images[lens]
        y, x = np.mgrid[:360:8, :360:8].astype(float)
        inside = np.hypot(x - 179.5, y - 179.5) < 0.95 * 180
        np.testing.assert_allclose(vignetting(got, x, y)[inside], vignetting(want, x, y)[inside], atol=0.02)
    # One frame of the same camera: the vignetting is held, as the seam ring alone cannot tell it.
    one = fit_exposure(start.replace(images=start.images[:2]), images[:2])
    assert np.isnan(one.vignetting_sd).all() and len(one.held) == 2  # each lens


def test_bad_input_is_named():
    rig = synthetic.ring_rig(3, width=64, height=48, projection=3, hfov=123.0, b=0.0)
    with pytest.raises(rigjax.RigjaxError, match="2 images for a project of 3"):
        fit_exposure(rig, [np.zeros((48, 64, 3), np.uint8)] * 2)
    with pytest.raises(rigjax.RigjaxError, match="image 1 is 32x48, its i line says 64x48"):
        fit_exposure(
            rig, [np.zeros((48, 64, 3), np.uint8), np.zeros((48, 32, 3), np.uint8), np.zeros((48, 64, 3), np.uint8)]
        )
