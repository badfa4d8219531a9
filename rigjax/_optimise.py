"""Staged Levenberg-Marquardt on control points: ``rigjax.optimise``.

Python-time analysis fixes a stage's structure (which camera fields come from which parameter,
as index arrays); one jit-compiled function solves any stage of any rig of the same sizes, with
all data passed as arguments, so a second project of the same shape does not recompile.

Each stage reports its status, steps, residual evaluations, RMS before and after (the transfer
error and libpano13's spherical distance, in pixels) and wall time. A stage that diverges keeps
its starting parameters and says so; raising is the caller's choice.
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import NamedTuple

import jax
import numpy as np

from ._camera import Camera
from ._errors import RigjaxError
from ._objective import LETTERS, _Args, _Config, _metrics, _stage_config, _theta_of
from ._panorama import Equirect
from ._project import Project
from ._residuals import (FIRST_STRAIGHT_LINE, HORIZONTAL_LINE, NORMAL, ROBUST_LOSSES, VERTICAL_LINE, LineGroups,
                         PointArrays)
from ._schedule import Layout, parse_schedule, stage_layout, variables_layout
from ._solver import BACKENDS, STATUS, SolverOptions, _metrics_batch, _solve, _solve_batch

__all__ = ["BACKENDS", "STATUS", "SolverOptions", "optimise", "optimise_batch", "evaluate"]

OBJECTIVES = ("transfer", "sphere", "hugin")
PADDED_POINTS = 256  # control points are padded (weight 0) to a multiple of this
PADDED_GROUPS = 16  # and straight-line rows, when there are any, to a multiple of this
PADDED_PARAMETERS = 16  # a stage's parameter vector is padded to a multiple of this


def _round_up(n: int, multiple: int) -> int:
    return -(-n // multiple) * multiple


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

    for pair in np.unique(cps.image_a[normal].astype(np.int64) * n + cps.image_b[normal]).tolist():
        a, b = divmod(pair, n)
        parent[root(a)] = root(b)
    groups: dict[int, list[int]] = {}
    for k in range(n):
        groups.setdefault(root(k), []).append(k)
    if len(groups) > 1:
        listed = "; ".join(str(g) for g in sorted(groups.values()))
        raise RigjaxError(f"the control points split the images into {len(groups)} unconnected groups: {listed}")


def _slot_matrix(layout: Layout) -> np.ndarray:
    return np.stack([layout.slot[letter] for letter in LETTERS], axis=-1)


def _initial_params(layout: Layout, cameras: Camera) -> np.ndarray:
    """The stage's starting parameters, padded with zeros to a multiple of PADDED_PARAMETERS (the
    zeros have zero Jacobian columns), so that stages of similar sizes share a compilation."""
    params = np.zeros(_round_up(layout.size, PADDED_PARAMETERS))
    theta = _theta_of(jax.tree_util.tree_map(np.asarray, cameras), np)
    slots = _slot_matrix(layout)
    params[slots[slots >= 0]] = theta[slots >= 0]
    return params


def _padded_points(project: Project, weight: np.ndarray, at_least: int | None = None) -> tuple[PointArrays, np.ndarray]:
    """Control points padded to a multiple of PADDED_POINTS (and to ``at_least``) with copies of
    the first, of weight 0."""
    cps = project.control_points
    n = max(len(cps), at_least or 0)
    size = max(PADDED_POINTS, _round_up(n, PADDED_POINTS))
    n = len(cps)
    pad = np.zeros(size - n, np.int64)

    def padded(values):
        return np.concatenate([values, values[pad]])

    points = PointArrays(*(padded(v) for v in (cps.image_a, cps.image_b, cps.xy_a, cps.xy_b, cps.kind)))
    return points, np.concatenate([weight, np.zeros(size - n)])


def _straight_line_rows(project: Project, weight: np.ndarray) -> list[tuple[int, int]]:
    """``(point, partner)`` of every straight-line (t3+) point in use: libpano13 pairs a point
    with the first other point of its ``t``. A line of one point has no residual."""
    kind = project.control_points.kind
    straight = np.flatnonzero((kind >= FIRST_STRAIGHT_LINE) & (weight > 0))
    rows = []
    for k in straight:
        others = straight[(kind[straight] == kind[k]) & (straight != k)]
        if others.size:
            rows.append((int(k), int(others[0])))
    return rows


def _padded_groups(project: Project, rows: list[tuple[int, int]], size: int) -> tuple[LineGroups, np.ndarray]:
    """Straight-line rows padded to ``size`` (weight 0; four coincident points)."""
    cps = project.control_points
    image, xy = np.zeros((size, 4), np.int64), np.zeros((size, 4, 2))
    for r, (k, j) in enumerate(rows):
        image[r] = cps.image_a[k], cps.image_b[k], cps.image_a[j], cps.image_b[j]
        xy[r] = cps.xy_a[k], cps.xy_b[k], cps.xy_a[j], cps.xy_b[j]
    weight = np.zeros(size)
    weight[: len(rows)] = 1.0
    return LineGroups(image, xy), weight


class _Shape(NamedTuple):
    """Padded sizes shared by the projects of one compiled solve."""

    points: int
    groups: int  # straight-line rows: 0, or a multiple of PADDED_GROUPS
    lines: bool  # any t1/t2 line point


def _shape_of(projects: list[Project]) -> _Shape:
    rows = max(len(_straight_line_rows(p, np.ones(len(p.control_points)))) for p in projects)
    kinds = [p.control_points.kind for p in projects]
    return _Shape(max(len(k) for k in kinds), _round_up(rows, PADDED_GROUPS),
                  any(bool(np.any((k == VERTICAL_LINE) | (k == HORIZONTAL_LINE))) for k in kinds))  # fmt: skip


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
    out = _metrics(project.cameras(host=True), points, project.canvas(host=True), padded_weight,
                   projections.pop() if len(projections) == 1 else None)  # fmt: skip
    return Evaluation(float(out[0]), float(out[1]), np.asarray(out[2])[:n_points], np.asarray(out[3])[:n_points])


class _Problem(NamedTuple):
    """A project analysed for solving: stages, static config and padded data. The data stay on the
    host (NumPy) until a jitted call takes them: its dispatch transfers them at a fraction of the
    cost of a ``jnp.asarray`` each."""

    stages: list[tuple[str, Layout]]
    config: _Config
    cameras: Camera
    points: PointArrays
    weight: np.ndarray  # padded; 0 for straight-line points, which have rows of their own
    groups: LineGroups
    group_weight: np.ndarray
    canvas: Equirect
    robust_scale: float
    cost_threshold: float
    solver: SolverOptions
    n_points: int
    not_optimised: tuple[str, ...]


def _prepare(
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
    shape: _Shape | None = None,
) -> _Problem:
    """:func:`optimise`'s arguments checked and turned into padded host arrays. ``shape`` pads
    the points as another project's (:func:`optimise_batch`)."""
    solver = solver or SolverOptions()
    if objective not in OBJECTIVES:
        raise RigjaxError(f"objective must be one of {OBJECTIVES}, got {objective!r}")
    if robust not in ROBUST_LOSSES:
        raise RigjaxError(f"robust must be one of {ROBUST_LOSSES}, got {robust!r}")
    if objective == "hugin" and robust is not None:
        raise RigjaxError("objective 'hugin' has no robust loss (Hugin 2022 sends libpano13 a Huber sigma of 0); "
                          "use objective 'transfer' or 'sphere' with a robust loss")
    _check_project(project, anchor)
    projections = {image.projection for image in project.images}
    n_points = len(project.control_points)
    weight = np.ones(n_points) if weights is None else np.asarray(weights, dtype=float)
    if weight.shape != (n_points,):
        raise RigjaxError(f"weights has shape {weight.shape}, expected ({n_points},)")
    kind = project.control_points.kind
    rows = _straight_line_rows(project, weight)
    observations = int(np.sum(np.where(kind == NORMAL, 2, 1) * (weight > 0) * (kind < FIRST_STRAIGHT_LINE)))
    observations += 2 * len(rows)
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
                f"(2 per control point, 1 per t1/t2 line point, 2 per straight-line point); add control points "
                f"or optimise fewer parameters"
            )
    shape = shape or _shape_of([project])
    projection = projections.pop() if len(projections) == 1 else None
    config = _Config(objective, shape.lines, robust, projection, solver.backend)
    points, padded_weight = _padded_points(project, weight * (kind < FIRST_STRAIGHT_LINE), shape.points)
    groups, group_weight = _padded_groups(project, rows, shape.groups)
    return _Problem(
        stages, config, project.cameras(host=True), points, padded_weight, groups, group_weight,
        project.canvas(host=True),
        float(robust_scale),
        solver.rms_threshold**2 * 2 * max(int(np.sum(weight > 0)), 1), solver,
        n_points, not_optimised,
    )  # fmt: skip


def _report(name: str, layout: Layout, status, steps, evaluations, before, after, seconds: float) -> StageReport:
    """A stage's report from the solve's status and counts and the metrics before and after it."""
    return StageReport(name, layout.names, STATUS[int(status)], int(steps), int(evaluations), float(before[0]),
                       float(after[0]), float(before[1]), float(after[1]), seconds)  # fmt: skip


def _args(problem: _Problem, layout: Layout, cameras: Camera) -> _Args:
    solver = problem.solver
    return _Args(cameras, _slot_matrix(layout), problem.points, problem.canvas, problem.weight,
                 np.asarray(problem.robust_scale), np.asarray(problem.cost_threshold), problem.groups,
                 problem.group_weight, np.asarray(solver.max_steps, np.int32), np.asarray(solver.xtol),
                 np.asarray(solver.ftol))  # fmt: skip


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
        project: cameras and control points (``t0`` matches; ``t1``/``t2`` line points; ``t3``+
            straight lines).
        schedule: stages such as ``"YPR,VBYPR"`` or ``"YPR,YPR_VB"`` (see :mod:`rigjax._schedule`).
        pto_vars: instead of a schedule, one stage of exactly the project's ``v`` lines, as
            Hugin's ``autooptimiser -n`` reads them (no anchor is fixed beyond what they leave out).
        objective: ``"transfer"`` (2-D reprojection errors both ways), ``"sphere"`` (the
            components of libpano13's spherical distance, Hugin's units) or ``"hugin"``
            (libpano13's two strategies with its FOV stabilisation, per stage: the optimum of
            Hugin's ``autooptimiser -n``).
        robust: ``None``, ``"huber"`` or ``"cauchy"``, with ``robust_scale`` in pixels.
        anchor: the image whose yaw, pitch and roll stay fixed.
        solver: stopping rules and backend.
        weights: ``(n_control_points,)`` 0/1 mask of the points to use (all by default).
    """
    problem = _prepare(project, schedule, pto_vars=pto_vars, objective=objective, robust=robust,
                       robust_scale=robust_scale, anchor=anchor, solver=solver, weights=weights)  # fmt: skip
    return _run_stages(project, problem)


def _run_stages(project: Project, problem: _Problem, stage_scale=None) -> Result:
    """The problem's stages one after the other, each from where the previous one ended.
    ``stage_scale``, if given, sets each stage's robust scale from the per-point transfer
    residuals ``(n, 4)`` where the stage starts (rigjax._prune's robust round)."""
    cameras, config, reports = problem.cameras, problem.config, []
    n, after = problem.n_points, None
    for name, layout in problem.stages:
        args = _args(problem, layout, cameras)
        start = time.perf_counter()
        # A stage starts where the previous one ended: its metrics are those of that end.
        before = after if after is not None else _metrics(cameras, args.points, args.canvas, args.weight, config.projection)
        if stage_scale is not None:
            args = args._replace(robust_scale=np.asarray(stage_scale(np.asarray(before[2])[:n])))
        cameras, status, steps, evaluations, after = _solve(_initial_params(layout, cameras), args,
                                                            _stage_config(config, args.slot))  # fmt: skip
        jax.block_until_ready(after)
        reports.append(_report(name, layout, status, steps, evaluations, before, after, time.perf_counter() - start))
    return Result(project.with_cameras(_to_host(cameras)), tuple(reports), np.asarray(after[2])[:n],
                  np.asarray(after[3])[:n], float(after[0]), float(after[1]), problem.not_optimised)  # fmt: skip


def optimise_batch(
    projects: list[Project],
    schedule: str = "YPR,VBYPR",
    *,
    pto_vars: bool = False,
    objective: str = "transfer",
    robust: str | None = None,
    robust_scale: float = 2.0,
    anchor: int = 0,
    solver: SolverOptions | None = None,
    vectorise: bool | None = None,
    workers: int | None = None,
) -> list[Result]:
    """Solve many projects of one structure: many starts for one rig, or one rig over many video
    frames. They must have the same images (count, sizes, lens types, links) and panorama; their
    control points may differ in number. Each element keeps its own status.

    Two ways, the same results (to round-off):

    * ``vectorise=True`` (the default on a GPU or TPU): one compiled, vmapped call per stage over
      the whole batch; a report's ``seconds`` is the whole batch's time.
    * ``vectorise=False`` (the default on a CPU): each project solved as :func:`optimise` solves it,
      ``workers`` at a time in threads (default: the usable CPUs + 1), all sharing one compilation;
      a report's ``seconds`` is that element's own. A CPU runs one solve's many small operations
      on about 1.5 cores, and under ``vmap`` every element runs until the slowest stops: threads
      are the faster way there (measured in the README, *Optimiser speed*).
    """
    if workers is not None and workers < 1:
        raise RigjaxError(f"workers must be at least 1, got {workers}")
    if not projects:
        return []
    shape = _shape_of(projects)
    problems = [_prepare(p, schedule, pto_vars=pto_vars, objective=objective, robust=robust, robust_scale=robust_scale,
                         anchor=anchor, solver=solver, shape=shape) for p in projects]  # fmt: skip
    first = problems[0]

    def structure(problem: _Problem):
        return (problem.config, [(name, _slot_matrix(layout).tolist()) for name, layout in problem.stages],
                np.asarray(problem.cameras.width).tolist(), np.asarray(problem.cameras.height).tolist())  # fmt: skip

    for k, problem in enumerate(problems):
        if structure(problem) != structure(first):
            raise RigjaxError(f"project {k} differs in structure from project 0 (images, lens types, links, "
                              "or parameters of the schedule); optimise_batch needs one structure")  # fmt: skip
    if vectorise is None:
        vectorise = jax.default_backend() != "cpu"
    if not vectorise:
        with ThreadPoolExecutor(workers or _usable_cpus() + 1) as pool:
            return list(pool.map(_run_stages, projects, problems))

    def stack(*leaves):
        return np.stack([np.asarray(leaf) for leaf in leaves])

    batched = ("cameras", "points", "canvas", "weight", "groups", "group_weight", "robust_scale", "cost_threshold")
    batch = first._replace(**{field: jax.tree_util.tree_map(stack, *(getattr(p, field) for p in problems))
                              for field in batched})  # fmt: skip
    cameras, points, canvas, weight = batch.cameras, batch.points, batch.canvas, batch.weight
    projection = first.config.projection
    reports: list[list[StageReport]] = [[] for _ in problems]
    host, after = cameras, None  # NumPy: elements are sliced on the host
    for name, layout in first.stages:
        args = _args(batch, layout, cameras)
        params0 = np.stack([_initial_params(layout, jax.tree_util.tree_map(lambda f: f[b], host))
                            for b in range(len(problems))])  # fmt: skip
        start = time.perf_counter()
        before = after if after is not None else _metrics_batch(cameras, points, canvas, weight, projection)
        cameras, *counts, after = _solve_batch(params0, args, _stage_config(first.config, args.slot))
        jax.block_until_ready(after)
        seconds = time.perf_counter() - start
        host, (status, steps, evaluations), before, after = jax.tree_util.tree_map(
            np.asarray, (cameras, counts, before, after))
        for b in range(len(problems)):
            element = lambda metrics: (metrics[0][b], metrics[1][b])  # noqa: E731
            reports[b].append(_report(name, layout, status[b], steps[b], evaluations[b], element(before),
                                      element(after), seconds))  # fmt: skip
    results = []
    for b, (project, problem) in enumerate(zip(projects, problems)):
        n = problem.n_points
        cams = jax.tree_util.tree_map(lambda f: f[b], host)
        results.append(Result(project.with_cameras(_to_host(cams)), tuple(reports[b]), after[2][b][:n],
                              after[3][b][:n], float(after[0][b]), float(after[1][b]), problem.not_optimised))  # fmt: skip
    return results


def _usable_cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on every platform
        return os.cpu_count() or 1


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
