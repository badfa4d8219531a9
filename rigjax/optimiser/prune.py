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

from dataclasses import dataclass

import numpy as np

from ..errors import RigjaxError
from ..pto.project import Project
from ..pto.records import ControlPoints, render_control_points
from .objective import point_error
from .problem import prepare
from .residuals import NORMAL, ROBUST_LOSSES
from .schedule import parse_schedule
from .staged import Result, run_stages

REMOVED_PREFIX = "#-rigjax pruned"


@dataclass(frozen=True)
class PruneConfig:
    """Settings of :func:`optimise_pruned` (see the module docstring)."""

    rounds: int = 10
    grid: int = 4
    fraction: float = 0.25
    factor: float = 3.0
    min_error_px: float = 2.0
    rms_threshold: float = 0.0
    start_loss: str | None = "cauchy"  # round 0's robust loss (None: the caller's loss)
    start_scale_px: float = 2.0  # its smallest scale (each stage's is the median error where it starts)
    readmit: bool = True  # removed points that fit the final cameras come back for one more solve

    def __post_init__(self) -> None:
        if self.start_loss not in ROBUST_LOSSES or not self.start_scale_px > 0:
            raise RigjaxError(
                f"prune start_loss must be one of huber, cauchy or none and start_scale_px > 0, got "
                f"{self.start_loss!r} and {self.start_scale_px!r}"
            )
        if self.rounds < 0 or self.grid < 1:
            raise RigjaxError(f"prune rounds must be >= 0 and grid >= 1, got {self.rounds} and {self.grid}")
        if not 0.0 < self.fraction <= 1.0:
            raise RigjaxError(f"prune fraction must be in (0, 1], got {self.fraction!r}")
        if not (self.factor > 0 and self.min_error_px >= 0 and self.rms_threshold >= 0):
            raise RigjaxError("prune factor must be > 0, min_error_px and rms_threshold >= 0")


@dataclass(frozen=True, eq=False)
class PrunedResult:
    """The final round's :class:`Result` (on the kept points; its project keeps every point),
    the kept mask, what was removed for good (index, round (1-based) and error (px) at removal),
    the LM solves, round 0's :class:`Result` with the schedule's every stage (``first``), and the
    points that were removed and came back (``readmitted``, in order of removal)."""

    result: Result
    kept: np.ndarray  # (n_control_points,) bool
    removed: np.ndarray  # indices into the project's control points, in order of removal
    removed_round: np.ndarray
    removed_error: np.ndarray
    rounds: tuple[tuple[int, float, int], ...]  # per LM solve: (points in use, rms px, points removed after it)
    first: Result  # round 0's solve of the whole schedule (robust unless start_loss is None), before any removal
    readmitted: np.ndarray  # indices into the project's control points

    @property
    def project(self) -> Project:
        """The optimised project with the kept points as ``c`` lines and the removed ones as comments."""
        return with_removed_points(self.result.project, self.kept, self.removed, self.removed_round, self.removed_error)


def point_errors(result: Result) -> np.ndarray:
    """Per control point: the larger of its two transfer errors, px."""
    return point_error(result.transfer_residuals, np)


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


def optimise_pruned(
    project: Project, schedule: str = "YPR,VBYPR", *, prune: PruneConfig | None = None, **optimise_kwargs
) -> PrunedResult:
    """:func:`rigjax.optimise` with iterative pruning; keyword arguments go to ``optimise``
    (``objective="reprojection"`` included: the bundle adjustment's points are pruned on their
    reprojection errors, and :class:`PrunedResult` then holds
    :class:`~rigjax.optimiser.bundle.BundleResult` values).

    Only normal control points (``t0``) are pruned; line points are kept.
    """
    prune = prune or PruneConfig()
    if "weights" in optimise_kwargs:
        raise RigjaxError("optimise_pruned chooses the weights itself; remove points from the project instead")
    n = len(project.control_points)
    prunable = project.control_points.kind == NORMAL
    kept = np.ones(n, bool)
    removed, removed_round, removed_error, rounds = [], [], [], []
    robust = prune.start_loss is not None and optimise_kwargs.get("robust") is None
    # Round 0 (robust: each stage at its median scale); every later solve is the schedule's last
    # stage alone.
    round_0 = dict(optimise_kwargs, robust=prune.start_loss) if robust else optimise_kwargs
    floor = prune.start_scale_px if robust else None
    last_stage = schedule if optimise_kwargs.get("pto_vars") else parse_schedule(schedule)[-1].name
    if optimise_kwargs.get("objective") == "reprojection":
        from .bundle import bundle_adjust

        # Every round starts from the previous one's cameras; the priors hold to where the first
        # started, and centres (held, or the start and prior of estimated ones) are the first's.
        fixed = {}
        if optimise_kwargs.get("priors") and optimise_kwargs.get("nominal") is None:
            fixed["nominal"] = project.cameras(host=True)
        if optimise_kwargs.get("centres") is None and project.centres is not None:
            fixed["centres"] = project.centres
        optimise_kwargs, round_0 = dict(optimise_kwargs, **fixed), dict(round_0, **fixed)

        def adjust(current: Project, stages: str, weights=None, **kwargs):
            kwargs = {k: v for k, v in kwargs.items() if k != "objective"}
            return bundle_adjust(current, schedule=stages, weights=weights, **kwargs)

        def errors(result) -> np.ndarray:  # the larger of each point's two reprojection errors
            return point_error(result.residuals, np)

        # Round 0 only starts the later rounds' solves: it stops as a preliminary stage does (a
        # robust bundle adjustment can crawl along the valley of hfov and depth for hundreds of steps).
        first = adjust(project, schedule, **round_0, median_scale_floor=floor, preliminary=prune.rounds > 0)

        def solve_last_stage(current: Project, kept: np.ndarray):
            return adjust(current, last_stage, kept.astype(float), **optimise_kwargs)

    else:
        problem = prepare(project, schedule, **round_0)
        first = run_stages(project, problem, floor)

        def solve_last_stage(current: Project, kept: np.ndarray) -> Result:  # on round 0's program
            return run_stages(
                current, prepare(current, last_stage, **optimise_kwargs, weights=kept.astype(float), like=problem)
            )

        errors = point_errors

    result = first
    cells = _cells(project, prune.grid)
    previous_bottom = np.zeros(n, bool)
    for round_ in range(1, prune.rounds + 1):
        rounds.append((int(kept.sum()), result.rms, 0))
        if result.rms <= prune.rms_threshold:
            break
        error = errors(result)
        active = kept & prunable
        if active.sum() == 0:
            break
        candidate = active & (error > _threshold(error, active, prune))
        rank = np.argsort(-np.where(active, error, -np.inf))
        bottom = np.zeros(n, bool)
        bottom[rank[: int(np.ceil(prune.fraction * active.sum()))]] = True
        drop = candidate & bottom & previous_bottom
        for cell in np.unique(cells[candidate]):
            members = np.flatnonzero(active & (cells == cell))
            worst = members[np.argsort(-error[members])][: max(1, int(prune.fraction * len(members)))]
            drop[worst[candidate[worst]]] = True
        previous_bottom = bottom
        if not drop.any():
            break
        order = np.flatnonzero(drop)[np.argsort(-error[drop])]
        removed += order.tolist()
        removed_round += [round_] * len(order)
        removed_error += error[order].tolist()
        kept[order] = False
        rounds[-1] = (rounds[-1][0], rounds[-1][1], len(order))
        result = solve_last_stage(result.project, kept)
    else:
        rounds.append((int(kept.sum()), result.rms, 0))
    removed, readmitted = np.array(removed, int), np.zeros(0, int)
    removed_round, removed_error = np.array(removed_round, int), np.array(removed_error, float)
    if prune.readmit and removed.size:
        error = errors(result)
        back = error[removed] <= _threshold(error, kept & prunable, prune)
        if back.any():
            readmitted, kept[removed[back]] = removed[back], True
            removed, removed_round, removed_error = removed[~back], removed_round[~back], removed_error[~back]
            result = solve_last_stage(result.project, kept)
            rounds.append((int(kept.sum()), result.rms, 0))
    if robust and not removed.size and not readmitted.size:  # round 0's robust solve was the last
        result = solve_last_stage(result.project, kept)  # end at the caller's loss
        rounds.append((int(kept.sum()), result.rms, 0))
    return PrunedResult(result, kept, removed, removed_round, removed_error, tuple(rounds), first, readmitted)


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
