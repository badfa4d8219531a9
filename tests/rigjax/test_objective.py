"""The rig objective's hand-written Jacobian (per-camera optics, per-point chain rule through the
lens maps) against central finite differences of the residuals themselves, and against plain
forward-mode differentiation of the same residuals."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rigjax
from rigjax import synthetic
from rigjax.optimiser import objective, staged
from rigjax.optimiser.problem import initial_params, prepare


def _mixed_rig() -> rigjax.Project:
    """Six cameras of three lens types with every distortion term non-zero, control points, a few
    vertical and horizontal line points and two straight lines (t3, t4)."""
    truth = synthetic.cube_rig(hfov=150.0, orientation_jitter_deg=4.0, seed=3)
    kinds = [3, 21, 3, 2, 21, 3]
    images = tuple(
        image.replace(projection=kind, a=0.004 * (k - 2), b=-0.01 + 0.002 * k, c=0.003, d=3.0 - k, e=0.5 * k)
        for k, (image, kind) in enumerate(zip(truth.images, kinds))
    )
    project = synthetic.control_points_from_truth(truth.replace(images=images), 300, noise_px=0.7, seed=4)
    cps = project.control_points
    kind = np.zeros(len(cps))
    kind[:6] = [1, 1, 2, 2, 1, 2]  # line points: their residual is a panorama column or row
    kind[6:12] = [3, 3, 3, 4, 4, 4]  # straight lines: distances from a line of the panorama
    return project.replace(control_points=rigjax.ControlPoints(cps.image_a, cps.image_b, cps.xy_a, cps.xy_b, kind))


def _stage(project: rigjax.Project, objective_name: str):
    problem = prepare(project, "VABCDEYPR", objective=objective_name)
    layout = problem.stages[0][1]
    args = staged._args(problem, layout, problem.cameras)
    return problem, layout, args, jnp.asarray(initial_params(layout, problem.cameras))


def _jacobian(params, args, config, strategy=None):
    return _value_and_jacobian(params, args, config, strategy)[1]


def _value_and_jacobian(params, args, config, strategy=None):
    """The residuals as forward mode's primal output (from the custom rule, where there is one)
    and their Jacobian, in one compiled call."""
    fn = jax.jacfwd(lambda *a: (objective.stage_residuals(*a),) * 2, has_aux=True)
    jac, value = jax.jit(fn, static_argnums=(2, 3))(params, args, config, strategy)
    return np.asarray(value), np.asarray(jac)


@pytest.mark.parametrize("objective_name", ["transfer", "sphere"])
def test_jacobian_matches_finite_differences(objective_name):
    project = synthetic.perturb(_mixed_rig(), angle_deg=(1, 3), hfov_offset_deg=(1, 2), b=None, seed=5)
    problem, layout, args, params = _stage(project, objective_name)
    assert problem.config.lines and problem.config.projection is None  # the paths under test
    assert problem.group_weight.sum() == 6
    residuals = jax.jit(objective.stage_residuals, static_argnums=2)
    jacobian = _jacobian(params, args, problem.config)

    h = 1e-5
    columns = []
    for k in range(layout.size):
        step = jnp.zeros_like(params).at[k].set(h)
        plus, minus = residuals(params + step, args, problem.config), residuals(params - step, args, problem.config)
        columns.append((np.asarray(plus) - np.asarray(minus)) / (2 * h))
    finite = np.stack(columns, axis=-1)
    scale = np.abs(finite).max(axis=0)  # px per unit of each parameter
    assert np.all(scale > 0)  # every parameter moves some residual
    np.testing.assert_allclose(jacobian[:, : layout.size], finite, rtol=0, atol=1e-5 * scale.max())
    np.testing.assert_array_equal(jacobian[:, layout.size :], 0.0)  # padding moves nothing


@pytest.mark.parametrize(("objective_name", "strategy"), [("transfer", None), ("hugin", "distance")])
def test_jacobian_matches_plain_forward_mode(objective_name, strategy, monkeypatch):
    """Rectilinear cameras with wrong matches: many transfers land behind the target camera, where
    the residual is the angle between the rays (its derivative is a separate branch)."""
    truth = synthetic.cube_rig(projection=0, hfov=110.0, b=-0.02, orientation_jitter_deg=3.0, seed=6)
    project = synthetic.control_points_from_truth(truth, 1500, noise_px=0.5, outlier_fraction=0.4, seed=7)
    project = synthetic.perturb(project, angle_deg=(1, 3), hfov_offset_deg=(1, 2), b=None, seed=8)
    problem, layout, args, params = _stage(project, objective_name)
    assert problem.config.projection == 0 and not problem.config.lines

    cps, cameras = project.control_points, problem.cameras
    undefined = 0
    for (source, xy), target in [((cps.image_a, cps.xy_a), cps.image_b), ((cps.image_b, cps.xy_b), cps.image_a)]:
        ray, ok = rigjax.img_to_ray(cameras.take(jnp.asarray(source)), jnp.asarray(xy))
        _, ok_back = rigjax.ray_to_img(cameras.take(jnp.asarray(target)), ray)
        undefined += np.sum(~np.asarray(ok & ok_back))
    assert undefined >= 10  # the undefined branch is exercised

    custom_value, custom = _value_and_jacobian(params, args, problem.config, strategy)
    monkeypatch.setattr(objective, "_rig_objective", objective._rig_objective.fun)  # no custom rule
    plain_value, plain = _value_and_jacobian(params, args, problem.config, strategy)
    assert np.abs(plain).max(axis=0)[: layout.size].min() > 0  # every parameter moves some residual
    np.testing.assert_allclose(custom, plain, rtol=0, atol=1e-9 * np.abs(plain).max())
    # The rule's own residuals (what LM steps from) are the primal function's.
    np.testing.assert_allclose(custom_value, plain_value, rtol=0, atol=1e-9 * np.abs(plain_value).max())


@pytest.mark.parametrize(("schedule", "letters"), [("YPR", "YPR"), ("YPR_VB", "VBYPR"), ("CDE", "CDE")])
def test_a_stage_differentiates_along_its_own_letters(schedule, letters, monkeypatch):
    """A stage's Jacobian runs along its letters only (through the intrinsics they move, or none
    for orientations): on the stage's parameters it is plain forward mode's, on a rig of three
    lens types with line points and straight lines."""
    project = synthetic.perturb(_mixed_rig(), angle_deg=(1, 3), hfov_offset_deg=(1, 2), b=None, seed=9)
    problem = prepare(project, schedule)
    layout = problem.stages[0][1]
    args = staged._args(problem, layout, problem.cameras)
    params = jnp.asarray(initial_params(layout, problem.cameras))
    config = objective.stage_config(problem.config, args.slot)
    assert config.letters == letters
    custom = _jacobian(params, args, config)
    monkeypatch.setattr(objective, "_rig_objective", objective._rig_objective.fun)  # no custom rule
    plain = _jacobian(params, args, problem.config)
    assert np.abs(plain).max(axis=0)[: layout.size].min() > 0  # every parameter moves some residual
    np.testing.assert_allclose(custom, plain, rtol=0, atol=1e-9 * np.abs(plain).max())


@pytest.mark.parametrize(
    ("schedule", "objective_name", "strategy", "robust"),
    [
        ("VABCDEYPR", "transfer", None, "cauchy"),
        ("YPR_VB", "sphere", None, "huber"),
        ("VABCDEYPR", "hugin", "distance", None),
    ],
)
def test_normal_equations_are_those_of_the_jacobian(schedule, objective_name, strategy, robust):
    """LM's model, summed from each point's two cameras, against the materialised Jacobian's
    ``J^T J`` and ``J^T r``: per-camera and shared letters, robust losses, line points (some
    within one image), straight lines, and Hugin's FOV factor where it is above 1 (the hfovs
    shrunk below the start's)."""
    project = synthetic.perturb(_mixed_rig(), angle_deg=(1, 3), hfov_offset_deg=(1, 2), b=None, seed=10)
    cps = project.control_points
    image_b = cps.image_b.copy()
    image_b[:3] = cps.image_a[:3]  # line points within one image, as Hugin's users often set them
    project = project.replace(control_points=rigjax.ControlPoints(cps.image_a, image_b, cps.xy_a, cps.xy_b, cps.kind))
    problem = prepare(project, schedule, objective=objective_name, robust=robust, robust_scale=1.0)
    layout = problem.stages[0][1]
    args = jax.tree_util.tree_map(jnp.asarray, staged._args(problem, layout, problem.cameras))
    config = objective.stage_config(problem.config, args.slot)
    v_slots = np.asarray(args.slot)[:, objective.LETTERS.index("V")]
    params = jnp.asarray(initial_params(layout, problem.cameras)).at[v_slots[v_slots >= 0]].add(-1.5)
    if objective_name == "hugin":
        assert (
            float(objective._fov_factor(objective.theta_from_params(params, args), args)) > 1.01
        )  # the factor under test
    value, jacobian = _value_and_jacobian(params, args, config, strategy)
    r, hessian, gradient = jax.jit(objective.normal_equations, static_argnums=(2, 3))(params, args, config, strategy)
    np.testing.assert_allclose(np.asarray(r), value, rtol=0, atol=1e-9 * np.abs(value).max())
    reference = jacobian.T @ jacobian
    np.testing.assert_allclose(np.asarray(hessian), reference, rtol=0, atol=1e-10 * np.abs(reference).max())
    reference = jacobian.T @ value
    np.testing.assert_allclose(np.asarray(gradient), reference, rtol=0, atol=1e-10 * np.abs(reference).max())
