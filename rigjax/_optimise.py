"""Staged Levenberg-Marquardt on control points: ``rigjax.optimise``.

Python-time analysis fixes a stage's structure (which camera fields come from which parameter,
as index arrays); one jit-compiled function solves any stage of any rig of the same sizes, with
all data passed as arguments, so a second project of the same shape does not recompile.

Each stage reports its status, steps, residual evaluations, RMS before and after (the transfer
error and libpano13's spherical distance, in pixels) and wall time. A stage that diverges keeps
its starting parameters and says so; raising is the caller's choice.
"""

from __future__ import annotations

import time
from functools import partial
from dataclasses import dataclass
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx

from ._camera import Camera
from ._errors import RigjaxError
from ._panorama import Equirect
from ._project import Project
from ._residuals import NORMAL, PointArrays, point_residuals, rms, robust_scale
from ._schedule import FIELD, UNIT, Layout, parse_schedule, stage_layout, variables_layout

OBJECTIVES = ("transfer", "sphere")
ROBUST_LOSSES = (None, "huber", "cauchy")
BACKENDS = ("optimistix", "jaxopt")
STATUS = ("converged", "max_steps", "diverged", "nonfinite")


@dataclass(frozen=True)
class SolverOptions:
    """Stopping rules of every stage. A stage stops at the first rule that holds:

    * ``max_steps`` LM steps;
    * the transfer RMS (px) is at most ``rms_threshold``;
    * an accepted step lowers the cost by less than ``ftol`` times the cost;
    * an accepted step moves the parameters by less than ``xtol`` times their norm.
    """

    max_steps: int = 100
    xtol: float = 1e-10
    ftol: float = 1e-12
    rms_threshold: float = 0.0
    backend: str = "optimistix"

    def __post_init__(self) -> None:
        if self.backend not in BACKENDS:
            raise RigjaxError(f"backend must be one of {BACKENDS}, got {self.backend!r}")
        if self.max_steps < 1:
            raise RigjaxError(f"max_steps must be at least 1, got {self.max_steps}")
        for name in ("xtol", "ftol", "rms_threshold"):
            if not getattr(self, name) >= 0.0:
                raise RigjaxError(f"{name} must be a number >= 0, got {getattr(self, name)!r}")


class StageReport(NamedTuple):
    """What one stage did. RMS values are in pixels."""

    name: str
    parameters: tuple[str, ...]
    status: str
    steps: int
    evaluations: int
    rms_initial: float
    rms_final: float
    sphere_rms_initial: float
    sphere_rms_final: float
    seconds: float


@dataclass(frozen=True, eq=False)
class Result:
    """The optimised project, a report per stage, and per-point residuals at the end.

    ``transfer_residuals`` is ``(n, 4)`` px (b from a, a from b), ``sphere_distance`` ``(n,)``
    panorama px (libpano13's ``distSphere``), both in the order of the project's control points.
    """

    project: Project
    stages: tuple[StageReport, ...]
    transfer_residuals: np.ndarray
    sphere_distance: np.ndarray
    rms: float
    sphere_rms: float
    not_optimised: tuple[str, ...] = ()  # v-line variables left out, with the reason

    @property
    def ok(self) -> bool:
        return all(stage.status == "converged" for stage in self.stages)


# ---------------------------------------------------------------------------------------------
# The compiled part. A rig's cameras are a (n_images, 9) array ``theta`` of the letters
# V A B C D E Y P R in internal units (see _schedule.UNIT); a stage's parameters fill the entries
# whose ``slot`` is >= 0. The parameter vector is padded to ``9 n + 6`` so that every stage and
# every schedule of a rig shares one compilation; unused entries have zero Jacobian columns.
LETTERS = "VABCDEYPR"
PADDED_POINTS = 256  # control points are padded (weight 0) to a multiple of this


class _Config(NamedTuple):
    """Static settings: a change recompiles (data never does)."""

    objective: str
    robust: str | None
    projection: int | None
    max_steps: int
    xtol: float
    ftol: float
    backend: str


class _Args(NamedTuple):
    base: Camera  # (n_images,) the cameras at the start of the stage
    slot: jax.Array  # (n_images, 9) int32, parameter index or -1
    points: PointArrays  # padded
    canvas: Equirect
    weight: jax.Array  # (n_padded,) 1 for points in the objective, 0 for points left out
    robust_scale: jax.Array
    cost_threshold: jax.Array  # sum of squared residuals at which a stage stops


def _theta_of(cameras: Camera) -> jax.Array:
    return jnp.stack([getattr(cameras, FIELD[letter]) / UNIT[letter] for letter in LETTERS], axis=-1)


def _with_theta(cameras: Camera, theta: jax.Array) -> Camera:
    return cameras._replace(**{FIELD[letter]: theta[..., i] * UNIT[letter] for i, letter in enumerate(LETTERS)})


def _theta(params: jax.Array, args: _Args) -> jax.Array:
    base = _theta_of(args.base)
    return jnp.where(args.slot >= 0, params[jnp.clip(args.slot, 0, params.shape[0] - 1)], base)


def _point_objective(theta_ab, fixed_ab: Camera, xy_a, xy_b, kind, canvas: Equirect, config: _Config):
    """The objective's four residuals of one control point, from the 2 x 9 parameters of its cameras."""
    cams = _with_theta(fixed_ab, theta_ab)
    point = PointArrays(jnp.zeros(1, jnp.int32), jnp.ones(1, jnp.int32), xy_a[None], xy_b[None], kind[None])
    res = point_residuals(cams, point, canvas, config.projection)
    pair = res.transfer[0] if config.objective == "transfer" else jnp.concatenate([res.sphere_components[0], jnp.zeros(2)])
    line = jnp.zeros(4, pair.dtype).at[0].set(res.line[0])
    return jnp.where(kind == NORMAL, pair, line)


@partial(jax.custom_jvp, nondiff_argnums=(4,))
def _rig_objective(theta: jax.Array, fixed: Camera, points: PointArrays, canvas: Equirect, config: _Config):
    """``(n_points, 4)`` residuals of the rig with parameters ``theta`` ``(n_images, 9)``."""
    theta_ab, fixed_ab = _per_point(theta, fixed, points)
    return jax.vmap(_point_objective, in_axes=(0, 0, 0, 0, 0, None, None))(
        theta_ab, fixed_ab, points.xy_a, points.xy_b, points.kind, canvas, config
    )


def _per_point(theta, fixed: Camera, points: PointArrays):
    pair = jnp.stack([points.image_a, points.image_b], axis=-1)  # (n, 2)
    return theta[pair], fixed.take(pair)


@_rig_objective.defjvp
def _rig_objective_jvp(config, primals, tangents):
    # Each point depends on its two cameras only: its 4 x (2 x 9) Jacobian is computed once, and
    # the JVP of the rig is a gather and a small contraction (cheap for any number of parameters).
    theta, fixed, points, canvas = primals
    dtheta = tangents[0]
    theta_ab, fixed_ab = _per_point(theta, fixed, points)

    def value_and_jacobian(t, f, xy_a, xy_b, kind):
        # One forward pass: the primal is shared by all 18 tangent directions (out_axes None).
        fn = lambda t_: _point_objective(t_, f, xy_a, xy_b, kind, canvas, config)  # noqa: E731
        basis = jnp.eye(t.size, dtype=t.dtype).reshape(-1, *t.shape)
        value, jac = jax.vmap(lambda v: jax.jvp(fn, (t,), (v,)), out_axes=(None, -1))(basis)
        return value, jac.reshape(value.shape + t.shape)

    value, jac = jax.vmap(value_and_jacobian)(theta_ab, fixed_ab, points.xy_a, points.xy_b, points.kind)
    dtheta_ab = dtheta[jnp.stack([points.image_a, points.image_b], axis=-1)]  # (n, 2, 9)
    return value, jnp.einsum("nrcj,ncj->nr", jac, dtheta_ab)


def _residuals(params: jax.Array, args: _Args, config: _Config) -> jax.Array:
    r = _rig_objective(_theta(params, args), args.base, args.points, args.canvas, config)
    pair = r.reshape(-1, 2, 2)
    norm = jnp.sqrt(jnp.sum(pair**2, axis=-1))
    pair = pair * robust_scale(norm, config.robust, args.robust_scale)[..., None]
    return (pair * args.weight[:, None, None]).reshape(-1)


class _LM(optx.LevenbergMarquardt):
    """optimistix's LM with the classic stopping rules added (see :class:`SolverOptions`).

    The cost threshold is read from the solve's ``args`` (``_Args.cost_threshold``), so a new
    threshold does not recompile.
    """

    xtol: float
    ftol: float

    def __init__(self, xtol: float, ftol: float):
        # Normal equations by Cholesky: (J^T J + lambda I) is a small P x P matrix, much cheaper
        # than a Householder QR of the tall [J; sqrt(lambda) I] for every trial step.
        super().__init__(rtol=xtol, atol=xtol * 1e-3, linear_solver=lx.Normal(lx.Cholesky()))
        self.xtol = xtol
        self.ftol = ftol

    def step(self, fn, y, args, options, state, tags):
        new_y, new_state, aux = super().step(fn, y, args, options, state, tags)
        moved = jnp.sqrt(jnp.sum((new_y - y) ** 2))
        accepted = ~state.first_step & (moved > 0.0)
        cost_old = jnp.sum(state.f_info.residual**2)
        cost_new = jnp.sum(new_state.f_info.residual**2)
        small_cost_change = cost_old - cost_new <= self.ftol * cost_old
        small_step = moved <= self.xtol * (jnp.sqrt(jnp.sum(y**2)) + self.xtol)
        below = cost_new <= args.cost_threshold
        stop = new_state.terminate | (accepted & (small_cost_change | small_step)) | below
        return new_y, eqx.tree_at(lambda s: s.terminate, new_state, stop), aux


def _solve_impl(params0: jax.Array, args: _Args, config: _Config):
    fn = lambda p, a: _residuals(p, a, config)  # noqa: E731
    if config.backend == "optimistix":
        sol = optx.least_squares(
            fn, _LM(config.xtol, config.ftol), params0, args=args, max_steps=config.max_steps, throw=False
        )
        params, steps = sol.value, sol.stats["num_steps"]
        status = jnp.argmax(jnp.stack([
            sol.result == optx.RESULTS.successful,
            sol.result == optx.RESULTS.nonlinear_max_steps_reached,
            sol.result == optx.RESULTS.nonlinear_divergence,
            sol.result == optx.RESULTS.nonfinite,
        ]))  # fmt: skip
    else:
        import jaxopt

        solver = jaxopt.LevenbergMarquardt(fn, maxiter=config.max_steps, xtol=config.xtol, tol=config.ftol,
                                           gtol=config.ftol, jit=True)  # fmt: skip
        params, state = solver.run(params0, args)
        steps = state.iter_num
        status = jnp.where(steps >= config.max_steps, 1, 0)
    finite = jnp.all(jnp.isfinite(params)) & jnp.isfinite(jnp.sum(fn(params, args) ** 2))
    status = jnp.where(finite, status, 3)
    theta = _theta(jnp.where(finite, params, params0), args)
    return _with_theta(args.base, theta), status, steps


_solve = jax.jit(_solve_impl, static_argnames=("config",))


@jax.jit(static_argnames=("projection",))
def _metrics(cameras: Camera, points: PointArrays, canvas: Equirect, weight: jax.Array, projection: int | None):
    """Transfer and sphere RMS (px) over the normal points in use, and the per-point residuals.

    A function of the cameras, not of a stage's parameters: compiled once per rig shape.
    """
    res = point_residuals(cameras, points, canvas, projection)
    normal = (points.kind == NORMAL) & (weight > 0)
    return rms(res.transfer, normal, per_point=2), rms(res.sphere, normal), res.transfer, res.sphere


# ---------------------------------------------------------------------------------------------
# The Python-time part: checks, layout, reports.
def _check_project(project: Project, anchor: int) -> None:
    n = len(project.images)
    if not 0 <= anchor < n:
        raise RigjaxError(f"anchor image {anchor} does not exist (the project has {n} images)")
    cps = project.control_points
    bad = np.flatnonzero(~np.all(np.isfinite(cps.xy_a) & np.isfinite(cps.xy_b), axis=1))
    if bad.size:
        k = bad[0]
        raise RigjaxError(f"control point {k} (images {cps.image_a[k]} and {cps.image_b[k]}) has a "
                          f"non-finite coordinate: {cps.xy_a[k].tolist()} {cps.xy_b[k].tolist()}")  # fmt: skip
    normal = cps.kind == NORMAL
    counts = np.bincount(np.concatenate([cps.image_a[normal], cps.image_b[normal]]), minlength=n)
    for k in np.flatnonzero(counts == 0):
        name = f" ({project.images[k].filename})" if project.images[k].filename else ""
        raise RigjaxError(f"image {k}{name} has no control points joining it to another image")
    parent = list(range(n))

    def root(k):
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    for a, b in zip(cps.image_a[normal], cps.image_b[normal]):
        parent[root(int(a))] = root(int(b))
    groups: dict[int, list[int]] = {}
    for k in range(n):
        groups.setdefault(root(k), []).append(k)
    if len(groups) > 1:
        listed = "; ".join(str(g) for g in sorted(groups.values()))
        raise RigjaxError(f"the control points split the images into {len(groups)} unconnected groups: {listed}")


def _slot_matrix(layout: Layout) -> np.ndarray:
    return np.stack([layout.slot[letter] for letter in LETTERS], axis=-1)


def _initial_params(layout: Layout, cameras: Camera, size: int) -> np.ndarray:
    """The stage's starting parameters, padded with zeros to ``size``."""
    params = np.zeros(size)
    theta = np.asarray(_theta_of(cameras))
    slots = _slot_matrix(layout)
    params[slots[slots >= 0]] = theta[slots >= 0]
    return params


def _padded_points(project: Project, weight: np.ndarray) -> tuple[PointArrays, np.ndarray]:
    """Control points padded to a multiple of PADDED_POINTS with copies of the first (weight 0)."""
    cps = project.control_points
    n = len(cps)
    size = max(PADDED_POINTS, -(-n // PADDED_POINTS) * PADDED_POINTS)
    pad = np.zeros(size - n, np.int64)

    def padded(values):
        return jnp.asarray(np.concatenate([values, values[pad]]))

    points = PointArrays(*(padded(v) for v in (cps.image_a, cps.image_b, cps.xy_a, cps.xy_b, cps.kind)))
    return points, np.concatenate([weight, np.zeros(size - n)])


class Evaluation(NamedTuple):
    """Residuals of a project at its current parameters (pixels; see :class:`Result`)."""

    rms: float
    sphere_rms: float
    transfer_residuals: np.ndarray
    sphere_distance: np.ndarray


def evaluate(project: Project, weights: np.ndarray | None = None) -> Evaluation:
    """The transfer and sphere RMS of a project's normal control points, and per-point residuals."""
    n_points = len(project.control_points)
    weight = np.ones(n_points) if weights is None else np.asarray(weights, dtype=float)
    points, padded_weight = _padded_points(project, weight)
    projections = {image.projection for image in project.images}
    out = _metrics(project.cameras(), points, project.canvas(), jnp.asarray(padded_weight),
                   projections.pop() if len(projections) == 1 else None)  # fmt: skip
    return Evaluation(float(out[0]), float(out[1]), np.asarray(out[2])[:n_points], np.asarray(out[3])[:n_points])


def optimise(
    project: Project,
    schedule: str = "YPR,VBYPR",
    *,
    pto_vars: bool = False,
    objective: str = "transfer",
    robust: str | None = None,
    robust_scale: float = 2.0,
    anchor: int = 0,
    solver: SolverOptions | None = None,
    weights: np.ndarray | None = None,
) -> Result:
    """Optimise a project's cameras on its control points, stage by stage.

    Args:
        project: cameras and control points (``t0`` matches; ``t1``/``t2`` line points).
        schedule: stages such as ``"YPR,VBYPR"`` or ``"YPR,YPR_VB"`` (see :mod:`rigjax._schedule`).
        pto_vars: instead of a schedule, one stage of exactly the project's ``v`` lines, as
            Hugin's ``autooptimiser -n`` reads them (no anchor is fixed beyond what they leave out).
        objective: ``"transfer"`` (2-D reprojection errors both ways) or ``"sphere"`` (the
            components of libpano13's spherical distance, Hugin's units).
        robust: ``None``, ``"huber"`` or ``"cauchy"``, with ``robust_scale`` in pixels.
        anchor: the image whose yaw, pitch and roll stay fixed.
        solver: stopping rules and backend.
        weights: ``(n_control_points,)`` 0/1 mask of the points to use (all by default).
    """
    solver = solver or SolverOptions()
    if objective not in OBJECTIVES:
        raise RigjaxError(f"objective must be one of {OBJECTIVES}, got {objective!r}")
    if robust not in ROBUST_LOSSES:
        raise RigjaxError(f"robust must be one of {ROBUST_LOSSES}, got {robust!r}")
    _check_project(project, anchor)
    cameras = project.cameras()
    projections = {image.projection for image in project.images}
    n_points = len(project.control_points)
    weight = np.ones(n_points) if weights is None else np.asarray(weights, dtype=float)
    if weight.shape != (n_points,):
        raise RigjaxError(f"weights has shape {weight.shape}, expected ({n_points},)")
    observations = int(np.sum(np.where(project.control_points.kind == NORMAL, 2, 1) * (weight > 0)))
    links = [dict(image.links) for image in project.images]
    not_optimised: tuple[str, ...] = ()
    if pto_vars:
        layout, not_optimised = variables_layout(project.variables, links)
        if layout.size == 0:
            raise RigjaxError("the project's v lines name no geometric variable to optimise")
        stages = [("v-lines", layout)]
    else:
        stages = [(stage.name, stage_layout(stage, links, anchor)) for stage in parse_schedule(schedule)]
    for name, layout in stages:
        if layout.size > observations:
            raise RigjaxError(
                f"stage {name}: {layout.size} parameters but only {observations} observations "
                f"(2 per control point, 1 per line point); add control points or optimise fewer parameters"
            )

    config = _Config(objective, robust, projections.pop() if len(projections) == 1 else None,
                     solver.max_steps, solver.xtol, solver.ftol, solver.backend)  # fmt: skip
    points, padded_weight = _padded_points(project, weight)
    canvas = project.canvas()
    cost_threshold = solver.rms_threshold**2 * 2 * max(int(np.sum(weight > 0)), 1)
    size = len(LETTERS) * len(project.images) + len(LETTERS)  # room for any stage of this rig
    reports = []
    for name, layout in stages:
        args = _Args(cameras, jnp.asarray(_slot_matrix(layout)), points, canvas, jnp.asarray(padded_weight),
                     jnp.asarray(float(robust_scale)), jnp.asarray(float(cost_threshold)))  # fmt: skip
        start = time.perf_counter()
        before = _metrics(cameras, points, canvas, args.weight, config.projection)
        cameras, status, steps = _solve(jnp.asarray(_initial_params(layout, cameras, size)), args, config)
        after = jax.block_until_ready(_metrics(cameras, points, canvas, args.weight, config.projection))
        seconds = time.perf_counter() - start
        reports.append(StageReport(name, layout.names, STATUS[int(status)], int(steps), int(steps) + 1,
                                   float(before[0]), float(after[0]), float(before[1]), float(after[1]), seconds))  # fmt: skip
    transfer, dist = np.asarray(after[2])[:n_points], np.asarray(after[3])[:n_points]
    return Result(project.with_cameras(_to_host(cameras)), tuple(reports), transfer, dist,
                  float(after[0]), float(after[1]), not_optimised)  # fmt: skip


def _to_host(cameras: Camera) -> Camera:
    """Host arrays, with yaw, pitch and roll wrapped into [-180, 180) as libpano13 does."""
    cameras = jax.tree_util.tree_map(np.asarray, cameras)
    wrap = lambda angle: (angle + 180.0) % 360.0 - 180.0  # noqa: E731
    return cameras._replace(yaw=wrap(cameras.yaw), pitch=wrap(cameras.pitch), roll=wrap(cameras.roll))


def format_report(result: Result) -> str:
    """The per-stage table the CLI prints."""
    lines = [f"{'stage':<10} {'status':<10} {'params':>6} {'steps':>5} {'evals':>5} "
             f"{'rms px':>17} {'sphere rms px':>17} {'time s':>7}"]  # fmt: skip
    for s in result.stages:
        lines.append(f"{s.name:<10} {s.status:<10} {len(s.parameters):>6} {s.steps:>5} {s.evaluations:>5} "
                     f"{s.rms_initial:>8.3f}->{s.rms_final:<8.3f} {s.sphere_rms_initial:>8.3f}->{s.sphere_rms_final:<8.3f} "
                     f"{s.seconds:>7.3f}")  # fmt: skip
    return "\n".join(lines)
