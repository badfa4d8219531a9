"""Tracking a grid through each pair's seam band: learnstitch's rig shape (three 185-degree
circular fisheyes 120 degrees apart, 512 px), rendered without parallax, so the true rig maps
every tracked point of one image onto its partner in the other."""

import dataclasses

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

import rigjax
from rigjax import synthetic
from rigjax.calibration.seam import band_from_world
from rigjax.camera.model import map_points

TEMPLATE = "configs/rig/tri_fisheye.yaml"


@pytest.fixture(scope="module")
def tri():
    truth = synthetic.rig_from_orientations(
        [(0, 0, 0), (120, 0, 0), (-120, 0, 0)],
        width=512,
        height=512,
        projection=2,
        hfov=185.0,
        b=0.0,
        orientation_jitter_deg=2.0,
        seed=5,
    )
    images = synthetic.render_images(truth, synthetic.procedural_environment(2048, seed=1), noise_std=2.0, seed=1)
    return truth, images


def _errors_arcmin(truth, pair) -> np.ndarray:
    """Angle between the true rays through each match's two pixels."""
    cameras = truth.cameras()
    ray_a, _ = map_points(rigjax.img_to_ray, cameras.take(pair.a), pair.xy_a)
    ray_b, _ = map_points(rigjax.img_to_ray, cameras.take(pair.b), pair.xy_b)
    return np.degrees(np.arccos(np.clip(np.sum(ray_a * ray_b, -1), -1.0, 1.0))) * 60


def _off_seam_deg(truth, pair) -> np.ndarray:
    """Each match's angle from its pair's seam (the great circle equally far from both axes)."""
    cameras = truth.cameras()
    axes = np.asarray(cameras.world_from_cam)[..., :, 2]
    ray_a, _ = map_points(rigjax.img_to_ray, cameras.take(pair.a), pair.xy_a)
    pole = band_from_world(axes[pair.a], axes[pair.b])[1]
    return np.degrees(np.abs(np.arcsin(np.clip(np.asarray(ray_a) @ pole, -1.0, 1.0))))


def test_tracking_the_seam_band_finds_correct_matches_across_the_whole_overlap(tri):
    truth, images = tri
    tracking = rigjax.load_template(TEMPLATE)  # it tracks, every 4 band pixels
    assert tracking.features.track_step_px == 4
    features = dataclasses.replace(tracking, features=dataclasses.replace(tracking.features, track_step_px=None))
    tracked = rigjax.match_images(images, tracking)
    matched = rigjax.match_images(images, features)
    for track, match in zip(tracked, matched):
        errors = _errors_arcmin(truth, track)
        # One band pixel is 22 arcmin here (158 px per radian).
        # Measured: 1531 / 1623 / 1691 tracked, medians 2.8 / 3.3 / 3.9 arcmin, 92-94 % within 8;
        # the features: 73 / 83 / 73 matches, 47 / 60 / 57 within 8 arcmin.
        assert np.median(errors) < 6.0 and np.mean(errors < 8.0) > 0.8, (track.a, track.b)
        assert (errors < 8.0).sum() > 4 * (_errors_arcmin(truth, match) < 8.0).sum()
        off_seam = _off_seam_deg(truth, track)
        # Measured: 90th percentiles 24-25 degrees from the seam, of a 30-degree band.
        assert np.mean(off_seam > 15.0) > 0.2 and off_seam.max() > 25.0  # out towards the overlap's edges


def test_tracking_needs_a_seam_band():
    with pytest.raises(rigjax.ConfigError, match="track_step_px: tracking runs in the seam bands"):
        rigjax.template_from_dict({"rig": {"cameras": 2}, "features": {"track_step_px": 4}})
    with pytest.raises(rigjax.ConfigError, match="track_bias_px: expected a standard deviation"):
        rigjax.template_from_dict({"rig": {"cameras": 2}, "features": {"track_bias_px": -0.1}})
    with pytest.raises(rigjax.ConfigError, match="track_step_px: expected band pixels"):
        rigjax.template_from_dict(
            {
                "rig": {"cameras": 2, "orientations": [[0, 0, 0], [180, 0, 0]]},
                "features": {"seam_band_deg": 8, "track_step_px": 0},
            }
        )


def test_seed_matches_keep_near_points_and_drop_wrong_ones():
    """The band matches that seed the tracks: those one small turn explains stay, with the centres
    those on near objects too (their parallax runs along their epipolar planes), wrong ones go."""
    from rigjax.calibration.seam import _BandMatches
    from rigjax.camera.panorama import Equirect, pano_to_ray, ray_to_pano
    from rigjax.camera.rotation import world_from_cam

    rng = np.random.default_rng(3)
    canvas = Equirect.create(996, 168, 360.0, dtype=np.float64)
    n = 60
    xy_a = np.stack([rng.uniform(200, 800, n), rng.uniform(10, 158, n)], axis=-1)
    ray_a = np.asarray(pano_to_ray(canvas, xy_a))
    baseline = np.array([0.0, 0.7, 0.0])  # along the band's pole, as two neighbours' centres lie
    depth = np.where(np.arange(n) < 20, rng.uniform(1.5, 3.0, n), rng.uniform(50.0, 100.0, n))  # 20 near points
    turn = np.asarray(world_from_cam(*np.radians([1.0, -0.5, 0.7])))  # band b's small error
    ray_b = (depth[:, None] * ray_a - baseline) @ turn  # turn.T @ (point - baseline)
    ray_b /= np.linalg.norm(ray_b, axis=-1, keepdims=True)
    xy_b = np.array(ray_to_pano(canvas, ray_b))
    wrong = np.zeros(n, bool)
    wrong[rng.choice(n, 18, replace=False)] = True
    xy_b[wrong] += rng.uniform(12.0, 30.0, (18, 2)) * rng.choice([-1.0, 1.0], (18, 2))  # 4-10 degrees off
    parallax = np.degrees(np.arccos(np.clip(np.sum(ray_a * (ray_b @ turn.T), -1), -1.0, 1.0)))
    assert parallax[:20].min() > 5.0  # the near points disagree with any rotation by degrees

    matched = _BandMatches(xy_a, xy_b)
    kept = matched.consistent(canvas, baseline, 2.0)
    seen = {tuple(p) for p in kept.xy_a}
    stays = np.array([tuple(p) in seen for p in xy_a])
    assert stays[~wrong].all()  # every right match, near ones included
    assert stays[wrong].sum() <= 2  # a wrong match can fall near its epipolar plane by chance
    rotation_only = {tuple(p) for p in matched.consistent(canvas, None, 2.0).xy_a}
    assert not any(tuple(p) in rotation_only for p in xy_a[:20][~wrong[:20]])  # no centres: near points go
    assert all(tuple(p) in rotation_only for p in xy_a[20:][~wrong[20:]])
