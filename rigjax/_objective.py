"""The rig objective: a stage's parameter vector -> cameras -> control-point residuals.

A rig's cameras are a ``(n_images, 9)`` array ``theta`` of the letters V A B C D E Y P R in
internal units (see :data:`rigjax._schedule.UNIT`); a stage's parameters fill the entries whose
``slot`` is >= 0. The parameter vector is padded to a multiple of 16 (rigjax._optimise), so that
stages of similar sizes share a compilation; unused entries have zero Jacobian columns.

Each control point depends on two cameras only, so its Jacobian is a 4 x (2 x L) block computed
once per evaluation (a custom JVP, :mod:`rigjax._point_jacobian`), spread over the letters of all
cameras as a dense block so that the JVP, and the Jacobian along all parameters, are matrix
products. ``L`` counts the letters the stage optimises (:func:`_stage_config`): an orientation
stage differentiates along the turn only, not through the lens maps' intrinsics, and its normal
equations have its own size (16 for a 6-camera rig), not a later stage's.
What a camera's points share (rotation, focal length, invertible range:
:class:`rigjax._camera.Optics`) and its derivatives are computed once per camera, not per point.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ._camera import Camera, Optics, optics
from ._panorama import Equirect
from ._point_jacobian import INTRINSICS, local_from_letters, pair_jacobian
from ._projection import safe_hypot
from ._residuals import (NORMAL, LineGroups, PointArrays, objective_residuals, pair_residuals, point_residuals, rms,
                         robust_scale, straight_line_residuals)
from ._schedule import FIELD, LENS_LETTERS, UNIT

LETTERS = "VABCDEYPR"


class _Config(NamedTuple):
    """Static settings: a change recompiles (data never does). The stopping rules, which a user
    tunes between runs, are data in :class:`_Args`."""

    objective: str  # "transfer", "sphere" or "hugin" (point residuals: also "distance")
    lines: bool  # the project has line points
    robust: str | None  # see rigjax._residuals.robust_scale
    projection: int | None
    backend: str
    # The letters the stage optimises (of any camera): derivatives are computed along these only,
    # so the Jacobian's columns for other letters are zero, not the derivatives (:func:`_stage_config`).
    letters: str = LETTERS


class _Args(NamedTuple):
    base: Camera  # (n_images,) the cameras at the start of the stage
    slot: jax.Array  # (n_images, 9) int32, parameter index or -1
    points: PointArrays  # padded
    canvas: Equirect
    weight: jax.Array  # (n_padded,) 1 for points in the objective, 0 for points left out
    robust_scale: jax.Array
    cost_threshold: jax.Array  # sum of squared residuals at which a stage stops
    groups: LineGroups  # straight-line (t3+) rows, padded; none at all for most projects
    group_weight: jax.Array  # (n_rows,) 1 in use, 0 padding
    max_steps: jax.Array  # int32; the stopping rules of rigjax._solver.SolverOptions
    xtol: jax.Array
    ftol: jax.Array


# The local coordinate (rigjax._point_jacobian.INTRINSICS) that each lens letter moves; Y, P and R
# turn the camera and move nothing else.
_INTRINSIC_OF = dict(zip(LENS_LETTERS, INTRINSICS))


def _stage_config(config: _Config, slot: np.ndarray) -> _Config:
    """``config`` for a stage whose parameters fill ``slot`` ``(n_images, 9)`` (>= 0 where
    optimised): its Jacobian runs along those letters only, through the intrinsics they move and
    the turn. Each set of letters is a compilation of its own."""
    moved = np.any(np.asarray(slot) >= 0, axis=0)
    return config._replace(letters="".join(letter for letter, on in zip(LETTERS, moved) if on))


def _theta_of(cameras: Camera, xp=jnp) -> jax.Array:
    """The ``(..., 9)`` letters of cameras (``xp=np`` for host arrays, without device work)."""
    return xp.stack([getattr(cameras, FIELD[letter]) / UNIT[letter] for letter in LETTERS], axis=-1)


def _with_theta(cameras: Camera, theta: jax.Array) -> Camera:
    return cameras._replace(**{FIELD[letter]: theta[..., i] * UNIT[letter] for i, letter in enumerate(LETTERS)})


def _theta(params: jax.Array, args: _Args) -> jax.Array:
    base = _theta_of(args.base)
    return jnp.where(args.slot >= 0, params[jnp.clip(args.slot, 0, params.shape[0] - 1)], base)


def _lens(theta_camera: jax.Array, fixed: Camera) -> Optics:
    """One camera's optics from its 9 parameters."""
    return optics(_with_theta(fixed, theta_camera))


def _point_cameras(points: PointArrays, n_images: int) -> jax.Array:
    """``(n, 2, n_images)``: one-hot rows selecting each point's two cameras."""
    return jax.nn.one_hot(jnp.stack([points.image_a, points.image_b], axis=-1), n_images)


def _at_points(values, onehot: jax.Array):
    """Per-camera values gathered to the points, ``(n_cameras, ...) -> (n, 2, ...)``, as a product
    with the one-hot :func:`_point_cameras`: XLA fuses the producers of a gather into it (a
    rotation's trigonometry, the polynomial's range...), computing them once per point instead of
    once per camera; it leaves a matrix product alone. Exact for finite values."""
    return jax.tree_util.tree_map(lambda v: jnp.einsum("npc,c...->np...", onehot.astype(v.dtype), v), values)


def _point_lenses(lenses: Optics, fixed: Camera, points: PointArrays, onehot: jax.Array, config: _Config):
    """Each point's two cameras as ``(lens type, optics)``, optics fields ``(n, ...)``, from the
    rig's per-camera optics and the points' :func:`_point_cameras`."""
    lens = _at_points(lenses, onehot)
    if config.projection is not None:  # a rig of one lens type: only that branch is traced
        types = (config.projection,) * 2
    else:
        types = (fixed.projection[points.image_a], fixed.projection[points.image_b])
    return tuple((types[k], jax.tree_util.tree_map(lambda field: field[:, k], lens)) for k in range(2))


@partial(jax.custom_jvp, nondiff_argnums=(4,))
def _rig_objective(theta: jax.Array, fixed: Camera, points: PointArrays, canvas: Equirect, config: _Config):
    """``(n_points, 4)`` residuals of the rig with parameters ``theta`` ``(n_images, 9)``."""
    onehot = _point_cameras(points, theta.shape[0])
    camera_a, camera_b = _point_lenses(jax.vmap(_lens)(theta, fixed), fixed, points, onehot, config)
    res = pair_residuals(camera_a, camera_b, points.xy_a, points.xy_b, points.kind, canvas)
    return objective_residuals(res.transfer, res, points.kind, config.objective, config.lines)


@_rig_objective.defjvp
def _rig_objective_jvp(config, primals, tangents):
    # Chain rule in two levels: per point, the residuals' derivatives along the local coordinates
    # of its two cameras (rigjax._point_jacobian); per camera, how its letters move its local
    # coordinates. Together: each point's derivatives along the stage's letters of every camera,
    # a dense (n, 4, cameras, letters) block that is zero outside the point's two cameras, so that
    # the JVP is a matrix product. Every LM step materialises the Jacobian along all parameters,
    # which makes that one matrix product too. (Measured against 18 products per point with the
    # tangent gathered from a per-camera table: one JVP 1.4 -> 1.9 ms, but the materialised
    # Jacobian 2.6 -> 2.1 ms and a whole solve 57 -> 45 ms, median of 10 starts.)
    theta, fixed, points, canvas = primals
    lenses = jax.vmap(_lens)(theta, fixed)
    onehot = _point_cameras(points, theta.shape[0])  # (n, 2, cameras)
    camera_a, camera_b = _point_lenses(lenses, fixed, points, onehot, config)
    # Only along the stage's letters: the intrinsics they move (k) and the turn.
    intrinsics = tuple(_INTRINSIC_OF[letter] for letter in config.letters if letter in _INTRINSIC_OF)
    columns = [LETTERS.index(letter) for letter in config.letters]
    value, jac = pair_jacobian(camera_a, camera_b, points.xy_a, points.xy_b, points.kind, canvas, config.objective,
                               config.lines, intrinsics)  # fmt: skip
    d_lens = jax.tree_util.tree_map(lambda d: d[..., columns], jax.vmap(jax.jacfwd(_lens))(theta, fixed))
    local = jax.vmap(partial(local_from_letters, intrinsics=intrinsics))(lenses, d_lens)  # (cameras, k + 3, letters)
    images = (points.image_a, points.image_b)
    # (n, 4, letters) each; as a sum of broadcast products, which XLA fuses (a batched dot of
    # 4 x k by k x letters blocks costs several times more on CPU)
    letters = [sum(jac[s][k][..., None] * local[images[s]][:, None, k] for k in range(jac.shape[1])) for s in range(2)]
    dense = sum(jnp.einsum("nrj,nc->nrcj", letters[s], onehot[:, s].astype(theta.dtype)) for s in range(2))
    return value, jnp.einsum("nrcj,cj->nr", dense, tangents[0][:, columns])


def _residuals(params: jax.Array, args: _Args, config: _Config, strategy: str | None = None) -> jax.Array:
    """The stage's residual vector. ``strategy`` picks the point residual of one of libpano13's
    strategies (``"distance"``, then ``"sphere"``) for ``objective="hugin"``."""
    theta = _theta(params, args)
    kind = config.objective if strategy is None else strategy
    r = _rig_objective(theta, args.base, args.points, args.canvas, config._replace(objective=kind))
    pairs = [(r.reshape(-1, 2, 2) * args.weight[:, None, None]).reshape(-1, 2)]  # 2-D residuals
    if args.group_weight.shape[0]:  # straight lines: few rows, plain autodiff over all cameras
        d = straight_line_residuals(_with_theta(args.base, theta), args.groups, args.canvas, config.projection)
        if kind == "distance":  # libpano13's strategy 1: one number per point
            d = jnp.stack([safe_hypot(d[:, 0], d[:, 1])[0], jnp.zeros_like(d[:, 0])], axis=-1)
        pairs.append(d * args.group_weight[:, None])
    pair = jnp.concatenate(pairs)
    norm = jnp.sqrt(jnp.sum(pair**2, axis=-1))
    r = (pair * robust_scale(norm, config.robust, args.robust_scale)[..., None]).reshape(-1)
    if config.objective == "hugin":
        # libpano13's FOV stabilisation (reference section 4.2): every residual grows as the mean
        # hfov of all images shrinks below its value at the start.
        mean_hfov = jnp.mean(jnp.abs(theta[:, LETTERS.index("V")])) * UNIT["V"]
        r = r * jnp.maximum(1.0, jnp.mean(args.base.hfov) / mean_hfov)
    return r


@jax.jit(static_argnames=("projection",))
def _metrics(cameras: Camera, points: PointArrays, canvas: Equirect, weight: jax.Array, projection: int | None):
    """Transfer and sphere RMS (px) over the normal points in use, and the per-point residuals.

    A function of the cameras, not of a stage's parameters: compiled once per rig shape.
    """
    res = point_residuals(cameras, points, canvas, projection)
    normal = (points.kind == NORMAL) & (weight > 0)
    return rms(res.transfer, normal, per_point=2), rms(res.sphere, normal), res.transfer, res.sphere
