"""The bundle adjustment's model: each point's reprojection residuals in the images that see it,
their derivatives along the cameras' and the point's parameters, and the normal equations with the
points eliminated (the Schur complement). The model and its parameters: :mod:`rigjax.optimiser.bundle`.

A point is seen in ``K`` slots (:class:`Views`): a control point in its two images (``K = 2``), a
track in every image it was followed through, an unused slot padded (``seen`` 0: no residual, no
derivative). The normal equations are summed by pair of slots (:func:`sum_by_slots`)."""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp

from ..camera.lenses import safe_hypot
from ..camera.model import Camera, optics, optics_ray_to_img
from ..camera.rotation import world_from_cam, ypr_from_world_from_cam
from .objective import (
    letter_columns,
    masked_median,
    sum_by_pair,
    theta_from_params,
    with_theta,
)
from .residuals import ray_angle, robust_scale, transfer_or_angle


class Views(NamedTuple):
    """Where each of ``n`` points is seen: ``K`` slots, an image and its pixel each."""

    image: jax.Array  # (n, K) int32: the slot's image (an unused slot repeats the first's)
    xy: jax.Array  # (n, K, 2) px (Hugin's image coordinates)
    seen: jax.Array  # (n, K): 1 where the slot holds an observation, 0 where it is padding

    @property
    def slots(self) -> int:
        return self.image.shape[1]


class BundleConfig(NamedTuple):
    """Static settings of a bundle adjustment's compiled solve, one for all its stages."""

    projection: int | None  # the rig's one lens type, or None
    letters: str  # the camera letters its stages optimise (derivatives along these only)
    robust: str | None = None  # robust loss of each observation's 2-D residual (residuals.robust_scale)
    centres: bool = False  # a stage estimates centres: each camera's letters, then its centre (x, y, z)
    rigid: bool = False  # some cameras' orientations are derived from others' (BundleArgs.rigid)


class BundleArgs(NamedTuple):
    """A stage's data (a change of values never recompiles)."""

    base: Camera  # (n_images,) the cameras where the stage starts
    slot: jax.Array  # (n_images, 9) int32: parameter index of each letter VABCDEYPR, or -1
    centres: jax.Array  # (n_images, 3) where the stage starts
    centre_slot: jax.Array  # (n_images, 3) int32: parameter index of each centre coordinate, or -1
    points: Views  # padded
    weight: jax.Array  # (n_padded,) 1 in use, 0 left out
    frame: jax.Array  # (n_padded, 3, 3): each point's direction where the stage starts and its tangents
    observed: jax.Array  # (n_padded, K, 3): each observation's ray in its camera's frame (stage start)
    # (n_padded,): 1 where the point's inverse depth is estimated, 0 where it is held at infinity
    # (q = 0 whatever its parameter: a match whose baseline is too short to tell its depth)
    finite: jax.Array
    # (n_images, 3) int32: a camera mounted on a rig whose frames turn, its orientation derived from
    # three others' as W_a W_b^T W_c (its row (a, b, c): its frame's first camera, the first frame's
    # first camera and the first frame's camera of its own mounting); -1: its own yaw, pitch and roll
    rigid: jax.Array
    # (n_padded,) int32: points whose errors may be shared (neighbouring tracks of one pair) carry one
    # number, and count as one draw in the covariance (covariance); every point its own: the textbook one
    cluster: jax.Array
    # px: the standard deviation of an offset that the later ends (every slot but the first) of each
    # cluster's points share and the residuals cannot show (covariance); 0: none
    cluster_error: jax.Array
    prior_mean: jax.Array  # (n_params,): each parameter's nominal value, where it has a prior
    prior_weight: jax.Array  # (n_params,): 1 / its standard deviation (parameter units); 0: no prior
    robust_scale: jax.Array  # px
    # >= 0: the robust scale is instead the median point error where the stage starts (the largest of
    # each point's reprojection errors), at least this many px (as SolveArgs.median_scale_floor)
    median_scale_floor: jax.Array
    max_steps: jax.Array
    xtol: jax.Array
    ftol: jax.Array


class Linearisation(NamedTuple):
    """The weighted residuals of every point and their derivatives at one point of the solve."""

    rows: jax.Array  # (n, 2 K): the residual in each slot's image, in turn
    d_cameras: jax.Array  # (n, 2 K, K L): along the solve's letters (and centre) of each slot's camera
    d_point: jax.Array  # (n, 2 K, 3): along the point's (u, v, q)
    prior: jax.Array  # (params,): the priors' residuals (p - m) / sd (0 without a prior); their
    # derivative is the diagonal BundleArgs.prior_weight
    # T (cameras x L, params): each camera's stage parameters' derivatives along the parameters
    # (:func:`camera_jacobian`)
    to_params: jax.Array


def _prior(params, args: BundleArgs) -> jax.Array:
    return args.prior_weight * (params - args.prior_mean)


def stage_width(config: BundleConfig) -> int:
    """``L``: the parameters of one camera in a stage, its letters and, with ``X``, its centre."""
    return len(config.letters) + 3 * config.centres


def camera_centres(params, args: BundleArgs) -> jax.Array:
    """``(n_images, 3)``: the estimated centres from ``params``, the others as the stage starts."""
    slot = args.centre_slot
    return jnp.where(slot >= 0, params[jnp.clip(slot, 0, params.shape[0] - 1)], args.centres)


_YPR = slice(6, 9)  # the columns of yaw, pitch and roll in a camera's letters VABCDEYPR


def rig_orientations(theta: jax.Array, rigid: jax.Array) -> jax.Array:
    """``theta`` ``(n_images, 9)`` with each derived camera's yaw, pitch and roll (``rigid``'s rows
    ``(a, b, c)``, :class:`BundleArgs`) those of ``W_a W_b^T W_c``: its frame's turn from the first
    frame (``W_a W_b^T``) applied to the first frame's camera of its mounting (``W_c``)."""
    world = world_from_cam(theta[:, 6], theta[:, 7], theta[:, 8])
    index = jnp.maximum(rigid, 0)
    derived = world[index[:, 0]] @ jnp.swapaxes(world[index[:, 1]], -1, -2) @ world[index[:, 2]]
    ypr = ypr_from_world_from_cam(derived)
    return theta.at[:, _YPR].set(jnp.where(rigid[:, :1] >= 0, ypr, theta[:, _YPR]))


def stage_cameras(params, args: BundleArgs, config: BundleConfig):
    """Every camera's 9 letters ``(n_images, 9)`` and its stage parameters ``(n_images, L)``: the
    stage's letters, then with ``X`` its centre; a derived camera's orientation from its rig
    (:func:`rig_orientations`)."""
    theta = theta_from_params(params, args)
    if config.rigid:
        theta = rig_orientations(theta, args.rigid)
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


def _slot_rows(sub, point, theta, fixed, centre, frame, xy, observed, finite, seen, columns, projection):
    """``(2,)``: a point's residual in one slot's image (0 where the slot is unused), from its
    camera's stage parameters ``sub`` ``(L,)`` (the letters ``columns``, then the centre where the
    stage estimates it; the rest of its letters from ``theta`` ``(9,)``) and ``point``."""
    n = columns.shape[0]
    if sub.shape[0] > n:  # the stage estimates centres
        centre = sub[n:]
    d, q = direction(frame, point), point[2] * finite
    return _observation(theta.at[columns].set(sub[:n]), fixed, centre, d, q, xy, observed, projection) * seen


def _by_slot(f, sub, point, theta, data, columns, projection):
    """``f(rows, sub_k, point)`` for each slot, mapped over the slots: ``rows(s, p)`` is that
    slot's :func:`_slot_rows` at its camera's stage parameters ``s`` and the point ``p``."""
    fixed, centres, frame, xy, observed, finite, seen = data

    def one(sub_k, theta_k, fixed_k, centre_k, xy_k, observed_k, seen_k):
        def rows(s, p):
            return _slot_rows(
                s, p, theta_k, fixed_k, centre_k, frame, xy_k, observed_k, finite, seen_k, columns, projection
            )

        return f(rows, sub_k, point)

    return jax.vmap(one)(sub, theta, fixed, centres, xy, observed, seen)


def point_rows(sub, point, theta, data, columns, projection):
    """``(2 K,)``: a point's residuals in each slot's image, from its cameras' stage parameters
    ``sub`` ``(K, L)`` (:func:`stage_cameras`) and ``point``; 0 in an unused slot."""
    return _by_slot(lambda rows, s, p: rows(s, p), sub, point, theta, data, columns, projection).reshape(-1)


def point_derivatives(sub, point, theta, data, columns, projection):
    """A point's :func:`point_rows` ``(2 K,)`` and their derivatives along its cameras' stage
    parameters ``(2 K, K L)`` (each slot's rows along its own camera's alone: the rest is 0) and
    along the point's own three ``(2 K, 3)``."""

    def slot(rows, s, p):
        d_sub, d_point = jax.jacfwd(rows, argnums=(0, 1))(s, p)
        return rows(s, p), d_sub, d_point

    rows, d_sub, d_point = _by_slot(slot, sub, point, theta, data, columns, projection)  # (K, 2, ...)
    slots, width = sub.shape
    d_cameras = jnp.einsum("krl,kj->krjl", d_sub, jnp.eye(slots, dtype=d_sub.dtype)).reshape(2 * slots, slots * width)
    return rows.reshape(-1), d_cameras, d_point.reshape(2 * slots, 3)


def point_data(args: BundleArgs):
    v = args.points
    return (
        args.base.take(v.image),
        args.centres[v.image],  # replaced by the stage's own where it estimates centres
        args.frame,
        v.xy,
        args.observed,
        args.finite,
        v.seen,
    )


def residuals(params, point_params, args: BundleArgs, config: BundleConfig) -> jax.Array:
    """``(n, 2 K)`` weighted residuals (px) at camera parameters ``params`` and points
    ``point_params``, each observation's through the robust loss (what the solve minimises)."""
    rows = raw_residuals(params, point_params, args, config)
    if config.robust is None:
        return rows
    robust = jax.vmap(jax.vmap(partial(_robust, args=args, config=config)))
    return robust(rows.reshape(rows.shape[0], -1, 2)).reshape(rows.shape)


def _robust(pair, args: BundleArgs, config: BundleConfig):
    """One observation's 2-D residual through the robust loss."""
    return pair * robust_scale(safe_hypot(pair[0], pair[1])[0], config.robust, args.robust_scale)


def raw_residuals(params, point_params, args: BundleArgs, config: BundleConfig) -> jax.Array:
    """``(n, 2 K)`` weighted residuals (px), without the robust loss: each slot's image's in turn."""
    theta, own = stage_cameras(params, args, config)
    image = args.points.image
    columns = jnp.asarray(letter_columns(config))
    rows = jax.vmap(partial(point_rows, columns=columns, projection=config.projection))(
        own[image], point_params, theta[image], point_data(args)
    )
    return rows * args.weight[:, None]


def view_errors(rows: jax.Array) -> jax.Array:
    """``(n,)`` px: each point's largest reprojection error over its slots (``rows`` ``(n, 2 K)``)."""
    pairs = rows.reshape(rows.shape[0], -1, 2)
    return jnp.max(jnp.hypot(pairs[..., 0], pairs[..., 1]), axis=1)


def median_view_error(rows: jax.Array, weight: jax.Array) -> jax.Array:
    """The median :func:`view_errors` over the points in use (0 without any)."""
    return masked_median(view_errors(rows), weight > 0)


def camera_jacobian(params, args: BundleArgs, config: BundleConfig) -> jax.Array:
    """``T`` ``(cameras x L, params)``: the derivatives of each camera's stage parameters
    (:func:`stage_cameras`) along the parameters. Where every camera's letters are parameters of its
    own or linked ones it is the one-hot map from parameters to letters (a linked letter takes its
    root's parameter); with derived cameras (``config.rigid``) a derived camera's orientation follows
    the three it is derived from, through their product's derivatives."""
    if config.rigid:
        return jax.jacfwd(lambda p: stage_cameras(p, args, config)[1])(params).reshape(-1, params.shape[0])
    index = args.slot[:, jnp.asarray(letter_columns(config))]
    if config.centres:
        index = jnp.concatenate([index, args.centre_slot], axis=1)
    return (index.reshape(-1)[:, None] == jnp.arange(params.shape[0])).astype(params.dtype)


def linearise(params, point_params, args: BundleArgs, config: BundleConfig) -> Linearisation:
    """The residuals and their derivatives along the stage's parameters of each point's cameras
    and along the point's own three parameters, and the cameras' stage parameters' derivatives
    along the parameters (:func:`camera_jacobian`)."""
    theta, own = stage_cameras(params, args, config)
    image = args.points.image
    columns = jnp.asarray(letter_columns(config))

    derivatives = partial(point_derivatives, columns=columns, projection=config.projection)
    rows, d_cameras, d_point = jax.vmap(derivatives)(own[image], point_params, theta[image], point_data(args))
    w = args.weight
    lin = Linearisation(
        rows * w[:, None],
        d_cameras * w[:, None, None],
        d_point * w[:, None, None],
        _prior(params, args),
        camera_jacobian(params, args, config),
    )
    if config.robust is None:
        return lin
    # Each observation's residual through the robust loss, its derivatives through the loss's own
    # 2 x 2 derivative.
    n = rows.shape[0]
    pairs = lin.rows.reshape(n, -1, 2)
    robust = partial(_robust, args=args, config=config)
    chain = jax.vmap(jax.vmap(jax.jacfwd(robust)))(pairs)  # (n, K, 2, 2)

    def through(d):
        return jnp.einsum("noij,nojk->noik", chain, d.reshape(n, pairs.shape[1], 2, -1)).reshape(d.shape)

    return lin._replace(
        rows=jax.vmap(jax.vmap(robust))(pairs).reshape(rows.shape),
        d_cameras=through(lin.d_cameras),
        d_point=through(lin.d_point),
    )


def unit_where_zero(diagonal: jax.Array) -> jax.Array:
    return jnp.where(diagonal > 0.0, diagonal, 1.0)


class Reduced(NamedTuple):
    """The normal equations with the points eliminated, and what back-substitution needs."""

    hessian: jax.Array  # (params, params): S = U - W V^-1 W^T
    gradient: jax.Array  # (params,): g_c - W V^-1 g_p
    scale: jax.Array  # (params,): diag(U), 1 where 0 (Marquardt's damping)
    coupling: jax.Array  # (n, K L + 1, 3): each point's W_k (its cameras' letters) and g_p,k (last row)
    point_inverse: jax.Array  # (n, 3, 3): each point's damped V_k^-1
    point_rank: jax.Array  # (n,): how many of the point's parameters have a derivative
    to_params: jax.Array  # T (cameras x L, params): Linearisation.to_params
    point_scores: jax.Array  # (n, K L): each point's share of the reduced gradient, its cameras' letters


def reduce(lin: Linearisation, damping, args: BundleArgs, config: BundleConfig) -> Reduced:
    """:class:`Reduced` of the damped normal equations (Marquardt's damping ``damping``; 0: none).

    A point parameter without any derivative (the depth, when every centre is at the origin or the
    point is held at infinity) gets
    a 1 on its diagonal, which changes nothing else: its row and column of ``V_k`` and ``W_k`` are 0.
    The priors add their squared weights to the diagonal and their share to the gradient."""
    n_images = args.base.hfov.shape[0]
    block = jnp.concatenate([lin.d_cameras, lin.rows[..., None]], axis=-1)  # (n, 2 K, K L + 1)
    products = jnp.einsum("nri,nrj->nij", block, block)
    coupling = jnp.einsum("nri,nrj->nij", block, lin.d_point)
    v = jnp.einsum("nri,nrj->nij", lin.d_point, lin.d_point)
    diagonal = jnp.diagonal(v, axis1=1, axis2=2)
    v = v + jax.vmap(jnp.diag)(damping * unit_where_zero(diagonal) + (diagonal <= 0.0))
    point_inverse = jnp.linalg.inv(v)
    reduced = products - jnp.einsum("nij,njk,nlk->nil", coupling, point_inverse, coupling)
    to_params = lin.to_params
    hessian, gradient = sum_by_slots(reduced, args.points.image, n_images)
    full, _ = sum_by_slots(products, args.points.image, n_images)
    prior_hessian = args.prior_weight**2
    return Reduced(
        to_params.T @ hessian @ to_params + jnp.diag(prior_hessian),
        to_params.T @ gradient + args.prior_weight * lin.prior,
        unit_where_zero(jnp.diagonal(to_params.T @ full @ to_params) + prior_hessian),
        coupling,
        point_inverse,
        jnp.sum(diagonal > 0.0, axis=1),
        to_params,
        reduced[:, :-1, -1],
    )


def sum_by_slots(products: jax.Array, image: jax.Array, n_images: int):
    """Each point's products ``(n, K L + 1, K L + 1)`` over ``[letters of slot 0's camera, ...,
    letters of slot K - 1's, residual]`` summed into the rig's ``(cameras x L, cameras x L)`` matrix
    and ``(cameras x L,)`` vector (the last row's first ``K L`` entries), by pair of slots: slots
    ``j`` and ``k``'s block goes to their cameras' ``(image_j, image_k)``."""
    slots = image.shape[1]
    if slots == 2:  # one segment sum by pair of cameras, the blocks taken apart after it
        return sum_by_pair(products, image[:, 0], image[:, 1], n_images)
    width = (products.shape[-1] - 1) // slots
    hessian = jnp.zeros((n_images * n_images, width, width), products.dtype)
    gradient = jnp.zeros((n_images, width), products.dtype)
    for j in range(slots):
        rows = slice(j * width, (j + 1) * width)
        gradient = gradient + jax.ops.segment_sum(products[:, -1, rows], image[:, j], n_images)
        for k in range(slots):
            key = image[:, j] * n_images + image[:, k]
            block = products[:, rows, k * width : (k + 1) * width]
            hessian = hessian + jax.ops.segment_sum(block, key, n_images * n_images)
    size = n_images * width
    hessian = jnp.swapaxes(hessian.reshape(n_images, n_images, width, width), 1, 2)
    return hessian.reshape(size, size), gradient.reshape(size)
