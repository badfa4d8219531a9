"""Bundle adjustment: cameras with centres, control points as 3-D points, and the reprojection
error in each image's own pixels (the ``reprojection`` objective).

The rotation-only objectives (:mod:`rigjax.optimiser.objective`) assume that every camera sees the
world from one point. A rig whose cameras sit apart sees a near object from different places, and
no rotation explains its control points. Here camera ``i`` has a centre ``c_i`` (rig frame; metres
or any unit; held at the given values, or estimated with the schedule letter ``X``) and control
point ``k`` is a scene point

    X_k = d_k / q_k,   d_k a unit direction from the rig's origin, q_k >= 0 its inverse depth

(``q = 0``: at infinity). Camera ``i`` sees it along ``q_k (X_k - c_i) = d_k - q_k c_i``, which
stays well defined as ``q_k`` goes to 0. Each observation's residual is the pixel the camera
predicts for that ray minus the observed one (Hartley and Zisserman's gold standard; 4 numbers
per control point). With every centre at the origin the depth drops out and the model is the
rotation-only one.

**Parameters.** A stage's camera letters (the schedules of :mod:`rigjax.optimiser.schedule`) and three per
point. The images cannot tell the rig's orientation in the world, only the centres can: centres that span a
plane with the origin turn with the rig, so every camera's yaw, pitch and roll are estimated, the anchor's
too, in the frame the centres are given in (holding the anchor at its start would turn that frame by the
anchor's error and bend the other cameras to fit centres turned away from where they are:
:func:`~rigjax.optimiser.bundle_setup.centres_fix_orientation`). Centres on one line through the origin
(every centre at the origin; a dual fisheye's two lenses either side of it) leave a turn about that line
free: the anchor's yaw, pitch and roll are held. (With ``X`` the centres' priors set that turn as well: a
turn of the whole rig about the anchor's held centre changes no observation.) Per point, ``(u, v)`` move its
direction in the tangent plane where the stage starts, ``d = normalize(d0 + u e1 + v e2)``, and ``q``, kept
>= 0 (a point at infinity whose step would go beyond is held there and the step solved again:
:func:`~rigjax.optimiser.bundle_solve.schur_step`). With ``X``, each camera's centre but the anchor's (which
fixes where the rig is) adds its three coordinates to the camera's letters; the images cannot tell the rig's
scale, so a prior on the centres (``x``) fixes it.

**Priors.** A lens letter (or the centres) may be held near its nominal value ``m`` (the lens's
stated tolerance; the rig's drawing):
each estimated parameter ``p`` of that letter adds the residual ``(p - m) / sd`` to the cost. With
parallax, a camera's hfov and the depths of the points it sees trade against each other along a
shallow valley of the reprojection error, which matches that cover only part of the image circle
do not close; the prior does (docs/design/optimiser.md).

**Each Levenberg-Marquardt step** solves the damped normal equations
``[[U, W], [W^T, V]] [dc; dp] = -[g_c; g_p]`` without forming them whole: ``V`` is block-diagonal
(3 x 3 per point), so the points are eliminated point by point (the Schur complement
``S = U - W V^-1 W^T``, ``g_S = g_c - W V^-1 g_p``), each point's reduced product summed into
``S`` by pair of cameras as the rotation-only normal equations are
(:func:`rigjax.optimiser.objective.sum_by_pair`); ``S dc = -g_S`` is solved, and each point's step
follows from its own 3 x 3 block: ``dp_k = -V_k^-1 (g_p,k + W_k^T dc)``. The cost per step is linear
in the number of points. Damping is Marquardt's, ``lambda diag(J^T J)`` (1 on a column with no
derivative: a padded parameter, or the depth when every centre is at the origin), updated by
Nielsen's rule.

**Where each part lives.** The residuals, their derivatives and the reduced normal equations:
:mod:`rigjax.optimiser.bundle_model`; the compiled solve of a stage (one program for all the
stages of a run): :mod:`rigjax.optimiser.bundle_solve`; the covariance and the standard deviations:
:mod:`rigjax.optimiser.bundle_covariance`; the host-side set-up of a stage (start values, clusters,
priors): :mod:`rigjax.optimiser.bundle_setup`; this module runs the stages and reports
(:func:`bundle_adjust`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..camera.model import Camera
from ..errors import RigjaxError
from ..pto.project import Project
from .bundle_covariance import standard_deviations
from .bundle_model import (
    BundleArgs,
    BundleConfig,
    Views,
    camera_centres,
    direction,
    rig_orientations,
    stage_cameras,
)
from .bundle_setup import (
    centre_matrix,
    centres_fix_orientation,
    check_priors,
    point_views,
    stage_args,
    start_params,
    triangulate,
    world_rays,
)
from .bundle_solve import final_residuals, solve
from .objective import LETTERS, point_error, stage_config, theta_of, with_theta
from .options import STATUS, SolverOptions
from .problem import check_project, parameter_count, slot_matrix
from .residuals import NORMAL, ROBUST_LOSSES
from .schedule import Layout, reoptimised, stage_layouts


class BundleStageReport(NamedTuple):
    """What one stage did; RMS values are the reprojection error per observation, px."""

    name: str
    parameters: tuple[str, ...]
    status: str
    steps: int
    rms_initial: float
    rms_final: float
    seconds: float


@dataclass(frozen=True, eq=False)
class BundleResult:
    """The adjusted project (cameras and centres), each control point's scene point and
    its reprojection residuals ``(n, 4)`` px (image a's, then image b's, in the project's order of
    control points; zeros for points not in use), and a report per stage: what the reprojection
    objective returns, an :class:`~rigjax.optimiser.result.OptimiseResult`."""

    project: Project
    centres: np.ndarray  # (n_images, 3)
    directions: np.ndarray  # (n_points, 3) unit, from the rig's origin
    inverse_depths: np.ndarray  # (n_points,) 1 / distance from the origin; 0 at infinity
    residuals: np.ndarray
    rms: float
    stages: tuple[BundleStageReport, ...]
    # The last stage's standard deviations (standard_deviations): (n_images, 9) letters VABCDEYPR,
    # NaN where not estimated, inf where the matches leave the letter free; each camera's orientation (degrees, the RMS of its turn); the
    # residuals' scale they assume (px per coordinate).
    standard_deviations: np.ndarray
    orientation_sd_deg: np.ndarray
    sigma: float
    centre_sd: np.ndarray  # (n_images, 3): each estimated centre coordinate's, in the centres' unit; NaN: held
    # (n_images, 3, 3): the covariance of each camera's turn (degrees squared, world axes, the rig's
    # own turn removed; NaN without yaw, pitch and roll): an error vector's Mahalanobis distance
    turn_covariance: np.ndarray
    not_optimised: tuple[str, ...] = ()  # with pto_vars: v-line variables left out, with the reason
    # (n_points,): each point's inverse depth's standard deviation with its cameras held, the last
    # stage's (inf where its depth is not estimated): inverse_depths / inverse_depth_sd tells a point's
    # parallax from its noise
    inverse_depth_sd: np.ndarray | None = None

    @property
    def ok(self) -> bool:
        """The last stage converged (earlier stages only start it)."""
        return self.stages[-1].status == "converged"

    @property
    def points(self) -> np.ndarray:
        """``(n_points, 3)`` scene points in the centres' units (``inf`` where at infinity)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.inverse_depths[:, None] > 0.0, self.directions / self.inverse_depths[:, None], np.inf)

    def point_errors(self) -> np.ndarray:
        """``(n_points,)`` px: per control point, the larger of its two reprojection errors."""
        return point_error(self.residuals, np)

    def format_stages(self) -> str:
        """The per-stage table the command line prints (:func:`format_stages`)."""
        return format_stages(self)

    def format_rms(self) -> str:
        return f"{self.rms:.4f} px (reprojection)"

    def format_deviations(self) -> str:
        """The standard deviations as the command line prints them (:func:`format_deviations`)."""
        return format_deviations(self)


class _Setup(NamedTuple):
    """A bundle adjustment's checked inputs (:func:`_set_up`), the same for every stage."""

    centres: np.ndarray  # (n_images, 3): where the first stage starts, and the centres' priors' means
    priors: dict[str, float]  # upper-case letters (check_priors)
    nominal: Camera  # what the lens and orientation priors hold to
    points: Views  # padded (point_views)
    weight: np.ndarray  # (n_points,) 1 in use
    padded_weight: np.ndarray  # (n_padded,)
    finite: np.ndarray  # (n_padded,) 1 where a point's depth is estimated, 0 where held at infinity
    point: np.ndarray  # (n_control_points,) each control point's point
    slots: np.ndarray  # (n_control_points, 2) the slots of its two ends
    rigid: np.ndarray  # (n_images, 3) int32: each derived camera's (a, b, c), -1 for the others
    stages: list[tuple[str, Layout]]
    not_optimised: tuple[str, ...]
    config: BundleConfig  # every stage's: the letters and centres of them all, one compiled solve
    parameters: int  # every stage's parameter vector's length (padded)


class _Options(NamedTuple):
    """:func:`bundle_adjust`'s settings that every stage's solve takes (see its arguments)."""

    solver: SolverOptions
    robust: str | None
    robust_scale: float
    median_scale_floor: float | None
    cluster_px: float
    cluster_error_px: float


class _State(NamedTuple):
    """Where a stage starts (and the previous one ended): the cameras, their centres ``(n_images, 3)``
    and each (padded) point's unit direction ``(n, 3)`` and inverse depth ``(n,)``."""

    cameras: Camera
    centres: np.ndarray
    directions: np.ndarray
    inverse_depths: np.ndarray


class _Solved(NamedTuple):
    """One stage's outcome: where the next stage starts, its report, and what the result takes from
    the last stage (its arguments and own letters, each observation's residual ``(n, 4)`` px, the
    parameters' covariance, the residuals' scale, the parameters the matches leave free and the
    points' inverse depths' deviations)."""

    state: _State
    report: BundleStageReport
    args: BundleArgs
    letters: str  # the letters the stage optimises (the solve's config runs along every stage's)
    residuals: np.ndarray
    covariance: np.ndarray
    sigma: float
    free: np.ndarray
    depth_sd: np.ndarray  # (n_padded,) each point's inverse depth's standard deviation, its cameras held
    # (n_images x letters, params): each camera's derivatives of the stage's own letters along the
    # parameters where the stage ends (its centres left out)
    jacobian: np.ndarray


def bundle_adjust(
    project: Project,
    centres=None,
    schedule: str = "YPR,VBYPR",
    *,
    pto_vars: bool = False,
    anchor: int = 0,
    solver: SolverOptions | None = None,
    weights: np.ndarray | None = None,
    robust: str | None = None,
    robust_scale: float = 2.0,
    median_scale_floor: float | None = None,
    preliminary: bool = False,
    cluster_px: float = 32.0,
    cluster_error_px: float = 0.0,
    priors=None,
    nominal: Camera | None = None,
    at_infinity: np.ndarray | None = None,
    hold_anchor: bool | None = None,
    rigid: np.ndarray | None = None,
    tracks: np.ndarray | None = None,
) -> BundleResult:
    """Adjust a project's cameras and its control points' scene points together, minimising the
    reprojection error (module docstring), stage by stage. ``rigjax.optimise`` calls it for objective
    ``reprojection``, with the arguments :meth:`rigjax.optimiser.config.OptimiseConfig.solve_kwargs` makes.

    Args:
        project: cameras and control points; only ``t0`` (normal) points are taken, and a project
            with line points is refused (they have no reprojection residual yet).
        centres: ``(n_images, 3)`` camera centres in the rig frame (x right, y down, z forward, as
            the cameras' orientations); their unit sets the depths'. All zero: the rotation-only
            model. Default: the project's (``Project.centres``, its ``#-rigjax centre`` lines).
            Held at these values, except in stages with ``X``, which start from them and estimate
            every centre but the anchor's, about these values as the priors' means.
        schedule: stages such as ``"YPR,VBYPR"`` or ``"YPR,VYPRX"`` (:mod:`rigjax.optimiser.schedule`).
        pto_vars: instead of a schedule, one stage of exactly the project's ``v`` lines, as Hugin
            reads them (``autooptimiser -n``; ``anchor`` unused); the variables left out are
            listed in ``not_optimised``.
        anchor: the image whose centre stays fixed with ``X``, and whose yaw, pitch and roll stay
            fixed where the centres do not fix the rig's orientation
            (:func:`~rigjax.optimiser.bundle_setup.centres_fix_orientation`).
        solver: stopping rules (its ``backend`` is not used: the solve is this module's own).
        weights: ``(n_control_points,)`` 0/1 mask of the points to use (all by default).
        robust: ``None``, ``"huber"`` or ``"cauchy"`` on each observation's 2-D residual, with
            ``robust_scale`` px; ``median_scale_floor``: each stage's scale is instead the median
            point error where it starts, at least this many px (pruning's first round).
        preliminary: a later solve starts from this one (pruning's first round): every stage stops
            at ``solver.preliminary_ftol``, as a stage that a later one optimises again does.
        cluster_px: the standard deviations count the points of one pair whose first ends lie in
            one cell of this many pixels as one draw
            (:func:`~rigjax.optimiser.bundle_covariance.covariance`): neighbouring tracks share
            their errors. 0: every point its own.
        cluster_error_px: the standard deviation (px, per coordinate) of an offset that the second
            ends of one cluster's points share and the fit can absorb, which the residuals then
            cannot show (:func:`~rigjax.optimiser.bundle_covariance.covariance`; the template's
            ``features.track_bias_px`` for tracks);
            the standard deviations count it. 0: none.
        priors: lens letters and their standard deviations about the ``nominal`` cameras' values
            (``{"v": 1.0}``: each estimated hfov within about a degree of its nominal value; degrees
            for ``v``, px for ``d``, ``e``, the project's units for ``a``, ``b``, ``c``), and ``x``
            for each coordinate of an estimated centre about ``centres`` (their unit; required
            with ``X``: the images cannot tell the rig's scale): each estimated parameter of the
            letter adds ``(value - nominal) / sd`` to the residuals, and its standard deviation
            includes the prior's. Default: none.
        nominal: the cameras whose values the priors hold to; default: the project's, where this
            adjustment starts (pass the nominal rig when the project has already been optimised).
        at_infinity: ``(n_control_points,)`` bool: points held at infinity (``q = 0``), their
            depths not estimated: matches whose baseline is too short to tell a depth, which would
            only trade against the lenses (a turning camera's lens matched with itself across
            frames; :mod:`rigjax.calibration.motion`). Default: every point's depth is estimated.
        hold_anchor: hold the anchor's yaw, pitch and roll (True) or estimate them (False); default
            (None): held where the centres leave the rig's orientation free
            (:func:`~rigjax.optimiser.bundle_setup.centres_fix_orientation`). Centres placed from the
            cameras' own start orientations (frames of a turning camera) fix it only to that start.
        rigid: ``(n_images, 3)`` int: cameras mounted together on a rig that turns between frames,
            each derived camera's row ``(a, b, c)`` (its frame's first camera, the first frame's first
            camera, the first frame's camera of its own mounting): its orientation is ``W_a W_b^T W_c``,
            its frame's turn applied to its mounting, and its yaw, pitch and roll are no parameters;
            ``-1`` rows: cameras of their own. So the rig's mounting is one, whichever frame shows it,
            and each camera's matches across frames measure the same turn: a turn about other axes
            than the first tells each mounting (the hand-eye constraint). Default: every camera its own.
        tracks: ``(n_control_points,)`` int: control points of one number ``>= 0`` are one scene
            point, seen in every image their ends name (a feature followed through frames: one
            depth, where a point per pair of images has a depth each that trades against the
            lenses); ``-1``: the control point is its own point. A track's ends in one image must
            be one pixel, and its control points all held at infinity or none; it is in use while
            all its control points are (a weight of 0 on one of them leaves the whole track out of
            the solve). Its residuals, depth and direction are reported on each of its control
            points (:func:`~rigjax.optimiser.bundle_setup.point_views`), so pruning judges them
            one by one, each from the track's point. Default: every control point its own point.

    Points start where the rays of their first two images from the start cameras meet
    (:func:`~rigjax.optimiser.bundle_setup.triangulate`), or at
    infinity; each stage starts from where the previous one ended.
    """
    setup = _set_up(
        project,
        centres,
        schedule,
        pto_vars,
        anchor,
        weights,
        robust,
        priors,
        nominal,
        cluster_error_px,
        at_infinity,
        hold_anchor,
        rigid,
        tracks,
    )
    options = _Options(
        solver or SolverOptions(), robust, robust_scale, median_scale_floor, cluster_px, cluster_error_px
    )
    cameras = project.cameras(host=True)
    if np.any(setup.rigid >= 0):  # derived cameras start where their rig puts them
        theta = rig_orientations(jnp.asarray(theta_of(cameras, np)), jnp.asarray(setup.rigid))
        cameras = jax.tree_util.tree_map(np.asarray, with_theta(cameras, theta))
    state = _State(cameras, setup.centres, *_start_points(cameras, setup.centres, setup.points, setup.finite))
    reports = []
    later = reoptimised([layout.names for _, layout in setup.stages])
    for k, (name, layout) in enumerate(setup.stages):
        solved = _solve_stage(setup, options, name, layout, state, preliminary or bool(later[k]))
        state = solved.state
        reports.append(solved.report)
    return _bundle_result(project, setup, state, solved, tuple(reports))


def _centres_of(project: Project, centres) -> np.ndarray:
    """``(n_images, 3)`` float: the given centres, or the project's; an error where there are none,
    or they have the wrong shape or a non-finite coordinate."""
    n_images = len(project.images)
    if centres is None:
        if project.centres is None:
            raise RigjaxError(
                "the reprojection objective needs the camera centres: pass centres, give them in the config "
                "(centres: [[x, y, z], ...]) or in the project ('#-rigjax centre N x y z' lines)"
            )
        centres = project.centres
    centres = np.asarray(centres, dtype=float)
    if centres.shape != (n_images, 3) or not np.all(np.isfinite(centres)):
        raise RigjaxError(f"centres must be finite, of shape ({n_images}, 3) (one per image), got {centres.shape}")
    return centres


def _set_up(
    project: Project,
    centres,
    schedule,
    pto_vars,
    anchor,
    weights,
    robust,
    priors,
    nominal,
    cluster_error_px,
    at_infinity,
    hold_anchor,
    rigid,
    tracks,
) -> _Setup:
    """:func:`bundle_adjust`'s arguments checked (errors name the argument and what it should be)
    and turned into its :class:`_Setup`: centres, priors, padded points and stages."""
    if robust not in ROBUST_LOSSES:
        raise RigjaxError(f"robust must be one of {ROBUST_LOSSES}, got {robust!r}")
    check_project(project, anchor)
    priors = check_priors(priors)
    n_images, cps = len(project.images), project.control_points
    centres = _centres_of(project, centres)
    lines = np.flatnonzero(cps.kind != NORMAL)
    if lines.size:
        raise RigjaxError(
            f"the reprojection objective takes normal (t0) control points only; control point {lines[0]} is a "
            f"line point (t{int(cps.kind[lines[0]])}), and {lines.size} in all: remove them or use objective 'transfer'"
        )
    if not (np.isfinite(cluster_error_px) and cluster_error_px >= 0.0):
        raise RigjaxError(f"cluster_error_px must be a standard deviation in pixels (>= 0), got {cluster_error_px!r}")
    weight = np.ones(len(cps)) if weights is None else np.asarray(weights, dtype=float)
    if weight.shape != (len(cps),):
        raise RigjaxError(f"weights has shape {weight.shape}, expected ({len(cps)},)")
    finite = np.ones(len(cps), bool) if at_infinity is None else ~np.asarray(at_infinity, bool)
    if finite.shape != (len(cps),):
        raise RigjaxError(f"at_infinity has shape {finite.shape}, expected ({len(cps)},) (one per control point)")
    points = point_views(cps, weight, finite.astype(float), tracks)
    rigid = _rigid_of(project, rigid, anchor)
    derived = np.flatnonzero(rigid[:, 0] >= 0).tolist()
    if pto_vars and (derived or hold_anchor is not None):
        raise RigjaxError("pto_vars takes the project's v lines as they are: rigid and hold_anchor do not apply")
    if hold_anchor is None:
        hold_anchor = not centres_fix_orientation(centres)
    stages, not_optimised = stage_layouts(project, schedule, anchor, pto_vars, hold_anchor, derived)
    estimates_centres = any(bool(np.any(centre_matrix(layout) >= 0)) for _, layout in stages)
    if "X" not in priors and estimates_centres:
        raise RigjaxError(
            f"schedule {schedule!r} estimates centres (X): give priors {{'x': sd}}, their standard deviation about "
            "the given centres, which fixes the rig's scale (images cannot tell it)"
        )
    for name, layout in stages:
        if layout.size > 2 * int(np.sum(weight > 0)):
            raise RigjaxError(
                f"stage {name}: {layout.size} parameters but only {2 * int(np.sum(weight > 0))} observations"
            )
    if nominal is None:
        nominal = project.cameras(host=True)
    elif np.shape(nominal.hfov) != (n_images,):
        raise RigjaxError(f"nominal: {np.size(nominal.hfov)} cameras for a project of {n_images} images")
    projections = {image.projection for image in project.images}
    projection = projections.pop() if len(projections) == 1 else None
    # One program for every stage: the letters and centres of them all (a stage's other letters and
    # padded parameters have zero Jacobian columns), as rigjax.optimiser.problem.prepare does.
    config = stage_config(BundleConfig(projection, "", robust), *(slot_matrix(layout) for _, layout in stages))
    config = config._replace(centres=estimates_centres, rigid=bool(derived))
    parameters = max(parameter_count(layout) for _, layout in stages)
    return _Setup(
        centres,
        priors,
        nominal,
        points.views,
        points.weight,
        points.padded_weight,
        points.finite,
        points.point,
        points.slots,
        rigid,
        stages,
        not_optimised,
        config,
        parameters,
    )


def _rigid_of(project: Project, rigid, anchor: int) -> np.ndarray:
    """``(n_images, 3)`` int32: :func:`bundle_adjust`'s ``rigid`` (default: no derived camera),
    checked: a row is all -1 or three other images with orientations of their own, the anchor is not
    derived, and no image's yaw, pitch or roll is linked to a derived one's."""
    n_images = len(project.images)
    if rigid is None:
        return np.full((n_images, 3), -1, np.int32)
    rigid = np.asarray(rigid)
    if rigid.shape != (n_images, 3) or not np.issubdtype(rigid.dtype, np.integer):
        raise RigjaxError(f"rigid must be integers of shape ({n_images}, 3) (one row per image), got {rigid.shape}")
    derived = rigid[:, 0] >= 0
    for k, row in enumerate(rigid):
        if np.all(row == -1):
            continue
        if np.any(row < 0) or np.any(row >= n_images) or np.any(derived[row]) or k in row or k == anchor:
            raise RigjaxError(
                f"rigid: image {k}'s orientation cannot follow images {row.tolist()}: each of the three must be "
                f"another image (0-{n_images - 1}) with an orientation of its own, and the anchor ({anchor}) its own"
            )
    for k, image in enumerate(project.images):
        linked = [letter for letter in "ypr" if derived[image.links.get(letter, k)] and image.links.get(letter, k) != k]
        if linked or (derived[k] and any(letter in image.links for letter in "ypr")):
            raise RigjaxError(
                f"rigid: image {k}'s yaw, pitch or roll is linked to or from an image whose orientation follows its "
                "rig: unlink them"
            )
    return rigid.astype(np.int32)


def _start_points(
    cameras: Camera, centres: np.ndarray, points: Views, finite: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Each (padded) point's start: ``(directions (n, 3), inverse depths (n,))`` where the rays of
    its first two slots through ``cameras`` from ``centres`` ``(n_images, 3)`` meet
    (:func:`triangulate`), or at infinity (along their mean ray), as every point held there
    (``finite`` 0) is."""
    rays = world_rays(cameras, points)
    held = finite[:, None] == 0.0
    first, second = (np.asarray(points.image)[:, k] for k in (0, 1))
    origin = np.zeros_like(centres[first])
    return triangulate(
        rays[:, 0], rays[:, 1], np.where(held, origin, centres[first]), np.where(held, origin, centres[second])
    )


def _solve_stage(
    setup: _Setup, options: _Options, name: str, layout: Layout, state: _State, preliminary: bool
) -> _Solved:
    """One stage ``name`` of :func:`bundle_adjust` (its ``layout``), from ``state``: the compiled solve,
    the points left out placed for the cameras, and the stage's report. ``preliminary``: stop at
    ``solver.preliminary_ftol`` (a later solve starts from this one)."""
    cameras, centres, directions, inverse_depths = state
    rays = world_rays(cameras, setup.points)  # the observations' rays through the cameras this stage starts from
    args = stage_args(
        cameras,
        centres,
        layout,
        setup.points,
        setup.padded_weight,
        rays,
        directions,
        options.solver,
        preliminary,
        options.robust_scale,
        options.median_scale_floor,
        options.cluster_px,
        setup.priors,
        setup.nominal,
        setup.centres,
        options.cluster_error_px,
        setup.finite,
        setup.rigid,
        setup.parameters,
    )
    config = setup.config
    start = time.perf_counter()
    point_params = np.concatenate([np.zeros((len(directions), 2)), inverse_depths[:, None]], axis=1)
    params = start_params(layout, cameras, centres, setup.parameters)
    params, point_params, status, steps, before, cov, sigma, free, depth_sd, jacobian = solve(
        params, point_params, args, config=config
    )
    fit = bool(np.any(setup.weight == 0))  # points left out (pruning): placed for the cameras
    point_params, after = final_residuals(params, point_params, args, config=config, fit=fit)
    theta, _ = stage_cameras(params, args, config)
    state = _State(
        jax.tree_util.tree_map(np.asarray, with_theta(args.base, theta)),
        np.asarray(camera_centres(params, args)),
        np.asarray(direction(args.frame, point_params)),
        np.asarray(point_params[:, 2]),
    )
    use = setup.padded_weight > 0
    seen = np.asarray(setup.points.seen)
    # The deviations are of the stage's own letters: the solve's Jacobian runs along every stage's.
    own = stage_config(config, args.slot).letters
    rows = [config.letters.index(letter) for letter in own]
    report = BundleStageReport(
        name,
        layout.names,
        STATUS[int(status)],
        int(steps),
        _rms(np.asarray(before), seen, use),
        _rms(np.asarray(after), seen, use),
        time.perf_counter() - start,
    )
    return _Solved(
        state,
        report,
        args,
        own,
        np.asarray(after),
        np.asarray(cov),
        float(sigma),
        np.asarray(free),
        np.asarray(depth_sd),
        np.asarray(jacobian).reshape(len(theta), -1, len(params))[:, rows].reshape(-1, len(params)),
    )


def _rms(rows: np.ndarray, seen: np.ndarray, use: np.ndarray) -> float:
    """px: the root mean square of the points' residuals ``(n, 2 K)`` per observation (``seen``
    ``(n, K)``) of the points in ``use``."""
    observations = max(float(np.sum(seen[use])), 1.0)
    return float(np.sqrt(np.sum(rows[use] ** 2) / observations))


def _bundle_result(
    project: Project, setup: _Setup, state: _State, last: _Solved, reports: tuple[BundleStageReport, ...]
) -> BundleResult:
    """The :class:`BundleResult` of the stages' end ``state``, with the last stage's standard
    deviations; each control point's from its point's (its two ends' residuals)."""
    point = setup.point
    ends = last.residuals.reshape(len(last.residuals), -1, 2)
    residuals = np.concatenate([ends[point, setup.slots[:, 0]], ends[point, setup.slots[:, 1]]], axis=1)
    deviations, orientation, turn_cov = standard_deviations(
        last.covariance, last.jacobian, last.letters, state.cameras, last.free
    )
    slot = np.asarray(last.args.centre_slot)
    diagonal = np.diagonal(last.covariance)[np.maximum(slot, 0)]
    centre_sd = np.where(slot >= 0, np.sqrt(np.maximum(diagonal, 0.0)), np.nan)
    centre_sd[(slot >= 0) & last.free[np.maximum(slot, 0)]] = np.inf
    return BundleResult(
        project.with_cameras(state.cameras).replace(centres=state.centres, deviations=deviations),
        state.centres,
        state.directions[point],
        state.inverse_depths[point],
        residuals,
        reports[-1].rms_final,
        reports,
        deviations,
        orientation,
        last.sigma,
        centre_sd,
        turn_cov,
        setup.not_optimised,
        last.depth_sd[point],
    )


def format_stages(result: BundleResult) -> str:
    """The per-stage table the CLI prints."""
    lines = [f"{'stage':<10} {'status':<10} {'params':>6} {'steps':>5} {'reprojection rms px':>21} {'time s':>7}"]
    for s in result.stages:
        lines.append(
            f"{s.name:<10} {s.status:<10} {len(s.parameters):>6} {s.steps:>5} "
            f"{s.rms_initial:>10.3f}->{s.rms_final:<10.3f} {s.seconds:>7.3f}"
        )
    return "\n".join(lines)


def _cell(value: float, width: int) -> str:
    """A deviation as the CLI prints it: '-' where held (NaN), 'free' where undetermined (inf)."""
    if np.isnan(value):
        return f"{'-':>{width}}"
    return f"{'free':>{width}}" if value == np.inf else f"{value:>{width}.4f}"


def format_deviations(result: BundleResult) -> str:
    """The last stage's standard deviations per camera, as the CLI prints them ('free': the matches
    leave it undetermined)."""
    sd = result.standard_deviations
    shown = [k for k in range(len(LETTERS)) if (~np.isnan(sd[:, k])).any()]
    lines = [
        f"standard deviations, degrees (residual scale {result.sigma:.3f} px; the rig's own orientation removed):",
        f"{'image':>5} {'turn':>8} " + " ".join(f"{LETTERS[k].lower():>8}" for k in shown),
    ]
    for i, row in enumerate(sd):
        cells = " ".join(_cell(row[k], 8) for k in shown)
        lines.append(f"{i:>5} {_cell(result.orientation_sd_deg[i], 8)} {cells}")
    if (~np.isnan(result.centre_sd)).any():
        lines.append("centres and their standard deviations (x, y, z; the centres' unit; '-': held):")
        for i, (centre, sd) in enumerate(zip(result.centres, result.centre_sd)):
            cells = " ".join(
                f"{c:>9.4f} ±{_cell(d, 8).strip():<8}" if not np.isnan(d) else f"{c:>9.4f} {'-':<9}"
                for c, d in zip(centre, sd)
            )
            lines.append(f"{i:>5} {cells}")
    return "\n".join(lines)
