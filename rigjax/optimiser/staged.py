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

from ..camera.model import Camera
from ..camera.panorama import Equirect
from ..compiled import Program
from ..errors import RigjaxError
from ..pto.project import Project
from .config import OptimiseConfig, as_config
from .objective import SolveArgs, point_error
from .options import BACKENDS, STATUS, SolverOptions
from .problem import Problem, initial_params, padded_points, prepare, shape_of, slot_matrix
from .residuals import LineGroups, PointArrays
from .result import OptimiseResult
from .schedule import Layout, reoptimised

__all__ = ["BACKENDS", "STATUS", "SolverOptions", "evaluate", "optimise", "optimise_batch"]

# A stage's solve and the metrics of a rig, loaded from their exports in a process after the first
# when the command line keeps compiled programs (rigjax.compiled): no tracing, and no import of the
# LM solver, in a run of a structure solved before.
_TYPES = (Camera, Equirect, PointArrays, LineGroups, SolveArgs)
_solve = Program("rigjax.optimiser.lm", "solve", static=("config",), types=_TYPES)
_point_metrics = Program("rigjax.optimiser.objective", "point_metrics", static=("projection",), types=_TYPES)


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
    """The optimised project, a report per stage, and per-point residuals at the end: what the
    rotation-only objectives return, an :class:`~rigjax.optimiser.result.OptimiseResult`.

    ``transfer_residuals`` is ``(n, 4)`` px (b from a, a from b), ``sphere_distance`` ``(n,)``
    panorama px (libpano13's ``distSphere``), both in the order of the project's control points.
    ``rms`` is the transfer RMS. Every camera sees from one point, and no standard deviations are
    estimated: ``standard_deviations``, ``orientation_sd_deg``, ``centres`` and ``points`` are None.
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
        """Every stage converged, or stopped early and a later stage that converged optimised all of
        its parameters again: a first ``YPR`` stage that runs out of steps because the lens is off
        nominal only starts ``VBYPR``, whose convergence is the calibration's."""
        later = reoptimised([stage.parameters for stage in self.stages])
        return all(
            stage.status == "converged" or any(self.stages[j].status == "converged" for j in later[k])
            for k, stage in enumerate(self.stages)
        )

    # What only the bundle adjustment estimates (OptimiseResult): none of it here. Every camera sees
    # from one point, the control points have directions and no scene points, and no standard
    # deviations are estimated.
    standard_deviations = orientation_sd_deg = centres = points = None

    def point_errors(self) -> np.ndarray:
        """``(n,)`` px: per control point, the larger of its two transfer errors."""
        return point_error(self.transfer_residuals, np)

    def format_stages(self) -> str:
        """The per-stage table the command line prints (:func:`format_report`)."""
        return format_report(self)

    def format_rms(self) -> str:
        return f"{self.rms:.4f} px (transfer), {self.sphere_rms:.4f} px (sphere)"

    def format_deviations(self) -> str:
        return ""


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
    points, padded_weight = padded_points(project, weight)
    projections = {image.projection for image in project.images}
    out = _point_metrics(
        project.cameras(host=True),
        points,
        project.canvas(host=True),
        padded_weight,
        projection=projections.pop() if len(projections) == 1 else None,
    )
    return Evaluation(float(out[0]), float(out[1]), np.asarray(out[2])[:n_points], np.asarray(out[3])[:n_points])


def _report(name: str, layout: Layout, status, steps, evaluations, before, after, seconds: float) -> StageReport:
    """A stage's report from the solve's status and counts and the metrics before and after it."""
    return StageReport(
        name,
        layout.names,
        STATUS[int(status)],
        int(steps),
        int(evaluations),
        float(before[0]),
        float(after[0]),
        float(before[1]),
        float(after[1]),
        seconds,
    )


def _args(
    problem: Problem,
    layout: Layout,
    cameras: Camera,
    preliminary: bool = False,
    median_scale_floor: float | None = None,
) -> SolveArgs:
    """A stage's data; ``preliminary``: a later stage optimises all its parameters again;
    ``median_scale_floor``: the robust scale is the median point error where the stage starts, at
    least this many px (``SolveArgs.median_scale_floor``)."""
    solver = problem.solver
    ftol = max(solver.ftol, solver.preliminary_ftol) if preliminary else solver.ftol
    return SolveArgs(
        cameras,
        slot_matrix(layout),
        problem.points,
        problem.canvas,
        problem.weight,
        np.asarray(problem.robust_scale),
        np.asarray(-1.0 if median_scale_floor is None else median_scale_floor),
        np.asarray(problem.cost_threshold),
        problem.groups,
        problem.group_weight,
        np.asarray(solver.max_steps, np.int32),
        np.asarray(solver.xtol),
        np.asarray(ftol),
    )


def optimise(
    project: Project,
    config: OptimiseConfig | str | None = None,
    *,
    weights: np.ndarray | None = None,
    nominal: Camera | None = None,
    cluster_error_px: float = 0.0,
    at_infinity: np.ndarray | None = None,
    hold_anchor: bool | None = None,
    rigid: np.ndarray | None = None,
    tracks: np.ndarray | None = None,
) -> OptimiseResult:
    """Optimise a project's cameras on its control points, stage by stage, as ``config`` says.

    Args:
        project: cameras and control points (``t0`` matches; ``t1``/``t2`` line points; ``t3``+
            straight lines).
        config: the settings (:class:`~rigjax.optimiser.config.OptimiseConfig`; its ``prune`` is
            :func:`~rigjax.optimiser.prune.optimise_pruned`'s), or a schedule such as ``"YPR,VBYPR"``
            or ``"YPR,YPR_VB"`` (:mod:`rigjax.optimiser.schedule`) with the other settings at their
            defaults; None: every default. Its objective picks the solver: ``"transfer"`` (2-D
            reprojection errors both ways), ``"sphere"`` (the components of libpano13's spherical
            distance, Hugin's units) or ``"hugin"`` (libpano13's two strategies with its FOV
            stabilisation, per stage: the optimum of Hugin's ``autooptimiser -n``) solve here and
            return a :class:`Result`; ``"reprojection"`` (cameras with centres, the control points
            as scene points) is the bundle adjustment of
            :func:`rigjax.optimiser.bundle.bundle_adjust`, with the config's ``centres`` or the
            project's, and returns a :class:`~rigjax.optimiser.bundle.BundleResult`. Both are
            :class:`~rigjax.optimiser.result.OptimiseResult` values. With ``pto_vars``, one stage of
            exactly the project's ``v`` lines, as Hugin's ``autooptimiser -n`` reads them.
        weights: ``(n_control_points,)`` 0/1 mask of the points to use (all by default).
        nominal: the cameras the reprojection objective's priors hold to (default: the project's);
            an error with the other objectives.
        cluster_error_px: the reprojection objective's offset that neighbouring tracks share,
            which its standard deviations count (:func:`rigjax.optimiser.bundle.bundle_adjust`);
            an error with the other objectives.
        at_infinity, hold_anchor, rigid, tracks: the reprojection objective's points held at
            infinity, its anchor's orientation, its cameras derived from others on a rig and its
            control points that are one scene point (:func:`rigjax.optimiser.bundle.bundle_adjust`);
            an error with the other objectives.
    """
    config = as_config(config)
    if config.objective == "reprojection":
        from .bundle import bundle_adjust

        return bundle_adjust(
            project,
            **config.solve_kwargs(),
            weights=weights,
            nominal=nominal,
            cluster_error_px=cluster_error_px,
            at_infinity=at_infinity,
            hold_anchor=hold_anchor,
            rigid=rigid,
            tracks=tracks,
        )
    reprojection_only(
        config, nominal=nominal, at_infinity=at_infinity, hold_anchor=hold_anchor, rigid=rigid, tracks=tracks
    )
    problem = prepare(project, **config.solve_kwargs(), weights=weights, cluster_error_px=cluster_error_px)
    return run_stages(project, problem)


def reprojection_only(config: OptimiseConfig, **given) -> None:
    """An error naming the first of ``given`` (the bundle adjustment's own arguments) that is set
    for an objective other than ``reprojection``."""
    for name, value in given.items():
        if value is not None:
            raise RigjaxError(f"{name} applies to objective reprojection only, not {config.objective!r}")


def run_stages(project: Project, problem: Problem, median_scale_floor: float | None = None) -> Result:
    """The problem's stages one after the other, each from where the previous one ended.
    ``median_scale_floor``, if given, sets each stage's robust scale to the median point error
    where the stage starts, at least that many px (rigjax.optimiser.prune's robust round)."""
    cameras, config, reports = problem.cameras, problem.config, []
    n = problem.n_points
    later = reoptimised([layout.names for _, layout in problem.stages])
    for k, (name, layout) in enumerate(problem.stages):
        args = _args(problem, layout, cameras, bool(later[k]), median_scale_floor)
        start = time.perf_counter()
        cameras, status, steps, evaluations, before, after = _solve(
            initial_params(layout, cameras, problem.parameters), args, config=config
        )
        jax.block_until_ready(after)
        reports.append(_report(name, layout, status, steps, evaluations, before, after, time.perf_counter() - start))
    return Result(
        project.with_cameras(_to_host(cameras)),
        tuple(reports),
        np.asarray(after[2])[:n],
        np.asarray(after[3])[:n],
        float(after[0]),
        float(after[1]),
        problem.not_optimised,
    )


def optimise_batch(
    projects: list[Project],
    config: OptimiseConfig | str | None = None,
    *,
    vectorise: bool | None = None,
    workers: int | None = None,
) -> list[Result]:
    """Solve many projects of one structure: many starts for one rig, or one rig over many video
    frames. They must have the same images (count, sizes, lens types, links) and panorama; their
    control points may differ in number. Each element keeps its own status. ``config``: the
    settings, as :func:`optimise` takes them; a rotation-only objective.

    Two ways, the same results (to round-off):

    * ``vectorise=True`` (the default on a GPU or TPU): one compiled, vmapped call per stage over
      the whole batch; a report's ``seconds`` is the whole batch's time.
    * ``vectorise=False`` (the default on a CPU): each project solved as :func:`optimise` solves it,
      ``workers`` at a time in threads (default: the usable CPUs + 1), all sharing one compilation;
      a report's ``seconds`` is that element's own. A CPU runs one solve's many small operations
      on about 1.5 cores, and under ``vmap`` every element runs until the slowest stops: threads
      are the faster way there (measured in docs/design/optimiser.md).
    """
    config = as_config(config)
    if workers is not None and workers < 1:
        raise RigjaxError(f"workers must be at least 1, got {workers}")
    if config.objective == "reprojection":
        raise RigjaxError(
            "optimise_batch solves the rotation-only objectives (transfer, sphere, hugin), not 'reprojection': "
            "call optimise on each project"
        )
    if not projects:
        return []
    shape = shape_of(projects)
    problems = [prepare(p, **config.solve_kwargs(), shape=shape) for p in projects]
    check_one_structure(problems)
    if vectorise is None:
        vectorise = jax.default_backend() != "cpu"
    if not vectorise:
        with ThreadPoolExecutor(workers or _usable_cpus() + 1) as pool:
            return list(pool.map(run_stages, projects, problems))
    return solve_vectorised(projects, problems)


def check_one_structure(problems: list[Problem]) -> None:
    """An error naming the first problem whose structure (stages and their parameters, image sizes,
    static config) differs from the first's: one compiled, batched solve cannot run both."""

    def structure(problem: Problem):
        return (
            problem.config,
            [(name, slot_matrix(layout).tolist()) for name, layout in problem.stages],
            np.asarray(problem.cameras.width).tolist(),
            np.asarray(problem.cameras.height).tolist(),
        )

    first = structure(problems[0])
    for k, problem in enumerate(problems):
        if structure(problem) != first:
            raise RigjaxError(
                f"project {k} differs in structure from project 0 (images, lens types, links, "
                "or parameters of the schedule); optimise_batch needs one structure"
            )


def stacked(problems: list[Problem]) -> Problem:
    """The problems of one structure (:func:`check_one_structure`) as one, their data stacked along
    a new first axis of size ``len(problems)`` (cameras ``(b, n_images)``, points ``(b, n_points)``,
    ...), the first's stages and config."""

    def stack(*leaves):
        return np.stack([np.asarray(leaf) for leaf in leaves])

    batched = ("cameras", "points", "canvas", "weight", "groups", "group_weight", "robust_scale", "cost_threshold")
    return problems[0]._replace(
        **{field: jax.tree_util.tree_map(stack, *(getattr(p, field) for p in problems)) for field in batched}
    )


def solve_vectorised(projects: list[Project], problems: list[Problem]) -> list[Result]:
    """:func:`optimise_batch`'s vmapped way: each stage one compiled call over the whole batch
    (``problems``: the projects', of one structure), each element from where its previous stage ended."""
    from .lm import solve_batch  # the solver, imported where it is traced

    first, batch = problems[0], stacked(problems)
    cameras = host = batch.cameras  # host: NumPy, elements are sliced on the host
    reports: list[list[StageReport]] = [[] for _ in problems]
    later = reoptimised([layout.names for _, layout in first.stages])
    for k, (name, layout) in enumerate(first.stages):
        args = _args(batch, layout, cameras, preliminary=bool(later[k]))
        params0 = np.stack([initial_params(layout, _element(host, b), first.parameters) for b in range(len(problems))])
        start = time.perf_counter()
        cameras, *counts, before, after = solve_batch(params0, args, first.config)
        jax.block_until_ready(after)
        seconds = time.perf_counter() - start
        host, (status, steps, evaluations), before, after = jax.tree_util.tree_map(
            np.asarray, (cameras, counts, before, after)
        )
        for b in range(len(problems)):
            element = lambda metrics: (metrics[0][b], metrics[1][b])  # noqa: E731
            reports[b].append(
                _report(name, layout, status[b], steps[b], evaluations[b], element(before), element(after), seconds)
            )
    return [
        Result(
            project.with_cameras(_to_host(_element(host, b))),
            tuple(reports[b]),
            after[2][b][: problem.n_points],
            after[3][b][: problem.n_points],
            float(after[0][b]),
            float(after[1][b]),
            problem.not_optimised,
        )
        for b, (project, problem) in enumerate(zip(projects, problems))
    ]


def _element(cameras: Camera, b: int) -> Camera:
    """Element ``b`` of batched cameras (each field ``(batch, n_images)``)."""
    return jax.tree_util.tree_map(lambda f: f[b], cameras)


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
    lines = [
        f"{'stage':<10} {'status':<10} {'params':>6} {'steps':>5} {'evals':>5} "
        f"{'rms px':>17} {'sphere rms px':>17} {'time s':>7}"
    ]
    for s in result.stages:
        lines.append(
            f"{s.name:<10} {s.status:<10} {len(s.parameters):>6} {s.steps:>5} {s.evaluations:>5} "
            f"{s.rms_initial:>8.3f}->{s.rms_final:<8.3f} {s.sphere_rms_initial:>8.3f}->{s.sphere_rms_final:<8.3f} "
            f"{s.seconds:>7.3f}"
        )
    return "\n".join(lines)
