"""Synthetic dual-fisheye frames (learnstitch.data.dual): the truth they are drawn with, Hugin's
photometric model applied to the scene's light, and `learnstitch demo --dual`."""

import dataclasses
from pathlib import Path

import jax
import numpy as np
import pytest

import rigjax
from learnstitch import cli
from learnstitch.data.dual import draw_dual, render_dual_frames


def _world(yaw, pitch, roll):
    with jax.enable_x64(True):
        return np.asarray(rigjax.world_from_cam(yaw, pitch, roll), np.float64)


def test_the_truth_is_drawn_as_stated_and_written_in_camera_0s_frame(tmp_path):
    truth = draw_dual(3, size=96)
    assert draw_dual(3, size=96).cameras.yaw.tolist() == truth.cameras.yaw.tolist()  # same seed, same camera
    c = truth.cameras
    assert c.hfov[0] == c.hfov[1] and 189.0 <= c.hfov[0] <= 191.0 and np.all(c.b == -0.01)
    assert np.all(np.abs(c.yaw - [0.0, 180.0]) <= 2.0) and np.all(np.abs(c.pitch) <= 2.0)
    assert 0.02 <= np.ptp(truth.centres[:, 2]) <= 0.03 and np.all(truth.centres[:, :2] == 0.0)
    truth.project(("a.png", "b.png")).save(tmp_path / "truth.pto")
    project = rigjax.load_project(tmp_path / "truth.pto")
    first, second = project.images
    assert (first.yaw, first.pitch, first.roll) == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)
    # Camera 1 relative to camera 0, the centres in camera 0's frame: as drawn in the world.
    world = [_world(c.yaw[k], c.pitch[k], c.roll[k]) for k in range(2)]
    np.testing.assert_allclose(_world(second.yaw, second.pitch, second.roll), world[0].T @ world[1], atol=1e-9)
    np.testing.assert_allclose(project.centres, truth.centres @ world[0], atol=1e-9)
    assert second.exposure_value == pytest.approx(truth.exposure_value[1] - truth.exposure_value[0])
    assert second.vignetting_b == pytest.approx(truth.vignetting_b, abs=1e-12) and first.white_balance_red == 1.0


def test_frames_carry_the_exposure_white_balance_and_vignetting_drawn():
    truth = draw_dual(1, size=96)
    clean = dataclasses.replace(truth, exposure_value=np.zeros(2), white_balance=np.ones((2, 2)), vignetting_b=0.0)
    light = render_dual_frames(1, clean, noise_std=0.0)[0].astype(float)
    pixels = render_dual_frames(1, truth, noise_std=0.0)[0].astype(float)
    # Hugin's model, closed form: I = L V(r) 2^-Eev (Er, 1, Eb), V = 1 + Vb r^2 (r in half diagonals).
    xy = np.stack(np.meshgrid(np.arange(96), np.arange(96)), -1)
    r2 = ((xy - 47.5) ** 2).sum(-1) / (2 * 48.0**2)
    for k in range(2):
        gain = (1 + truth.vignetting_b * r2) * 2.0 ** -truth.exposure_value[k]
        balance = np.array([truth.white_balance[k, 0], 1.0, truth.white_balance[k, 1]])
        half = slice(96 * k, 96 * (k + 1))
        want = light[:, half] * gain[..., None] * balance
        bright = light[:, half] > 40  # away from 8-bit rounding's relative error
        assert np.abs(pixels[:, half][bright] - want[bright]).max() <= 1.0
    two = render_dual_frames(1, truth, frames=2, noise_std=0.0)
    assert np.array_equal(two[0], pixels) and not np.array_equal(two[1], two[0])  # the camera turned


def test_the_dual_demo_writes_frames_and_their_truth(tmp_path, capsys):
    assert cli.main(["demo", "--dual", "96", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert "rigjax calibrate" in printed and "configs/rig/dual_fisheye.yaml" in printed
    frames = [rigjax.read_image(tmp_path / f"frame{k}.png") for k in range(3)]
    assert all(frame.shape == (96, 192, 3) for frame in frames)
    truth = rigjax.load_project(tmp_path / "truth.pto")
    assert [im.filename for im in truth.images] == ["frame0-left.png", "frame0-right.png"]
    np.testing.assert_array_equal(rigjax.read_image(tmp_path / "frame0-right.png"), frames[0][:, 96:])


def test_three_frames_calibrate_with_the_dual_template_end_to_end(tmp_path):
    """The README's dual-fisheye example at half size: `rigjax calibrate` of three side-by-side frames
    with a near object in each seam (lenses 2-3 cm apart) and the shipped template (tracks, the
    bundle adjustment with the lenses' nominal centres, the lens's prior, the exposure fit). The
    frames are pooled unchecked (checks.frames_max_ray_deg null): calibrating each alone as well
    would double the test's time, and the check has its own (tests/rigjax/test_agreement.py)."""
    from rigjax import cli as rigjax_cli

    truth = draw_dual(1, size=720)
    paths = []
    for k, frame in enumerate(render_dual_frames(1, truth, frames=3)):
        paths.append(str(tmp_path / f"frame{k}.png"))
        rigjax.write_image(paths[-1], frame)
    out = tmp_path / "rig.pto"
    template = tmp_path / "dual_fisheye.yaml"
    text = Path("configs/rig/dual_fisheye.yaml").read_text()
    template.write_text(
        text.replace("max_turn_from_nominal_deg: 4.0}", "max_turn_from_nominal_deg: 4.0, frames_max_ray_deg: null}")
    )
    assert "frames_max_ray_deg: null" in template.read_text()
    assert rigjax_cli.main(["calibrate", *paths, "--template", str(template), "-o", str(out)]) == 0
    project = rigjax.load_project(out)
    assert [im.filename for im in project.images] == ["frame0-left.png", "frame0-right.png"]
    assert project.centres is not None and (tmp_path / "frame0-right.png").exists()
    # The relative orientation and the lens against the truth, in units of the standard deviations
    # the calibration writes (#-rigjax sd lines): within 3.
    hfov_sd, yaw_sd, pitch_sd, roll_sd = project.deviations[1, [0, 6, 7, 8]]
    turn_sd = np.sqrt(yaw_sd**2 + pitch_sd**2 + roll_sd**2)
    relative, got = truth.relative(), project.images[1]
    turn = _world(got.yaw, got.pitch, got.roll).T @ _world(relative.yaw[1], relative.pitch[1], relative.roll[1])
    error = np.degrees(np.arccos(np.clip((np.trace(turn) - 1.0) / 2.0, -1.0, 1.0)))
    assert error < 3 * turn_sd and turn_sd < 0.5
    assert abs(got.hfov - truth.cameras.hfov[0]) < 3 * hfov_sd
    assert got.exposure_value == pytest.approx(truth.exposure_value[1] - truth.exposure_value[0], abs=0.05)
