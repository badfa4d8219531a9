"""The bundle adjustment's compiled Levenberg-Marquardt solve of one stage (:func:`solve`): Schur
steps on :mod:`rigjax.optimiser.bundle_model`'s reduced normal equations, Nielsen's damping, the
stopping rules of :class:`rigjax.optimiser.options.SolverOptions`, and the covariance where it ends."""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp

from .bundle_covariance import covariance
from .bundle_model import (
    BundleArgs,
    BundleConfig,
    Linearisation,
    linearise,
    median_view_error,
    point_data,
    point_rows,
    raw_residuals,
    reduce,
    stage_cameras,
    stage_width,
    unit_where_zero,
)
from .objective import letter_columns

# Nielsen's damping: the start, relative to diag(J^T J), and the value at which no step is left to try.
_INITIAL_DAMPING, _MAX_DAMPING = 1e-3, 1e30


def _cost(lin: Linearisation) -> jax.Array:
    """The objective: half the squared residuals, the priors' included."""
    return 0.5 * (jnp.sum(lin.rows**2) + jnp.sum(lin.prior**2))


def schur_step(lin: Linearisation, damping, args: BundleArgs, config: BundleConfig, n_params: int, inverse_depths=None):
    """The damped Gauss-Newton step ``(dc, dp)`` with the points eliminated (module docstring),
    and the cost ``0.5 |r + J d|^2`` the linear model predicts after it (the priors' included).

    With the points' current ``inverse_depths`` the step keeps them >= 0: a point at infinity
    (``q = 0``) whose step would take it beyond stays there, and the step is solved again with its
    depth held (the model's minimum on that bound, not a cut step the model cannot predict, which
    made the trust region crawl); a step that would take a nearer point below 0 stops it at 0."""
    d_cameras, d_points, d_slots = _solve_reduced(lin, damping, args, config, n_params)
    if inverse_depths is not None:
        held = (inverse_depths <= 0.0) & (d_points[:, 2] < 0.0)
        lin = lin._replace(d_point=lin.d_point.at[:, :, 2].multiply(jnp.where(held, 0.0, 1.0)[:, None]))
        d_cameras, d_points, d_slots = _solve_reduced(lin, damping, args, config, n_params)
        d_points = d_points.at[:, 2].set(jnp.maximum(d_points[:, 2], -inverse_depths))
    linear = (
        lin.rows + jnp.einsum("nri,ni->nr", lin.d_cameras, d_slots) + jnp.einsum("nri,ni->nr", lin.d_point, d_points)
    )
    prior = lin.prior + args.prior_weight * d_cameras
    return d_cameras, d_points, 0.5 * (jnp.sum(linear**2) + jnp.sum(prior**2))


def _solve_reduced(lin: Linearisation, damping, args: BundleArgs, config: BundleConfig, n_params: int):
    """The damped step: the cameras' from the reduced equations, each point's by back-substitution;
    and each point's cameras' step ``(n, K L)``."""
    n_images = args.base.hfov.shape[0]
    r = reduce(lin, damping, args, config)
    d_cameras = jnp.linalg.solve(r.hessian + damping * jnp.diag(r.scale), -r.gradient)
    d_letters = (r.to_params @ d_cameras).reshape(n_images, stage_width(config))
    image = args.points.image
    d_slots = d_letters[image].reshape(image.shape[0], -1)
    with_one = jnp.concatenate([d_slots, jnp.ones_like(d_slots[:, :1])], -1)
    return d_cameras, -jnp.einsum("nij,nkj,nk->ni", r.point_inverse, r.coupling, with_one), d_slots


class _State(NamedTuple):
    params: jax.Array
    point_params: jax.Array
    lin: Linearisation
    cost: jax.Array
    damping: jax.Array
    growth: jax.Array  # Nielsen's nu
    steps: jax.Array
    done: jax.Array
    status: jax.Array


def solve_stage(params0, point_params0, args: BundleArgs, config: BundleConfig):
    """One stage to its stopping rules (those of :class:`rigjax.optimiser.options.SolverOptions`:
    ``max_steps``; a step that changes the cost, and that the model predicts to change it, by at
    most ``ftol`` of it; an accepted step shorter than ``xtol`` of the parameters' norm; a cost of 0).

    With a robust loss and ``args.median_scale_floor >= 0``, the loss's scale is the median point
    error where the stage starts, at least that floor (as the rotation-only solve does).

    Each trial point is linearised whole (residuals and derivatives in one pass, kept if the step
    is accepted), the start included: the compiled solve holds one copy of the derivatives, where a
    residual pass, a conditional linearisation and one of the start compiled in about twice the time.

    Returns ``(params, point_params, status code, steps, residuals at the start, covariance,
    sigma, free, depth_sd, T)``: the residuals without the robust loss, the covariance, residual
    scale, free parameters and the points' inverse depths' deviations where it ends
    (:func:`rigjax.optimiser.bundle_covariance.covariance`), and there each camera's stage parameters'
    derivatives along the parameters (:func:`rigjax.optimiser.bundle_model.camera_jacobian`).
    """
    n_params = params0.shape[0]
    raw0 = raw_residuals(params0, point_params0, args, config)
    if config.robust is not None:
        median = median_view_error(raw0, args.weight)
        floor = args.median_scale_floor
        args = args._replace(robust_scale=jnp.where(floor >= 0, jnp.maximum(floor, median), args.robust_scale))
    # The loop's first pass linearises the start (a zero step from a zero model, always accepted),
    # so that the compiled solve holds one copy of the derivatives.
    zeros = jax.eval_shape(partial(linearise, config=config), params0, point_params0, args)
    lin0 = jax.tree_util.tree_map(lambda leaf: jnp.zeros(leaf.shape, leaf.dtype), zeros)
    one = jnp.ones((), raw0.dtype)
    state = _State(
        params0,
        point_params0,
        lin0,
        jnp.inf * one,
        _INITIAL_DAMPING * one,
        2.0 * one,
        jnp.array(-1),
        False,
        jnp.array(0),
    )

    def body(s: _State) -> _State:
        first = s.steps < 0
        d_cameras, d_points, predicted_cost = schur_step(s.lin, s.damping, args, config, n_params, s.point_params[:, 2])
        d_cameras, d_points = jnp.where(first, 0.0, d_cameras), jnp.where(first, 0.0, d_points)
        params = s.params + d_cameras
        point_params = s.point_params + d_points
        point_params = point_params.at[:, 2].set(jnp.maximum(point_params[:, 2], 0.0))  # round-off
        trial = linearise(params, point_params, args, config)
        cost = _cost(trial)
        actual, predicted = s.cost - cost, s.cost - predicted_cost
        accept = first | (jnp.isfinite(cost) & (actual > 0.0) & (predicted > 0.0))
        lin = jax.tree_util.tree_map(lambda new, old: jnp.where(accept, new, old), trial, s.lin)
        ratio = actual / jnp.where(predicted > 0.0, predicted, 1.0)
        damping = jnp.where(
            accept, s.damping * jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * ratio - 1.0) ** 3), s.damping * s.growth
        )
        damping = jnp.where(first, s.damping, damping)
        growth = jnp.where(accept, 2.0, 2.0 * s.growth)
        moved = jnp.sqrt(jnp.sum(d_cameras**2) + jnp.sum(d_points**2))
        size = jnp.sqrt(jnp.sum(s.params**2) + jnp.sum(s.point_params**2))
        small_change = (jnp.abs(actual) <= args.ftol * s.cost) & (jnp.abs(predicted) <= args.ftol * s.cost)
        converged = small_change | (accept & (moved <= args.xtol * (size + args.xtol)))
        converged = converged | (damping > _MAX_DAMPING)  # no step reduces the cost any more
        converged = jnp.where(first, False, converged) | (accept & (cost == 0.0))
        steps = s.steps + 1
        new_cost = jnp.where(accept, cost, s.cost)
        finite = jnp.isfinite(new_cost)
        status = jnp.where(~finite, 3, jnp.where(converged, 0, jnp.where(steps >= args.max_steps, 1, 0)))
        return _State(
            jnp.where(accept, params, s.params),
            jnp.where(accept, point_params, s.point_params),
            lin,
            new_cost,
            damping,
            growth,
            steps,
            converged | (steps >= args.max_steps) | ~finite,
            status,
        )

    end = jax.lax.while_loop(lambda s: ~s.done, body, state)
    cov, sigma, free, depth_sd = covariance(end.lin, args, config, n_params)
    return end.params, end.point_params, end.status, end.steps, raw0, cov, sigma, free, depth_sd, end.lin.to_params


# Gauss-Newton steps that place the points left out of a solve for its cameras.
_POINT_FIT_STEPS = 10


@partial(jax.jit, static_argnames=("config", "fit"))
def final_residuals(params, point_params, args: BundleArgs, config: BundleConfig, fit: bool):
    """``(point_params, residuals)``: with ``fit``, the points not in use (weight 0) placed for the
    cameras (:func:`fit_points`); and every point's raw residuals (weight 1 for all)."""
    everyone = args._replace(weight=jnp.ones_like(args.weight))
    config = config._replace(robust=None)
    if fit:
        point_params = fit_points(params, point_params, everyone, config, args.weight == 0)
    return point_params, raw_residuals(params, point_params, everyone, config)


def fit_points(params, point_params, args: BundleArgs, config: BundleConfig, which):
    """``point_params`` with the points ``which`` (bool ``(n,)``) moved to where they fit the cameras
    ``params`` best, each on its own (damped Gauss-Newton, a step kept where it lowers the point's
    error): what a point that no solve used reprojects to, so that pruning can judge and readmit it."""

    theta, own = stage_cameras(params, args, config)
    image = args.points.image
    columns = jnp.asarray(letter_columns(config))

    def linear(sub, th, point, data):  # a point's residuals and their derivatives along it alone
        f = partial(point_rows, sub, theta=th, data=data, columns=columns, projection=config.projection)
        return f(point), jax.jacfwd(f)(point)

    def step(_, current):
        points, damping = current
        rows, d_point = jax.vmap(linear)(own[image], theta[image], points, point_data(args))
        v = jnp.einsum("nri,nrj->nij", d_point, d_point)
        diagonal = jnp.diagonal(v, axis1=1, axis2=2)
        v = v + jax.vmap(jnp.diag)(damping[:, None] * unit_where_zero(diagonal) + (diagonal <= 0.0))
        d = -jnp.linalg.solve(v, jnp.einsum("nri,nr->ni", d_point, rows)[..., None])[..., 0]
        d = d.at[:, 2].set(jnp.maximum(d[:, 2], -points[:, 2]))
        trial = points + d
        better = jnp.sum(raw_residuals(params, trial, args, config) ** 2, axis=1) < jnp.sum(rows**2, axis=1)
        keep = better & which
        return jnp.where(keep[:, None], trial, points), jnp.where(better, damping / 3.0, damping * 4.0)

    damping = jnp.full(point_params.shape[0], _INITIAL_DAMPING, point_params.dtype)
    return jax.lax.fori_loop(0, _POINT_FIT_STEPS, step, (point_params, damping))[0]


solve = jax.jit(solve_stage, static_argnames=("config",))
