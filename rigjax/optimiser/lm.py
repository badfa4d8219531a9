"""The Levenberg-Marquardt solve of one stage: stopping rules, backends, batching.

One function (:func:`solve_stage`, compiled as ``solve``) runs a whole stage inside jit;
``solve_batch`` is the same under ``vmap``, each element with its own status. Results are values:
the cameras, a status code (:data:`rigjax.optimiser.options.STATUS`), the step count and the
metrics at the end; nothing raises inside. The options themselves live in
:mod:`rigjax.optimiser.options`.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx

from .objective import (
    SolveArgs,
    SolveConfig,
    median_point_error,
    normal_equations,
    point_metrics,
    stage_residuals,
    theta_from_params,
    with_theta,
)


class _Reductions(eqx.Module):
    """The trust region's state: its step size, and the last trial's changes of 0.5 |r|^2."""

    step_size: jax.Array
    predicted: jax.Array  # change of 0.5 |r|^2 the linear model predicts for the trial step
    actual: jax.Array  # and the change the trial step made


class _TrustRegion(optx.ClassicalTrustRegion):
    """optimistix's trust region, which also keeps the last trial's predicted and actual change
    of the cost for the stopping rules of :class:`_LM`."""

    def init(self, y, f_info_struct):
        zero = jnp.zeros((), jax.tree_util.tree_leaves(y)[0].dtype)
        return _Reductions(super().init(y, f_info_struct).step_size, zero, zero)

    def step(self, first_step, y, y_eval, f_info, f_eval_info, state):
        step_size, accept, result, inner = super().step(first_step, y, y_eval, f_info, f_eval_info, state)
        # The search's own prediction again: XLA merges the two (the compiled solve has as many
        # dot and fusion ops as with a constant here).
        predicted = self.predict_reduction(jax.tree_util.tree_map(jnp.subtract, y_eval, y), f_info)
        actual = f_eval_info.as_min() - f_info.as_min()
        return step_size, accept, result, _Reductions(inner.step_size, predicted, actual)


class _Model(optx.FunctionInfo.EvalGradHessian):
    """The Gauss-Newton model of ``0.5 |r|^2`` at a point: ``f``, its gradient ``J^T r``, the
    Hessian ``J^T J``, and the residuals ``r`` themselves (the stopping rules and the metrics read
    them)."""

    residual: jax.Array


class _State(eqx.Module):
    """:class:`_LM`'s state between steps (the fields optimistix's ``terminate`` and
    ``postprocess`` read included)."""

    first_step: jax.Array
    y_eval: jax.Array  # the trial point
    f_info: _Model  # at the last accepted point
    search_state: _Reductions
    descent_state: eqx.Module
    terminate: jax.Array
    result: optx.RESULTS
    num_steps: jax.Array


def _model(normal_equations, y: jax.Array, args) -> _Model:
    r, hessian, gradient = normal_equations(y, args)
    return _Model(0.5 * jnp.sum(r**2), gradient, lx.MatrixLinearOperator(hessian, lx.positive_semidefinite_tag), r)


class _LM(optx.LevenbergMarquardt):
    """optimistix's Levenberg-Marquardt (its damped Newton descent and trust region; its Cauchy
    termination restated in :meth:`step`), its Gauss-Newton model built by ``normal_equations`` (``(y, args) -> (r, J^T J,
    J^T r)``, :func:`rigjax.optimiser.objective.normal_equations`) rather than from a linearisation of the
    residuals, with the classic stopping rules added (see :class:`rigjax.optimiser.options.SolverOptions`).

    The model is what an LM step needs: ``(J^T J + lambda I) dy = -J^T r`` by Cholesky, and the
    predicted reduction ``g . dy + dy^T J^T J dy / 2``. Built from each point's two-camera block,
    it never forms ``J`` (4 rows per point by the stage's parameters, padded). The rules' values
    are data (the tolerances are this module's array fields, the step limit and the cost threshold
    are read from the solve's ``args``, :class:`rigjax.optimiser.objective.SolveArgs`), so new values do not
    recompile. The step limit is checked here rather than by optimistix's ``max_steps``, which
    must be a Python int.
    """

    xtol: jax.Array
    ftol: jax.Array
    normal_equations: Callable = eqx.field(static=True)

    def __init__(self, xtol: jax.Array, ftol: jax.Array, normal_equations: Callable):
        super().__init__(rtol=xtol, atol=xtol * 1e-3, linear_solver=lx.Cholesky())
        self.search = _TrustRegion()
        self.xtol = xtol
        self.ftol = ftol
        self.normal_equations = normal_equations

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        shapes = jax.eval_shape(partial(_model, self.normal_equations), y, args)
        f_info = jax.tree_util.tree_map(lambda leaf: jnp.zeros(leaf.shape, leaf.dtype), shapes)
        return _State(
            jnp.array(True),
            y,
            f_info,
            self.search.init(y, f_info),
            self.descent.init(y, f_info),
            jnp.array(False),
            optx.RESULTS.successful,
            jnp.array(0),
        )

    def step(self, fn, y, args, options, state, tags):
        f_eval = _model(self.normal_equations, state.y_eval, args)
        step_size, accept, search_result, search_state = self.search.step(
            state.first_step, y, state.y_eval, state.f_info, f_eval, state.search_state
        )
        f_info = jax.tree_util.tree_map(lambda new, old: jnp.where(accept, new, old), f_eval, state.f_info)
        descent_state = self.descent.query(state.y_eval, f_info, state.descent_state)
        new_y = jnp.where(accept, state.y_eval, y)
        step, descent_result = self.descent.step(step_size, descent_state)
        result = optx.RESULTS.where(search_result == optx.RESULTS.successful, descent_result, search_result)
        num_steps = state.num_steps + 1

        moved = jnp.sqrt(jnp.sum((new_y - y) ** 2))
        accepted = ~state.first_step & (moved > 0.0)

        # optimistix's Cauchy rule on an accepted step: every parameter and every residual changed
        # by less than atol + rtol times its value.
        def small(diff, value):
            return jnp.max(jnp.abs(diff) / (self.atol + self.rtol * jnp.abs(value))) < 1

        cauchy = (
            accept
            & small(state.y_eval - y, state.y_eval)
            & small(f_eval.residual - state.f_info.residual, f_eval.residual)
        )
        small_step = moved <= self.xtol * (jnp.sqrt(jnp.sum(y**2)) + self.xtol)
        # MINPACK's ftol test, on every step, accepted or not: the trial changed the cost by at
        # most ftol of it, the linear model predicted at most that too, and at least half the
        # change made (MINPACK's ratio <= 2; a prediction of 0 passes).
        cost = state.f_info.as_min()
        small_cost_change = (
            ~state.first_step
            & (jnp.abs(search_state.actual) <= self.ftol * cost)
            & (jnp.abs(search_state.predicted) <= self.ftol * cost)
            & ((search_state.predicted == 0) | (search_state.actual >= 2 * search_state.predicted))
        )
        below = 2.0 * f_info.as_min() <= args.cost_threshold
        converged = cauchy | small_cost_change | (accepted & small_step) | below
        out_of_steps = ~converged & (num_steps >= args.max_steps)
        result = optx.RESULTS.where(
            out_of_steps & (result == optx.RESULTS.successful), optx.RESULTS.nonlinear_max_steps_reached, result
        )
        new_state = _State(
            jnp.array(False),
            new_y + step,
            f_info,
            search_state,
            descent_state,
            converged | out_of_steps,
            result,
            num_steps,
        )
        return new_y, new_state, None


def _run(params0: jax.Array, args: SolveArgs, config: SolveConfig, strategy: str | None, ftol: jax.Array):
    """One LM run to its stopping rules: ``(params, status code, steps, residuals at params)``."""
    fn = lambda p, a: stage_residuals(p, a, config, strategy)  # noqa: E731
    if config.backend == "optimistix":
        model = partial(normal_equations, config=config, strategy=strategy)
        sol = optx.least_squares(fn, _LM(args.xtol, ftol, model), params0, args=args, max_steps=None, throw=False)
        status = jnp.argmax(
            jnp.stack(
                [
                    sol.result == optx.RESULTS.successful,
                    sol.result == optx.RESULTS.nonlinear_max_steps_reached,
                    sol.result == optx.RESULTS.nonlinear_divergence,
                    sol.result == optx.RESULTS.nonfinite,
                ]
            )
        )
        # The solver's last accepted point and its residuals (no evaluation more).
        return sol.value, status, sol.stats["num_steps"], sol.state.f_info.residual
    import jaxopt

    # The Jacobian materialised (jacfwd through rigjax's custom JVP) and the normal equations
    # solved by Cholesky (jaxopt takes no model of ours, as the optimistix path does); jaxopt's default (matrix-free CG through jvp and vjp,
    # wrapped for implicit differentiation) compiles several times longer for the same optimum. A
    # while loop (unroll=False), not jaxopt's default scan without implicit differentiation, which
    # needs a Python int for the step limit.
    solver = jaxopt.LevenbergMarquardt(
        fn,
        maxiter=args.max_steps,
        xtol=args.xtol,
        tol=ftol,
        gtol=ftol,
        jit=True,
        materialize_jac=True,
        solver="cholesky",
        implicit_diff=False,
        unroll=False,
    )
    params, state = solver.run(params0, args)
    # Evaluated again: jaxopt blends its accepted and rejected states arithmetically, so a rejected
    # trial's non-finite residuals would reach state.residual.
    return params, jnp.where(state.iter_num >= args.max_steps, 1, 0), state.iter_num, fn(params, args)


# libpano13's strategy 1 stops as soon as progress slows (MINPACK ftol 0.05): it only brings the
# start close for strategy 2, whose optimum is Hugin's answer (reference section 4.3).
_HUGIN_STRATEGY_1_FTOL = 0.05


def solve_stage(params0: jax.Array, args: SolveArgs, config: SolveConfig):
    """A stage: ``(cameras, status code, steps, residual evaluations, metrics before, metrics
    after)``, the metrics (:func:`rigjax.optimiser.objective.point_metrics`) those of the cameras
    it starts from (``args.base``) and of those it returns.

    With ``args.median_scale_floor >= 0`` (and a robust loss) the stage's robust scale is the
    median point error at its start, at least that floor: far from the optimum a scale of a couple
    of pixels would leave the good points as flat as the wrong ones, and LM would crawl.

    ``objective="hugin"`` runs libpano13's two strategies one after the other (the spherical
    distance, then its two components); the status is the second one's.
    """
    before = point_metrics(args.base, args.points, args.canvas, args.weight, config.projection)
    if config.robust is not None:
        median = median_point_error(before[2], args.points, args.weight)
        floor = args.median_scale_floor
        args = args._replace(robust_scale=jnp.where(floor >= 0, jnp.maximum(floor, median), args.robust_scale))
    if config.objective == "hugin":
        strategy_1_ftol = jnp.asarray(_HUGIN_STRATEGY_1_FTOL, args.ftol.dtype)
        params1, _, steps1, _ = _run(params0, args, config, "distance", strategy_1_ftol)
        params1 = jnp.where(jnp.all(jnp.isfinite(params1)), params1, params0)
        params, status, steps2, residuals = _run(params1, args, config, "sphere", args.ftol)
        steps, evaluations = steps1 + steps2, steps1 + steps2 + 2
    else:
        params, status, steps, residuals = _run(params0, args, config, None, args.ftol)
        evaluations = steps + 1
    finite = jnp.all(jnp.isfinite(params)) & jnp.isfinite(jnp.sum(residuals**2))
    status = jnp.where(finite, status, 3)
    cameras = with_theta(args.base, theta_from_params(jnp.where(finite, params, params0), args))
    after = point_metrics(cameras, args.points, args.canvas, args.weight, config.projection)
    return cameras, status, steps, evaluations, before, after


solve = jax.jit(solve_stage, static_argnames=("config",))


_BATCH_AXES = SolveArgs(
    base=0,
    slot=None,
    points=0,
    canvas=0,
    weight=0,
    robust_scale=0,
    median_scale_floor=None,
    cost_threshold=0,
    groups=0,
    group_weight=0,
    max_steps=None,
    xtol=None,
    ftol=None,
)


@partial(jax.jit, static_argnums=2)
def solve_batch(params0, args: SolveArgs, config: SolveConfig):
    return jax.vmap(lambda p, a: solve_stage(p, a, config), in_axes=(0, _BATCH_AXES))(params0, args)
