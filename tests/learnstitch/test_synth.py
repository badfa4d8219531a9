"""learnstitch's synthetic triplets: geometry against rigjax and Hugin, parallax, determinism, bad config."""

import dataclasses
import subprocess

import jax
import jax.numpy as jnp
import kornia
import numpy as np
import pytest
import torch

import rigjax
from learnstitch.baselines import (
    align_rig,
    calibrated_stitch,
    orientation_errors_deg,
    orientation_turns_deg,
    psnr,
    rig_template,
    rotation_only_stitch,
    stitch_with_cameras,
)
from learnstitch.config import config_from_dict, load_config
from learnstitch.data import scene as _scene
from learnstitch.data import textures as _textures
from learnstitch.data.rig import fisheye_rays, nominal_cameras, sample_rig
from learnstitch.data.sample import SynthConfig, make_sample
from learnstitch.data.scene import render, sample_scene
from rigjax.errors import ConfigError

# No photometric differences between cameras: what remains is geometry.
GEOMETRY = dict(gain_jitter=0.0, vignetting=0.0, noise_std=0.0)


def _blur(image):
    return kornia.filters.gaussian_blur2d(image[None], (9, 9), (1.5, 1.5))[0]


def test_with_the_cameras_at_the_centre_rotation_only_stitching_is_the_ground_truth():
    # Fisheyes at 4x the panorama's angular resolution, so that bilinear resampling loses little.
    config = SynthConfig(fisheye_size=384, pano_width=192, distance=0.0, **GEOMETRY)
    sample = make_sample(config, 7)
    pano, covered = rotation_only_stitch(sample.fisheyes, sample.rig, config)
    inner = kornia.morphology.erosion(covered[None, None].float(), torch.ones(5, 5))[0, 0] > 0
    assert inner.float().mean() > 0.95  # three 185-degree lenses see nearly everything
    # Textures carry detail at the pixel scale, which one bilinear resampling cannot keep (29-33 dB
    # raw). A Gaussian low-pass (sigma 1.5 px) removes most of that aliasing: measured 40.1, 41.8
    # and 43.8 dB with fisheyes at 1, 2 and 4x the panorama's angular resolution (seed 7, 192 px
    # wide) -- rising with it, so what is left is resampling, not geometry. The smallest error
    # worth catching, the panorama one pixel off, gives 33.7-34.4 dB.
    aligned = psnr(_blur(pano), _blur(sample.pano), inner)
    shifted = psnr(_blur(pano), _blur(torch.roll(sample.pano, 1, dims=-1)), inner)
    assert aligned > 40.0
    assert shifted < 35.0


def test_aligning_a_calibrated_rig_removes_one_rotation_of_the_whole_rig_and_nothing_else():
    truth = sample_rig(np.random.default_rng(4), 64, 185.0, 0.2, 2.0, 1.0).cameras
    R = np.asarray(rigjax.world_from_cam(truth.yaw, truth.pitch, truth.roll), np.float64)
    turn = np.asarray(rigjax.world_from_cam(25.0, -8.0, 4.0), np.float64)  # the rig turned as a whole

    def cameras(world_from_cam):
        yaw, pitch, roll = np.asarray(rigjax.ypr_from_world_from_cam(world_from_cam), np.float64).T
        return truth._replace(yaw=yaw, pitch=pitch, roll=roll)

    turned = cameras(turn @ R)
    assert orientation_errors_deg(turned, truth).min() > 20.0
    assert orientation_errors_deg(align_rig(turned, truth), truth).max() < 1e-6
    # One camera also off by 1.5 degrees: what is left after alignment is that error, spread over
    # the rig (the rotation that minimises the squared chordal distances): one camera's 1.5 degrees
    # becomes 1.0 on it and 0.5 on each of the others, whatever the whole rig's turn.
    tilt = np.asarray(rigjax.world_from_cam(0.0, 1.5, 0.0), np.float64)
    off = turn @ R
    off[1] = off[1] @ tilt
    errors = orientation_errors_deg(align_rig(cameras(off), truth), truth)
    np.testing.assert_allclose(errors, [0.5, 1.0, 0.5], atol=2e-3)
    # The same errors as turns about the world's axes: their lengths, all about one axis (camera 1's pitch).
    turns = orientation_turns_deg(align_rig(cameras(off), truth), truth)
    np.testing.assert_allclose(np.linalg.norm(turns, axis=1), errors, rtol=1e-4)
    np.testing.assert_allclose(
        np.abs(turns @ turns[1]) / np.linalg.norm(turns, axis=1) / np.linalg.norm(turns[1]), 1.0, atol=1e-6
    )


def test_calibrated_stitching_recovers_the_rig_from_its_images_without_parallax():
    """With the cameras at the centre, rigjax calibrates the jittered rig from the three fisheyes
    (configs/rig/tri_fisheye.yaml) and its stitch is as good as one with the true cameras."""
    config = SynthConfig(fisheye_size=256, pano_width=512, distance=0.0, **GEOMETRY)
    sample = make_sample(config, 1_000_000_000)
    truth = sample.rig.cameras
    result = calibrated_stitch(
        sample.fisheyes, config, rigjax.load_template("configs/rig/tri_fisheye.yaml"), reference=truth
    )
    assert result.failure is None
    nominal = align_rig(nominal_cameras(config.fisheye_size, config.hfov), truth)
    # Measured, points tracked through the seam bands: 0.02-0.04 degrees (nominal rig: 1.6-2.3), hfov
    # within 0.04 with the 1-degree hfov prior, 0.03 without (the jitter is +-1); with SIFT features
    # and no prior it was 0.08-0.19 and 0.01-0.62.
    assert (
        orientation_errors_deg(result.cameras, truth).max() < 0.2 < 1.5 < orientation_errors_deg(nominal, truth).min()
    )
    assert np.abs(np.asarray(result.cameras.hfov) - truth.hfov).max() < 0.3
    # The data's nominal centres (all at the middle here) went to the bundle adjustment, whose points
    # come back: at infinity, without a baseline to place them.
    np.testing.assert_array_equal(result.centres, np.zeros((3, 3)))
    assert len(result.points) > 300 and np.isinf(result.points).all()
    true_psnr = psnr(rotation_only_stitch(sample.fisheyes, sample.rig, config)[0], sample.pano)
    nominal_psnr = psnr(stitch_with_cameras(sample.fisheyes, nominal, config)[0], sample.pano)
    # Measured: 27.57 dB calibrated (27.06 with SIFT features), 27.58 true, 21.52 nominal.
    assert true_psnr - 1.0 < psnr(result.pano, sample.pano) and nominal_psnr + 3.0 < true_psnr


def test_the_calibrated_baseline_gives_a_template_without_centres_the_datas_rig():
    template = rigjax.load_template("configs/rig/tri_fisheye.yaml")
    assert template.rig.centres is None and template.optimise.objective == "transfer"
    config = SynthConfig(fisheye_size=64, pano_width=128, distance=0.4, **GEOMETRY)
    rig = rig_template(template, config)
    assert rig.optimise.objective == "reprojection"
    # the lenses' and the mounting's stated tolerances
    angle = config.angle_jitter_deg
    assert rig.optimise.priors.as_dict() == {"V": config.hfov_jitter_deg, "Y": angle, "P": angle, "R": angle}
    # 0.4 m out along each nominal axis (yaw 0, 120, -120; x right, z forward)
    np.testing.assert_allclose(
        rig.rig.centres,
        [[0, 0, 0.4], [0.4 * np.sin(np.radians(120)), 0, -0.2], [-0.4 * np.sin(np.radians(120)), 0, -0.2]],
        atol=1e-12,
    )
    own = dataclasses.replace(template, rig=dataclasses.replace(template.rig, centres=((0, 0, 1.0),) * 3))
    assert rig_template(own, config) is own  # a template's own centres (and objective) stay


def test_a_point_at_infinity_appears_at_one_panorama_pixel_from_every_camera():
    config = SynthConfig(fisheye_size=96, pano_width=192, distance=0.4, **GEOMETRY)
    sample = make_sample(config, 3)
    scene, cameras = sample_scene(3), sample.rig.cameras
    canvas = rigjax.Equirect.create(config.pano_width, config.pano_height)
    rays, inside, theta = fisheye_rays(cameras, config.circle_deg)
    jcams = jax.tree_util.tree_map(jnp.asarray, cameras)
    checked = 0
    for k in range(3):
        # Sky pixels of camera k: nothing in the way from its centre nor from the panorama's.
        ys, xs = np.nonzero(inside[k] & (theta[k] < config.circle_deg / 2 - 3.0) & (rays[k, ..., 1] < -0.3))  # up
        pick = np.random.default_rng(k).choice(len(ys), 400, replace=False)
        ys, xs = ys[pick], xs[pick]
        directions = torch.as_tensor(rays[k, ys, xs], dtype=torch.float32)
        _, from_camera = render(scene, torch.as_tensor(sample.rig.centres[k], dtype=torch.float32), directions)
        colour, from_centre = render(scene, torch.zeros(3), directions)
        sky = (torch.isinf(from_camera) & torch.isinf(from_centre)).numpy()
        assert sky.sum() > 50
        # The fisheye shows there what the panorama's renderer shows in that direction...
        image = sample.fisheyes[k][:, ys[sky], xs[sky]].T
        np.testing.assert_allclose(image.numpy(), colour[sky].numpy(), atol=1e-5)
        # ...and every camera that sees it puts it at the same panorama pixel.
        xy = np.stack([xs[sky], ys[sky]], -1).astype(float)
        n = len(xy)
        pano_xy, _ = rigjax.transform_points(jcams, canvas, np.full(n, k), xy, reverse=False)
        for j in range(3):
            xy_j, valid = rigjax.transform_points(jcams, canvas, np.full(n, j), pano_xy, reverse=True)
            centre = config.fisheye_size / 2 - 0.5
            seen = valid & (np.hypot(*(xy_j - centre).T) < config.fisheye_size / 2)
            back, _ = rigjax.transform_points(jcams, canvas, np.full(int(seen.sum()), j), xy_j[seen], reverse=False)
            np.testing.assert_allclose(back, pano_xy[seen], atol=1e-6)
            checked += int(seen.sum()) if j != k else 0
    assert checked > 50  # points seen by two cameras


def _written_project(tmp_path, n=300):
    """A sample's ``rig.pto`` saved to disk, random pixels inside the image circles ``(image,
    integer xy)``, and the panorama pixels of the rays the renderer cast through them."""
    config = SynthConfig(fisheye_size=64, pano_width=128, distance=0.3)
    sample = make_sample(config, 5)
    path = tmp_path / "rig.pto"
    sample.rig.project((config.pano_width, config.pano_height), ("f0.png", "f1.png", "f2.png")).save(path)
    rng = np.random.default_rng(1)
    image = rng.integers(0, 3, n)
    px = np.floor(rng.uniform(0.2, 0.8, (n, 2)) * config.fisheye_size).astype(int)
    rays, _, _ = fisheye_rays(sample.rig.cameras, config.circle_deg)  # what the renderer cast
    canvas = rigjax.Equirect.create(config.pano_width, config.pano_height)
    return path, image, px, np.asarray(rigjax.ray_to_pano(canvas, jnp.asarray(rays[image, px[:, 1], px[:, 0]])))


def test_the_samples_project_maps_pixels_where_the_renderer_cast_them(tmp_path):
    path, image, px, expected = _written_project(tmp_path)
    project = rigjax.load_project(path)
    got, valid = rigjax.transform_points(project.cameras(), project.canvas(), image, px.astype(float), reverse=False)
    assert np.all(valid)
    np.testing.assert_allclose(got, expected, atol=1e-6)


def test_the_samples_project_opens_in_hugin_with_the_same_geometry(tmp_path, hugin_tools):
    path, image, px, expected = _written_project(tmp_path)
    text = "".join(f"{k} {x} {y}\n" for k, (x, y) in zip(image, px))
    out = subprocess.run(["pano_trafo", str(path)], input=text, capture_output=True, text=True, check=True).stdout
    hugin = np.array([[float(v) for v in line.split()] for line in out.strip().split("\n")])
    np.testing.assert_allclose(hugin, expected, atol=1e-3)  # pano_trafo prints 6 decimals, stops Newton at 1e-6


def test_parallax_lowers_the_rotation_only_psnr_as_the_cameras_move_out():
    means = []
    for distance in (0.0, 0.2, 0.4):
        config = SynthConfig(fisheye_size=96, pano_width=192, distance=distance, **GEOMETRY)
        values = []
        for seed in (11, 12):
            sample = make_sample(config, seed)
            pano, covered = rotation_only_stitch(sample.fisheyes, sample.rig, config)
            values.append(float(psnr(pano, sample.pano, covered)))
        means.append(np.mean(values))
    assert means[0] > means[1] + 0.5 > means[2] + 1.0, means


def test_gain_and_vignetting_strengths_are_drawn_per_sample_down_to_none():
    """Against the same sample rendered clean (no noise either): each camera's gain (at its axis,
    where there is no vignetting) is within 1 +- gain_jitter, the brightness lost at the circle's
    edge within [0, vignetting], and across samples both reach near zero and near their bound."""
    configured = SynthConfig(fisheye_size=64, pano_width=64, gain_jitter=0.2, vignetting=0.4, noise_std=0.0)
    clean = dataclasses.replace(configured, gain_jitter=0.0, vignetting=0.0)
    gains, losses = [], []
    for seed in range(24):
        a, b = make_sample(configured, seed).fisheyes, make_sample(clean, seed).fisheyes
        centre = (slice(30, 34), slice(30, 34))  # around the optical axis (pixel 31.5)
        ratio = a[:, :, centre[0], centre[1]].sum(dim=(1, 2, 3)) / b[:, :, centre[0], centre[1]].sum(dim=(1, 2, 3))
        gains.append((ratio - 1.0).abs().max().item())
        # Near the circle's edge (theta ~ 90 degrees of 92.5): falloff 1 - v (90 / 92.5)^2, times the gain.
        edge = (slice(30, 34), slice(1, 3))
        falloff = a[:, :, edge[0], edge[1]].sum(dim=(1, 2, 3)) / b[:, :, edge[0], edge[1]].sum(dim=(1, 2, 3)) / ratio
        losses.append(((1.0 - falloff) / (90.0 / 92.5) ** 2).mean().item())
    assert max(gains) <= 0.2 + 1e-3 and min(gains) < 0.03 and max(gains) > 0.12
    assert -0.03 < min(losses) < 0.05 and 0.3 < max(losses) <= 0.4 + 0.03


def test_the_same_seed_gives_the_same_sample_and_another_seed_another():
    config = SynthConfig(fisheye_size=48, pano_width=96, distance=0.2)
    a, b, c = make_sample(config, 21), make_sample(config, 21), make_sample(config, 22)
    assert torch.equal(a.fisheyes, b.fisheyes) and torch.equal(a.pano, b.pano) and torch.equal(a.depth, b.depth)
    assert np.array_equal(a.rig.cameras.yaw, b.rig.cameras.yaw)
    assert (a.fisheyes - c.fisheyes).abs().mean() > 0.02 and (a.pano - c.pano).abs().mean() > 0.02
    assert not np.array_equal(a.rig.cameras.yaw, c.rig.cameras.yaw)


def test_rendering_does_not_depend_on_the_chunk_size_nor_the_threads():
    scene = sample_scene(4)
    rng = np.random.default_rng(2)
    directions = torch.as_tensor(rng.standard_normal((5000, 3)), dtype=torch.float32)
    a = render(scene, torch.zeros(3), directions, chunk=1 << 15)
    b = render(scene, torch.zeros(3), directions, chunk=777)
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        c = render(scene, torch.zeros(3), directions)
    finally:
        torch.set_num_threads(threads)
    assert torch.equal(a[0], c[0]) and torch.equal(a[1], c[1])


def _closest_hit_dense(scene, o, d):
    """Reference for the culled tracer: every ray against every primitive, the first minimum of
    [ground, boxes, cylinders, spheres]."""
    t_ground = torch.where(
        d[:, 1] > 1e-9,
        (scene.camera_height - o[:, 1]) / d[:, 1].clamp_min(1e-9),
        torch.full_like(d[:, 1], float("inf")),
    )
    t_box, axis = _scene._boxes(o, d, scene.box_min, scene.box_max)
    t_cyl, cap = _scene._cylinders(o, d, scene.cyl_centre, scene.cyl_radius, scene.cyl_top, scene.cyl_bottom)
    t_sph = _scene._spheres(o, d, scene.sph_centre, scene.sph_radius)
    depth, first = torch.cat([t_ground[:, None], t_box, t_cyl, t_sph], dim=1).min(dim=1)
    faces = torch.cat(
        [torch.zeros_like(first)[:, None], axis, cap.long(), torch.zeros_like(t_sph, dtype=torch.int64)], dim=1
    )
    return depth, first - 1, faces.gather(1, first[:, None])[:, 0]  # the ground: column -1


@pytest.mark.parametrize("seed", [3, 8, 13])
def test_culled_tracing_finds_the_same_hits_as_testing_every_primitive(seed):
    scene = sample_scene(seed)
    rng = np.random.default_rng(seed)
    # Rays from the centre, from a camera position and from scattered origins (the culling
    # bounds a block's origins), in counts that leave a partial last block.
    d = torch.as_tensor(rng.standard_normal((30011, 3)), dtype=torch.float32)
    d = d / torch.sqrt((d * d).sum(-1, keepdim=True))
    origins = [
        torch.zeros(3),
        torch.tensor([0.35, 0.0, -0.2]),
        torch.as_tensor(rng.uniform(-0.4, 0.4, (30011, 3)), dtype=torch.float32),
    ]
    for origin in origins:
        o = origin.expand_as(d).contiguous()
        depth, column, face = _scene._trace(scene, _scene._Columns.of(scene), o, d)
        ref_depth, ref_column, ref_face = _closest_hit_dense(scene, o, d)
        assert torch.equal(depth, ref_depth)
        assert torch.equal(column, ref_column)
        hit = torch.isfinite(depth) & (column >= 0)
        assert torch.equal(face[hit], ref_face[hit])
        assert hit.float().mean() > 0.3 and (column >= 0).unique().numel() == 2  # rays hit primitives and the ground


def test_the_texture_hash_is_its_32_bit_formula():
    """The int32 hash, against the same formula in Python integers (exact, any size)."""
    rng = np.random.default_rng(0)
    points = rng.integers(-(2**31), 2**31, (1001, 3))  # an odd count: vectorised and scalar tails
    points[:5] = [[0, 0, 0], [-1, -1, -1], [2**31 - 1, -(2**31), 7], [123456, -654321, 0], [1, 2, 3]]
    seed = 77

    def reference(x, y, z):
        m = 0xFFFFFFFF
        h = ((x * 73856093) ^ (y * 19349663) ^ (z * 83492791) ^ (seed * 2654435761)) & m
        h = (((h >> 16) ^ h) * 0x7FEB352D) & m
        h = (((h >> 15) ^ h) * 0x846CA68B) & m
        h = (h >> 16) ^ h
        return (h & 0xFFFFFF) / float(1 << 24)

    ix, iy, iz = (torch.as_tensor(points[:, k], dtype=torch.int64).to(torch.int32) for k in range(3))
    got = _textures._hash(ix, iy, iz, seed)
    want = torch.tensor([reference(*map(int, p)) for p in points], dtype=torch.float32)
    assert torch.equal(got, want)
    # value_noise's shared corner terms, (i + 1) * P as i * P + P, wrap the same way.
    x = torch.tensor([2.0**31 - 1.5, -(2.0**31) + 0.5, 3.25], dtype=torch.float32)
    corners = _textures.value_noise(x, x, None, seed)
    ix = torch.floor(x).to(torch.int64)
    fx = torch.frac(x - torch.floor(x))
    fade = fx * fx * (3 - 2 * fx)
    h = {
        (a, b): torch.tensor([reference(int(i) + a, int(i) + b, 0) for i in ix], dtype=torch.float32)
        for a in (0, 1)
        for b in (0, 1)
    }
    top, bottom = h[0, 0] + fade * (h[1, 0] - h[0, 0]), h[0, 1] + fade * (h[1, 1] - h[0, 1])
    assert torch.equal(corners, top + fade * (bottom - top))


@pytest.mark.parametrize("name", ["paper_d02", "paper_d04", "cpu_tiny_d02", "cpu_tiny_d04"])
def test_shipped_configs_load(name):
    config = load_config(f"configs/stitch/{name}.yaml")
    assert config.data.distance == (0.2 if name.endswith("02") else 0.4)
    assert config.data.pano_width == 2 * config.data.pano_height


@pytest.mark.parametrize(
    "values, message",
    [
        ({"data": {"fisheye_size": 64, "distanse": 0.2}}, r"data: unknown key 'distanse' \(allowed: fisheye_size"),
        ({"dataset": {}}, r"unknown key 'dataset' \(allowed: data, model, loss, train, evaluate, render, name\)"),
        ({"data": {"fisheye_size": 4}}, "impossible sizes: fisheye_size 4"),
        ({"data": {"pano_width": 255}}, "pano_width 255"),
        ({"data": {"fisheye_size": "big"}}, r"data.fisheye_size: expected an integer, got 'big'"),
        ({"data": {"distance": -0.1}}, "distance must be in"),
    ],
)
def test_bad_configs_name_the_key(values, message):
    with pytest.raises(ConfigError, match=message):
        config_from_dict(values, "configs/stitch/x.yaml")


def test_a_config_file_error_names_the_file(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("data:\n  noise: 0.1\n")
    with pytest.raises(ConfigError, match=r"bad.yaml: data: unknown key 'noise' \(allowed: fisheye_size"):
        load_config(path)


def test_the_inverse_depth_map_of_points_on_a_sphere_and_far_from_them():
    """Points 2 m away over a band of directions: 1/2 m^-1 among them (shrunk by 0.5 / (w + 0.5),
    w the weights' sum, about 23 at this density), 0 (infinity) where no point is near; points at
    infinity count as inverse depth 0."""
    from learnstitch.baselines import inverse_depth_map

    rng = np.random.default_rng(0)
    directions = rng.normal(size=(16000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    band = directions[np.abs(directions[:, 1]) < 0.3]  # within about 17 degrees of the horizon
    far = np.full((50, 3), np.inf)
    q = inverse_depth_map(np.concatenate([2.0 * band, far]), 256, 128).numpy()
    rows = np.arange(128)
    latitude = 90.0 - (rows + 0.5) * 180.0 / 128  # the panorama's rows, top to bottom
    among = np.abs(latitude) < 10.0
    away = np.abs(latitude) > 45.0
    assert np.abs(q[among] - 0.5).max() < 0.03 and q[away].max() < 0.01


def test_a_depth_stitch_at_infinity_is_the_rotation_only_stitch_and_at_the_true_depth_the_oracle():
    """At infinity every input is sampled along the panorama's ray, as the rotation-only stitch
    does. Through the sample's own depth it is the depth oracle wherever no input that holds a
    point in its image circle has it hidden (the oracle ray casts that; the depth stitch cannot
    know it), and far nearer the truth than the rotation-only stitch."""
    from learnstitch.baselines import depth_oracle_stitch, depth_stitch
    from learnstitch.data.visibility import sight_lines

    config = SynthConfig(fisheye_size=128, pano_width=256, distance=0.4, **GEOMETRY)
    sample = make_sample(config, 1_000_000_001)
    cameras, centres = sample.rig.cameras, sample.rig.centres
    rotation_only = rotation_only_stitch(sample.fisheyes, sample.rig, config)[0]
    zero = torch.zeros(config.pano_height, config.pano_width)
    torch.testing.assert_close(
        depth_stitch(sample.fisheyes, cameras, centres, zero, config), rotation_only, atol=1e-5, rtol=0
    )
    pano = depth_stitch(sample.fisheyes, cameras, centres, 1.0 / sample.depth, config)
    lines = sight_lines(sample, config)
    oracle = depth_oracle_stitch(sample.fisheyes, lines, config, rotation_only)
    unhidden = lines.seen & (lines.visible | (lines.theta >= config.circle_deg / 2)).all(dim=0)
    assert unhidden.float().mean() > 0.8
    torch.testing.assert_close(pano[:, unhidden], oracle[:, unhidden], atol=1e-5, rtol=0)
    seen = lines.seen
    assert psnr(pano, sample.pano, seen) > psnr(rotation_only, sample.pano, seen) + 1.0
