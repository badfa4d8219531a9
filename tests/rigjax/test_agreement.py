"""A calibration pooled from several frames, checked against each frame's own
(rigjax.calibration.agreement): the measures against closed forms, the choice of frames on planted
solutions, and a planted bad frame in a dual-fisheye clip."""

import dataclasses
import math

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

from test_dual_fisheye import dual_rig  # two 191-degree lenses back to back, turned up to 2 degrees

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


def turned(project: rigjax.Project, camera: int, **degrees: float) -> rigjax.Project:
    images = list(project.images)
    image = images[camera]
    images[camera] = image.replace(**{key: getattr(image, key) + value for key, value in degrees.items()})
    return project.replace(images=tuple(images))


def solution(name: str, project: rigjax.Project, turn_sd: float = 0.05, **sd: float) -> FrameSolution:
    """A calibration whose cameras' turns are known to ``turn_sd`` degrees about every axis and the
    lens letters ``sd`` (solver units) to theirs; the rest held (NaN)."""
    deviations = np.full((2, 9), np.nan)
    for letter, value in sd.items():
        deviations[:, "VABCDEYPR".index(letter)] = value
    turns = np.where(np.eye(3, dtype=bool), turn_sd**2, 0.0)
    return FrameSolution(name, project, deviations, np.broadcast_to(turns, (2, 3, 3)))


def test_sigmas_apart_is_the_largest_difference_over_the_deviation_of_the_difference():
    rig = dual_rig(720)
    # a 0.002 apart, known to 0.1 hundredths (0.001) on one side and exact on the other: 2 deviations.
    # Camera 1 turned 0.3 degrees about the vertical: less the rig's mean turn, each camera 0.15
    # degrees, under a covariance of 2 x 0.1^2 per axis: 0.15 / (0.1 sqrt 2) = 1.06 deviations.
    moved = turned(rig, 1, yaw=0.3, a=0.002)
    value, what = sigmas_apart(solution("a", moved, 0.1, A=0.1), solution("b", rig, 0.1))
    assert value == pytest.approx(2.0) and what == "camera 1's a"
    value, what = sigmas_apart(solution("a", turned(rig, 1, yaw=0.3), 0.1), solution("b", rig, 0.1))
    assert value == pytest.approx(0.15 / (0.1 * math.sqrt(2)), rel=1e-6) and what == "camera 0's turn"
    # Yaws either side of 180 are 0.2 apart, not 359.8; a side without deviations counts as exact.
    a = turned(rig, 1, yaw=179.9 - rig.images[1].yaw)
    b = turned(rig, 1, yaw=-179.9 - rig.images[1].yaw)
    assert sigmas_apart(solution("a", a, 0.1), FrameSolution("b", b))[0] == pytest.approx(1.0, rel=1e-6)
    # Letters and turns left free (inf) are not compared; no deviations at all: nothing known.
    assert math.isnan(sigmas_apart(solution("a", moved, np.inf, A=np.inf), solution("b", rig, np.inf))[0])
    assert math.isnan(sigmas_apart(FrameSolution("a", moved), FrameSolution("b", rig))[0])


def test_ray_difference_removes_the_rigs_own_turn_and_sees_a_lens_turned():
    rig = dual_rig(720)
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
    rig = dual_rig(720)
    good = [solution(f"f{k}.png", turned(rig, 1, yaw=0.02 * k)) for k in range(3)]
    bad = solution("bad.png", turned(rig, 1, pitch=2.0))
    found = agreeing_frames([good[0], bad, good[1], good[2]], **LIMITS)
    assert found.trusted == (0, 2, 3) and found.refusal is None
    assert len(found.outliers) == 1 and found.outliers[0].startswith(
        "bad.png: its own calibration disagrees with f0.png's ("
    )
    assert "camera 0's turn" in found.outliers[0]
    # A frame that knows its turn only to 5 degrees agrees with anything within that.
    vague = solution("vague.png", turned(rig, 1, pitch=2.0), turn_sd=5.0)
    assert agreeing_frames([good[0], vague, good[1]], **LIMITS).trusted == (0, 1, 2)
    # One pair a little apart among five frames: each of the two still agrees with the other three.
    pair = [
        solution("near.png", turned(rig, 1, pitch=0.6)),
        solution("far.png", turned(rig, 1, pitch=-0.6)),
    ]
    assert agreeing_frames([good[0], pair[0], good[1], pair[1], good[2]], **LIMITS).trusted == (0, 1, 2, 3, 4)
    # Two frames that disagree, or two groups of two: no majority.
    assert "no majority" in agreeing_frames([good[0], bad], **LIMITS).refusal
    other = solution("other.png", turned(rig, 1, pitch=2.02))
    tie = agreeing_frames([good[0], good[1], bad, other], **LIMITS)
    assert tie.trusted == () and "bad.png and f0.png" not in tie.refusal and "f0.png and bad.png" in tie.refusal
    # A frame that cannot be calibrated alone is named, and not trusted.
    failed = FrameSolution("dark.png", failure="only 3 of their 9 matches agree")
    found = agreeing_frames([good[0], failed, good[1]], **LIMITS)
    assert found.trusted == (0, 2) and found.outliers == (
        "dark.png: its matches alone do not calibrate the rig (only 3 of their 9 matches agree)",
    )
    # None calibrated alone: nothing to check against, no refusal (the pool stands on its own checks).
    alone = agreeing_frames([failed, failed], **LIMITS)
    assert alone.trusted == () and alone.refusal is None and len(alone.outliers) == 2
    # The pooled result checked against each trusted frame through that frame's deviations: refused
    # where most of them contradict it, a note for each of a minority.
    assert contradicted_by(turned(rig, 1, yaw=0.05), good, **LIMITS) == (None, ())
    line, notes = contradicted_by(turned(rig, 1, pitch=2.0), good, **LIMITS)
    assert line.startswith("the calibration pooled from the frames differs from f0.png's own by ") and notes == ()
    assert 0.9 < float(line.split(" by ")[1].split(" deg")[0]) < 1.1  # half the turn, as above
    assert line.count("'s own by") == 3 and line.endswith(": the frames do not make one rig")
    line, notes = contradicted_by(rig, [good[0], good[1], bad], **LIMITS)  # bad's own alone differs
    assert (
        line is None
        and len(notes) == 1
        and notes[0].startswith("note: the calibration pooled from the frames differs from bad.png's own by")
    )


@pytest.fixture(scope="module")
def clip():
    """Three frames of a dual-fisheye camera in a turning scene, and a fourth of the same camera
    whose back lens was knocked 3 degrees in pitch (a frame of another rig, planted)."""
    truth = dual_rig(720)
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
    # The pool of all three agrees with the good frames' own and is written, as right as either
    # alone (measured: 0.3 arcmin).
    assert note.endswith("; the pool of every frame is written, checked against the 2 trusted frames' own")
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

    def pulled(pool, config, seed, progress, **names):
        calibration = real(pool, config, seed, progress, **names)
        if len(pool) == 3:
            return dataclasses.replace(calibration, project=turned(calibration.project, 1, pitch=2.0))
        return calibration

    monkeypatch.setattr(pipeline, "_pooled", pulled)
    config = rigjax.load_template(TEMPLATE)
    pooled = rigjax.calibrate([frames[3], frames[0], frames[1]], config, names=["bad.png", "f0.png", "f1.png"])
    assert pooled.undetermined == ()
    (note,) = [line for line in pooled.notes if "bad-left.png" in line]
    assert note.startswith("note: left out: bad-left.png: its own calibration disagrees with f0-left.png's (")
    assert synthetic.ray_errors_arcmin(pooled.project, truth, grid=240, off_axis_deg=(84.5, 95.5)).max() < 2.0
    # The project still names the first frame's images, the ones rigjax calibrate writes beside it.
    assert [im.filename for im in pooled.project.images] == ["bad-left.png", "bad-right.png"]
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
