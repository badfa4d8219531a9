"""Iterative pruning of badly matched control points between Levenberg-Marquardt rounds.

Round 0 runs the whole schedule on every point with a robust loss (``start_loss``, Cauchy by
default, unless the caller chose a loss), each stage at a scale of the median point error where it
starts, at least ``start_scale_px``: with a fifth or more of the points wrong by hundreds of
pixels, least squares would settle far from the truth (hfov tens of degrees off) and no ranking
of its errors could tell the wrong points from the good. Each later round looks at the per-point
error (the larger of a point's two transfer errors, px) and removes:

- *locally*, within each cell of a ``grid x grid`` raster over every image, the worst candidates
  of the cell, at most ``fraction`` of the cell's points (at least one): a dense cluster of good
  points does not hide its few bad ones, and a sparse region is not emptied at once;
- *globally*, candidates that were in the worst ``fraction`` of all points in the previous
  round too: points that stay at the bottom of the ranking go even when their cell is crowded.

A candidate is a point whose error exceeds ``max(min_error_px, factor * sigma)``, with sigma the
robust spread of the errors (1.4826 x their median), so a clean project loses nothing. The last
stage of the schedule is then solved again, with the caller's loss (least squares by default), from
where the previous round ended. Pruning stops when the transfer RMS is at most ``rms_threshold``,
when no point is a candidate, or after ``rounds`` rounds; if the last solve was round 0's robust
one, the last stage is solved once more with the caller's loss.

A point removed in an early round, while the cameras were still off, may fit the final ones well:
with ``readmit``, every removed point whose error at the end is within the last round's threshold
(from the kept points' errors) comes back, and the last stage is solved once more. Removed points
are returned with their round and error, and :func:`with_removed_points` keeps them in the written
project as comment lines.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..camera.model import Camera
from ..errors import RigjaxError
from ..pto.project import Project
from ..pto.records import ControlPoints, render_control_points
from .config import OptimiseConfig, PruneConfig, RobustConfig, as_config
from .problem import prepare
from .residuals import NORMAL
from .result import OptimiseResult
from .schedule import parse_schedule
from .staged import reprojection_only, run_stages

REMOVED_PREFIX = "#-rigjax pruned"


@dataclass(frozen=True, eq=False)
class PrunedResult:
    """The final round's result (on the kept points; its project keeps every point), the kept mask,
    what was removed for good (index, round (1-based) and error (px) at removal), the LM solves,
    round 0's result with the schedule's every stage (``first``), and the points that were removed
    and came back (``readmitted``, in order of removal). The results are the objective's
    (:class:`~rigjax.optimiser.result.OptimiseResult`: a :class:`~rigjax.optimiser.staged.Result`, or a
    :class:`~rigjax.optimiser.bundle.BundleResult` with objective ``reprojection``)."""

    result: OptimiseResult
    kept: np.ndarray  # (n_control_points,) bool
    removed: np.ndarray  # indices into the project's control points, in order of removal
    removed_round: np.ndarray
    removed_error: np.ndarray
    rounds: tuple[tuple[int, float, int], ...]  # per LM solve: (points in use, rms px, points removed after it)
    # Round 0's solve of the whole schedule (robust unless start_loss is None), before any removal.
    first: OptimiseResult
    readmitted: np.ndarray  # indices into the project's control points

    @property
    def project(self) -> Project:
        """The optimised project with the kept points as ``c`` lines and the removed ones as comments."""
        return with_removed_points(self.result.project, self.kept, self.removed, self.removed_round, self.removed_error)


def point_errors(result: OptimiseResult) -> np.ndarray:
    """Per control point: the larger of its two errors, px (transfer errors, or reprojection errors
    with objective ``reprojection``: :meth:`~rigjax.optimiser.result.OptimiseResult.point_errors`)."""
    return result.point_errors()


def _threshold(error: np.ndarray, active: np.ndarray, prune: PruneConfig) -> float:
    """The error above which a point is a candidate for removal: ``max(min_error_px, factor * sigma)``,
    sigma the robust spread of the active points' errors."""
    return max(prune.min_error_px, prune.factor * 1.4826 * float(np.median(error[active])))


def _cells(project: Project, grid: int) -> np.ndarray:
    """Each point's cell: image a, and its raster cell there."""
    cps = project.control_points
    size = np.array([[im.width, im.height] for im in project.images], float)[cps.image_a]
    cell = np.clip(((cps.xy_a + 0.5) / size * grid).astype(int), 0, grid - 1)
    return (cps.image_a * grid + cell[:, 1]) * grid + cell[:, 0]


class _Solves(NamedTuple):
    """Pruning's solves: round 0's result (the whole schedule), and the solve of the schedule's last
    stage from a project's cameras on the points a ``(n_control_points,)`` bool mask keeps."""

    first: OptimiseResult
    last_stage: Callable[[Project, np.ndarray], OptimiseResult]


@dataclass
class _Removals:
    """What pruning has done so far: the kept mask, the removed points (index, round, error px) in
    order of removal, the readmitted ones, and per LM solve ``(points in use, rms px, removed after it)``."""

    kept: np.ndarray
    removed: list[int] = field(default_factory=list)
    removed_round: list[int] = field(default_factory=list)
    removed_error: list[float] = field(default_factory=list)
    rounds: list[tuple[int, float, int]] = field(default_factory=list)
    readmitted: np.ndarray = field(default_factory=lambda: np.zeros(0, int))


def optimise_pruned(
    project: Project,
    config: OptimiseConfig | str | None = None,
    *,
    nominal: Camera | None = None,
    cluster_error_px: float = 0.0,
    at_infinity: np.ndarray | None = None,
    hold_anchor: bool | None = None,
    rigid: np.ndarray | None = None,
    tracks: np.ndarray | None = None,
) -> PrunedResult:
    """:func:`rigjax.optimise` with iterative pruning as ``config.prune`` says (the module docstring).

    ``config``, ``nominal``, ``cluster_error_px``, ``at_infinity``, ``hold_anchor``, ``rigid`` and ``tracks`` are
    :func:`rigjax.optimise`'s (a string: the
    default settings with that schedule, pruning included); pruning chooses the weights itself.
    With objective ``reprojection`` the bundle adjustment's points are pruned on their reprojection
    errors, and :class:`PrunedResult` holds :class:`~rigjax.optimiser.bundle.BundleResult` values.
    Only normal control points (``t0``) are pruned; line points are kept.
    """
    config = as_config(config)
    prune = config.prune
    if prune is None:
        raise RigjaxError("config.prune is None (no pruning): call optimise, or give the config a PruneConfig")
    robust = prune.start_loss is not None and config.robust.loss is None
    # Round 0 (robust: each stage at its median scale); every later solve is the schedule's last
    # stage alone, with the caller's loss.
    round_0 = config.replace(robust=RobustConfig(prune.start_loss, config.robust.scale)) if robust else config
    floor = prune.start_scale_px if robust else None
    last_stage = config if config.pto_vars else config.replace(schedule=parse_schedule(config.schedule)[-1].name)
    if config.objective == "reprojection":
        bundle = dict(
            nominal=nominal,
            cluster_error_px=cluster_error_px,
            at_infinity=at_infinity,
            hold_anchor=hold_anchor,
            rigid=rigid,
            tracks=tracks,
        )
        solves = _bundle_solves(project, round_0, last_stage, floor, prune, bundle)
    else:
        reprojection_only(
            config, nominal=nominal, at_infinity=at_infinity, hold_anchor=hold_anchor, rigid=rigid, tracks=tracks
        )
        solves = _transfer_solves(project, round_0, last_stage, floor, cluster_error_px)
    removals = _Removals(np.ones(len(project.control_points), bool))
    result = _prune_rounds(project, solves, prune, removals)
    if prune.readmit and removals.removed:
        result = _readmit(project, result, solves, prune, removals)
    if robust and not removals.removed and not removals.readmitted.size:  # round 0's robust solve was the last
        result = solves.last_stage(result.project, removals.kept)  # end at the caller's loss
        removals.rounds.append((int(removals.kept.sum()), result.rms, 0))
    return PrunedResult(
        result,
        removals.kept,
        np.array(removals.removed, int),
        np.array(removals.removed_round, int),
        np.array(removals.removed_error, float),
        tuple(removals.rounds),
        solves.first,
        removals.readmitted,
    )


def _transfer_solves(
    project: Project,
    round_0: OptimiseConfig,
    last_stage: OptimiseConfig,
    floor: float | None,
    cluster_error_px: float,
) -> _Solves:
    """Round 0 and the later rounds' solve with a rotation-only objective: ``round_0``'s settings,
    each stage's robust scale at least ``floor`` px (the median error; None: the config's), then
    ``last_stage``'s on round 0's compiled program."""
    problem = prepare(project, **round_0.solve_kwargs(), cluster_error_px=cluster_error_px)
    first = run_stages(project, problem, floor)

    def solve_last_stage(current: Project, kept: np.ndarray) -> OptimiseResult:
        kwargs = dict(last_stage.solve_kwargs(), weights=kept.astype(float), like=problem)
        return run_stages(current, prepare(current, **kwargs, cluster_error_px=cluster_error_px))

    return _Solves(first, solve_last_stage)


def _bundle_solves(
    project: Project,
    round_0: OptimiseConfig,
    last_stage: OptimiseConfig,
    floor: float | None,
    prune: PruneConfig,
    bundle: dict,
) -> _Solves:
    """Round 0 and the later rounds' solve with objective ``reprojection`` (as
    :func:`_transfer_solves`; ``bundle``: :func:`optimise_pruned`'s arguments of the bundle
    adjustment). Every round starts from the previous one's cameras; the priors hold to where the
    first started (``nominal``, else the project's cameras), and the centres (held, or the start and
    prior of estimated ones) are the first's (the config's, else the project's)."""
    from .bundle import bundle_adjust

    fixed = dict(bundle)
    if round_0.priors.as_dict() and fixed["nominal"] is None:
        fixed["nominal"] = project.cameras(host=True)
    if round_0.centres is None and project.centres is not None:
        fixed["centres"] = project.centres
    # Round 0 only starts the later rounds' solves: it stops as a preliminary stage does (a robust
    # bundle adjustment can crawl along the valley of hfov and depth for hundreds of steps).
    first_kwargs = dict(round_0.solve_kwargs(), **fixed)
    first = bundle_adjust(project, **first_kwargs, median_scale_floor=floor, preliminary=prune.rounds > 0)

    def solve_last_stage(current: Project, kept: np.ndarray) -> OptimiseResult:
        return bundle_adjust(current, **dict(last_stage.solve_kwargs(), **fixed), weights=kept.astype(float))

    return _Solves(first, solve_last_stage)


def _prune_rounds(project: Project, solves: _Solves, prune: PruneConfig, removals: _Removals) -> OptimiseResult:
    """Up to ``prune.rounds`` rounds from round 0's result, each removing the points
    :func:`_to_drop` chooses and solving the last stage again; the last result. Records each
    solve and removal in ``removals``."""
    result = solves.first
    prunable = project.control_points.kind == NORMAL
    cells = _cells(project, prune.grid)
    previous_bottom = np.zeros(len(prunable), bool)
    kept = removals.kept
    for round_ in range(1, prune.rounds + 1):
        removals.rounds.append((int(kept.sum()), result.rms, 0))
        if result.rms <= prune.rms_threshold:
            break
        error = result.point_errors()
        active = kept & prunable
        if active.sum() == 0:
            break
        drop, previous_bottom = _to_drop(error, active, cells, previous_bottom, prune)
        if not drop.any():
            break
        order = np.flatnonzero(drop)[np.argsort(-error[drop])]
        removals.removed += order.tolist()
        removals.removed_round += [round_] * len(order)
        removals.removed_error += error[order].tolist()
        kept[order] = False
        removals.rounds[-1] = (removals.rounds[-1][0], removals.rounds[-1][1], len(order))
        result = solves.last_stage(result.project, kept)
    else:
        removals.rounds.append((int(kept.sum()), result.rms, 0))
    return result


def _to_drop(
    error: np.ndarray, active: np.ndarray, cells: np.ndarray, previous_bottom: np.ndarray, prune: PruneConfig
) -> tuple[np.ndarray, np.ndarray]:
    """``(drop, bottom)``, bool ``(n_control_points,)``: the points one round removes (the module
    docstring: the worst candidates of each cell, and candidates in the worst ``fraction`` this round
    and the previous one, ``previous_bottom``) and this round's worst ``fraction``. ``error``: each
    point's error, px; ``active``: the points in use that may be pruned; ``cells``: each point's cell."""
    candidate = active & (error > _threshold(error, active, prune))
    rank = np.argsort(-np.where(active, error, -np.inf))
    bottom = np.zeros(len(error), bool)
    bottom[rank[: int(np.ceil(prune.fraction * active.sum()))]] = True
    drop = candidate & bottom & previous_bottom
    for cell in np.unique(cells[candidate]):
        members = np.flatnonzero(active & (cells == cell))
        worst = members[np.argsort(-error[members])][: max(1, int(prune.fraction * len(members)))]
        drop[worst[candidate[worst]]] = True
    return drop, bottom


def _readmit(
    project: Project, result: OptimiseResult, solves: _Solves, prune: PruneConfig, removals: _Removals
) -> OptimiseResult:
    """The removed points whose error at ``result`` is within the last round's threshold back in
    ``removals``, and the last stage solved once more if any came back; the last result."""
    removed = np.array(removals.removed, int)
    error = result.point_errors()
    kept = removals.kept
    back = error[removed] <= _threshold(error, kept & (project.control_points.kind == NORMAL), prune)
    if not back.any():
        return result
    removals.readmitted, kept[removed[back]] = removed[back], True
    removals.removed = removed[~back].tolist()
    removals.removed_round = np.array(removals.removed_round, int)[~back].tolist()
    removals.removed_error = np.array(removals.removed_error, float)[~back].tolist()
    result = solves.last_stage(result.project, kept)
    removals.rounds.append((int(kept.sum()), result.rms, 0))
    return result


def with_removed_points(
    project: Project, kept: np.ndarray, removed: np.ndarray, removed_round: np.ndarray, removed_error: np.ndarray
) -> Project:
    """The project with only the kept control points as ``c`` lines; each removed point follows
    as a comment line (Hugin ignores it; rigjax keeps it on every rewrite)::

        #-rigjax pruned round 2 error 35.214 px: c n0 N1 x... y... X... Y... t0
    """
    cps = project.control_points
    keep = np.flatnonzero(kept)

    def subset(index: np.ndarray) -> ControlPoints:
        return ControlPoints(
            cps.image_a[index],
            cps.image_b[index],
            cps.xy_a[index],
            cps.xy_b[index],
            cps.kind[index],
            tuple(cps.extra[i] for i in index),
        )

    lines = render_control_points(subset(np.asarray(removed, int)))
    comments = [
        f"{REMOVED_PREFIX} round {r} error {e:.3f} px: {line}"
        for line, r, e in zip(lines, removed_round, removed_error)
    ]
    return project.replace(control_points=subset(keep)).with_comment_lines(comments)


def format_pruning(pruned: PrunedResult, project: Project) -> str:
    """What pruning did, for the CLI: rounds, and the removed points with their errors."""
    cps = project.control_points
    lines = [
        f"pruning: {len(pruned.removed)} of {len(cps)} points removed in {sum(1 for r in pruned.rounds if r[2])} "
        "round(s)"
    ]
    lines += [
        f"  solve {k}: {n} points, rms {rms:.3f} px, then removed {d}" for k, (n, rms, d) in enumerate(pruned.rounds)
    ]
    if pruned.readmitted.size:
        lines.append(
            f"  readmitted {pruned.readmitted.size} removed point(s) that fit the final cameras before "
            f"the last solve: {', '.join(str(i) for i in pruned.readmitted)}"
        )
    for i, r, e in zip(pruned.removed, pruned.removed_round, pruned.removed_error):
        lines.append(
            f"  removed (round {r}, {e:.2f} px): point {i}, image {cps.image_a[i]} "
            f"({cps.xy_a[i, 0]:.1f}, {cps.xy_a[i, 1]:.1f}) - image {cps.image_b[i]} "
            f"({cps.xy_b[i, 0]:.1f}, {cps.xy_b[i, 1]:.1f})"
        )
    return "\n".join(lines)
