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

**Parameters.** A stage's camera letters (the schedules of :mod:`rigjax.optimiser.schedule`) and
three per point. The images cannot tell the rig's orientation in the world, only the centres can:
centres that span a plane with the origin turn with the rig, so every camera's yaw, pitch and roll
are estimated, the anchor's too, in the frame the centres are given in (holding the anchor at its
start would turn that frame by the anchor's error and bend the other cameras to fit centres turned
away from where they are: :func:`centres_fix_orientation`). Centres on one line through the origin
(every centre at the origin; a dual fisheye's two lenses either side of it) leave a turn about that
line free: the anchor's yaw, pitch and roll are held. (With ``X`` the centres' priors set that turn
as well: a turn of the whole rig about the anchor's held centre changes no observation.) Per point,
``(u, v)`` move its direction in the tangent plane where the stage starts,
``d = normalize(d0 + u e1 + v e2)``, and ``q``, kept >= 0 (a point at infinity whose step would
go beyond is held there and the step solved again: :func:`schur_step`). With ``X``, each camera's
centre but the anchor's (which fixes where the rig is) adds its three coordinates to the
camera's letters; the images cannot tell the rig's scale, so a prior on the centres (``x``) fixes it.

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
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..camera.lenses import safe_hypot
from ..camera.model import Camera, img_to_ray, optics, optics_ray_to_img
from ..camera.rotation import world_from_cam
from ..errors import RigjaxError
from ..pto.project import Project
from .objective import (
    LETTERS,
    letter_columns,
    median_point_error,
    stage_config,
    sum_by_pair,
    theta_from_params,
    theta_of,
    with_theta,
)
from .options import STATUS, SolverOptions
from .problem import check_project, initial_params, padded_points, parameter_count, slot_matrix
from .residuals import NORMAL, ROBUST_LOSSES, PointArrays, ray_angle, rms, robust_scale, transfer_or_angle
from .schedule import CENTRE_KEYS, LENS_LETTERS, UNIT, Layout, reoptimised, stage_layouts

# Nielsen's damping: the start, relative to diag(J^T J), and the value at which no step is left to try.
_INITIAL_DAMPING, _MAX_DAMPING = 1e-3, 1e30


class BundleConfig(NamedTuple):
    """Static settings of a stage's compiled solve."""

    projection: int | None  # the rig's one lens type, or None
    letters: str  # the camera letters the stage optimises (derivatives along these only)
    robust: str | None = None  # robust loss of each observation's 2-D residual (residuals.robust_scale)
    centres: bool = False  # the stage estimates centres: each camera's letters, then its centre (x, y, z)


class BundleArgs(NamedTuple):
    """A stage's data (a change of values never recompiles)."""

    base: Camera  # (n_images,) the cameras where the stage starts
    slot: jax.Array  # (n_images, 9) int32: parameter index of each letter VABCDEYPR, or -1
    centres: jax.Array  # (n_images, 3) where the stage starts
    centre_slot: jax.Array  # (n_images, 3) int32: parameter index of each centre coordinate, or -1
    points: PointArrays  # padded
    weight: jax.Array  # (n_padded,) 1 in use, 0 left out
    frame: jax.Array  # (n_padded, 3, 3): each point's direction where the stage starts and its tangents
    observed: jax.Array  # (n_padded, 2, 3): each observation's ray in its camera's frame (stage start)
    # (n_padded,) int32: points whose errors may be shared (neighbouring tracks of one pair) carry one
    # number, and count as one draw in the covariance (covariance); every point its own: the textbook one
    cluster: jax.Array
    # px: the standard deviation of an offset that the second ends of each cluster's points share
    # and the residuals cannot show (covariance); 0: none
    cluster_error: jax.Array
    prior_mean: jax.Array  # (n_params,): each parameter's nominal value, where it has a prior
    prior_weight: jax.Array  # (n_params,): 1 / its standard deviation (parameter units); 0: no prior
    robust_scale: jax.Array  # px
    # >= 0: the robust scale is instead the median point error where the stage starts (the larger of
    # each point's two reprojection errors), at least this many px (as SolveArgs.median_scale_floor)
    median_scale_floor: jax.Array
    max_steps: jax.Array
    xtol: jax.Array
    ftol: jax.Array


class Linearisation(NamedTuple):
    """The weighted residuals of every point and their derivatives at one point of the solve."""

    rows: jax.Array  # (n, 4): the residual in image a, then in image b
    d_cameras: jax.Array  # (n, 4, 2 L): along the stage's letters (and centre) of camera a, then of b
    d_point: jax.Array  # (n, 4, 3): along the point's (u, v, q)
    prior: jax.Array  # (params,): the priors' residuals (p - m) / sd (0 without a prior); their
    # derivative is the diagonal BundleArgs.prior_weight


def _prior(params, args: BundleArgs) -> jax.Array:
    return args.prior_weight * (params - args.prior_mean)


def _cost(lin: Linearisation) -> jax.Array:
    """The objective: half the squared residuals, the priors' included."""
    return 0.5 * (jnp.sum(lin.rows**2) + jnp.sum(lin.prior**2))


def _width(config: BundleConfig) -> int:
    """``L``: the parameters of one camera in a stage, its letters and, with ``X``, its centre."""
    return len(config.letters) + 3 * config.centres


def camera_centres(params, args: BundleArgs) -> jax.Array:
    """``(n_images, 3)``: the estimated centres from ``params``, the others as the stage starts."""
    slot = args.centre_slot
    return jnp.where(slot >= 0, params[jnp.clip(slot, 0, params.shape[0] - 1)], args.centres)


def _cameras(params, args: BundleArgs, config: BundleConfig):
    """Every camera's 9 letters ``(n_images, 9)`` and its stage parameters ``(n_images, L)``: the
    stage's letters, then with ``X`` its centre."""
    theta = theta_from_params(params, args)
    own = theta[:, jnp.asarray(letter_columns(config))]
    if config.centres:
        own = jnp.concatenate([own, camera_centres(params, args)], axis=1)
    return theta, own


def direction(frame: jax.Array, point: jax.Array) -> jax.Array:
    """A point's unit direction from its tangent-plane coordinates ``point[..., :2]``."""
    v = frame[..., 0, :] + point[..., :1] * frame[..., 1, :] + point[..., 1:2] * frame[..., 2, :]
    return v / jnp.linalg.norm(v, axis=-1, keepdims=True)


def _observation(theta, fixed: Camera, centre, d, q, xy, observed, projection):
    """``(2,)`` px: one camera's predicted pixel of the point ``(d, q)`` minus the observed ``xy``.
    Where the camera cannot map the ray, the angle to the observed ray (``observed``, camera frame)
    in its pixels, as the transfer residual does."""
    lens = optics(with_theta(fixed, theta))
    ray = d - q * centre
    predicted, ok = optics_ray_to_img(fixed.projection if projection is None else projection, lens, ray)
    unit = ray / jnp.maximum(jnp.linalg.norm(ray), jnp.finfo(ray.dtype).tiny)
    angle = ray_angle(unit, lens.world_from_cam @ observed)
    return transfer_or_angle(predicted, ok, xy, lens.focal, angle)


def _point_rows(sub_a, sub_b, point, theta_a, theta_b, data, columns, projection):
    """``(4,)``: a point's residuals in image a, then in image b, from its cameras' stage
    parameters ``sub_a``, ``sub_b`` (:func:`_cameras`: the letters ``columns``, then the centre
    where the stage estimates it; the rest of their letters from ``theta_a``, ``theta_b``) and
    ``point``."""
    fixed_a, fixed_b, centre_a, centre_b, frame, xy_a, xy_b, observed = data
    n = columns.shape[0]
    if sub_a.shape[0] > n:  # the stage estimates centres
        centre_a, centre_b = sub_a[n:], sub_b[n:]
    d, q = direction(frame, point), point[2]
    theta_a, theta_b = theta_a.at[columns].set(sub_a[:n]), theta_b.at[columns].set(sub_b[:n])
    rows_a = _observation(theta_a, fixed_a, centre_a, d, q, xy_a, observed[0], projection)
    rows_b = _observation(theta_b, fixed_b, centre_b, d, q, xy_b, observed[1], projection)
    return jnp.concatenate([rows_a, rows_b])


def _point_data(args: BundleArgs):
    p = args.points
    return (
        args.base.take(p.image_a),
        args.base.take(p.image_b),
        args.centres[p.image_a],  # replaced by the stage's own where it estimates centres
        args.centres[p.image_b],
        args.frame,
        p.xy_a,
        p.xy_b,
        args.observed,
    )


def residuals(params, point_params, args: BundleArgs, config: BundleConfig) -> jax.Array:
    """``(n, 4)`` weighted residuals (px) at camera parameters ``params`` and points
    ``point_params``, each observation's through the robust loss (what the solve minimises)."""
    rows = raw_residuals(params, point_params, args, config)
    return (
        rows
        if config.robust is None
        else jax.vmap(jax.vmap(partial(_robust, args=args, config=config)))(rows.reshape(-1, 2, 2)).reshape(rows.shape)
    )


def _robust(pair, args: BundleArgs, config: BundleConfig):
    """One observation's 2-D residual through the robust loss."""
    return pair * robust_scale(safe_hypot(pair[0], pair[1])[0], config.robust, args.robust_scale)


def raw_residuals(params, point_params, args: BundleArgs, config: BundleConfig) -> jax.Array:
    """``(n, 4)`` weighted residuals (px), without the robust loss: image a's, then image b's."""
    theta, own = _cameras(params, args, config)
    p = args.points
    columns = jnp.asarray(letter_columns(config))
    rows = jax.vmap(partial(_point_rows, columns=columns, projection=config.projection))(
        own[p.image_a], own[p.image_b], point_params, theta[p.image_a], theta[p.image_b], _point_data(args)
    )
    return rows * args.weight[:, None]


def linearise(params, point_params, args: BundleArgs, config: BundleConfig) -> Linearisation:
    """The residuals and their derivatives along the stage's parameters of each point's two
    cameras and along the point's own three parameters."""
    theta, own = _cameras(params, args, config)
    p = args.points
    columns = jnp.asarray(letter_columns(config))

    def one(sa, sb, ta, tb, pt, data):
        f = partial(_point_rows, theta_a=ta, theta_b=tb, data=data, columns=columns, projection=config.projection)
        rows = f(sa, sb, pt)
        d_a, d_b, d_point = jax.jacfwd(f, argnums=(0, 1, 2))(sa, sb, pt)
        return rows, jnp.concatenate([d_a, d_b], axis=-1), d_point

    rows, d_cameras, d_point = jax.vmap(one)(
        own[p.image_a], own[p.image_b], theta[p.image_a], theta[p.image_b], point_params, _point_data(args)
    )
    w = args.weight
    lin = Linearisation(
        rows * w[:, None], d_cameras * w[:, None, None], d_point * w[:, None, None], _prior(params, args)
    )
    if config.robust is None:
        return lin
    # Each observation's residual through the robust loss, its derivatives through the loss's own
    # 2 x 2 derivative.
    n = rows.shape[0]
    pairs = lin.rows.reshape(n, 2, 2)
    robust = partial(_robust, args=args, config=config)
    chain = jax.vmap(jax.vmap(jax.jacfwd(robust)))(pairs)  # (n, 2, 2, 2)

    def through(d):
        return jnp.einsum("noij,nojk->noik", chain, d.reshape(n, 2, 2, -1)).reshape(d.shape)

    return Linearisation(
        jax.vmap(jax.vmap(robust))(pairs).reshape(n, 4), through(lin.d_cameras), through(lin.d_point), lin.prior
    )


def _to_params(args: BundleArgs, config: BundleConfig, n_params: int) -> jax.Array:
    """``T`` ``(cameras x L, params)``: the one-hot map from parameters to each camera's stage
    parameters (:func:`_cameras`; a linked letter takes its root's parameter)."""
    index = args.slot[:, jnp.asarray(letter_columns(config))]
    if config.centres:
        index = jnp.concatenate([index, args.centre_slot], axis=1)
    index = index.reshape(-1)
    return (index[:, None] == jnp.arange(n_params)).astype(args.centres.dtype)


def _unit_where_zero(diagonal: jax.Array) -> jax.Array:
    return jnp.where(diagonal > 0.0, diagonal, 1.0)


class Reduced(NamedTuple):
    """The normal equations with the points eliminated, and what back-substitution needs."""

    hessian: jax.Array  # (params, params): S = U - W V^-1 W^T
    gradient: jax.Array  # (params,): g_c - W V^-1 g_p
    scale: jax.Array  # (params,): diag(U), 1 where 0 (Marquardt's damping)
    coupling: jax.Array  # (n, 2 L + 1, 3): each point's W_k (its cameras' letters) and g_p,k (last row)
    point_inverse: jax.Array  # (n, 3, 3): each point's damped V_k^-1
    point_rank: jax.Array  # (n,): how many of the point's parameters have a derivative
    to_params: jax.Array  # T (cameras x letters, params)
    point_scores: jax.Array  # (n, 2 L): each point's share of the reduced gradient, its cameras' letters


def reduce(lin: Linearisation, damping, args: BundleArgs, config: BundleConfig, n_params: int) -> Reduced:
    """:class:`Reduced` of the damped normal equations (Marquardt's damping ``damping``; 0: none).

    A point parameter without any derivative (the depth, when every centre is at the origin) gets
    a 1 on its diagonal, which changes nothing else: its row and column of ``V_k`` and ``W_k`` are 0.
    The priors add their squared weights to the diagonal and their share to the gradient."""
    n_images = args.base.hfov.shape[0]
    block = jnp.concatenate([lin.d_cameras, lin.rows[..., None]], axis=-1)  # (n, 4, 2 L + 1)
    products = jnp.einsum("nri,nrj->nij", block, block)
    coupling = jnp.einsum("nri,nrj->nij", block, lin.d_point)
    v = jnp.einsum("nri,nrj->nij", lin.d_point, lin.d_point)
    diagonal = jnp.diagonal(v, axis1=1, axis2=2)
    v = v + jax.vmap(jnp.diag)(damping * _unit_where_zero(diagonal) + (diagonal <= 0.0))
    point_inverse = jnp.linalg.inv(v)
    reduced = products - jnp.einsum("nij,njk,nlk->nil", coupling, point_inverse, coupling)
    to_params = _to_params(args, config, n_params)
    hessian, gradient = sum_by_pair(reduced, args.points, n_images)
    full, _ = sum_by_pair(products, args.points, n_images)
    prior_hessian = args.prior_weight**2
    return Reduced(
        to_params.T @ hessian @ to_params + jnp.diag(prior_hessian),
        to_params.T @ gradient + args.prior_weight * lin.prior,
        _unit_where_zero(jnp.diagonal(to_params.T @ full @ to_params) + prior_hessian),
        coupling,
        point_inverse,
        jnp.sum(diagonal > 0.0, axis=1),
        to_params,
        reduced[:, :-1, -1],
    )


def schur_step(lin: Linearisation, damping, args: BundleArgs, config: BundleConfig, n_params: int, inverse_depths=None):
    """The damped Gauss-Newton step ``(dc, dp)`` with the points eliminated (module docstring),
    and the cost ``0.5 |r + J d|^2`` the linear model predicts after it (the priors' included).

    With the points' current ``inverse_depths`` the step keeps them >= 0: a point at infinity
    (``q = 0``) whose step would take it beyond stays there, and the step is solved again with its
    depth held (the model's minimum on that bound, not a cut step the model cannot predict, which
    made the trust region crawl); a step that would take a nearer point below 0 stops it at 0."""
    d_cameras, d_points, d_pair = _solve_reduced(lin, damping, args, config, n_params)
    if inverse_depths is not None:
        held = (inverse_depths <= 0.0) & (d_points[:, 2] < 0.0)
        lin = lin._replace(d_point=lin.d_point.at[:, :, 2].multiply(jnp.where(held, 0.0, 1.0)[:, None]))
        d_cameras, d_points, d_pair = _solve_reduced(lin, damping, args, config, n_params)
        d_points = d_points.at[:, 2].set(jnp.maximum(d_points[:, 2], -inverse_depths))
    linear = (
        lin.rows + jnp.einsum("nri,ni->nr", lin.d_cameras, d_pair) + jnp.einsum("nri,ni->nr", lin.d_point, d_points)
    )
    prior = lin.prior + args.prior_weight * d_cameras
    return d_cameras, d_points, 0.5 * (jnp.sum(linear**2) + jnp.sum(prior**2))


def _solve_reduced(lin: Linearisation, damping, args: BundleArgs, config: BundleConfig, n_params: int):
    """The damped step: the cameras' from the reduced equations, each point's by back-substitution;
    and each point's cameras' step ``(n, 2 L)``."""
    n_images = args.base.hfov.shape[0]
    r = reduce(lin, damping, args, config, n_params)
    d_cameras = jnp.linalg.solve(r.hessian + damping * jnp.diag(r.scale), -r.gradient)
    d_letters = (r.to_params @ d_cameras).reshape(n_images, _width(config))
    d_pair = jnp.concatenate([d_letters[args.points.image_a], d_letters[args.points.image_b]], axis=-1)
    with_one = jnp.concatenate([d_pair, jnp.ones_like(d_pair[:, :1])], -1)
    return d_cameras, -jnp.einsum("nij,nkj,nk->ni", r.point_inverse, r.coupling, with_one), d_pair


def covariance(lin: Linearisation, args: BundleArgs, config: BundleConfig, n_params: int):
    """The covariance ``(params, params)`` of a stage's camera parameters at the linearisation
    ``lin`` of its optimum (the points eliminated; the anchor held where the centres do not fix the
    orientation) and ``sigma``,
    the residuals' scale (px per coordinate): ``sigma^2 = |r|^2 / (observations - unknowns)``, the
    unknowns counting each point's parameters that have a derivative. Padded parameters get 0.

    The textbook covariance ``sigma^2 S^-1`` assumes every observation's error its own. Tracks of
    neighbouring windows share theirs, and then it is too small by about the square root of how many
    share one. So the errors' covariance is estimated from the residuals, cluster by cluster
    (``args.cluster``): ``S^-1 (sum_c g_c g_c^T) S^-1`` with ``g_c`` the cluster's share of the
    reduced gradient (the cluster-robust "sandwich" of Liang and Zeger, 1986, with the small-sample
    factor ``C / (C - 1)`` of ``C`` clusters). With every point its own cluster and errors of one
    scale it estimates the textbook one. A prior is one more draw, of known variance: its weight
    squared, in the middle as in ``S``.

    Residuals show only the part of an error that the cameras cannot follow. Tracks of one region
    can be off together, across their epipolar lines (a period of a facade, an edge's direction),
    and where few points fix a direction (the yaw of a seam whose epipolar lines run along it)
    the fit turns the cameras to absorb it: the residuals then look clean and the estimate is off.
    ``args.cluster_error`` adds such an offset of known size: each cluster's second ends moved
    together by a draw of that standard deviation per coordinate, propagated through the
    Jacobian with the points eliminated (``A_k - B_k V_k^-1 B_k^T A_k`` for a point's camera
    rows ``A_k`` and its own ``B_k``), ``sigma_c^2 S^-1 (sum_c M_c M_c^T) S^-1`` with ``M_c`` the
    cluster's sum of their second ends' rows. Where the residuals do show the offsets as well,
    both count them: the deviations err large."""
    r = reduce(lin, 0.0, args, config, n_params)
    used = args.weight > 0
    estimated = jnp.diagonal(r.hessian) > 0.0
    unknowns = jnp.sum(jnp.where(used, r.point_rank, 0)) + jnp.sum(estimated)
    sigma2 = jnp.sum(lin.rows**2) / jnp.maximum(4 * jnp.sum(used) - unknowns, 1)
    inverse = jnp.linalg.inv(r.hessian + jnp.diag(~estimated))
    n_images, width = args.base.hfov.shape[0], _width(config)
    letters = r.to_params.reshape(n_images, width, n_params)
    p = args.points
    scores = jnp.einsum("nl,nlp->np", r.point_scores[:, :width], letters[p.image_a]) + jnp.einsum(
        "nl,nlp->np", r.point_scores[:, width:], letters[p.image_b]
    )
    clusters = jnp.zeros_like(scores).at[args.cluster].add(scores * used[:, None])
    count = jnp.sum(jnp.zeros(used.shape).at[args.cluster].max(used.astype(scores.dtype)))
    meat = clusters.T @ clusters * (count / jnp.maximum(count - 1.0, 1.0)) + jnp.diag(args.prior_weight**2)
    # The shared offsets of the second ends (image b's rows): each point's camera rows with its own
    # directions projected out, in the parameters, summed by cluster.
    cameras_b = lin.d_cameras[:, 2:] - jnp.einsum(
        "nrj,njk,nik->nri", lin.d_point[:, 2:], r.point_inverse, r.coupling[:, :-1]
    )
    shared = (
        jnp.einsum("nrl,nlp->npr", cameras_b[..., :width], letters[p.image_a])
        + jnp.einsum("nrl,nlp->npr", cameras_b[..., width:], letters[p.image_b])
    ) * used[:, None, None]
    shared = jnp.zeros_like(shared).at[args.cluster].add(shared)
    meat = meat + args.cluster_error**2 * jnp.einsum("cpr,cqr->pq", shared, shared)
    sandwich = inverse @ meat @ inverse
    mask = estimated[:, None] & estimated[None, :]
    return jnp.where(mask, sandwich, 0.0), jnp.sqrt(sigma2)


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
    sigma)``: the residuals without the robust loss, the covariance and residual scale where it
    ends (:func:`covariance`).
    """
    n_params = params0.shape[0]
    raw0 = raw_residuals(params0, point_params0, args, config)
    if config.robust is not None:
        median = median_point_error(raw0, args.points, args.weight)
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
    cov, sigma = covariance(end.lin, args, config, n_params)
    return end.params, end.point_params, end.status, end.steps, raw0, cov, sigma


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

    theta, own = _cameras(params, args, config)
    p = args.points
    columns = jnp.asarray(letter_columns(config))

    def linear(sa, sb, ta, tb, point, data):  # a point's residuals and their derivatives along it alone
        f = partial(
            _point_rows, sa, sb, theta_a=ta, theta_b=tb, data=data, columns=columns, projection=config.projection
        )
        return f(point), jax.jacfwd(f)(point)

    def step(_, current):
        points, damping = current
        rows, d_point = jax.vmap(linear)(
            own[p.image_a], own[p.image_b], theta[p.image_a], theta[p.image_b], points, _point_data(args)
        )
        v = jnp.einsum("nri,nrj->nij", d_point, d_point)
        diagonal = jnp.diagonal(v, axis1=1, axis2=2)
        v = v + jax.vmap(jnp.diag)(damping[:, None] * _unit_where_zero(diagonal) + (diagonal <= 0.0))
        d = -jnp.linalg.solve(v, jnp.einsum("nri,nr->ni", d_point, rows)[..., None])[..., 0]
        d = d.at[:, 2].set(jnp.maximum(d[:, 2], -points[:, 2]))
        trial = points + d
        better = jnp.sum(raw_residuals(params, trial, args, config) ** 2, axis=1) < jnp.sum(rows**2, axis=1)
        keep = better & which
        return jnp.where(keep[:, None], trial, points), jnp.where(better, damping / 3.0, damping * 4.0)

    damping = jnp.full(point_params.shape[0], _INITIAL_DAMPING, point_params.dtype)
    return jax.lax.fori_loop(0, _POINT_FIT_STEPS, step, (point_params, damping))[0]


solve = jax.jit(solve_stage, static_argnames=("config",))


# ---------------------------------------------------------------------------------------------
# The Python-time part: a project's stages, its points' start values, the report.


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
    control points; zeros for points not in use), and a report per stage."""

    project: Project
    centres: np.ndarray  # (n_images, 3)
    directions: np.ndarray  # (n_points, 3) unit, from the rig's origin
    inverse_depths: np.ndarray  # (n_points,) 1 / distance from the origin; 0 at infinity
    residuals: np.ndarray
    rms: float
    stages: tuple[BundleStageReport, ...]
    # The last stage's standard deviations (standard_deviations): (n_images, 9) letters VABCDEYPR,
    # NaN where not estimated; each camera's orientation (degrees, the RMS of its turn); the
    # residuals' scale they assume (px per coordinate).
    standard_deviations: np.ndarray
    orientation_sd_deg: np.ndarray
    sigma: float
    centre_sd: np.ndarray  # (n_images, 3): each estimated centre coordinate's, in the centres' unit; NaN: held
    # (n_images, 3, 3): the covariance of each camera's turn (degrees squared, world axes, the rig's
    # own turn removed; NaN without yaw, pitch and roll): an error vector's Mahalanobis distance
    turn_covariance: np.ndarray
    not_optimised: tuple[str, ...] = ()  # with pto_vars: v-line variables left out, with the reason

    @property
    def ok(self) -> bool:
        """The last stage converged (earlier stages only start it)."""
        return self.stages[-1].status == "converged"

    @property
    def points(self) -> np.ndarray:
        """``(n_points, 3)`` scene points in the centres' units (``inf`` where at infinity)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.inverse_depths[:, None] > 0.0, self.directions / self.inverse_depths[:, None], np.inf)


def centres_fix_orientation(centres: np.ndarray) -> bool:
    """Whether the centres ``(n, 3)`` (world frame, about the origin) tell the rig's orientation:
    only rotations about a line through the origin that holds every centre leave them all in
    place, so centres that span a plane with the origin fix it, and the images' parallax measures
    it. Centres all on one line through the origin (every one at the origin, too) leave a turn about
    that line free: the anchor's yaw, pitch and roll are held instead."""
    singular = np.linalg.svd(np.asarray(centres, float), compute_uv=False)
    return bool(singular[0] > 0.0 and singular[1] > 1e-6 * singular[0])


def turn_jacobians(cameras: Camera) -> np.ndarray:
    """``(n, 3, 3)``: how each camera's world-frame turn ``omega`` (radians; ``R -> exp([omega]x) R``)
    moves with its yaw, pitch and roll (degrees), at the cameras' orientations."""

    def turn(ypr, base):
        m = world_from_cam(*(ypr + base)) @ world_from_cam(*base).T
        return 0.5 * jnp.stack([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]])

    base = jnp.stack([jnp.asarray(cameras.yaw), jnp.asarray(cameras.pitch), jnp.asarray(cameras.roll)], axis=-1)
    return np.asarray(jax.vmap(jax.jacfwd(turn))(jnp.zeros_like(base), base))


def standard_deviations(cov: np.ndarray, slot: np.ndarray, letters: str, cameras: Camera):
    """Per camera and letter ``(n_images, 9)`` (VABCDEYPR; NaN where not estimated), per camera
    its orientation's ``(n_images,)`` (degrees: the RMS of the angle it may be turned by), and the
    covariance of each camera's turn ``(n_images, 3, 3)`` (degrees squared, world axes; its trace
    the orientation's variance), from the covariance ``cov`` of a stage's parameters
    (:func:`covariance`).

    Images cannot tell the whole rig's orientation (the anchor's is held), or tell it only weakly,
    through the parallax of the centres; so the orientations are reported with that rotation
    removed: each camera's turn ``omega_i`` minus the mean turn of all cameras (the rotation that
    aligns the rig with another of the same shape, to first order). The anchor gets its own
    deviation like the others.
    """
    n_images = slot.shape[0]
    columns = [LETTERS.index(letter) for letter in letters]
    to_params = (slot[:, columns].reshape(-1)[:, None] == np.arange(cov.shape[0])).astype(float)
    estimated = (slot[:, columns] >= 0).reshape(-1)
    c = to_params @ cov @ to_params.T  # (cameras x letters) squared
    width = len(columns)
    turns = all(letter in letters for letter in "YPR")
    orientation = np.full(n_images, np.nan)
    turn_cov = np.full((n_images, 3, 3), np.nan)
    if turns:
        ypr = [letters.index(letter) for letter in "YPR"]
        jac = turn_jacobians(cameras)
        inverse = np.linalg.inv(jac)
        a = np.eye(n_images * width)
        for i in range(n_images):
            for j in range(n_images):
                rows, cols = i * width + np.array(ypr), j * width + np.array(ypr)
                a[np.ix_(rows, cols)] = inverse[i] @ jac[j] * ((i == j) - 1.0 / n_images)
        c = a @ c @ a.T
        for i in range(n_images):
            rows = i * width + np.array(ypr)
            turn_cov[i] = np.degrees(1.0) ** 2 * jac[i] @ c[np.ix_(rows, rows)] @ jac[i].T
            orientation[i] = np.sqrt(max(np.trace(turn_cov[i]), 0.0))  # round-off of a weakly known rig turn
            estimated[rows] = True
    deviations = np.full((n_images, len(LETTERS)), np.nan)
    deviations[:, columns] = np.where(estimated, np.sqrt(np.maximum(np.diag(c), 0.0)), np.nan).reshape(n_images, width)
    return deviations, orientation, turn_cov


def tangent_frames(directions: np.ndarray) -> np.ndarray:
    """``(n, 3, 3)``: each unit direction and two unit tangents, orthogonal to it and each other."""
    helper = np.where(np.abs(directions[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    e1 = np.cross(directions, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(directions, e1)
    return np.stack([directions, e1, e2], axis=1)


def triangulate(ray_a: np.ndarray, ray_b: np.ndarray, centre_a: np.ndarray, centre_b: np.ndarray):
    """Start values ``(directions, inverse depths)`` of points seen along unit world rays ``ray_a``
    from ``centre_a`` and ``ray_b`` from ``centre_b`` (each ``(n, 3)``): the midpoint of the rays'
    closest approach where both reach it ahead of their cameras, else at infinity along the mean
    ray (parallel rays, rays that meet behind a camera, or every centre at the origin)."""
    baseline = centre_b - centre_a
    cos = np.sum(ray_a * ray_b, axis=1)
    along_a, along_b = np.sum(ray_a * baseline, axis=1), np.sum(ray_b * baseline, axis=1)
    parallel = 1.0 - cos**2
    safe = np.where(parallel > 1e-12, parallel, 1.0)
    s, t = (along_a - cos * along_b) / safe, (cos * along_a - along_b) / safe
    point = 0.5 * (centre_a + s[:, None] * ray_a + centre_b + t[:, None] * ray_b)
    distance = np.linalg.norm(point, axis=1)
    near = (parallel > 1e-12) & (s > 0.0) & (t > 0.0) & (distance > 0.0)
    mean = ray_a + ray_b
    directions = np.where(
        near[:, None],
        point / np.where(near, distance, 1.0)[:, None],
        mean / np.linalg.norm(mean, axis=1, keepdims=True),
    )
    return directions, np.where(near, 1.0 / np.where(near, distance, 1.0), 0.0)


def world_rays(cameras: Camera, points: PointArrays) -> tuple[np.ndarray, np.ndarray]:
    """Each control point's two observed rays in the world frame, through ``cameras``."""
    rays = [
        np.asarray(img_to_ray(cameras.take(index), xy)[0])
        for index, xy in ((points.image_a, points.xy_a), (points.image_b, points.xy_b))
    ]
    return rays[0], rays[1]


def clusters(points: PointArrays, cell_px: float) -> np.ndarray:
    """``(n,)`` int32: one number for the points of one pair of images whose first ends fall in one
    square cell of ``cell_px`` pixels (``0``: every point its own)."""
    n = len(points.image_a)
    if cell_px <= 0.0:
        return np.arange(n, dtype=np.int32)
    cells = np.floor(np.asarray(points.xy_a, float) / cell_px).astype(np.int64)
    keys = np.column_stack([np.asarray(points.image_a), np.asarray(points.image_b), cells])
    return np.unique(keys, axis=0, return_inverse=True)[1].reshape(-1).astype(np.int32)


_PRIOR_LETTERS = LENS_LETTERS + "YPRX"


def check_priors(priors) -> dict[str, float]:
    """``priors`` (a mapping of lens letters, ``y``, ``p``, ``r``, or ``x`` for the centres, to
    standard deviations, or None) with upper-case letters; an error names a letter that cannot
    have a prior or a deviation that is not > 0."""
    checked = {}
    for letter, sd in (priors or {}).items():
        if str(letter).upper() not in _PRIOR_LETTERS:
            raise RigjaxError(f"priors: {letter!r} cannot have a prior (one of {', '.join(_PRIOR_LETTERS.lower())})")
        if not (isinstance(sd, (int, float)) and sd > 0.0 and np.isfinite(sd)):
            raise RigjaxError(f"priors: {letter} must be a positive standard deviation, got {sd!r}")
        checked[str(letter).upper()] = float(sd)
    return checked


def prior_arrays(
    slot: np.ndarray, centre_slot: np.ndarray, nominal: Camera, nominal_centres, priors: dict[str, float], n_params: int
):
    """``(mean, weight)`` ``(n_params,)`` of the priors (:func:`check_priors`'s letters): each
    estimated parameter of a letter with a prior at its cameras' mean ``nominal`` value (a centre
    coordinate at ``nominal_centres``'), with weight ``1 / sd`` in the parameter's units (``0``:
    no prior)."""
    values = np.concatenate([theta_of(jax.tree_util.tree_map(np.asarray, nominal), np), nominal_centres], axis=1)
    slots = np.concatenate([slot, centre_slot], axis=1)
    units = {**UNIT, "X": 1.0}
    total, count, weight = np.zeros(n_params), np.zeros(n_params), np.zeros(n_params)
    for letter, sd in priors.items():
        centre = range(len(LETTERS), len(LETTERS) + 3)  # the columns after the letters'
        for k in centre if letter == "X" else [LETTERS.index(letter)]:
            for i in np.flatnonzero(slots[:, k] >= 0):
                p = slots[i, k]
                total[p] += values[i, k]
                count[p] += 1
                weight[p] = units[letter] / sd
    return np.where(count > 0, total / np.maximum(count, 1), 0.0), weight


def centre_matrix(layout: Layout) -> np.ndarray:
    """``(n_images, 3)`` int32: the parameter index of each camera's centre coordinates, or -1."""
    return np.stack([layout.slot[key] for key in CENTRE_KEYS], axis=-1)


def start_params(layout: Layout, cameras: Camera, centres) -> np.ndarray:
    """A stage's parameters where it starts (padded as :func:`rigjax.optimiser.problem.initial_params`):
    the cameras' letters and, with ``X``, their ``centres``."""
    params = initial_params(layout, cameras)
    slot = centre_matrix(layout)
    params[slot[slot >= 0]] = np.asarray(centres, float)[slot >= 0]
    return params


def stage_args(
    cameras: Camera,
    centres,
    layout: Layout,
    points: PointArrays,
    weight,
    rays: tuple[np.ndarray, np.ndarray],
    directions,
    solver: SolverOptions,
    preliminary: bool,
    robust_scale: float = 2.0,
    median_scale_floor: float | None = None,
    cluster_px: float = 0.0,
    priors: dict[str, float] | None = None,
    nominal: Camera | None = None,
    nominal_centres=None,
    cluster_error_px: float = 0.0,
) -> BundleArgs:
    """A stage's data for :func:`solve`: its layout, the cameras' ``centres`` where it starts, the
    points' start ``directions`` (their frames), each observation's ray (``rays``:
    :func:`world_rays` through ``cameras``) in its camera's frame, the stopping rules
    (``preliminary``: a later stage optimises the same parameters again), the robust loss's scale,
    the points' clusters (:func:`clusters`) and the offset they may share (``cluster_error_px``,
    :func:`covariance`), and the priors (:func:`check_priors`' letters; their
    means ``nominal``'s values and ``nominal_centres``, else ``cameras``' and ``centres``)."""
    rays_a, rays_b = rays
    rotation = np.asarray(world_from_cam(cameras.yaw, cameras.pitch, cameras.roll))
    observed = np.stack(
        [
            np.einsum("nji,nj->ni", rotation[points.image_a], rays_a),
            np.einsum("nji,nj->ni", rotation[points.image_b], rays_b),
        ],
        axis=1,
    )
    ftol = max(solver.ftol, solver.preliminary_ftol) if preliminary else solver.ftol
    slot, centre_slot = slot_matrix(layout), centre_matrix(layout)
    centres = np.asarray(centres, float)
    prior_mean, prior_weight = prior_arrays(
        slot,
        centre_slot,
        cameras if nominal is None else nominal,
        centres if nominal_centres is None else np.asarray(nominal_centres, float),
        priors or {},
        parameter_count(layout),
    )
    return BundleArgs(
        cameras,
        slot,
        centres,
        centre_slot,
        points,
        weight,
        tangent_frames(directions),
        observed,
        clusters(points, cluster_px),
        np.asarray(cluster_error_px, float),
        prior_mean,
        prior_weight,
        np.asarray(robust_scale, float),
        np.asarray(-1.0 if median_scale_floor is None else median_scale_floor, float),
        np.asarray(solver.max_steps, np.int32),
        np.asarray(solver.xtol),
        np.asarray(ftol),
    )


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
) -> BundleResult:
    """Adjust a project's cameras and its control points' scene points together, minimising the
    reprojection error (module docstring), stage by stage.

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
            fixed where the centres do not fix the rig's orientation (:func:`centres_fix_orientation`).
        solver: stopping rules (its ``backend`` is not used: the solve is this module's own).
        weights: ``(n_control_points,)`` 0/1 mask of the points to use (all by default).
        robust: ``None``, ``"huber"`` or ``"cauchy"`` on each observation's 2-D residual, with
            ``robust_scale`` px; ``median_scale_floor``: each stage's scale is instead the median
            point error where it starts, at least this many px (pruning's first round).
        preliminary: a later solve starts from this one (pruning's first round): every stage stops
            at ``solver.preliminary_ftol``, as a stage that a later one optimises again does.
        cluster_px: the standard deviations count the points of one pair whose first ends lie in
            one cell of this many pixels as one draw (:func:`covariance`): neighbouring tracks share
            their errors. 0: every point its own.
        cluster_error_px: the standard deviation (px, per coordinate) of an offset that the second
            ends of one cluster's points share and the fit can absorb, which the residuals then
            cannot show (:func:`covariance`; the template's ``features.track_bias_px`` for tracks);
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

    Points start where their two rays from the start cameras meet (:func:`triangulate`), or at
    infinity; each stage starts from where the previous one ended.
    """
    solver = solver or SolverOptions()
    if robust not in ROBUST_LOSSES:
        raise RigjaxError(f"robust must be one of {ROBUST_LOSSES}, got {robust!r}")
    check_project(project, anchor)
    priors = check_priors(priors)
    n_images, cps = len(project.images), project.control_points
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
    lines = np.flatnonzero(cps.kind != NORMAL)
    if lines.size:
        raise RigjaxError(
            f"the reprojection objective takes normal (t0) control points only; control point {lines[0]} is a "
            f"line point (t{int(cps.kind[lines[0]])}), and {lines.size} in all: remove them or use objective 'transfer'"
        )
    if not (np.isfinite(cluster_error_px) and cluster_error_px >= 0.0):
        raise RigjaxError(f"cluster_error_px must be a standard deviation in pixels (>= 0), got {cluster_error_px!r}")
    n_points = len(cps)
    weight = np.ones(n_points) if weights is None else np.asarray(weights, dtype=float)
    if weight.shape != (n_points,):
        raise RigjaxError(f"weights has shape {weight.shape}, expected ({n_points},)")
    points, padded_weight = padded_points(project, weight)
    stages, not_optimised = stage_layouts(project, schedule, anchor, pto_vars, not centres_fix_orientation(centres))
    if "X" not in priors and any(np.any(centre_matrix(layout) >= 0) for _, layout in stages):
        raise RigjaxError(
            f"schedule {schedule!r} estimates centres (X): give priors {{'x': sd}}, their standard deviation about "
            "the given centres, which fixes the rig's scale (images cannot tell it)"
        )
    nominal_centres = centres
    projections = {image.projection for image in project.images}
    projection = projections.pop() if len(projections) == 1 else None
    cameras = project.cameras(host=True)
    if nominal is None:
        nominal = cameras
    elif np.shape(nominal.hfov) != (n_images,):
        raise RigjaxError(f"nominal: {np.size(nominal.hfov)} cameras for a project of {n_images} images")
    rays = world_rays(cameras, points)
    directions, inverse_depths = triangulate(*rays, centres[points.image_a], centres[points.image_b])
    reports = []
    later = reoptimised([layout.names for _, layout in stages])
    for k, (name, layout) in enumerate(stages):
        if layout.size > 2 * int(np.sum(weight > 0)):
            raise RigjaxError(
                f"stage {name}: {layout.size} parameters but only {2 * int(np.sum(weight > 0))} observations"
            )
        if k:  # the observations' rays through the cameras this stage starts from
            rays = world_rays(cameras, points)
        args = stage_args(
            cameras,
            centres,
            layout,
            points,
            padded_weight,
            rays,
            directions,
            solver,
            preliminary or bool(later[k]),
            robust_scale,
            median_scale_floor,
            cluster_px,
            priors,
            nominal,
            nominal_centres,
            cluster_error_px,
        )
        config = stage_config(BundleConfig(projection, "", robust), args.slot)
        config = config._replace(centres=bool(np.any(args.centre_slot >= 0)))
        start = time.perf_counter()
        point_params = np.concatenate([np.zeros((len(directions), 2)), inverse_depths[:, None]], axis=1)
        params = start_params(layout, cameras, centres)
        params, point_params, status, steps, before, cov, sigma = solve(params, point_params, args, config=config)
        fit = bool(np.any(weight == 0))  # points left out (pruning): placed for the cameras
        point_params, after = final_residuals(params, point_params, args, config=config, fit=fit)
        theta = theta_from_params(params, args)
        cameras = jax.tree_util.tree_map(np.asarray, with_theta(args.base, theta))
        centres = np.asarray(camera_centres(params, args))
        directions = np.asarray(direction(args.frame, point_params))
        inverse_depths = np.asarray(point_params[:, 2])
        use = padded_weight > 0
        reports.append(
            BundleStageReport(
                name,
                layout.names,
                STATUS[int(status)],
                int(steps),
                float(rms(before, use, 2)),
                float(rms(after, use, 2)),
                time.perf_counter() - start,
            )
        )
    cov = np.asarray(cov)
    deviations, orientation, turn_cov = standard_deviations(cov, np.asarray(args.slot), config.letters, cameras)
    slot = args.centre_slot
    centre_sd = np.where(slot >= 0, np.sqrt(np.maximum(np.diagonal(cov)[np.maximum(slot, 0)], 0.0)), np.nan)
    return BundleResult(
        project.with_cameras(cameras).replace(centres=centres, deviations=deviations),
        centres,
        directions[:n_points],
        inverse_depths[:n_points],
        np.asarray(after)[:n_points],
        reports[-1].rms_final,
        tuple(reports),
        deviations,
        orientation,
        float(sigma),
        centre_sd,
        turn_cov,
        not_optimised,
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


def format_deviations(result: BundleResult) -> str:
    """The last stage's standard deviations per camera, as the CLI prints them."""
    sd = result.standard_deviations
    shown = [k for k, letter in enumerate(LETTERS) if np.isfinite(sd[:, k]).any()]
    lines = [
        f"standard deviations, degrees (residual scale {result.sigma:.3f} px; the rig's own orientation removed):",
        f"{'image':>5} {'turn':>8} " + " ".join(f"{LETTERS[k].lower():>8}" for k in shown),
    ]
    for i, row in enumerate(sd):
        cells = " ".join(f"{row[k]:>8.4f}" if np.isfinite(row[k]) else f"{'-':>8}" for k in shown)
        lines.append(f"{i:>5} {result.orientation_sd_deg[i]:>8.4f} {cells}")
    if np.isfinite(result.centre_sd).any():
        lines.append("centres and their standard deviations (x, y, z; the centres' unit; '-': held):")
        for i, (centre, sd) in enumerate(zip(result.centres, result.centre_sd)):
            cells = " ".join(
                f"{c:>9.4f} ±{d:<8.4f}" if np.isfinite(d) else f"{c:>9.4f} {'-':<9}" for c, d in zip(centre, sd)
            )
            lines.append(f"{i:>5} {cells}")
    return "\n".join(lines)
