"""The stages of :func:`~rigjax.calibration.pipeline.calibrate_matches`: matches to a calibrated rig.

Each stage is a function of typed arguments with a typed result, called in order by the driver:

1. :func:`ransac_stage`: each pair's rotation by RANSAC on bearing vectors of the nominal lens
   (:mod:`rigjax.calibration.ransac`; with the template's camera centres and objective
   ``reprojection``, a match agrees when it lies on its epipolar plane, so that near points stay);
   the inliers, at most ``features.max_points_per_pair`` a frame, become control points;
2. :func:`start_stage`: the project LM starts from: orientations from the template, or in closed
   form over a maximum spanning tree of the match graph (:mod:`rigjax.calibration.initial`), the
   control points and the variables;
3. :func:`search_stage`: the Lévy-flight starts around it (:mod:`rigjax.calibration.levy`) solved
   with the template's schedule, rotation-only, in one ``optimise_batch`` call; best (lowest
   truncated cost) first;
4. :func:`refine_stage`: iterative pruning with the schedule's last stage
   (:mod:`rigjax.optimiser.prune`); with objective ``reprojection``, of the bundle adjustment
   (:mod:`rigjax.optimiser.bundle`) of every RANSAC inlier from the search's best cameras;
5. :func:`check_stage`: the parameters the matches did not determine, or that no lens or mounting
   of the template's can have, and what the priors rather than the matches fixed
   (:mod:`rigjax.calibration.checks`).

A stage that finds that the matches cannot be calibrated says why in its result's ``failure``; the
driver raises it (:class:`~rigjax.calibration.pipeline.CalibrationError`). A new stage (the lens from
a camera's own motion, say: matches within one lens across frames) is one more function of this
kind and one more call in the driver.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np
from jaxtyping import Float

from ..camera.model import img_to_ray, map_points
from ..camera.rotation import world_from_cam, ypr_from_world_from_cam
from ..errors import RigjaxError
from ..optimiser.config import OptimiseConfig, Priors
from ..optimiser.prune import PrunedResult, optimise_pruned
from ..optimiser.result import OptimiseResult
from ..optimiser.schedule import parse_schedule, without_centres
from ..optimiser.staged import Result, optimise, optimise_batch
from ..pto.project import Project
from ..pto.records import ControlPoints, Image, OptVariable, PanoramaLine
from .checks import beyond_mounting, beyond_priors, held_by_prior, undetermined
from .initial import orientations_from_pairs
from .levy import levy_starts, score
from .ransac import ransac_rotation
from .template import CalibrateConfig

# One pair's points: ``(a, b, xy_a, xy_b)``, pixels of image ``a`` and their matches in image ``b``
# (a :class:`~rigjax.calibration.pipeline.PairMatches` is one).
PairPoints = tuple[int, int, Float[np.ndarray, "n 2"], Float[np.ndarray, "n 2"]]


class PairReport(NamedTuple):
    """One pair's count of matches and of RANSAC inliers, and whether its inliers are used."""

    a: int
    b: int
    matches: int
    inliers: int
    used: bool


class PairInliers(NamedTuple):
    """:func:`ransac_stage`'s result.

    ``reports``: every pair's matches and inliers, in the order of the matches; ``rotations``:
    ``(b_from_a, inliers)`` of every used pair ``(a, b)``; ``points``: every used pair's kept
    inliers; ``failure``: why the matches cannot be calibrated (a pair the template says overlaps
    has too few inliers; the stage stops there), else None.
    """

    reports: tuple[PairReport, ...]
    rotations: dict[tuple[int, int], tuple[Float[np.ndarray, "3 3"], int]]
    points: tuple[PairPoints, ...]
    failure: str | None = None


class Start(NamedTuple):
    """:func:`start_stage`'s result: ``project``, the rig LM starts from (initial orientations, the
    template's lens, every kept inlier as a control point, the variables), or ``failure``: why
    there is none (cameras without a used pair), with ``project`` None."""

    project: Project | None
    failure: str | None = None


class Refinement(NamedTuple):
    """:func:`refine_stage`'s result: the refined ``project``, its final ``result`` (a
    :class:`~rigjax.optimiser.bundle.BundleResult` with objective ``reprojection``) and the pruning
    rounds (``pruned``; None when pruning is off)."""

    project: Project
    result: OptimiseResult
    pruned: PrunedResult | None


class Findings(NamedTuple):
    """:func:`check_stage`'s result: a line per parameter the matches did not determine or that
    left the template's plausible lens, priors or mounting (``undetermined``), and a line per
    parameter a prior rather than the matches held (``notes``)."""

    undetermined: tuple[str, ...]
    notes: tuple[str, ...]


def nominal_project(config: CalibrateConfig, sizes: Sequence[tuple[int, int]], names: Sequence[str]) -> Project:
    """The template's rig as a project (no control points): nominal lens (each camera's own with
    ``rig.lenses``) and orientations. ``sizes``: each image's ``(width, height)``."""
    rig = config.rig
    images = []
    for k, (width, height) in enumerate(sizes):
        yaw, pitch, roll = rig.orientations[k] if rig.orientations else (0.0, 0.0, 0.0)
        links = {letter: 0 for letter in "vabc"} if rig.shared_lens and k > 0 else {}
        if rig.lenses is None:
            lens = dict(hfov=rig.hfov, b=rig.b)
        else:
            if (width, height) != tuple(rig.image_size):
                raise RigjaxError(
                    f"{names[k]} is {width}x{height}, but the template's lenses are of "
                    f"{rig.image_size[0]}x{rig.image_size[1]} images (rig.image_size)"
                )
            start = rig.lenses[k]
            lens = dict(hfov=start.v, a=start.a, b=start.b, c=start.c, d=start.d, e=start.e, crop=start.crop)
            lens |= dict(zip(("vignetting_b", "vignetting_c", "vignetting_d"), start.vignetting))
            lens |= dict(zip(("vignetting_x", "vignetting_y"), start.vignetting_centre))
        images.append(
            Image(
                width=width,
                height=height,
                projection=rig.projection,
                **lens,
                yaw=yaw,
                pitch=pitch,
                roll=roll,
                filename=names[k],
                links=links,
            )
        )
    return Project.new(PanoramaLine(rig.panorama_width, rig.panorama_width // 2), images)


def rig_centres(config: CalibrateConfig) -> Float[np.ndarray, "n 3"] | None:
    """The cameras' centres when the template's objective is ``reprojection``, else None."""
    if config.optimise.objective != "reprojection":
        return None
    return np.asarray(config.optimise.centres or config.rig.centres, float)


def _baseline(centres: np.ndarray | None, config: CalibrateConfig, images, a: int, b: int) -> np.ndarray | None:
    """Camera b's centre from camera a's in camera a's (nominal) frame, for RANSAC's epipolar
    test; None without centres or nominal orientations (then RANSAC fits a rotation)."""
    if centres is None or config.rig.orientations is None:
        return None
    world_from_a = np.asarray(world_from_cam(*(images[a].value(x) for x in "ypr")))
    return world_from_a.T @ (centres[b] - centres[a])


def ransac_stage(
    matches: Sequence[PairPoints],
    nominal: Project,
    config: CalibrateConfig,
    *,
    names: Sequence[str],
    seed: int,
    frames: int,
    progress: Callable[[str], None] | None = None,
) -> PairInliers:
    """Each pair's rotation and inliers by RANSAC on bearings of the ``nominal`` lens (its
    orientations only for the epipolar test with centres); each used pair keeps at most
    ``features.max_points_per_pair * frames`` inliers, a seeded random subset."""
    images = list(nominal.images)
    lens = nominal.cameras()._replace(
        yaw=np.zeros(len(images)), pitch=np.zeros(len(images)), roll=np.zeros(len(images))
    )
    required = set(config.rig.overlaps or ())
    reports, rotations, points = [], {}, []
    rng = np.random.default_rng(seed)
    centres = rig_centres(config)
    for a, b, xy_a, xy_b in matches:
        if progress:
            progress(f"RANSAC {a}-{b}")
        inliers = np.zeros(len(xy_a), bool)
        if len(xy_a) >= 2:
            u_a, ok_a = map_points(img_to_ray, lens.take(a), xy_a)
            u_b, ok_b = map_points(img_to_ray, lens.take(b), xy_b)
            fit = ransac_rotation(
                u_a,
                u_b,
                threshold_deg=config.ransac.threshold_deg,
                iterations=config.ransac.iterations,
                seed=seed,
                baseline=_baseline(centres, config, images, a, b),
            )
            inliers = fit.inliers & ok_a & ok_b
        count = int(inliers.sum())
        used = count >= config.ransac.min_inliers
        reports.append(PairReport(a, b, len(xy_a), count, used))
        if not used:
            if (a, b) in required or (b, a) in required:
                failure = (
                    f"cameras {a} ({names[a]}) and {b} ({names[b]}) should overlap, but only "
                    f"{count} of their {len(xy_a)} matches agree on a rotation (min_inliers "
                    f"{config.ransac.min_inliers}): check the images, the template's lens or its overlaps"
                )
                return PairInliers(tuple(reports), rotations, tuple(points), failure)
            continue
        rotations[(a, b)] = (fit.b_from_a, count)
        index = np.flatnonzero(inliers)
        limit = config.features.max_points_per_pair * frames
        if len(index) > limit:
            index = np.sort(rng.choice(index, limit, replace=False))
        points.append((a, b, xy_a[index], xy_b[index]))
    return PairInliers(tuple(reports), rotations, tuple(points))


def start_stage(nominal: Project, inliers: PairInliers, config: CalibrateConfig, *, names: Sequence[str]) -> Start:
    """The project LM starts from: the ``nominal`` rig turned to the template's orientations, or
    to those the used pairs' rotations give in closed form; the kept inliers as control points;
    every camera's yaw, pitch and roll but the anchor's, and hfov and K2 (once with a shared lens)."""
    anchor = config.optimise.anchor
    images, points = list(nominal.images), inliers.points
    if config.rig.orientations is None:
        anchor_rotation = np.asarray(world_from_cam(*(images[anchor].value(x) for x in "ypr")))
        world, _ = orientations_from_pairs(
            len(images), inliers.rotations, anchor=anchor, anchor_world_from_cam=anchor_rotation
        )
        ypr = np.asarray(ypr_from_world_from_cam(world))
        images = [im.replace(yaw=float(y), pitch=float(p), roll=float(r)) for im, (y, p, r) in zip(images, ypr)]
    else:
        seen = {k for a, b, *_ in points for k in (a, b)}
        lonely = [k for k in range(len(images)) if k not in seen]
        if lonely:
            return Start(
                None,
                f"cameras {lonely} ({', '.join(names[k] for k in lonely)}) have no pair with "
                f"{config.ransac.min_inliers} or more consistent matches",
            )
    if not points:
        return Start(None, "no pair of images has enough consistent matches")
    cps = ControlPoints.from_pairs(points)
    variables = [OptVariable(x, k) for k in range(len(images)) for x in "ypr" if k != anchor]
    variables += [OptVariable(x, k) for k in range(1 if config.rig.shared_lens else len(images)) for x in "vb"]
    return Start(Project.new(nominal.panorama, images, cps, variables))


def _search_settings(config: CalibrateConfig) -> OptimiseConfig:
    """The search's settings: the template's, rotation-only (with centres, objective ``transfer``,
    the schedule's cameras at one point and no priors: the bundle adjustment refines it); the
    template's schedule, never its ``v`` lines."""
    opt = config.optimise
    settings = opt.replace(schedule=without_centres(opt.schedule), pto_vars=False)  # its cameras at one point
    if opt.objective != "reprojection":
        return settings
    return settings.replace(objective="transfer", centres=None, priors=Priors())


def search_stage(
    start: Project, config: CalibrateConfig, *, seed: int, progress: Callable[[str], None] | None = None
) -> tuple[Result, ...]:
    """LM from ``start`` with the template's schedule (its cameras at one point), or from each
    Lévy-flight start around it (template ``levy``); the results, lowest truncated cost first."""
    settings = _search_settings(config)
    if progress:
        progress("Lévy-flight search and LM" if config.levy else "LM")
    if config.levy is None:
        return (optimise(start, settings),)
    starts, _ = levy_starts(start, config.levy, anchor=config.optimise.anchor, seed=seed)
    results = optimise_batch(starts, settings)
    scale = config.levy.cost_scale_px
    final = [
        score(r.project, np.array([[[im.yaw, im.pitch, im.roll] for im in r.project.images]]), scale)[0]
        for r in results
    ]
    return tuple(results[k] for k in np.argsort(final))


def refine_stage(
    search: Sequence[Result],
    start: Project,
    config: CalibrateConfig,
    *,
    progress: Callable[[str], None] | None = None,
) -> Refinement:
    """From the search's best result: pruning with the schedule's last stage (template
    ``optimise.prune``) and, with centres, the bundle adjustment of every control point, its
    priors holding the lens to ``start``'s (the template's); neither: the search's best as it is."""
    opt = config.optimise
    centres = rig_centres(config)
    result, pruned, project = search[0], None, search[0].project
    # The template's settings (objective reprojection with centres) on the schedule's last stage.
    settings, data = opt.replace(schedule=parse_schedule(opt.schedule)[-1].name, pto_vars=False), {}
    if centres is not None:  # every RANSAC inlier, adjusted from the rotation-only search's cameras
        settings = settings.replace(centres=tuple(tuple(centre) for centre in centres.tolist()))
        data = dict(
            nominal=start.cameras(host=True),  # the template's lenses: what the priors hold to
            cluster_error_px=config.features.track_bias_px if config.features.track_step_px is not None else 0.0,
        )
    steps = [
        step for step, on in (("bundle adjustment", centres is not None), ("pruning", opt.prune is not None)) if on
    ]
    if progress and steps:
        progress(" and ".join(steps))
    if opt.prune is not None:
        pruned = optimise_pruned(search[0].project, settings, **data)
        result, project = pruned.result, pruned.project
    elif centres is not None:
        result = optimise(search[0].project, settings, **data)
        project = result.project
    return Refinement(project, result, pruned)


def check_stage(refined: Refinement, start: Project, config: CalibrateConfig) -> Findings:
    """What the refined rig's matches did not determine, or what left the template's plausible
    lens (:func:`~rigjax.calibration.checks.undetermined`), its priors (with centres) or its
    mounting around ``start``; and what the priors held (:func:`~rigjax.calibration.checks.held_by_prior`)."""
    opt = config.optimise
    centres = rig_centres(config)
    prior_v = opt.priors.v if centres is not None else None  # priors apply to the bundle adjustment
    project, result = refined.project, refined.result
    return Findings(
        undetermined(project, result, config.checks, config.rig.hfov, prior_v)
        + (beyond_priors(project, start, opt.priors.as_dict(), config.checks) if centres is not None else ())
        + beyond_mounting(project, start, config.checks),
        held_by_prior(project, result, {} if prior_v is None else {"V": prior_v}),
    )


__all__ = [
    "Findings",
    "PairInliers",
    "PairPoints",
    "PairReport",
    "Refinement",
    "Start",
    "check_stage",
    "nominal_project",
    "ransac_stage",
    "refine_stage",
    "rig_centres",
    "search_stage",
    "start_stage",
]
