"""Synthetic video of a moving 360 rig (learnstitch.data.sequence): the pose in closed form, frame 0
as the stills draw it, and the truth panorama in the frame of the project a stitcher uses, checked
through rigjax's camera model."""

import dataclasses
import math

import jax
import numpy as np
import pytest
import torch

import rigjax
from learnstitch.data.config import SynthConfig
from learnstitch.data.dual import draw_dual, render_dual_frames
from learnstitch.data.rigs import FULLRES_RIGS, render_rig
from learnstitch.data.scene import render
from learnstitch.data.sequence import (
    CLEARANCE_M,
    Motion,
    draw_sequence,
    render_sequence,
    rig_pose,
    sequence_project,
    surface_distance,
    wobble,
)
from learnstitch.data.store import to_uint8
from learnstitch.data.visibility import rig_sight_lines
from rigjax import Equirect
from rigjax.errors import ConfigError

# A fast turn, a walk and a strong wobble: a frame in the wrong frame is far off.
BRISK = Motion(speed=1.4, yaw_rate=300.0, wobble_deg=4.0)


def _frames(kind, seed, count, motion=BRISK, size=96, width=128):
    return list(render_sequence(kind, seed, count, size=size, motion=motion, pano_width=width))


def _ry(degrees):
    a = math.radians(degrees)
    return np.array([[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]])


def test_the_pose_turns_and_walks_as_the_motion_says():
    steady = Motion(speed=1.4, yaw_rate=15.0, wobble_deg=0.0, fps=30.0)
    start, direction = _ry(30.0), np.array([0.6, 0.0, 0.8])
    first = rig_pose(steady, 5, 0, start, direction)
    np.testing.assert_array_equal(first.world_from_rig, start)  # frame 0: as drawn
    np.testing.assert_array_equal(first.position, np.zeros(3))
    for frame in (0, 1, 17):
        now, after = rig_pose(steady, 5, frame, start, direction), rig_pose(steady, 5, frame + 1, start, direction)
        np.testing.assert_allclose(after.world_from_rig @ now.world_from_rig.T, _ry(15.0 / 30.0), atol=1e-12)
        np.testing.assert_allclose(after.position - now.position, direction * 1.4 / 30.0, atol=1e-12)
        np.testing.assert_allclose(now.position, direction * 1.4 * frame / 30.0, atol=1e-12)


def test_the_wobble_is_bounded_smooth_seeded_and_still_at_frame_0():
    times = np.arange(600) / 30.0
    angles = np.array([wobble(2.0, 3, t) for t in times])
    assert wobble(2.0, 3, 0.0) == (0.0, 0.0) and np.abs(angles).max() <= 2.0 and np.abs(angles).max() > 0.5
    # Sinusoids of at most 1.5 Hz: no step larger than the amplitude's fastest slope allows.
    assert np.abs(np.diff(angles, axis=0)).max() <= 2.0 * 2 * math.pi * 1.5 / 30.0
    assert np.array_equal(angles, np.array([wobble(2.0, 3, t) for t in times]))
    assert not np.allclose(angles, np.array([wobble(2.0, 4, t) for t in times]))
    pose = rig_pose(Motion(yaw_rate=0.0, wobble_deg=2.0), 3, 12)
    with jax.enable_x64(True):
        ypr = np.asarray(rigjax.ypr_from_world_from_cam(pose.world_from_rig), np.float64)
    np.testing.assert_allclose(ypr, [0.0, *wobble(2.0, 3, 12 / 30.0)], atol=1e-9)  # Hugin's pitch and roll


def test_same_seed_same_frames_and_other_seeds_differ():
    one, two = _frames("three", 4, 2), _frames("three", 4, 2)
    for a, b in zip(one, two):
        assert all(np.array_equal(x, y) for x, y in zip(a.images, b.images))
        assert np.array_equal(a.pano, b.pano) and np.array_equal(a.inverse_depth, b.inverse_depth)
        assert np.array_equal(a.visibility, b.visibility) and np.array_equal(a.pose.position, b.pose.position)
    other = _frames("three", 5, 1)[0]
    assert not np.array_equal(other.pano, one[0].pano) and not np.array_equal(other.images[0], one[0].images[0])
    assert not np.array_equal(one[1].images[0], one[0].images[0])  # the rig moved


def test_frames_are_shaped_as_documented():
    frame = _frames("dual", 2, 1, width=64)[0]
    assert [image.shape for image in frame.images] == [(96, 96, 3)] * 2 and frame.images[0].dtype == np.uint8
    assert frame.side_by_side.shape == (96, 192, 3) and frame.pano.shape == (32, 64, 3) and frame.pano.dtype == np.uint8
    assert frame.inverse_depth.shape == (32, 64) and frame.inverse_depth.dtype == np.float32
    assert frame.visibility.shape == (2, 32, 64) and frame.visibility.dtype == bool
    assert (frame.inverse_depth == 0.0).any() and frame.inverse_depth.max() < 1.0 / CLEARANCE_M  # sky; nothing closer


def test_frame_0_is_the_stills_and_a_pure_turn_is_render_dual_frames():
    # The dual camera turning 72 degrees a frame on the spot: render_dual_frames' sequence.
    turning = Motion(speed=0.0, yaw_rate=72.0 * 30.0, wobble_deg=0.0)
    frames = _frames("dual", 1, 2, motion=turning)
    stills = render_dual_frames(1, draw_dual(1, 96), 2)
    assert np.array_equal(frames[0].side_by_side, stills[0]) and np.array_equal(frames[1].side_by_side, stills[1])
    # The three-fisheye rig's frame 0 (any motion): render_rig's sample of fullres_demo's rig.
    frame = _frames("three", 2, 1)[0]
    sample = render_rig(dataclasses.replace(FULLRES_RIGS["tri_d04"], size=96), 2, 128, SynthConfig())
    assert all(np.array_equal(a, to_uint8(b)) for a, b in zip(frame.images, sample.fisheyes))
    assert np.array_equal(frame.pano, to_uint8(sample.pano))
    depth = sample.depth.numpy()
    np.testing.assert_array_equal(frame.inverse_depth, np.where(np.isfinite(depth), 1.0 / depth, 0.0))
    lines = rig_sight_lines(sample.scene, sample.rig.cameras, sample.rig.centres, sample.depth, 185.0)
    assert np.array_equal(frame.visibility, lines.visible.numpy())  # the depth oracle's visibility


def _camera(cameras, k):
    return jax.tree_util.tree_map(lambda v: v[k], cameras)


@pytest.mark.parametrize("kind", ["three", "dual"])
def test_the_truth_panorama_is_in_the_projects_frame(kind, tmp_path):
    """Frame 2 (turned 20 degrees, walked 9 cm, wobbled): each panorama pixel's point (its
    direction times its depth, rigjax's equirectangular canvas) projected into each camera that
    sees it through the saved project's camera and centre shows the truth's colour there; the
    same through the rig as it stood at frame 0 does not."""
    size, width = 128, 256
    frame = _frames(kind, 3, 3, size=size, width=width)[2]
    sequence_project(kind, 3, size=size, pano_width=width, motion=BRISK).save(tmp_path / "rig.pto")
    project = rigjax.load_project(tmp_path / "rig.pto")
    xy = np.stack(np.meshgrid(np.arange(width), np.arange(width // 2)), -1).astype(np.float64)
    with jax.enable_x64(True):
        cameras = project.cameras(dtype=np.float64)
        rays = np.asarray(rigjax.pano_to_ray(Equirect.create(width, width // 2, 360.0), xy), np.float64)
        inverse = frame.inverse_depth.astype(np.float64)[..., None]
        frozen = rig_pose(BRISK, 3, 2).world_from_rig.T  # frame 0's rig, that did not turn with the camera
        for k in range(len(project.images)):
            seen = frame.visibility[k]
            scores = []
            for turn in (np.eye(3), frozen):
                points = rays @ turn.T
                towards = np.where(
                    inverse > 0, points - inverse * project.centres[k], points
                )  # depth x (dir - c / depth)
                img_xy, valid = rigjax.ray_to_img(_camera(cameras, k), towards[seen])
                pixel = np.clip(np.round(np.asarray(img_xy)).astype(int), 0, size - 1)
                got = frame.images[k][pixel[:, 1], pixel[:, 0]].astype(float)
                want = frame.pano[seen].astype(float)
                assert np.asarray(valid).all()
                scores.append(np.corrcoef(got.ravel(), want.ravel())[0, 1])
            assert seen.mean() > 0.3 and scores[0] > 0.9 and scores[1] < scores[0] - 0.2, (k, scores)


def test_the_dual_project_is_camera_0s_frame_and_the_pose_starts_as_drawn():
    truth = draw_sequence("dual", 6, size=64)
    lens = draw_dual(6, 64)
    c = lens.cameras
    with jax.enable_x64(True):
        world_from_0 = np.asarray(rigjax.world_from_cam(c.yaw[0], c.pitch[0], c.roll[0]), np.float64)
    np.testing.assert_allclose(truth.pose(0).world_from_rig, world_from_0, atol=1e-12)
    project = truth.project(("l.png", "r.png"), 128)
    assert project.panorama.width == 128 and [im.filename for im in project.images] == ["l.png", "r.png"]
    assert (project.images[0].yaw, project.images[0].pitch, project.images[0].roll) == pytest.approx(
        (0, 0, 0), abs=1e-9
    )
    np.testing.assert_allclose(project.centres, lens.centres @ world_from_0, atol=1e-12)


def test_the_walk_keeps_every_camera_clear_of_the_street():
    truth = draw_sequence("three", 1, size=16)
    motion = truth.motion
    axis = np.array([math.sin(truth.scene.road_angle), 0.0, math.cos(truth.scene.road_angle)])
    assert abs(truth.direction[1]) == 0.0 and np.linalg.norm(truth.direction) == pytest.approx(1.0)
    assert abs(truth.direction @ axis) >= math.cos(math.radians(90.0)) and truth.clearance >= CLEARANCE_M
    # Rays cast from every camera over the planned walk reach no surface nearer than the clearance.
    directions = torch.as_tensor(_sphere(400), dtype=torch.float32)
    for frame in range(0, motion.max_frames, 10):
        pose = truth.pose(frame)
        for centre in truth.centres @ pose.world_from_rig.T + pose.position:
            _, depth = render(truth.scene, torch.as_tensor(centre, dtype=torch.float32), directions)
            assert depth.min() >= CLEARANCE_M
    assert surface_distance(truth.scene, np.array([[0.0, truth.scene.camera_height - 0.5, 0.0]]))[0] <= 0.5


def _sphere(count):
    """Unit directions spread over the sphere (a Fibonacci lattice)."""
    k = np.arange(count) + 0.5
    y = 1.0 - 2.0 * k / count
    angle = math.pi * (3.0 - math.sqrt(5.0)) * k
    r = np.sqrt(1.0 - y**2)
    return np.stack([r * np.cos(angle), y, r * np.sin(angle)], axis=-1)


def test_bad_arguments_say_what_was_expected():
    with pytest.raises(ConfigError, match="kind must be one of"):
        draw_sequence("quad", 0, size=16)
    with pytest.raises(ConfigError, match=r"Motion.fps must be finite and > 0, got 0"):
        Motion(fps=0.0)
    with pytest.raises(ConfigError, match="Motion.speed"):
        Motion(speed=-1.0)
    with pytest.raises(ConfigError, match="count must be 1 to 121 frames"):
        draw_sequence("three", 0, size=16).frames(122)
    with pytest.raises(ConfigError, match="pano_width must be an even integer"):
        draw_sequence("three", 0, size=16).frames(1, pano_width=33)
    with pytest.raises(ConfigError, match="seed 59: no walk of 5.6 m"):
        draw_sequence("three", 59, size=16)
