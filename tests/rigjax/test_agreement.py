"""A calibration pooled from several frames, checked against each frame's own
(rigjax.calibration.agreement): the measures against closed forms, the choice of frames on planted
solutions, and a planted bad frame in a dual-fisheye clip."""

import dataclasses
import math

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

import rigjax
from rigjax import cli, synthetic
from rigjax.calibration.agreement import (
    FrameSolution,
    agreeing_frames,
    contradicted_by,
    ray_difference_deg,
    sigmas_apart,
)
from rigjax.camera.rotation import world_from_cam, ypr_from_world_from_cam

TEMPLATE = "configs/rig/dual_fisheye_far.yaml"
LIMITS = dict(max_ray_deg=0.5, max_sigmas=4.0)  # the template defaults


def dual_rig(size: int = 720) -> rigjax.Project:
    return synthetic.rig_from_orientations(
        [(0, 0, 0), (180, 0, 0)],
        width=size,
        height=size,
        projection=2,
        hfov=191.0,
        b=-0.01,
        orientation_jitter_deg=2.0,
        seed=3,
    )


def turned(project: rigjax.Project, camera: int, **degrees: float) -> rigjax.Project:
    images = list(project.images)
    image = images[camera]
    images[camera] = image.replace(**{key: getattr(image, key) + value for key, value in degrees.items()})
    return project.replace(images=tuple(images))


def deviations(n: int = 2, **sd: float) -> np.ndarray:
    """Standard deviations ``(n, 9)`` in the solver's units, letters VABCDEYPR; 0: held."""
    out = np.zeros((n, 9))
    for letter, value in sd.items():
        out[:, "VABCDEYPR".index(letter)] = value
    return out


def test_sigmas_apart_is_the_largest_difference_over_the_deviation_of_the_difference():
    rig = dual_rig()
    moved = turned(rig, 1, yaw=0.3, a=0.002)
    # Yaw 0.3 over hypot(0.1, 0.1); a 0.002 over hypot(0.1, 0) hundredths = 0.001: the yaw is 2.12, the a 2.0.
    value, what = sigmas_apart(moved, deviations(Y=0.1, A=0.1), rig, deviations(Y=0.1))
    assert value == pytest.approx(0.3 / math.hypot(0.1, 0.1)) and what == "camera 1's yaw"
    # Yaws either side of 180 are 0.2 apart, not 359.8.
    a = turned(rig, 1, yaw=179.9 - rig.images[1].yaw)
    b = turned(rig, 1, yaw=-179.9 - rig.images[1].yaw)
    assert sigmas_apart(a, deviations(Y=0.1), b, None)[0] == pytest.approx(2.0)
    # Held or free letters are not compared; no deviations at all: nothing known.
    assert math.isnan(sigmas_apart(moved, deviations(Y=np.inf), rig, deviations(Y=np.inf))[0])
    assert math.isnan(sigmas_apart(moved, None, rig, None)[0])


def test_ray_difference_removes_the_rigs_own_turn_and_sees_a_lens_turned():
    rig = dual_rig()
    # The whole rig turned together: the images cannot tell it.
    turn = np.asarray(world_from_cam(10.0, 5.0, -3.0))
    images = []
    for image in rig.images:
        r = turn @ np.asarray(world_from_cam(image.yaw, image.pitch, image.roll))
        yaw, pitch, roll = (float(x) for x in ypr_from_world_from_cam(r))
        images.append(image.replace(yaw=yaw, pitch=pitch, roll=roll))
    assert ray_difference_deg(rig.replace(images=tuple(images)), rig) < 1e-6
    # One lens turned 1 degree about the other's axis: the best common rotation takes half of it
    # from each, so their rays differ by about half a degree.
    apart = ray_difference_deg(turned(rig, 1, pitch=1.0), rig)
    assert 0.4 < apart < 0.6


def test_the_frames_that_agree_are_trusted_and_the_others_named():
    rig = dual_rig()
    sure, unsure = deviations(Y=0.05, P=0.05, R=0.05), deviations(Y=5.0, P=5.0, R=5.0)
    good = [FrameSolution(f"f{k}.png", turned(rig, 1, yaw=0.02 * k), sure) for k in range(3)]
    bad = FrameSolution("bad.png", turned(rig, 1, pitch=2.0), sure)
    found = agreeing_frames([good[0], bad, good[1], good[2]], **LIMITS)
    assert found.trusted == (0, 2, 3) and found.refusal is None
    assert len(found.outliers) == 1 and found.outliers[0].startswith(
        "bad.png: its own calibration disagrees with f0.png's ("
    )
    assert "camera 1's pitch" in found.outliers[0]
    # A frame that knows its turn only to 5 degrees agrees with anything within that.
    vague = FrameSolution("vague.png", turned(rig, 1, pitch=2.0), unsure)
    assert agreeing_frames([good[0], vague, good[1]], **LIMITS).trusted == (0, 1, 2)
    # One pair a little apart among five frames: each of the two still agrees with the other three.
    pair = [
        FrameSolution("near.png", turned(rig, 1, pitch=0.6), sure),
        FrameSolution("far.png", turned(rig, 1, pitch=-0.6), sure),
    ]
    assert agreeing_frames([good[0], pair[0], good[1], pair[1], good[2]], **LIMITS).trusted == (0, 1, 2, 3, 4)
    # Two frames that disagree, or two groups of two: no majority.
    assert "no majority" in agreeing_frames([good[0], bad], **LIMITS).refusal
    other = FrameSolution("other.png", turned(rig, 1, pitch=2.02), sure)
    tie = agreeing_frames([good[0], good[1], bad, other], **LIMITS)
    assert tie.trusted == () and "bad.png and f0.png" not in tie.refusal and "f0.png and bad.png" in tie.refusal
    # A frame that cannot be calibrated alone is named, and not trusted.
    failed = FrameSolution("dark.png", failure="only 3 of their 9 matches agree")
    found = agreeing_frames([good[0], failed, good[1]], **LIMITS)
    assert found.trusted == (0, 2) and found.outliers == (
        "dark.png: its matches alone do not calibrate the rig (only 3 of their 9 matches agree)",
    )
    # The pooled result checked against each trusted frame through that frame's deviations.
    assert contradicted_by(turned(rig, 1, yaw=0.05), good, **LIMITS) is None
    line = contradicted_by(turned(rig, 1, pitch=2.0), good, **LIMITS)
    assert line.startswith("the calibration pooled from the frames differs from f0.png's own by 1.")


@pytest.fixture(scope="module")
def clip():
    """Three frames of a dual-fisheye camera in a turning scene, and a fourth of the same camera
    whose back lens was knocked 3 degrees in pitch (a frame of another rig, planted)."""
    truth = dual_rig()
    knocked = turned(truth, 1, pitch=3.0)
    scene = synthetic.procedural_environment(4096, seed=0)
    frames = []
    for f, rig in enumerate([truth, truth, truth, knocked]):
        turning = np.roll(scene, f * 4096 * 25 // 360, axis=1)
        frames.append(np.concatenate(synthetic.render_images(rig, turning, noise_std=2.0, seed=f), axis=1))
    return truth, frames


def test_a_planted_bad_frame_is_named_and_the_pool_checked(clip):
    truth, frames = clip
    config = rigjax.load_template(TEMPLATE)
    names = ["f0.png", "bad.png", "f1.png"]
    pooled = rigjax.calibrate([frames[0], frames[3], frames[1]], config, names=names)
    assert pooled.undetermined == ()
    (note,) = [line for line in pooled.notes if "bad-left.png" in line]
    assert note.startswith("note: bad-left.png: its own calibration disagrees with f0-left.png's (")
    # The pool's RANSAC left the planted frame's matches out: it agrees with the good frames and
    # is written, as right as either alone (measured: 0.3 arcmin).
    assert note.endswith("kept: the pool of every frame agrees with the others'")
    assert synthetic.ray_errors_arcmin(pooled.project, truth, grid=240, off_axis_deg=(84.5, 95.5)).max() < 2.0
    # Good frames only: every frame kept, nothing said.
    good = rigjax.calibrate([frames[0], frames[1], frames[2]], config, names=["f0.png", "f1.png", "f2.png"])
    assert good.undetermined == () and not [line for line in good.notes if "own calibration" in line]


def test_a_pool_pulled_off_its_frames_is_pooled_again_without_the_bad_one(clip, monkeypatch):
    """The pool of every frame made to come out 2 degrees off (as a planted frame's matches pull it
    where RANSAC keeps them): the trusted frames contradict it, and they alone are pooled."""
    from rigjax.calibration import pipeline

    truth, frames = clip
    real = pipeline._pooled

    def pulled(pool, config, seed, progress):
        calibration = real(pool, config, seed, progress)
        if len(pool) == 3:
            return dataclasses.replace(calibration, project=turned(calibration.project, 1, pitch=2.0))
        return calibration

    monkeypatch.setattr(pipeline, "_pooled", pulled)
    config = rigjax.load_template(TEMPLATE)
    pooled = rigjax.calibrate([frames[0], frames[3], frames[1]], config, names=["f0.png", "bad.png", "f1.png"])
    assert pooled.undetermined == ()
    (note,) = [line for line in pooled.notes if "bad-left.png" in line]
    assert note.startswith("note: left out: bad-left.png: its own calibration disagrees with f0-left.png's (")
    assert synthetic.ray_errors_arcmin(pooled.project, truth, grid=240, off_axis_deg=(84.5, 95.5)).max() < 2.0
    # Unchecked, the pulled pool is what would be written.
    unchecked = dataclasses.replace(config, checks=dataclasses.replace(config.checks, frames_max_ray_deg=None))
    pulled_pool = rigjax.calibrate([frames[0], frames[3], frames[1]], unchecked, names=["f0.png", "bad.png", "f1.png"])
    assert synthetic.ray_errors_arcmin(pulled_pool.project, truth, grid=240, off_axis_deg=(84.5, 95.5)).max() > 10.0


def test_two_frames_that_disagree_are_refused_in_one_line(clip, tmp_path, capsys):
    _, frames = clip
    for k, frame in zip((0, 3), (frames[0], frames[3])):
        rigjax.write_image(tmp_path / f"f{k}.png", frame)
    out = tmp_path / "rig.pto"
    args = ["calibrate", str(tmp_path / "f0.png"), str(tmp_path / "f3.png"), "--template", TEMPLATE, "-o", str(out)]
    assert cli.main([*args, "-q"]) == 3
    err = capsys.readouterr().err
    assert "the frames' own calibrations disagree and no majority of them agrees (f0-left.png and f3-left.png: " in err
    assert not out.exists()
