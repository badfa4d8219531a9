"""The parts of ``rigjax calibrate``, each against an independent reference: closed-form rotations,
RANSAC on planted outliers, the spanning tree, Mantegna's constant, pruning of known wrong matches,
and rendering through the camera model against the environment it looked at."""

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

import rigjax
from rigjax import synthetic
from rigjax.calibration.initial import orientations_from_pairs
from rigjax.calibration.levy import mantegna_sigma_u, mantegna_steps
from rigjax.calibration.ransac import angle_between, ransac_rotation, ransac_turn, rotation_from_bearings
from rigjax.rendering.images import read_video_frame


def _random_rotations(rng, n):
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def test_ypr_from_world_from_cam_inverts_world_from_cam_including_straight_up_and_down():
    rng = np.random.default_rng(0)
    ypr = np.column_stack([rng.uniform(-180, 180, 200), rng.uniform(-89, 89, 200), rng.uniform(-180, 180, 200)])
    back = np.asarray(rigjax.ypr_from_world_from_cam(rigjax.world_from_cam(*ypr.T)))
    np.testing.assert_allclose(back, ypr, atol=1e-9)
    for pitch in (90.0, -90.0):  # only the rotation is defined there: compare matrices
        m = np.asarray(rigjax.world_from_cam(37.0, pitch, 12.0))
        again = np.asarray(rigjax.world_from_cam(*np.asarray(rigjax.ypr_from_world_from_cam(m))))
        np.testing.assert_allclose(again, m, atol=1e-12)


def test_rotation_from_bearings_recovers_a_rotation_and_ransac_rejects_planted_outliers():
    rng = np.random.default_rng(1)
    truth = _random_rotations(rng, 1)[0]
    u_a = rng.normal(size=(300, 3))
    u_a /= np.linalg.norm(u_a, axis=1, keepdims=True)
    u_b = u_a @ truth.T
    np.testing.assert_allclose(rotation_from_bearings(u_a[:2], u_b[:2]), truth, atol=1e-12)  # minimal sample
    wrong = rng.random(300) < 0.5
    u_b[wrong] = rng.normal(size=(wrong.sum(), 3))
    u_b /= np.linalg.norm(u_b, axis=1, keepdims=True)
    u_b[~wrong] = (u_a[~wrong] + rng.normal(scale=1e-3, size=((~wrong).sum(), 3))) @ truth.T  # ~0.06 deg noise
    u_b /= np.linalg.norm(u_b, axis=1, keepdims=True)
    fit = ransac_rotation(u_a, u_b, threshold_deg=0.5, seed=0)
    # A random bearing lands within 0.5 degrees of its prediction with probability ~2e-5.
    np.testing.assert_array_equal(fit.inliers, ~wrong)
    assert np.degrees(angle_between(fit.b_from_a @ [0.0, 0.0, 1.0], truth @ [0.0, 0.0, 1.0])) < 0.02
    assert fit.iterations < 1000  # the adaptive stop: 50 % inliers need ~25 samples at 99.9 %


def _moved_views(rng, truth, travel, n=400):
    """Bearings of ``n`` scene points 0.5-5 m away from a camera at the origin, and from the camera
    turned by ``truth`` (``b_from_a``) after moving ``travel`` metres (in view a's frame)."""
    u = rng.normal(size=(n, 3))
    points = u / np.linalg.norm(u, axis=1, keepdims=True) * rng.uniform(0.5, 5.0, (n, 1))
    u_a = points / np.linalg.norm(points, axis=1, keepdims=True)
    in_b = (points - travel) @ truth.T
    return u_a, in_b / np.linalg.norm(in_b, axis=1, keepdims=True)


def test_the_turn_of_a_camera_that_moved_among_near_points_is_exact_and_outliers_are_left_out():
    """ransac_turn against the rotation the bearings were made with: a camera that walked 20 cm
    among points from half a metre away (a rotation alone is degrees off there), a fifth of the
    matches wrong; and a camera that only turned, where every baseline fits the matches."""
    rng = np.random.default_rng(4)
    truth = _random_rotations(rng, 1)[0]
    u_a, u_b = _moved_views(rng, truth, travel=np.array([0.12, -0.05, 0.15]))
    wrong = rng.random(len(u_a)) < 0.2
    u_b[wrong] = rng.normal(size=(wrong.sum(), 3))
    u_b /= np.linalg.norm(u_b, axis=1, keepdims=True)
    alone = ransac_rotation(u_a, u_b, threshold_deg=0.5, seed=0)
    off = lambda r: np.degrees(np.linalg.norm(r - truth) / np.sqrt(2))  # noqa: E731  the angle, to first order
    assert off(alone.b_from_a) > 0.5
    fit = ransac_turn(u_a, u_b, threshold_deg=0.5, seed=0)
    assert off(fit.b_from_a) < 1e-6
    assert fit.inliers[~wrong].all() and fit.inliers[wrong].mean() < 0.05  # a random bearing near its plane: ~1 %
    u_a, u_b = _moved_views(rng, truth, travel=np.zeros(3))
    still = ransac_turn(u_a, u_b, threshold_deg=0.5, seed=1)
    assert off(still.b_from_a) < 1e-9 and still.inliers.all()


def test_orientations_from_pairs_chain_exact_rotations_and_name_unconnected_images():
    cameras = synthetic.ring_rig(orientation_jitter_deg=5, seed=3).cameras()
    truth = np.asarray(rigjax.world_from_cam(cameras.yaw, cameras.pitch, cameras.roll))
    pairs = {(a, (a + 1) % 6): (truth[(a + 1) % 6].T @ truth[a], 100 + a) for a in range(6)}
    world, edges = orientations_from_pairs(6, pairs, anchor=2, anchor_world_from_cam=truth[2])
    np.testing.assert_allclose(world, truth, atol=1e-12)
    assert edges[0] == (2, 3)  # the anchor's strongest pair joins first (pair 2-3 has 102 inliers, 1-2 101)
    with pytest.raises(rigjax.RigjaxError, match=r"images \[4, 5\] share no matched pair"):
        orientations_from_pairs(6, {k: v for k, v in pairs.items() if k[0] < 3}, anchor=0)


def test_mantegna_steps_use_the_published_scale_and_have_the_tail_of_index_beta():
    # sigma_u = 0.6966 for beta = 1.5, the constant of Yang & Deb's cuckoo search.
    assert abs(mantegna_sigma_u(1.5) - 0.6966) < 1e-4
    # A Lévy tail of index beta: P(|x| > 10 t) / P(|x| > t) -> 10^-beta (0.0316 for 1.5, 0.1 for a
    # Cauchy, ~0 for a Gaussian). Measured 0.032-0.034 on three seeds of 10^6 steps.
    steps = np.abs(mantegna_steps(np.random.default_rng(0), (1_000_000,), 1.5))
    ratio = np.mean(steps > 100) / np.mean(steps > 10)
    assert 0.025 < ratio < 0.04


def test_pruning_removes_every_planted_wrong_match_and_reaches_the_noise_floor(tmp_path):
    # 30 % of the points wrong (second end at a random pixel); the first solve must be robust: on such
    # a project least squares put one hfov 39 degrees off (measured), and no ranking recovered.
    rig = synthetic.cube_rig(orientation_jitter_deg=3, seed=1)
    truth = synthetic.control_points_from_truth(rig, 4000, noise_px=0.3, outlier_fraction=0.3, seed=2)
    clean = synthetic.control_points_from_truth(rig, 4000, noise_px=0.3, seed=2)
    wrong = np.any(truth.control_points.xy_b != clean.control_points.xy_b, axis=1)  # the planted ones
    assert 0.25 < wrong.mean() < 0.35
    start = synthetic.perturb(truth, angle_deg=(1.0, 3.0), hfov_offset_deg=(2.0, 3.0), b=0.0, seed=3)
    pruned = rigjax.optimise_pruned(start, "YPR,VBYPR")
    assert not np.any(pruned.kept & wrong), "a wrong match survived"
    # Good points removed in early rounds, while the cameras were still off, come back at the end:
    # exactly the good points are kept (the first rounds removed 23 of them, measured).
    assert pruned.readmitted.size > 0 and not np.any(wrong[pruned.readmitted])
    np.testing.assert_array_equal(pruned.kept, ~wrong)
    without = rigjax.optimise_pruned(start, rigjax.OptimiseConfig(prune=rigjax.PruneConfig(readmit=False)))
    assert without.readmitted.size == 0
    assert sorted(without.removed) == sorted(np.concatenate([pruned.removed, pruned.readmitted]))
    floor = rigjax.evaluate(truth, weights=pruned.kept.astype(float)).rms  # the truth on the same points
    assert pruned.result.rms <= floor * 1.001
    assert np.max(synthetic.ray_errors_arcmin(pruned.result.project, truth)) < 1.0
    # Every removed point is in the written project, as a comment Hugin ignores and rigjax keeps.
    path = tmp_path / "pruned.pto"
    pruned.project.save(path)
    again = rigjax.load_project(path)
    assert len(again.control_points) == pruned.kept.sum()
    comments = [line for line in path.read_text().splitlines() if line.startswith("#-rigjax pruned")]
    assert len(comments) == len(pruned.removed) == (~pruned.kept).sum()
    again.save(tmp_path / "again.pto")
    assert (tmp_path / "again.pto").read_text() == path.read_text()


def test_pruning_leaves_a_clean_project_alone():
    truth = synthetic.control_points_from_truth(synthetic.cube_rig(seed=1), 600, noise_px=0.5, seed=5)
    pruned = rigjax.optimise_pruned(synthetic.perturb(truth, seed=6), "YPR,VBYPR")
    assert pruned.kept.all() and len(pruned.removed) == 0
    assert len(pruned.rounds) == 2  # the robust solve, nothing a candidate, the least-squares solve
    plain = rigjax.optimise(synthetic.perturb(truth, seed=6), "YPR,VBYPR")  # ... at least squares' optimum
    np.testing.assert_allclose(pruned.result.rms, plain.rms, rtol=1e-6)


@pytest.fixture(scope="module")
def environment():
    return synthetic.procedural_environment(2048, seed=0)


def test_images_rendered_from_the_environment_render_back_to_it(environment):
    """Environment -> fisheye images (through the camera model) -> panorama: the panorama is the
    environment again, up to two resamplings; a 1-degree error in one camera's yaw shows."""
    import cv2

    rig = synthetic.ring_rig(4, width=480, height=360, hfov=150.0, b=-0.01, pano_width=1024, seed=0)
    images = synthetic.render_images(rig, environment)
    reference = cv2.resize(environment, (1024, 512), interpolation=cv2.INTER_AREA).astype(float)

    def psnr(project, blend):
        pano, covered = rigjax.render(project, images, blend=blend)
        band = covered.copy()
        band[:160], band[-160:] = False, False  # the ring sees +-50 degrees of latitude fully
        return 10 * np.log10(255**2 / np.mean((pano.astype(float) - reference)[band] ** 2))

    # Measured 32.2 (multiband), 33.8 (feather), 33.1 dB (none): the environment's 1-px detail
    # through two bilinear resamplings; one camera turned by 1 degree: 26.1 dB.
    for blend in ("multiband", "feather", "none"):
        assert psnr(rig, blend) > 30.0, blend
    turned = rig.replace(images=(rig.images[0].replace(yaw=rig.images[0].yaw + 1.0),) + rig.images[1:])
    assert psnr(turned, "none") < psnr(rig, "none") - 2.0


@pytest.mark.parametrize("blend", ["multiband", "feather"])
def test_a_360_degree_panorama_is_blended_across_its_edges(environment, blend):
    """A full-circle canvas has no edge: turning every camera by 180 degrees of yaw shifts the
    panorama by half its width and changes nothing else, also where a seam lies at +-180 degrees.
    One image is darkened so that the seam there is a step the blenders must spread."""
    rig = synthetic.ring_rig(4, width=240, height=180, hfov=150.0, pano_width=512, seed=0)
    images = synthetic.render_images(rig, environment)
    images[1] = (images[1] * 0.6).astype(np.uint8)

    def turned(degrees):  # cameras at 45, 135, -135, -45 degrees: the seam of 1 and 2 at +-180
        return rig.replace(images=tuple(image.replace(yaw=image.yaw + degrees) for image in rig.images))

    pano, covered = rigjax.render(turned(45.0), images, blend=blend)
    shifted, shifted_covered = rigjax.render(turned(45.0 + 180.0), images, blend=blend)
    shifted, shifted_covered = np.roll(shifted, 256, axis=1), np.roll(shifted_covered, 256, axis=1)
    np.testing.assert_array_equal(covered, shifted_covered)
    difference = np.abs(pano.astype(int) - shifted.astype(int))[covered]
    assert difference.max() <= 2, difference.max()  # resampling round-off only
    # The seam at the edges is blended: no step between the last column and the first.
    edge = np.abs(pano[:, -1].astype(int) - pano[:, 0].astype(int))[covered[:, 0] & covered[:, -1]].mean()
    inside = np.abs(pano[:, 255].astype(int) - pano[:, 256].astype(int))[covered[:, 255] & covered[:, 256]].mean()
    assert edge < 2.0 * inside, (edge, inside)


def test_render_refuses_images_that_do_not_fit(environment):
    rig = synthetic.ring_rig(4, width=120, height=90, pano_width=256)
    images = synthetic.render_images(rig, environment)
    with pytest.raises(rigjax.ImageError, match=r"the project has 4 images, 3 were given"):
        rigjax.render(rig, images[:3])
    with pytest.raises(rigjax.ImageError, match=r"b.png: is 90x120, but image 1 of the project is 120x90"):
        rigjax.render(
            rig, [images[0], images[1].transpose(1, 0, 2).copy()] + images[2:], names=[f"{c}.png" for c in "abcd"]
        )


@pytest.mark.parametrize(
    "change, message",
    [
        ({"rig": {"cameras": 6, "hfov": 120.0, "lens": 3}}, r"rig: unknown key 'lens'"),
        ({"rig": {"cameras": 2, "orientations": [[0, 0, 0]]}}, r"rig: orientations: 1 orientations for 2 cameras"),
        ({"rig": {"cameras": 2, "overlaps": [[0, 2]]}}, r"rig: overlaps: pair \[0, 2\] is not two different cameras"),
        (
            {"rig": {"cameras": 2, "orientations": [[0, 0], [1, 2]]}},
            r"rig.orientations\[0\]: expected a list of 3 values, got \[0, 0\]",
        ),
        ({"rig": {"cameras": 2}, "ransac": {"min_inliers": 1}}, r"min_inliers >= 2"),
        ({"rig": {"cameras": 2}, "features": {"detector": "surf"}}, r"features: detector must be one of sift, orb"),
        ({"rig": {"cameras": 2}, "levy": {"beta": 3.0}}, r"levy beta must be in \(0, 2\]"),
        ({"cameras": 2}, r"unknown key 'cameras'"),
        ({"rig": {"cameras": 3, "side_by_side": True}}, r"two cameras, so cameras must be even, got 3"),
        (
            {"rig": {"cameras": 2}, "features": {"seam_band_deg": 8}},
            r"seam_band_deg: .* rig.orientations must be given",
        ),
        ({"rig": {"cameras": 2, "orientations": [[0, 0, 0]] * 2}, "features": {"seam_band_deg": 95}}, r"in \(0, 90\)"),
        ({"rig": {"cameras": 2, "centres": [[0, 0, 0]]}}, r"rig: centres: 1 centres for 2 cameras"),
        ({"rig": {"cameras": 2}, "features": {"retrack": 1}}, r"retrack: expected passes \(>= 0\) of tracking"),
        (
            {"rig": {"cameras": 2}, "optimise": {"objective": "reprojection"}},
            r"needs the cameras' centres: give rig.centres",
        ),
    ],
)
def test_template_errors_name_the_file_and_key(change, message):
    with pytest.raises(rigjax.ConfigError, match=r"^t.yaml: .*" + message):
        rigjax.template_from_dict(change, "t.yaml")


def test_shipped_templates_load():
    for name in ("ring6", "cube6"):
        config = rigjax.load_template(f"configs/rig/{name}.yaml")
        assert config.rig.cameras == 6 and config.rig.projection == 3
    for name in ("dual_fisheye", "dual_fisheye_far"):
        dual = rigjax.load_template(f"configs/rig/{name}.yaml")
        assert dual.rig.side_by_side and dual.rig.cameras == 2 and dual.features.seam_band_deg == 8.0
    assert dual.rig.centres is None and dual.optimise.objective == "transfer"  # the far one: rotation-only
    dual = rigjax.load_template("configs/rig/dual_fisheye.yaml")
    assert np.ptp(np.asarray(dual.rig.centres)[:, 2]) == pytest.approx(0.025)  # the lenses 2.5 cm apart
    assert dual.optimise.objective == "reprojection" and dual.optimise.priors.v == 1.0
    assert rigjax.load_template("configs/rig/ring6.yaml").rig.orientations[3] == (180.0, 0.0, 0.0)


def test_read_video_frame_returns_the_frame_on_screen_and_names_the_file(tmp_path):
    import cv2

    path = str(tmp_path / "cam0.avi")
    writer = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 48))
    for k in range(10):  # frame k is grey level 25 k, on screen from k/10 s
        writer.write(np.full((48, 64, 3), 25 * k, np.uint8))
    writer.release()
    for seconds, frame in ((0.0, 0), (0.55, 5), (0.95, 9)):
        assert abs(read_video_frame(path, seconds).mean() - 25 * frame) < 3, seconds
    with pytest.raises(rigjax.ImageError, match=r"cam0.avi: no frame at 1.5 s \(the video is 1.000 s long\)"):
        read_video_frame(path, 1.5)
    with pytest.raises(rigjax.ImageError, match=r"missing.avi: no such video file"):
        read_video_frame(tmp_path / "missing.avi", 0.0)


def test_ransac_with_the_baseline_keeps_near_points_that_no_rotation_explains():
    """Two cameras 0.4 m apart looking the same way, points 1-50 m away, a fifth of the matches
    wrong: the rotation test (1 degree) drops the near points (parallax over 3 degrees) with the
    wrong ones; the epipolar test keeps every good match and drops the wrong ones."""
    rng = np.random.default_rng(0)
    centre_b = np.array([0.4, 0.0, 0.0])  # camera b's centre in camera a's frame (both unturned)
    direction = rng.normal(size=(300, 3)) * [1.0, 0.5, 0.0] + [0.0, 0.0, 2.0]
    points = direction / np.linalg.norm(direction, axis=1, keepdims=True)
    points *= np.exp(rng.uniform(0.0, np.log(50.0), (300, 1)))
    u_a = points / np.linalg.norm(points, axis=1, keepdims=True)
    u_b = (points - centre_b) / np.linalg.norm(points - centre_b, axis=1, keepdims=True)
    wrong = rng.random(300) < 0.2
    u_b[wrong] = rng.normal(size=(int(wrong.sum()), 3))
    u_b[wrong] /= np.linalg.norm(u_b[wrong], axis=1, keepdims=True)
    parallax = np.degrees(np.arccos(np.clip(np.sum(u_a * u_b, axis=1), -1, 1)))
    near = ~wrong & (parallax > 3.0)
    assert near.sum() > 30
    rotation = ransac_rotation(u_a, u_b, threshold_deg=1.0, seed=0)
    assert rotation.inliers[near].mean() < 0.1 and rotation.inliers[~wrong].mean() < 0.9
    epipolar = ransac_rotation(u_a, u_b, threshold_deg=1.0, seed=0, baseline=centre_b)
    assert epipolar.inliers[~wrong].all()
    assert epipolar.inliers[wrong].mean() < 0.05  # a wrong match near its epipolar plane passes
    np.testing.assert_allclose(epipolar.b_from_a, np.eye(3), atol=0.02)
