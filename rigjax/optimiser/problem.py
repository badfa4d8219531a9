"""A project turned into the padded host arrays of one compiled solve, once.

:func:`prepare` checks :func:`rigjax.optimise`'s arguments and the project (anchor, finite
coordinates, every image joined to the others), lays out each stage's parameters, and pads the
control points, the straight-line rows and the parameter vector to fixed multiples, so that
projects and stages of similar sizes share one compilation (``docs/design/optimiser.md``).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import numpy as np

from ..camera.model import Camera
from ..camera.panorama import Equirect
from ..errors import RigjaxError
from ..pto.project import Project
from .objective import LETTERS, SolveConfig, stage_config, theta_of
from .options import SolverOptions
from .residuals import (
    FIRST_STRAIGHT_LINE,
    HORIZONTAL_LINE,
    NORMAL,
    ROBUST_LOSSES,
    VERTICAL_LINE,
    LineGroups,
    PointArrays,
)
from .schedule import Layout, has_centres, stage_layouts

OBJECTIVES = ("transfer", "sphere", "hugin")
PADDED_POINTS = 256  # control points are padded (weight 0) to a multiple of this
PADDED_GROUPS = 16  # and straight-line rows, when there are any, to a multiple of this
PADDED_PARAMETERS = 16  # a stage's parameter vector is padded to a multiple of this


def round_up(n: int, multiple: int) -> int:
    return -(-n // multiple) * multiple


# ---------------------------------------------------------------------------------------------
# The Python-time part: checks, layout, reports.
def check_project(project: Project, anchor: int) -> None:
    n = len(project.images)
    if not 0 <= anchor < n:
        raise RigjaxError(f"anchor image {anchor} does not exist (the project has {n} images)")
    cps = project.control_points
    bad = np.flatnonzero(~np.all(np.isfinite(cps.xy_a) & np.isfinite(cps.xy_b), axis=1))
    if bad.size:
        k = bad[0]
        raise RigjaxError(
            f"control point {k} (images {cps.image_a[k]} and {cps.image_b[k]}) has a "
            f"non-finite coordinate: {cps.xy_a[k].tolist()} {cps.xy_b[k].tolist()}"
        )
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


def slot_matrix(layout: Layout) -> np.ndarray:
    return np.stack([layout.slot[letter] for letter in LETTERS], axis=-1)


def parameter_count(layout: Layout, size: int = 0) -> int:
    """The length of a stage's parameter vector: ``size`` or its parameters rounded up to a multiple
    of PADDED_PARAMETERS, whichever is larger."""
    return max(size, round_up(layout.size, PADDED_PARAMETERS))


def initial_params(layout: Layout, cameras: Camera, size: int = 0) -> np.ndarray:
    """The stage's starting parameters, padded with zeros to :func:`parameter_count` (the zeros
    have zero Jacobian columns), so that stages of similar sizes share a compilation."""
    params = np.zeros(parameter_count(layout, size))
    theta = theta_of(jax.tree_util.tree_map(np.asarray, cameras), np)
    slots = slot_matrix(layout)
    params[slots[slots >= 0]] = theta[slots >= 0]
    return params


def padded_points(project: Project, weight: np.ndarray, at_least: int | None = None) -> tuple[PointArrays, np.ndarray]:
    """Control points padded to a multiple of PADDED_POINTS (and to ``at_least``) with copies of
    the first, of weight 0."""
    cps = project.control_points
    n = max(len(cps), at_least or 0)
    size = max(PADDED_POINTS, round_up(n, PADDED_POINTS))
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


class Shape(NamedTuple):
    """Padded sizes shared by the projects of one compiled solve."""

    points: int
    groups: int  # straight-line rows: 0, or a multiple of PADDED_GROUPS
    lines: bool  # any t1/t2 line point


def shape_of(projects: list[Project]) -> Shape:
    rows = max(len(_straight_line_rows(p, np.ones(len(p.control_points)))) for p in projects)
    kinds = [p.control_points.kind for p in projects]
    return Shape(
        max(len(k) for k in kinds),
        round_up(rows, PADDED_GROUPS),
        any(bool(np.any((k == VERTICAL_LINE) | (k == HORIZONTAL_LINE))) for k in kinds),
    )


class Problem(NamedTuple):
    """A project analysed for solving: stages, static config and padded data. The data stay on the
    host (NumPy) until a jitted call takes them: its dispatch transfers them at a fraction of the
    cost of a ``jnp.asarray`` each."""

    stages: list[tuple[str, Layout]]
    config: SolveConfig
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
    parameters: int  # every stage's parameter vector padded to this: the stages share one program


def prepare(
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
    shape: Shape | None = None,
    like: Problem | None = None,
    priors=None,
    cluster_error_px: float = 0.0,
) -> Problem:
    """:func:`optimise`'s arguments checked and turned into padded host arrays. ``shape`` pads
    the points as another project's (:func:`optimise_batch`).

    All stages run one compiled solve: its Jacobian runs along the letters of them all, and every
    stage's parameters are padded to the largest stage's count. ``like``: run ``like``'s compiled
    solve instead, where it covers this problem (the same objective and projection, its letters
    and parameter count at least this problem's; a problem without a robust loss runs ``like``'s
    loss switched off): pruning's later rounds run round 0's program. ``priors`` and
    ``cluster_error_px`` are the reprojection objective's (:func:`rigjax.optimiser.bundle.bundle_adjust`):
    an error here."""
    solver = solver or SolverOptions()
    if robust is not None and not robust_scale > 0:
        raise RigjaxError(f"robust_scale must be > 0 px, got {robust_scale!r}")
    if objective not in OBJECTIVES:
        raise RigjaxError(f"objective must be one of {OBJECTIVES}, got {objective!r}")
    if robust not in ROBUST_LOSSES:
        raise RigjaxError(f"robust must be one of {ROBUST_LOSSES}, got {robust!r}")
    if objective == "hugin" and robust is not None:
        raise RigjaxError(
            "objective 'hugin' has no robust loss (Hugin 2022 sends libpano13 a Huber sigma of 0); "
            "use objective 'transfer' or 'sphere' with a robust loss"
        )
    for name, value in (("priors apply", priors), ("cluster_error_px applies", cluster_error_px)):
        if value:
            raise RigjaxError(f"{name} to objective reprojection only, not {objective!r}")
    if not pto_vars and has_centres(schedule):
        raise RigjaxError(
            f"schedule {schedule!r} estimates camera centres (X), which needs objective 'reprojection' "
            f"(the {objective!r} objective has every camera at one point)"
        )
    check_project(project, anchor)
    projections = {image.projection for image in project.images}
    n_points = len(project.control_points)
    weight = np.ones(n_points) if weights is None else np.asarray(weights, dtype=float)
    if weight.shape != (n_points,):
        raise RigjaxError(f"weights has shape {weight.shape}, expected ({n_points},)")
    kind = project.control_points.kind
    rows = _straight_line_rows(project, weight)
    observations = int(np.sum(np.where(kind == NORMAL, 2, 1) * (weight > 0) * (kind < FIRST_STRAIGHT_LINE)))
    observations += 2 * len(rows)
    stages, not_optimised = stage_layouts(project, schedule, anchor, pto_vars)
    for name, layout in stages:
        if layout.size > observations:
            raise RigjaxError(
                f"stage {name}: {layout.size} parameters but only {observations} observations "
                f"(2 per control point, 1 per t1/t2 line point, 2 per straight-line point); add control points "
                f"or optimise fewer parameters"
            )
    shape = shape or shape_of([project])
    projection = projections.pop() if len(projections) == 1 else None
    config = stage_config(
        SolveConfig(objective, shape.lines, robust, projection, solver.backend),
        *(slot_matrix(layout) for _, layout in stages),
    )
    parameters = round_up(max(layout.size for _, layout in stages), PADDED_PARAMETERS)
    if like is not None and _covers(like, config, parameters):
        if robust is None and like.config.robust is not None:
            robust_scale = 0.0  # the loss switched off (rigjax.optimiser.residuals.robust_scale)
        config, parameters = like.config, like.parameters
    points, padded_weight = padded_points(project, weight * (kind < FIRST_STRAIGHT_LINE), shape.points)
    groups, group_weight = _padded_groups(project, rows, shape.groups)
    return Problem(
        stages,
        config,
        project.cameras(host=True),
        points,
        padded_weight,
        groups,
        group_weight,
        project.canvas(host=True),
        float(robust_scale),
        solver.rms_threshold**2 * 2 * max(int(np.sum(weight > 0)), 1),
        solver,
        n_points,
        not_optimised,
        parameters,
    )


def _covers(like: Problem, config: SolveConfig, parameters: int) -> bool:
    """Whether ``like``'s compiled solve can run a problem of this config and parameter count."""
    return (
        set(config.letters) <= set(like.config.letters)
        and parameters <= like.parameters
        and config.robust in (None, like.config.robust)
        and config._replace(letters="", robust=None) == like.config._replace(letters="", robust=None)
    )
