"""Bundle adjustment (rigjax.optimiser.bundle): cameras with centres, control points as 3-D points."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rigjax
from rigjax import RigjaxError, optimise, synthetic
from rigjax.camera.model import ray_to_img
from rigjax.optimiser.bundle import bundle_adjust
from rigjax.optimiser.bundle_model import (
    BundleConfig,
    Views,
    direction,
    linearise,
    raw_residuals,
    residuals,
)
from rigjax.optimiser.bundle_setup import (
    check_priors,
    point_views,
    stage_args,
    start_params,
    tangent_frames,
    triangulate,
    world_rays,
)
from rigjax.optimiser.bundle_solve import schur_step, solve
from rigjax.optimiser.config import Priors
from rigjax.optimiser.objective import stage_config
from rigjax.optimiser.options import SolverOptions
from rigjax.optimiser.schedule import has_centres, parse_schedule, stage_layout, without_centres
from rigjax.pto.records import ControlPoints


def fisheye_rig(distance: float):
    """Three 185-degree fisheyes 120 degrees apart, each ``distance`` out along its axis (the
    rig of learnstitch's data), and their centres."""
    truth = synthetic.ring_rig(3, width=512, height=512, projection=3, hfov=185.0, b=0.0)
    return truth, synthetic.centres_on_axes(truth, distance)


def scene(n: int, seed: int, near: float = 1.0, far: float = 50.0):
    return synthetic.scene_points(n, near=near, far=far, seed=seed)


def test_centres_on_axes_are_along_each_cameras_yaw():
    truth, centres = fisheye_rig(0.4)
    yaw = np.radians([image.yaw for image in truth.images])
    np.testing.assert_allclose(centres, 0.4 * np.stack([np.sin(yaw), np.zeros(3), np.cos(yaw)], axis=-1), atol=1e-15)


def test_control_points_from_scene_are_the_pixels_of_each_point_seen_from_each_centre():
    truth, centres = fisheye_rig(0.4)
    points = scene(200, seed=3)
    project, index = synthetic.control_points_from_scene(truth, centres, points)
    cps = project.control_points
    cameras = truth.cameras()
    for image, xy in ((cps.image_a, cps.xy_a), (cps.image_b, cps.xy_b)):
        # the camera's frame: x right, y down, z forward, turned by its yaw about y
        yaw = np.radians(np.array([truth.images[k].yaw for k in image]))
        ray = points[index] - centres[image]
        x = np.cos(yaw) * ray[:, 0] - np.sin(yaw) * ray[:, 2]
        z = np.sin(yaw) * ray[:, 0] + np.cos(yaw) * ray[:, 2]
        theta = np.arctan2(np.hypot(x, ray[:, 1]), z)
        # Hugin's full-frame fisheye (f3) is equidistant: r = f theta with f = w / hfov
        focal = 512 / np.radians(185.0)
        radius = focal * theta / np.hypot(x, ray[:, 1])
        expected = np.stack([255.5 + radius * x, 255.5 + radius * ray[:, 1]], axis=-1)
        np.testing.assert_allclose(xy, expected, atol=1e-8)
        assert np.asarray(ray_to_img(cameras.take(image), ray)[1]).all()
    assert len(cps) > 100


def test_triangulated_start_is_the_point_for_exact_rays_and_infinity_without_a_baseline():
    rng = np.random.default_rng(0)
    centres_a, centres_b = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    points = rng.normal(size=(50, 3)) * 10.0
    rays = [p / np.linalg.norm(p, axis=1, keepdims=True) for p in (points - centres_a, points - centres_b)]
    directions, inverse_depths = triangulate(*rays, centres_a, centres_b)
    np.testing.assert_allclose(directions / inverse_depths[:, None], points, rtol=1e-9, atol=1e-9)
    directions, inverse_depths = triangulate(rays[0], rays[0], np.zeros((50, 3)), np.zeros((50, 3)))
    np.testing.assert_array_equal(inverse_depths, 0.0)
    np.testing.assert_allclose(directions, rays[0])


def _unpadded(views: Views, n: int) -> Views:
    return Views(*(np.asarray(a)[:n] for a in views))


def _track_views(project, index) -> Views:
    """Each scene point (``index``: each control point's) as one track over the images that see it,
    its slots in image order, padded with unused slots to the longest track's."""
    cps = project.control_points
    seen = {}
    for a, b, xa, xb, i in zip(cps.image_a, cps.image_b, cps.xy_a, cps.xy_b, index):
        seen.setdefault(int(i), {}).setdefault(int(a), xa)
        seen[int(i)].setdefault(int(b), xb)
    slots = max(len(v) for v in seen.values())
    image, xy, used = [], [], []
    for views in seen.values():
        ks = sorted(views)
        pad = slots - len(ks)
        image.append(ks + [ks[0]] * pad)
        xy.append([views[k] for k in ks] + [views[ks[0]]] * pad)
        used.append([1.0] * len(ks) + [0.0] * pad)
    return Views(np.array(image, np.int32), np.array(xy), np.array(used))


def _stage(project, centres, schedule, priors=None, nominal=None, finite=None, rigid=None, views=None):
    """A stage's args, config and start values as bundle_adjust builds them (``views``: the points
    as given, else the project's control points)."""
    cameras = project.cameras(host=True)
    cps = project.control_points  # unpadded: the dense reference's Jacobian stays small
    points = views or _unpadded(point_views(cps, np.ones(len(cps)), np.ones(len(cps))).views, len(cps))
    weight = np.ones(len(points.image))
    derived = [] if rigid is None else np.flatnonzero(np.asarray(rigid)[:, 0] >= 0).tolist()
    layout = stage_layout(
        parse_schedule(schedule)[0], [dict(image.links) for image in project.images], 0, True, derived
    )
    rays = world_rays(cameras, points)
    image = np.asarray(points.image)
    directions, _ = triangulate(rays[:, 0], rays[:, 1], centres[image[:, 0]], centres[image[:, 1]])
    args = stage_args(
        cameras,
        centres,
        layout,
        points,
        weight,
        rays,
        directions,
        SolverOptions(),
        False,
        priors=priors,
        nominal=nominal,
        finite=finite,
        rigid=rigid,
    )
    config = stage_config(BundleConfig(3, ""), args.slot)._replace(
        centres=bool(np.any(args.centre_slot >= 0)), rigid=rigid is not None
    )
    return args, config, start_params(layout, cameras, centres)


@pytest.mark.parametrize(
    "schedule, priors, held, rigid, tracks",
    [
        ("VBYPR", None, False, False, False),
        ("VBYPR", {"v": 0.5, "b": 0.002}, False, False, False),
        ("VBYPRX", {"v": 0.5, "x": 0.05}, False, False, False),
        ("VBYPR", None, True, False, False),
        ("VBYPR", None, False, True, False),
        ("VBYPRX", {"x": 0.05}, True, False, True),
    ],
)
def test_schur_reduced_step_is_the_full_normal_equations_step(schedule, priors, held, rigid, tracks):
    """tracks: each scene point one point seen in every image that sees it (two or three slots, the
    shorter padded), instead of one per pair of images."""
    truth, centres = fisheye_rig(0.4)
    project, index = synthetic.control_points_from_scene(
        truth, centres, scene(40, seed=1, near=0.8), noise_px=0.5, seed=2
    )
    start = synthetic.perturb(project, angle_deg=(0.5, 2.0), hfov_offset_deg=(1.0, 2.0), b=0.0, seed=3)
    views = _track_views(start, index) if tracks else None
    n_points = len(start.control_points) if views is None else len(views.image)
    # The priors' nominal rig: the truth's lenses (the start is 1-2 degrees of hfov off them); the
    # centres start 2 cm off the truth, at their prior's mean.
    start_centres = centres + np.random.default_rng(5).normal(scale=0.02, size=centres.shape)
    # held: every third point at infinity, its depth no parameter of the cost
    finite = (np.arange(n_points) % 3 != 0).astype(float) if held else None
    # rigid: camera 2's orientation derived from cameras 1 and 0 (W_1 W_0^T W_1), no parameter of its own
    derived = np.array([[-1, -1, -1], [-1, -1, -1], [1, 0, 1]]) if rigid else None
    args, config, params = _stage(
        start, start_centres, schedule, check_priors(priors), truth.cameras(host=True), finite, derived, views
    )
    if tracks:  # tracks of three images and of two, the latter with an unused slot
        used = np.asarray(views.seen).sum(axis=1)
        assert views.slots == 3 and (used == 3).sum() >= 2 and (used == 2).sum() >= 5
    point_params = np.zeros((args.frame.shape[0], 3))
    point_params[:, :2] = np.random.default_rng(4).normal(scale=1e-3, size=(len(point_params), 2))
    point_params[:, 2] = 0.3
    damping = 0.01
    lin = jax.jit(linearise, static_argnames="config")(params, point_params, args, config)
    step = jax.jit(schur_step, static_argnames=("config", "n_params"))
    d_cameras, d_points, predicted = step(lin, damping, args, config, params.shape[0])

    # Reference: the Jacobian of all residuals along all parameters (cameras, then every point's
    # three), the damped normal equations formed whole and solved densely.
    n_cam, n_pts = params.shape[0], point_params.size

    # The priors' rows from their definition, (value - nominal) / sd, in the letters' units (b in
    # hundredths): (parameter, nominal, 1 / sd) per camera and letter.
    prior_rows = [
        (int(args.slot[k, column]), getattr(truth.images[k], field) / unit, unit / priors[letter])
        for letter, field, column, unit in (("v", "hfov", 0, 1.0), ("b", "b", 2, 0.01))
        for k in range(3 if priors and letter in priors else 0)
    ]
    # Each centre's but the anchor's coordinates, in the parameters after the letters'.
    estimated = np.array([[False] * 3, [True] * 3, [True] * 3]) & ("X" in schedule)
    np.testing.assert_array_equal(args.centre_slot >= 0, estimated)
    prior_rows += [
        (int(args.centre_slot[k, j]), start_centres[k, j], 1.0 / priors["x"]) for k, j in zip(*np.nonzero(estimated))
    ]

    def flat(x):
        rows = residuals(x[:n_cam], x[n_cam:].reshape(point_params.shape), args, config).reshape(-1)
        prior = [w * (x[i] - m) for i, m, w in prior_rows]
        return jnp.concatenate([rows, jnp.stack(prior)]) if prior else rows

    x = np.concatenate([params, point_params.reshape(-1)])
    r, jac = np.asarray(flat(jnp.asarray(x))), np.asarray(jax.jit(jax.jacfwd(flat))(jnp.asarray(x)))
    hessian = jac.T @ jac
    scale = np.diag(hessian).copy()
    scale[scale <= 0.0] = 1.0
    step = np.linalg.solve(hessian + damping * np.diag(scale), -jac.T @ r)
    assert np.abs(step[:n_cam]).max() > 1e-3  # a real step, in degrees
    np.testing.assert_allclose(np.asarray(d_cameras), step[:n_cam], rtol=1e-7, atol=1e-10)
    np.testing.assert_allclose(np.asarray(d_points).reshape(-1), step[n_cam:], rtol=1e-7, atol=1e-10)
    np.testing.assert_allclose(float(predicted), 0.5 * np.sum((r + jac @ step) ** 2), rtol=1e-9)
    assert n_pts == 3 * args.frame.shape[0]
    if rigid:  # camera 2's yaw, pitch and roll are no parameters; its letters still are
        assert np.all(np.asarray(args.slot)[2, 6:] == -1) and np.all(np.asarray(args.slot)[2, [0, 2]] >= 0)
    if held:  # a held point's depth neither moves nor changes a residual
        np.testing.assert_array_equal(np.asarray(d_points)[finite == 0.0, 2], 0.0)
        np.testing.assert_array_equal(jac[:, n_cam:].reshape(len(r), -1, 3)[:, finite == 0.0, 2], 0.0)
        assert np.abs(np.asarray(d_points)[finite == 1.0, 2]).max() > 1e-3


def test_points_held_at_infinity_are_the_rotation_only_model_for_them():
    """Every point held at infinity: the rig's centres change nothing, and the adjustment is the one
    with every centre at the origin (the anchor held in both)."""
    truth, centres = fisheye_rig(0.4)
    project = synthetic.control_points_from_truth(truth, 300, noise_px=0.5, seed=7)
    start = synthetic.perturb(project, angle_deg=(0.5, 2.0), hfov_offset_deg=(1.0, 2.0), b=0.0, seed=8)
    held = bundle_adjust(
        start, centres, "YPR,VBYPR", at_infinity=np.ones(len(start.control_points), bool), hold_anchor=True
    )
    one_point = bundle_adjust(start, np.zeros_like(centres), "YPR,VBYPR")
    assert held.ok and one_point.ok and held.rms > 0.1
    np.testing.assert_array_equal(held.inverse_depths, 0.0)
    for a, b in zip(held.project.images, one_point.project.images):
        for x in ("hfov", "b", "yaw", "pitch", "roll"):
            assert getattr(a, x) == pytest.approx(getattr(b, x), abs=1e-9), x
    assert held.rms == pytest.approx(one_point.rms, rel=1e-9)
    with_depths = bundle_adjust(start, centres, "YPR,VBYPR", hold_anchor=True)  # every depth free, to fit noise
    assert with_depths.rms < held.rms and np.any(with_depths.inverse_depths > 0.0)


def test_priors_hold_the_lens_where_the_cost_with_them_is_least():
    """A solve with an hfov prior ends where its cost (the reprojection errors and the prior's
    residuals, (hfov - nominal) / sd, written out here) has no slope along the cameras, not where
    the reprojection errors alone have none, and nearer the nominal hfov than without it."""
    truth, centres = fisheye_rig(0.4)
    project, _ = synthetic.control_points_from_scene(
        truth, centres, scene(60, seed=11, near=0.8), noise_px=0.5, seed=12
    )
    start = synthetic.perturb(project, angle_deg=(0.5, 2.0), hfov_offset_deg=(1.0, 2.0), b=0.0, seed=13)
    nominal = np.array([image.hfov for image in start.images])  # 1-2 degrees off the truth: the data pull away
    ends = {}
    for priors in (None, {"v": 0.3}):
        args, config, params = _stage(start, centres, "VYPR", check_priors(priors))
        point_params = np.zeros((args.frame.shape[0], 3))
        point_params[:, 2] = 0.3
        end, end_points, status, *_ = solve(params, point_params, args, config=config)
        assert int(status) == 0
        hfov = np.asarray(end)[args.slot[:, 0]]
        ends[bool(priors)] = hfov

        def data(p, points=end_points, args=args, config=config):
            return 0.5 * jnp.sum(raw_residuals(p, points, args, config) ** 2)

        def prior(p, slot=args.slot[:, 0]):
            return 0.5 * jnp.sum(((p[slot] - nominal) / 0.3) ** 2)

        slope = np.asarray(jax.grad(data)(end))
        if priors:
            slope_prior = np.asarray(jax.grad(prior)(end))
            assert np.abs(slope).max() > 0.1  # the data alone would move the hfov
            np.testing.assert_allclose(slope + slope_prior, 0.0, atol=1e-6 * np.abs(slope).max())
        else:
            assert np.abs(slope).max() < 1e-6
    assert np.all(np.abs(ends[True] - nominal) < np.abs(ends[False] - nominal))


def test_rig_with_centres_and_near_points_is_recovered_to_round_off():
    truth, centres = fisheye_rig(0.4)
    points = scene(600, seed=5, near=0.8, far=40.0)
    project, index = synthetic.control_points_from_scene(truth, centres, points)
    start = synthetic.perturb(project, angle_deg=(0.5, 2.0), hfov_offset_deg=(1.0, 3.0), b=0.0, seed=6)
    result = bundle_adjust(start, centres, "YPR,VYPR")
    assert result.ok and [s.status for s in result.stages] == ["converged", "converged"]
    assert result.stages[0].rms_initial > 1.0 and result.rms < 1e-9
    for got, want in zip(result.project.images, truth.images):
        for field in ("yaw", "pitch", "roll", "hfov"):
            assert abs(getattr(got, field) - getattr(want, field)) < 1e-9, field
    np.testing.assert_allclose(result.inverse_depths, 1.0 / np.linalg.norm(points[index], axis=1), atol=1e-9)
    np.testing.assert_allclose(result.points, points[index], rtol=1e-8)


def test_estimated_centres_are_recovered_up_to_the_turn_and_scale_their_prior_sets():
    """``X``: from exact observations of near points, centres that start 3 cm off come back to the
    truth's shape. The images cannot tell how that shape is turned about the anchor's held centre
    ``a`` or scaled, which the centres' prior sets: the turn ``G`` and scale ``s`` that bring the
    truth's offsets ``u_i`` nearest to the prior's means ``m_i`` (the start), in closed form
    (orthogonal Procrustes of ``sum (m_i - a) u_i^T``, then ``s = sum (m_i - a) . G u_i / sum |u_i|^2``).
    The cameras come back turned by ``G``, the lenses as they are, the points turned and scaled
    with the rig. The prior (1 m) pulls the solution off the data's exact ones by a little (2e-6 px
    of reprojection error): the closed form is its limit as the prior weakens."""
    truth, centres = fisheye_rig(0.4)
    points = scene(600, seed=5, near=0.8, far=40.0)
    project, index = synthetic.control_points_from_scene(truth, centres, points)
    start = synthetic.perturb(project, angle_deg=(0.5, 2.0), hfov_offset_deg=(1.0, 3.0), b=0.0, seed=6)
    start_centres = centres.copy()
    start_centres[1:] += np.random.default_rng(7).normal(scale=0.03, size=(2, 3))
    result = bundle_adjust(start, start_centres, "YPR,VYPRX", priors={"x": 1.0})
    assert result.ok and result.stages[0].rms_initial > 1.0 and result.rms < 1e-5
    a, u, m = centres[0], centres[1:] - centres[0], start_centres[1:] - centres[0]
    left, _, right = np.linalg.svd(m.T @ u)
    turn = left @ np.diag([1.0, 1.0, np.linalg.det(left @ right)]) @ right
    s = np.sum(m * (u @ turn.T)) / np.sum(u * u)
    assert abs(s - 1.0) > 1e-3 and np.degrees(np.arccos((np.trace(turn) - 1) / 2)) > 0.5  # the start is off both
    np.testing.assert_allclose(result.centres, a + s * (centres - a) @ turn.T, atol=1e-6)
    np.testing.assert_array_equal(result.project.centres, result.centres)  # what the .pto keeps
    got = np.asarray(result.project.cameras().world_from_cam)
    np.testing.assert_allclose(got, turn @ np.asarray(truth.cameras().world_from_cam), atol=1e-6)
    np.testing.assert_allclose([im.hfov for im in result.project.images], [im.hfov for im in truth.images], atol=1e-6)
    np.testing.assert_allclose(result.points, a + s * (points[index] - a) @ turn.T, rtol=1e-4)
    assert np.isnan(result.centre_sd[0]).all() and (result.centre_sd[1:] > 0).all()


def test_the_projects_v_lines_are_adjusted_exactly(tmp_path, capsys):
    """``pto_vars`` (``--pto-vars``): one stage of the project's v lines, as Hugin reads them. From
    exact observations the rig comes back to round-off; a variable the adjustment has no use for is
    named, and the hfov that no v line names is left as it was."""
    from rigjax.cli import main

    truth, centres = fisheye_rig(0.4)
    points = scene(600, seed=5, near=0.8, far=40.0)
    project, _ = synthetic.control_points_from_scene(truth, centres, points)
    start = synthetic.perturb(project, angle_deg=(0.5, 2.0), hfov_offset_deg=(1.0, 3.0), b=0.0, seed=6)
    variables = [rigjax.OptVariable(n, k) for k in (1, 2) for n in "ypr"]
    variables += [rigjax.OptVariable("v", k) for k in (0, 1, 2)] + [rigjax.OptVariable("Eev", 1)]
    start = start.replace(variables=tuple(variables), centres=centres)
    result = rigjax.optimise(start, rigjax.OptimiseConfig(objective="reprojection", pto_vars=True))
    assert result.ok and [s.name for s in result.stages] == ["v-lines"] and len(result.stages[0].parameters) == 9
    assert result.not_optimised == ("Eev1: not a geometric variable (kept in the file, not optimised)",)
    for got, want in zip(result.project.images, truth.images):
        for field in ("yaw", "pitch", "roll", "hfov"):
            assert abs(getattr(got, field) - getattr(want, field)) < 1e-8, field
    # Without the v lines of the hfov, it is not touched: the other letters settle around it.
    held = rigjax.optimise(
        start.replace(variables=tuple(variables[:6])), rigjax.OptimiseConfig(objective="reprojection", pto_vars=True)
    )
    assert [im.hfov for im in held.project.images] == [im.hfov for im in start.images]
    start.save(tmp_path / "in.pto")
    out = tmp_path / "out.pto"
    command = ["optimise", str(tmp_path / "in.pto"), "-o", str(out), "--objective", "reprojection", "--pto-vars"]
    assert main([*command, "--no-prune"]) == 0
    printed = capsys.readouterr().out
    assert printed.splitlines()[1].split()[:3] == ["v-lines", "converged", "9"]
    assert "not optimised: Eev1" in printed
    for got, want in zip(rigjax.load_project(out).images, truth.images):
        assert abs(got.yaw - want.yaw) < 1e-6 and abs(got.hfov - want.hfov) < 1e-6
    # A config's priors reach the adjustment: a tight one holds each hfov where the project has it.
    config = tmp_path / "held.yaml"
    config.write_text("objective: reprojection\nschedule: YPR,VYPR\npriors: {v: 1.0e-5}\n")
    assert main(["optimise", str(tmp_path / "in.pto"), "-o", str(out), "--config", str(config), "--no-prune"]) == 0
    hfov = [image.hfov for image in rigjax.load_project(out).images]
    np.testing.assert_allclose(hfov, [image.hfov for image in start.images], atol=1e-4)
    assert np.abs(np.subtract(hfov, [image.hfov for image in truth.images])).min() > 0.5
    # Centres estimated from the command line: the table shows them with their deviations, the anchor's held.
    config.write_text("objective: reprojection\nschedule: YPR,VYPRX\npriors: {x: 0.05}\n")
    assert main(["optimise", str(tmp_path / "in.pto"), "-o", str(out), "--config", str(config), "--no-prune"]) == 0
    printed = capsys.readouterr().out
    assert "centres and their standard deviations" in printed
    rows = printed.split("centres and their standard deviations")[1].splitlines()[1:4]
    assert rows[0].split()[1:] == ["0.0000", "-", "0.0000", "-", "0.4000", "-"] and "±" in rows[1]
    np.testing.assert_allclose(rigjax.load_project(out).centres, centres, atol=1e-6)  # exact data: the truth


def test_zero_centres_are_the_rotation_only_model():
    truth = synthetic.ring_rig(6, b=-0.01)
    project = synthetic.control_points_from_truth(truth, 600, noise_px=0.5, seed=7)
    start = synthetic.perturb(project, angle_deg=(0.5, 2.0), hfov_offset_deg=(1.0, 2.0), b=0.0, seed=8)
    compiled = solve._cache_size()
    result = bundle_adjust(start, np.zeros((6, 3)), "YPR,VBYPR")
    assert solve._cache_size() - compiled <= 1  # both stages one program: the letters of them all
    reference = optimise(start, "YPR,VBYPR")
    assert result.ok and reference.ok
    # Without centres the depths have no derivative and stay at infinity.
    np.testing.assert_array_equal(result.inverse_depths, 0.0)

    # Both objectives estimate the same rig from the same points; they differ by much less than
    # either's error (0.5 px noise, about 12 px per degree, a few hundred points per camera).
    def difference(one, other):  # degrees, angles wrapped
        d = np.array(
            [[getattr(a, f) - getattr(b, f) for f in ("yaw", "pitch", "roll", "hfov")] for a, b in zip(one, other)]
        )
        return np.abs((d + 180.0) % 360.0 - 180.0)

    assert difference(result.project.images, reference.project.images).max() < 2e-3
    assert difference(result.project.images, truth.images).max() < 0.05
    assert difference(reference.project.images, truth.images).max() > 0.01
    # Both results are OptimiseResults, read alike; what only the bundle adjustment estimates is
    # None in the rotation-only result.
    n = len(start.control_points)
    for one in (result, reference):
        assert isinstance(one, rigjax.OptimiseResult) and one.format_stages().startswith("stage")
        assert one.point_errors().shape == (n,) and one.format_rms().startswith(f"{one.rms:.4f} px (")
    assert result.standard_deviations.shape == (6, 9) and result.points.shape == (n, 3) and result.format_deviations()
    assert (
        reference.standard_deviations is reference.orientation_sd_deg is reference.centres is reference.points is None
    )
    assert reference.format_deviations() == ""
    # Its residual of a point is the distance to the point's pixel: zero at the truth without noise.
    exact = synthetic.control_points_from_truth(truth, 600, seed=7)  # the same points, noise-free
    assert bundle_adjust(exact, np.zeros((6, 3)), "YPR").stages[0].rms_initial < 1e-9


def test_the_deviations_are_the_last_stages_own_letters():
    """The stages share one program along the letters of them all; the result's deviations are the
    last stage's letters alone: after a last stage of the hfov only, no orientation is reported."""
    truth = synthetic.ring_rig(6, b=-0.01)
    project = synthetic.control_points_from_truth(truth, 300, noise_px=0.5, seed=7)
    start = synthetic.perturb(project, angle_deg=(0.5, 1.0), hfov_offset_deg=(0.5, 1.0), b=0.0, seed=8)
    result = bundle_adjust(start, np.zeros((6, 3)), "YPR,V")
    deviations = result.standard_deviations
    assert np.all(np.isfinite(deviations[:, 0])) and np.all(deviations[:, 0] > 0.0)  # v
    assert np.all(np.isnan(deviations[:, 1:])) and np.all(np.isnan(result.orientation_sd_deg))


def test_bad_input_is_refused_with_what_is_wrong():
    truth, centres = fisheye_rig(0.4)
    project, _ = synthetic.control_points_from_scene(truth, centres, scene(100, seed=1))
    with pytest.raises(RigjaxError, match=r"centres must be finite, of shape \(3, 3\)"):
        bundle_adjust(project, centres[:2])
    lined = synthetic.control_points_from_truth(synthetic.cube_rig(), 300, seed=1)
    lined = synthetic.vertical_lines_from_truth(lined, kind=1)
    with pytest.raises(RigjaxError, match=r"control point 1\d\d is a line point \(t1\)"):
        bundle_adjust(lined, np.zeros((6, 3)))
    with pytest.raises(RigjaxError, match=r"estimates centres \(X\): give priors \{'x': sd\}"):
        bundle_adjust(project, centres, "YPR,VYPRX")
    with pytest.raises(RigjaxError, match=r"priors: 'q' cannot have a prior \(one of v, a, b, c, d, e, y, p, r, x\)"):
        bundle_adjust(project, centres, "YPR,VYPR", priors={"q": 1.0})
    with pytest.raises(RigjaxError, match=r"schedule 'YPR,VYPRX' estimates centres \(X\): set objective reprojection"):
        optimise(project, "YPR,VYPRX")
    with pytest.raises(RigjaxError, match=r"priors apply to objective reprojection only, not 'transfer'"):
        rigjax.OptimiseConfig("YPR", objective="transfer", priors=Priors(v=1.0))  # the rotation-only objectives
    sphere = rigjax.OptimiseConfig("YPR", objective="sphere")
    for run in (optimise, rigjax.optimise_pruned):
        with pytest.raises(RigjaxError, match=r"cluster_error_px applies to objective reprojection only, not 'sphere'"):
            run(project, sphere, cluster_error_px=0.3)
        with pytest.raises(RigjaxError, match=r"nominal applies to objective reprojection only, not 'sphere'"):
            run(project, sphere, nominal=project.cameras(host=True))
        with pytest.raises(RigjaxError, match=r"at_infinity applies to objective reprojection only, not 'sphere'"):
            run(project, sphere, at_infinity=np.zeros(len(project.control_points), bool))
    with pytest.raises(RigjaxError, match=r"at_infinity has shape \(3,\), expected \(\d+,\) \(one per control point\)"):
        bundle_adjust(project, centres, "YPR", at_infinity=np.zeros(3, bool))
    own = np.full((3, 3), -1)
    for row in ([1, 0, 2], [2, 0, 1], [-1, 0, 1], [1, 0, 5]):  # a cycle, the anchor, a half row, no such image
        rigid = own.copy()
        rigid[2 if row[0] != 2 else 0] = row
        with pytest.raises(RigjaxError, match=r"rigid: image \d's orientation cannot follow images"):
            bundle_adjust(project, centres, "YPR", rigid=rigid)
    rigid = own.copy()
    rigid[2] = (1, 0, 1)
    linked = project.replace(images=(*project.images[:2], project.images[2].replace(links={"y": 1})))
    with pytest.raises(RigjaxError, match=r"rigid: image 2's yaw, pitch or roll is linked"):
        bundle_adjust(linked, centres, "YPR", rigid=rigid)
    with pytest.raises(RigjaxError, match=r"pto_vars takes the project's v lines as they are: rigid and hold_anchor"):
        bundle_adjust(project, centres, pto_vars=True, hold_anchor=True)
    with pytest.raises(RigjaxError, match=r"cluster_error_px must be a standard deviation in pixels \(>= 0\), got -1"):
        bundle_adjust(project, centres, "YPR", cluster_error_px=-1.0)
    with pytest.raises(rigjax.ScheduleError, match=r"stage 'YPR_X': centres are per camera and cannot be shared"):
        parse_schedule("YPR_X")


def test_centre_letters_in_schedules():
    """``X``: a stage's centres, per camera and the anchor's held; ``rigjax calibrate``'s
    rotation-only search runs the schedule without them."""
    layout = stage_layout(parse_schedule("VYPRX")[0], [{}, {}, {}], anchor=1)
    assert layout.names[-6:] == ("cx0", "cy0", "cz0", "cx2", "cy2", "cz2")
    assert [int(layout.slot["cx"][k]) for k in range(3)] == [layout.size - 6, -1, layout.size - 3]
    assert without_centres("YPR,VYPRX,X") == "YPR,VYPR" and has_centres("YPR,XVYPR") and not has_centres("YPR_V")
    assert parse_schedule("XYPRV")[0].name == "VYPRX"


def test_tangent_frames_are_orthonormal_and_start_at_the_direction():
    rng = np.random.default_rng(0)
    d = rng.normal(size=(100, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d[0] = [1.0, 0.0, 0.0]
    frames = tangent_frames(d)
    np.testing.assert_allclose(
        np.einsum("nij,nkj->nik", frames, frames), np.broadcast_to(np.eye(3), (100, 3, 3)), atol=1e-12
    )
    np.testing.assert_allclose(np.asarray(direction(frames, np.zeros((100, 3)))), d, atol=1e-15)


def test_reported_standard_deviations_match_the_spread_over_noise_draws():
    """40 draws of 0.5 px noise on one rig's points: the orientations' spread (each camera's turn
    from the truth, the rig's mean turn removed, as the report removes it) and the hfovs' spread
    against the deviations the adjustments report, pooled over the three cameras; and each turn
    whitened by its reported covariance (``L^-1 turn``, ``L L^T`` the covariance), whose second
    moments are the identity when the covariance is right in every direction, not only in its
    trace (the yaw's deviation is several times the pitch's and roll's here)."""
    truth, centres = fisheye_rig(0.4)
    points = scene(400, seed=0)
    true_turn = _rotations(truth)
    turns, hfovs, reported_turn, reported_hfov, sigma, whitened = [], [], [], [], [], []
    for draw in range(40):
        project, _ = synthetic.control_points_from_scene(truth, centres, points, noise_px=0.5, seed=100 + draw)
        start = synthetic.perturb(project, angle_deg=(0.2, 0.5), hfov_offset_deg=(0.5, 1.0), b=0.0, seed=draw)
        result = bundle_adjust(start, centres, "YPR,VYPR")
        m = _rotations(result.project) @ np.swapaxes(true_turn, 1, 2)
        turn = 0.5 * np.stack([m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]], axis=-1)
        turns.append(np.degrees(turn - turn.mean(axis=0)))
        whitened.append(np.linalg.solve(np.linalg.cholesky(result.turn_covariance), turns[-1][..., None])[..., 0])
        hfovs.append([got.hfov - want.hfov for got, want in zip(result.project.images, truth.images)])
        reported_turn.append(result.orientation_sd_deg)
        reported_hfov.append(result.standard_deviations[:, 0])
        sigma.append(result.sigma)
    assert abs(np.mean(sigma) - 0.5) < 0.05  # the residuals' scale is the noise's
    spread = np.sqrt(np.mean(np.sum(np.array(turns) ** 2, axis=-1)))
    assert spread > 0.01
    assert abs(np.sqrt(np.mean(np.array(reported_turn) ** 2)) / spread - 1.0) < 0.2
    np.testing.assert_allclose(result.orientation_sd_deg, np.sqrt(np.trace(result.turn_covariance, axis1=1, axis2=2)))
    whitened = np.concatenate(whitened)
    moments = whitened.T @ whitened / len(whitened)
    assert np.abs(moments - np.eye(3)).max() < 0.3, moments
    hfovs = np.array(hfovs)
    spread = np.sqrt(np.mean((hfovs - hfovs.mean(axis=0)) ** 2))
    assert abs(np.sqrt(np.mean(np.array(reported_hfov) ** 2)) / spread - 1.0) < 0.2


def test_standard_deviations_count_points_that_share_an_error_as_one():
    """Each control point five times over with one error (as neighbouring tracks share theirs): the
    textbook covariance counts five draws and is too small by about sqrt(5); counted by cluster
    (``cluster_px``), the reported deviations match the spread over 30 noise draws."""
    from rigjax.pto.records import ControlPoints

    truth, centres = fisheye_rig(0.4)
    clean, _ = synthetic.control_points_from_scene(truth, centres, scene(60, seed=1))
    cps = clean.control_points
    true_turn = _rotations(truth)
    turns, reported, textbook = [], [], []
    for draw in range(30):
        noise = np.random.default_rng(200 + draw).normal(scale=0.5, size=(2, len(cps), 2))
        repeat = lambda v: np.repeat(v, 5, axis=0)  # noqa: E731
        noisy = ControlPoints(
            repeat(cps.image_a),
            repeat(cps.image_b),
            repeat(cps.xy_a + noise[0]),
            repeat(cps.xy_b + noise[1]),
            repeat(cps.kind),
        )
        start = synthetic.perturb(clean.replace(control_points=noisy), angle_deg=(0.2, 0.5), b=0.0, seed=draw)
        result = bundle_adjust(start, centres, "YPR")
        m = _rotations(result.project) @ np.swapaxes(true_turn, 1, 2)
        turn = 0.5 * np.stack([m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]], axis=-1)
        turns.append(np.degrees(turn - turn.mean(axis=0)))
        reported.append(result.orientation_sd_deg)
        if draw < 5:
            textbook.append(bundle_adjust(start, centres, "YPR", cluster_px=0.0).orientation_sd_deg)
    spread = np.sqrt(np.mean(np.sum(np.array(turns) ** 2, axis=-1)))
    assert abs(np.sqrt(np.mean(np.array(reported) ** 2)) / spread - 1.0) < 0.25
    assert np.sqrt(np.mean(np.array(textbook) ** 2)) / spread < 0.6


def test_a_shared_offset_of_each_clusters_second_ends_is_propagated_as_moving_them_does():
    """``cluster_error_px`` adds to each camera's turn covariance what moving one cluster's second
    ends together does to the adjusted rig: checked against re-adjusting the project with each
    cluster's second ends moved by a small step along x and along y (finite differences of the
    whole solve, the rig's mean turn removed as the report removes it)."""
    from rigjax.optimiser.bundle_setup import clusters
    from rigjax.pto.records import ControlPoints

    truth, centres = fisheye_rig(0.4)
    project, _ = synthetic.control_points_from_scene(truth, centres, scene(150, seed=3), noise_px=0.3, seed=4)
    cell, sd, step = 256.0, 0.7, 0.05
    on = bundle_adjust(project, centres, "VYPR", cluster_px=cell, cluster_error_px=sd)
    off = bundle_adjust(project, centres, "VYPR", cluster_px=cell)
    np.testing.assert_allclose(on.project.cameras(host=True).yaw, off.project.cameras(host=True).yaw)
    cps = project.control_points
    cluster = clusters(_unpadded(point_views(cps, np.ones(len(cps)), np.ones(len(cps))).views, len(cps)), cell)
    assert 6 <= cluster.max() + 1 <= 12  # every pair's points in a few cells
    base = _rotations(off.project)

    def turn(result):  # each camera's turn from the unmoved solution, degrees, the rig's mean removed
        m = _rotations(result.project) @ np.swapaxes(base, 1, 2)
        t = 0.5 * np.stack([m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]], axis=-1)
        return np.degrees(t - t.mean(axis=0))

    added = np.zeros((3, 3, 3))
    for c in range(cluster.max() + 1):
        for axis in range(2):
            xy_b = cps.xy_b.copy()
            xy_b[cluster == c, axis] += step
            moved = project.replace(control_points=ControlPoints(cps.image_a, cps.image_b, cps.xy_a, xy_b, cps.kind))
            derivative = turn(bundle_adjust(moved, centres, "VYPR", cluster_px=cell)) / step
            added += sd**2 * np.einsum("ni,nj->nij", derivative, derivative)
    np.testing.assert_allclose(on.turn_covariance - off.turn_covariance, added, rtol=0.05, atol=1e-3 * added.max())
    assert np.all(on.orientation_sd_deg > 1.5 * off.orientation_sd_deg)  # the offsets matter here


def _rotations(project) -> np.ndarray:
    from rigjax.camera.rotation import world_from_cam

    angles = [np.array([getattr(image, f) for image in project.images]) for f in ("yaw", "pitch", "roll")]
    return np.asarray(world_from_cam(*angles))


def wrong_matches(project, fraction: float = 0.2, seed: int = 0):
    """The project with ``fraction`` of its control points' second ends moved to random pixels of a
    512-pixel image, and which ones."""
    from rigjax.pto.records import ControlPoints

    cps = project.control_points
    rng = np.random.default_rng(seed)
    wrong = rng.random(len(cps)) < fraction
    xy_b = cps.xy_b.copy()
    xy_b[wrong] = rng.uniform(0.0, 512.0, (int(wrong.sum()), 2))
    return project.replace(control_points=ControlPoints(cps.image_a, cps.image_b, cps.xy_a, xy_b, cps.kind)), wrong


def test_command_line_adjusts_and_prunes_a_project_with_centres(tmp_path, capsys):
    """A fifth of the matches wrong: pruning on the reprojection errors removes them all and no
    good one, and the rig comes out as from clean points."""
    from rigjax.cli import main

    truth, centres = fisheye_rig(0.4)
    clean, _ = synthetic.control_points_from_scene(truth, centres, scene(400, seed=1), noise_px=0.5, seed=1)
    project, wrong = wrong_matches(clean)
    cps, xy_b = clean.control_points, project.control_points.xy_b
    start = synthetic.perturb(project, angle_deg=(0.5, 2.0), hfov_offset_deg=(1.0, 2.0), b=0.0, seed=3)
    start.replace(centres=centres).save(tmp_path / "in.pto")
    out = tmp_path / "out.pto"
    command = ["optimise", str(tmp_path / "in.pto"), "-o", str(out), "--objective", "reprojection"]
    assert main([*command, "--schedule", "YPR,VYPR"]) == 0
    printed = capsys.readouterr().out
    assert [line.split()[:2] for line in printed.splitlines()[1:3]] == [["YPR", "converged"], ["VYPR", "converged"]]
    assert "standard deviations, degrees (residual scale 0.5" in printed
    written = rigjax.load_project(out)
    kept = np.concatenate([written.control_points.xy_a, written.control_points.xy_b], axis=1)
    original = np.concatenate([cps.xy_a, xy_b], axis=1)
    is_kept = (np.abs(original[:, None] - kept[None]).max(axis=-1) < 1e-6).any(axis=1)
    np.testing.assert_array_equal(is_kept, ~wrong)  # every wrong match removed, every good one kept
    assert written.to_text().count("#-rigjax pruned") == wrong.sum()
    np.testing.assert_allclose(written.centres, centres, atol=1e-14)
    assert np.isfinite(written.deviations[:, [0, 6, 7, 8]]).all() and np.isnan(written.deviations[:, 1:6]).all()
    for got, want in zip(written.images, truth.images):
        assert abs(got.yaw - want.yaw) < 0.3 and abs(got.hfov - want.hfov) < 0.6

    # the centres from the config instead; without any, an error that says where to give them
    config = tmp_path / "ba.yaml"
    config.write_text(
        "objective: reprojection\nschedule: YPR,VYPR\nprune: false\ncentres: " + str(centres.tolist()) + "\n"
    )
    synthetic.perturb(clean, angle_deg=(0.5, 2.0), hfov_offset_deg=(1.0, 2.0), b=0.0, seed=3).save(
        tmp_path / "bare.pto"
    )
    assert main(["optimise", str(tmp_path / "bare.pto"), "-o", str(out), "--config", str(config)]) == 0
    assert main(["optimise", str(tmp_path / "bare.pto"), "-o", str(out), "--objective", "reprojection"]) == 2
    assert "needs the camera centres" in capsys.readouterr().err


def test_calibrating_matches_with_centres_adjusts_the_bundle_and_warns_of_a_poorly_known_yaw():
    """rigjax.calibrate_matches with a template that gives the centres and objective reprojection:
    RANSAC keeps the near points (epipolar test), the bundle adjustment and its pruning remove the
    wrong matches, and the summary carries the deviations and the warnings."""
    import dataclasses

    from rigjax.calibration.pipeline import PairMatches

    truth, centres = fisheye_rig(0.4)
    clean, _ = synthetic.control_points_from_scene(truth, centres, scene(400, seed=1), noise_px=0.5, seed=1)
    project, wrong = wrong_matches(clean)
    cps, xy_b = project.control_points, project.control_points.xy_b
    pairs = [
        PairMatches(
            a, b, cps.xy_a[(cps.image_a == a) & (cps.image_b == b)], xy_b[(cps.image_a == a) & (cps.image_b == b)]
        )
        for a, b in ((0, 1), (0, 2), (1, 2))
    ]
    template = rigjax.template_from_dict(
        {
            "rig": {
                "cameras": 3,
                "projection": 3,
                "hfov": 185.0,
                "orientations": [[0, 0, 0], [120, 0, 0], [-120, 0, 0]],
                "centres": centres.tolist(),
            },
            "ransac": {"threshold_deg": 1.0, "min_inliers": 8},
            "levy": False,
            "optimise": {"objective": "reprojection", "schedule": "YPR,VYPR"},
        }
    )
    calibration = rigjax.calibrate_matches(pairs, [(512, 512)] * 3, template)
    assert calibration.result.ok and hasattr(calibration.result, "standard_deviations")
    assert sum(p.inliers for p in calibration.pairs) >= (~wrong).sum() - 5  # near points kept by RANSAC
    for got, want in zip(calibration.project.images, truth.images):
        assert abs(got.yaw - want.yaw) < 0.3 and abs(got.hfov - want.hfov) < 0.6
    np.testing.assert_allclose(calibration.project.centres, centres)
    assert "standard deviations, degrees" in calibration.summary() and not calibration.warnings
    assert calibration.undetermined == ()  # rigjax.calibration.checks: a rig its matches determine
    strict = dataclasses.replace(calibration, warn_yaw_sd_deg=0.001)
    assert len(strict.warnings) == 3 and "camera 0's yaw is known to" in strict.warnings[0]
    assert strict.warnings[0] in strict.summary()
    # Matches that are tracks (features.track_step_px): the same cameras, and deviations that allow
    # for the bias a region's tracks share (features.track_bias_px).
    features = dataclasses.replace(template.features, seam_band_deg=30.0, track_step_px=4)
    tracks = rigjax.calibrate_matches(pairs, [(512, 512)] * 3, dataclasses.replace(template, features=features))
    for got, want in zip(tracks.project.images, calibration.project.images):
        assert (got.yaw, got.pitch, got.roll, got.hfov) == (want.yaw, want.pitch, want.roll, want.hfov)
    assert np.all(tracks.result.orientation_sd_deg > 1.05 * calibration.result.orientation_sd_deg)


def test_centres_fix_the_rigs_orientation_unless_they_lie_on_one_line_through_the_origin():
    from rigjax.optimiser.bundle_setup import centres_fix_orientation

    _, centres = fisheye_rig(0.4)
    assert centres_fix_orientation(centres)
    assert not centres_fix_orientation(np.zeros((3, 3)))
    assert not centres_fix_orientation(np.array([[0.0, 0.0, 0.03], [0.0, 0.0, -0.03]]))  # a dual fisheye's lenses
    assert centres_fix_orientation(np.array([[0.0, 0.0, 0.03], [0.0, 0.02, -0.03]]))


def test_held_centres_set_the_rigs_orientation_and_the_anchor_follows_them():
    """The anchor starts 2 degrees off its true orientation, the centres held where they are: the
    whole rig, anchor included, comes back to the truth from exact observations (holding the anchor
    at its start would turn the centres' frame by 2 degrees against the cameras, and no orientation
    of the others could fit the near points then). A tight prior on yaw, pitch and roll about the
    start instead holds every camera there, the anchor too."""
    truth, centres = fisheye_rig(0.4)
    points = scene(600, seed=5, near=0.8, far=40.0)
    project, _ = synthetic.control_points_from_scene(truth, centres, points)
    start = synthetic.perturb(project, angle_deg=(0.5, 2.0), hfov_offset_deg=(1.0, 3.0), b=0.0, seed=6)
    anchor = start.images[0]
    start = start.replace(images=(anchor.replace(yaw=anchor.yaw + 2.0, pitch=anchor.pitch - 1.0), *start.images[1:]))
    result = bundle_adjust(start, centres, "YPR,VYPR")
    assert result.ok and result.rms < 1e-8
    for got, want in zip(result.project.images, truth.images):
        for field in ("yaw", "pitch", "roll", "hfov"):
            assert abs(getattr(got, field) - getattr(want, field)) < 1e-8, field
    held = bundle_adjust(start, centres, "YPR,VYPR", priors={"y": 1e-6, "p": 1e-6, "r": 1e-6})
    for got, want in zip(held.project.images, start.images):
        for field in ("yaw", "pitch", "roll"):
            assert abs(getattr(got, field) - getattr(want, field)) < 1e-4, field


def test_point_views_are_one_point_per_control_point_or_per_track():
    """Control points each their own point (two slots, image a then b), or one point per track over
    the images its ends name; a track that sees one image at two pixels, or holds only some of its
    control points at infinity, is refused naming it."""
    xy = np.arange(12.0).reshape(6, 2)
    cps = ControlPoints(np.array([0, 0, 1, 2, 0, 1]), np.array([1, 2, 2, 3, 3, 3]), xy, xy + 100.0, np.zeros(6))
    # tracks 7 (images 0, 1, 2: each image at one pixel) and 4 (image 2 and 3), the rest their own
    cps = ControlPoints(
        cps.image_a,
        cps.image_b,
        np.array([[0, 0], [0, 0], [1, 1], [2, 2], [9, 9], [8, 8.0]]),
        np.array([[1, 1], [2, 2], [2, 2], [3, 3], [7, 7], [6, 6.0]]),
        cps.kind,
    )
    own = point_views(cps, np.ones(6), np.ones(6))
    one_image = ControlPoints(np.array([3]), np.array([3]), np.array([[1.0, 2.0]]), np.array([[5.0, 6.0]]), np.zeros(1))
    np.testing.assert_array_equal(point_views(one_image, np.ones(1), np.ones(1)).views.xy[0], [[1, 2], [5, 6]])
    np.testing.assert_array_equal(own.views.image[:6], np.stack([cps.image_a, cps.image_b], 1))
    np.testing.assert_array_equal(own.views.xy[:6], np.stack([cps.xy_a, cps.xy_b], 1))
    np.testing.assert_array_equal(own.point, np.arange(6))
    np.testing.assert_array_equal(own.slots, [[0, 1]] * 6)
    assert len(own.views.image) % 256 == 0 and own.padded_weight[6:].max() == 0.0
    tracks = np.array([7, 7, 7, 4, -1, -1])
    weight = np.array([1.0, 1.0, 0.0, 1.0, 1.0, 1.0])
    got = point_views(cps, weight, np.ones(6), tracks)
    np.testing.assert_array_equal(got.point, [0, 0, 0, 1, 2, 3])
    np.testing.assert_array_equal(got.views.image[:4], [[0, 1, 2], [2, 3, 2], [0, 3, 0], [1, 3, 1]])
    np.testing.assert_array_equal(got.views.seen[:4], [[1, 1, 1], [1, 1, 0], [1, 1, 0], [1, 1, 0]])
    np.testing.assert_array_equal(got.views.xy[0], [[0, 0], [1, 1], [2, 2]])
    np.testing.assert_array_equal(got.slots, [[0, 1], [0, 2], [1, 2], [0, 1], [0, 1], [0, 1]])
    np.testing.assert_array_equal(got.weight, [0.0, 1.0, 1.0, 1.0])  # track 7 has a control point left out
    moved = ControlPoints(
        cps.image_a, cps.image_b, cps.xy_a, cps.xy_b + np.array([[0, 0], [0, 0.5], *[[0, 0]] * 4]), cps.kind
    )
    with pytest.raises(RigjaxError, match="track 7 sees image 2 at two pixels"):
        point_views(moved, np.ones(6), np.ones(6), tracks)
    with pytest.raises(RigjaxError, match="track 7 has control points held at infinity and others not"):
        point_views(cps, np.ones(6), np.array([1.0, 0.0, 1.0, 1.0, 1.0, 1.0]), tracks)
