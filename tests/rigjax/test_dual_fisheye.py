"""Dual-fisheye calibration: two 191-degree circular fisheyes back to back in one side-by-side
image, overlapping in a ring 5.5 degrees either side of the seam, matched in the seam band: a scene
at infinity, with the rotation-only template (``dual_fisheye_far.yaml``). The shipped template on a
street with near objects in the seams: tests/learnstitch/test_dual_data.py."""

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

import rigjax
from rigjax import cli, synthetic
from rigjax.calibration.seam import band_from_world
from rigjax.camera.model import map_points

TEMPLATE = "configs/rig/dual_fisheye_far.yaml"


def dual_rig(size: int):
    """The template's lens is hfov 190, K2 -0.01; the true lens is 1 degree wider (K2 as nominal: the
    seam cannot tell it, see the template), and the lenses are turned by up to 2 degrees."""
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


@pytest.fixture(scope="module")
def dual():
    truth = dual_rig(1440)
    halves = synthetic.render_images(truth, synthetic.procedural_environment(4096, seed=0), noise_std=2.0, seed=0)
    return truth, np.concatenate(halves, axis=1)


def _correct(truth, pair, limit_arcmin=8.0):
    """How many of a pair's matches the true rig maps onto each other within ``limit_arcmin``
    (8 arcmin: one pixel at the seam, where the lenses have 434 px per radian)."""
    cameras = truth.cameras()
    ray_a, _ = map_points(rigjax.img_to_ray, cameras.take(pair.a), pair.xy_a)  # padded: one compile for all pairs
    ray_b, _ = map_points(rigjax.img_to_ray, cameras.take(pair.b), pair.xy_b)
    angle = np.degrees(np.arccos(np.clip(np.sum(ray_a * ray_b, -1), -1.0, 1.0))) * 60
    return int((angle < limit_arcmin).sum())


def test_band_frame_puts_the_seam_on_the_equator():
    rng = np.random.default_rng(0)
    for _ in range(5):
        a, b = (v / np.linalg.norm(v) for v in rng.normal(size=(2, 3)))
        rotation = band_from_world(a, b)
        np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(rotation) == pytest.approx(1.0)
        # Rays equally far from both axes have no component along the band's pole (latitude 0).
        rays = rng.normal(size=(50, 3))
        rays -= np.outer(rays @ (a - b), a - b) / np.dot(a - b, a - b)
        assert np.abs((rays @ rotation.T)[:, 1]).max() < 1e-12
    # Back to back, the pole is camera a's axis.
    np.testing.assert_allclose(band_from_world([0, 0, 1.0], [0, 0, -1.0])[1], [0, 0, 1.0])
    with pytest.raises(rigjax.RigjaxError, match="look the same way"):
        band_from_world([0, 0, 1.0], [0, 0, 1.0])


def test_seam_band_finds_more_correct_matches_than_the_fisheye_images(dual):
    truth, image = dual
    config = rigjax.load_template(TEMPLATE)
    halves, names = rigjax.split_side_by_side([image], config, ["dual.jpg"])
    assert names == ["dual-left.png", "dual-right.png"] and halves[0].shape == (1440, 1440, 3)
    band = rigjax.match_images(halves, config)[0]
    direct = rigjax.match_images(
        halves,
        rigjax.template_from_dict(
            {"rig": {"cameras": 2, "projection": 2, "hfov": 190.0, "b": -0.01, "side_by_side": True}}
        ),
    )[0]
    # Measured: 559 matches of which 518 correct in the band, 242 of which 183 in the images.
    assert _correct(truth, band) > 2 * _correct(truth, direct)
    assert _correct(truth, band) > 0.85 * len(band.xy_a)


def test_dual_fisheye_calibrates_from_one_side_by_side_image(dual, tmp_path, capsys):
    truth, image = dual
    rigjax.write_image(tmp_path / "dual.png", image)
    out = tmp_path / "rig.pto"
    code = cli.main(
        [
            "calibrate",
            str(tmp_path / "dual.png"),
            "--template",
            TEMPLATE,
            "-o",
            str(out),
            "--render",
            str(tmp_path / "pano.png"),
            "--width",
            "1024",
            "-q",
        ]
    )
    assert code == 0
    calibrated = rigjax.load_project(out)
    assert [im.filename for im in calibrated.images] == ["dual-left.png", "dual-right.png"]
    np.testing.assert_array_equal(rigjax.read_image(tmp_path / "dual-right.png"), image[:, 1440:])
    # Measured: 0.16 arcmin over the lenses, 0.17 in the overlap ring; hfov 190.999.
    assert synthetic.ray_errors_arcmin(calibrated, truth).max() < 1.0
    assert synthetic.ray_errors_arcmin(calibrated, truth, grid=240, off_axis_deg=(84.5, 95.5)).max() < 1.0
    assert calibrated.images[0].hfov == pytest.approx(191.0, abs=0.05)
    assert "pair      matches  inliers" in capsys.readouterr().out
    # The project opens with the halves written beside it.
    pano, covered = rigjax.render(calibrated, width=512)
    assert pano.shape == (256, 512, 3) and covered.all()


def test_side_by_side_input_errors_name_the_image(dual):
    _, image = dual
    config = rigjax.load_template(TEMPLATE)
    ring = rigjax.load_template("configs/rig/ring6.yaml")
    with pytest.raises(rigjax.CalibrationError, match=r"takes 6 image\(s\) per frame \(6 cameras\), but 4 images"):
        rigjax.calibrate([image] * 4, ring, names=["a.jpg", "b.jpg", "c.jpg", "d.jpg"])
    with pytest.raises(rigjax.CalibrationError, match=r"frame 2 \(b-left.png, b-right.png\): its images are"):
        rigjax.calibrate([image, image[:, 2:-2]], config, names=["a.jpg", "b.jpg"])
    with pytest.raises(rigjax.CalibrationError, match=r"odd.jpg: a side-by-side image needs an even width"):
        rigjax.split_side_by_side([image[:, :-1]], config, ["odd.jpg"])


def test_frames_of_a_video_pool_into_one_calibration(tmp_path, capsys):
    """rigjax calibrate clip.avi --every 2 --frames 2: a side-by-side video of the dual rig in a
    scene that turns by 25 degrees a frame; frames 0 and 2 are matched and calibrated as one."""
    import cv2

    truth = dual_rig(720)
    scene = synthetic.procedural_environment(4096, seed=0)
    clip = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(clip), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (1440, 720))
    for f in range(4):  # the scene turned about the vertical axis: its texture's columns rolled
        halves = synthetic.render_images(truth, np.roll(scene, f * 4096 * 25 // 360, axis=1), noise_std=2.0, seed=f)
        writer.write(cv2.cvtColor(np.concatenate(halves, axis=1), cv2.COLOR_RGB2BGR))
    writer.release()
    out = tmp_path / "rig.pto"
    args = ["calibrate", "--video", str(clip), "--every", "2", "--frames", "2", "--template", TEMPLATE, "-o", str(out)]
    assert cli.main([*args, "-q"]) == 0
    printed = capsys.readouterr().out
    matches = int(printed.split("\n")[1].split()[1])  # the pair's line: ' 0-1   matches  inliers'
    # The pooled matches are the two frames' own, each matched alone.
    config = rigjax.load_template(TEMPLATE)
    frames = rigjax.frames_of(rigjax.read_video_frames(clip, 2, 2), config, ["f0.png", "f2.png"])
    own = [len(rigjax.match_images(images, config, names=names)[0].xy_a) for images, names in frames]
    assert matches == sum(own) and min(own) > 0
    calibrated = rigjax.load_project(out)
    assert [im.filename for im in calibrated.images] == ["clip_0s-left.png", "clip_0s-right.png"]
    assert (tmp_path / "clip_0s-left.png").exists()
    assert synthetic.ray_errors_arcmin(calibrated, truth, grid=240, off_axis_deg=(84.5, 95.5)).max() < 2.0
    assert cli.main(["calibrate", "a.png", "--every", "3", "--template", TEMPLATE, "-o", str(out)]) == 2
    assert "--every reads frames of --video files" in capsys.readouterr().err


def test_pooled_matches_keep_each_pair_and_every_frames_points():
    from rigjax.calibration.pipeline import PairMatches, pool_matches

    first = [PairMatches(0, 1, np.zeros((3, 2)), np.ones((3, 2))), PairMatches(1, 2, np.zeros((1, 2)), np.ones((1, 2)))]
    second = [PairMatches(0, 1, np.full((2, 2), 5.0), np.full((2, 2), 6.0))]
    pooled = pool_matches([first, second])
    assert [(p.a, p.b, len(p.xy_a)) for p in pooled] == [(0, 1, 5), (1, 2, 1)]
    np.testing.assert_array_equal(pooled[0].xy_b[3:], np.full((2, 2), 6.0))


def test_seam_disagreement_grows_with_a_turned_lens_and_ignores_a_gain(dual):
    truth, image = dual
    halves = [image[:, :1440], image[:, 1440:]]
    right = rigjax.seam_disagreement(truth, halves, width=512)
    # Noise of 2 grey levels in each image: their difference's median |d| is at most 0.67 * 2 sqrt(2),
    # about 1.9 (the resampling smooths it).
    assert 0 < right.median < 3.0 and right.pixels > 1000
    turned = truth.replace(images=(truth.images[0], truth.images[1].replace(yaw=truth.images[1].yaw + 0.5)))
    wrong = rigjax.seam_disagreement(turned, halves, width=512)
    assert wrong.median > right.median and wrong.p90 > 2 * right.p90  # edges show a turn, flat areas little
    # Exposure-normalised, in image b's grey levels: a gain on image b scales the figure, nothing more.
    darker = [halves[0], np.round(halves[1] * 0.6).astype(np.uint8)]
    assert rigjax.seam_disagreement(truth, darker, width=512).median == pytest.approx(0.6 * right.median, rel=0.1)
    with pytest.raises(rigjax.RigjaxError, match="image 1: is 720x1440, but image 1 of the project is 1440x1440"):
        rigjax.seam_disagreement(truth, [halves[0], halves[1][:, :720]])
