"""The rig objective: a stage's parameter vector -> cameras -> control-point residuals.

A rig's cameras are a ``(n_images, 9)`` array ``theta`` of the letters V A B C D E Y P R in
internal units (see :data:`rigjax.optimiser.schedule.UNIT`); a stage's parameters fill the entries whose
``slot`` is >= 0. The parameter vector is padded to a multiple of 16 (rigjax.optimiser.staged), so that
stages of similar sizes share a compilation; unused entries have zero Jacobian columns.

Each control point depends on two cameras only, so its Jacobian is a 4 x (2 x L) block computed
once per evaluation (:mod:`rigjax.optimiser.point_jacobian`). LM's model, ``J^T J`` and ``J^T r``, is summed
from these blocks by pair of cameras (:func:`normal_equations`), without forming ``J``; for
forward mode (a custom JVP: jaxopt, ``jax.jacfwd``) they are spread over the letters of all
cameras as a dense block, so that the JVP, and the Jacobian along all parameters, are matrix
products. ``L`` counts the letters the stage optimises (:func:`stage_config`): an orientation
stage differentiates along the turn only, not through the lens maps' intrinsics, and its normal
equations have its own size (16 for a 6-camera rig), not a later stage's.
What a camera's points share (rotation, focal length, invertible range:
:class:`rigjax.camera.model.Optics`) and its derivatives are computed once per camera, not per point.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..camera.lenses import safe_hypot
from ..camera.model import Camera, Optics, optics
from ..camera.panorama import Equirect
from .point_jacobian import INTRINSICS, local_from_letters, pair_jacobian
from .residuals import (
    NORMAL,
    LineGroups,
    PointArrays,
    objective_residuals,
    pair_residuals,
    point_residuals,
    rms,
    robust_scale,
    straight_line_residuals,
)
from .schedule import FIELD, LENS_LETTERS, UNIT

LETTERS = "VABCDEYPR"


class SolveConfig(NamedTuple):
    """Static settings: a change recompiles (data never does). The stopping rules, which a user
    tunes between runs, are data in :class:`SolveArgs`."""

    objective: str  # "transfer", "sphere" or "hugin" (point residuals: also "distance")
    lines: bool  # the project has line points
    robust: str | None  # see rigjax.optimiser.residuals.robust_scale
    projection: int | None
    backend: str
    # The letters the stage optimises (of any camera): derivatives are computed along these only,
    # so the Jacobian's columns for other letters are zero, not the derivatives (:func:`stage_config`).
    letters: str = LETTERS


class SolveArgs(NamedTuple):
    base: Camera  # (n_images,) the cameras at the start of the stage
    slot: jax.Array  # (n_images, 9) int32, parameter index or -1
    points: PointArrays  # padded
    canvas: Equirect
    weight: jax.Array  # (n_padded,) 1 for points in the objective, 0 for points left out
    robust_scale: jax.Array
    # >= 0: the robust scale is instead the median point error where the stage starts (the larger
    # of each normal point's two transfer errors), at least this many px (pruning's robust round)
    median_scale_floor: jax.Array
    cost_threshold: jax.Array  # sum of squared residuals at which a stage stops
    groups: LineGroups  # straight-line (t3+) rows, padded; none at all for most projects
    group_weight: jax.Array  # (n_rows,) 1 in use, 0 padding
    max_steps: jax.Array  # int32; the stopping rules of rigjax.optimiser.options.SolverOptions
    xtol: jax.Array
    ftol: jax.Array


# The local coordinate (rigjax.optimiser.point_jacobian.INTRINSICS) that each lens letter moves; Y, P and R
# turn the camera and move nothing else.
_INTRINSIC_OF = dict(zip(LENS_LETTERS, INTRINSICS))


def stage_config(config: SolveConfig, *slots: np.ndarray) -> SolveConfig:
    """``config`` for stages whose parameters fill ``slots`` (each ``(n_images, 9)``, >= 0 where
    optimised): the Jacobian runs along the letters they optimise only, through the intrinsics
    those move and the turn. Each set of letters is a compilation of its own; the stages of one
    run share the set of them all (rigjax.optimiser.problem.prepare), so a run is one program."""
    moved = np.any([np.any(np.asarray(slot) >= 0, axis=0) for slot in slots], axis=0)
    return config._replace(letters="".join(letter for letter, on in zip(LETTERS, moved) if on))


def theta_of(cameras: Camera, xp=jnp) -> jax.Array:
    """The ``(..., 9)`` letters of cameras (``xp=np`` for host arrays, without device work)."""
    return xp.stack([getattr(cameras, FIELD[letter]) / UNIT[letter] for letter in LETTERS], axis=-1)


def with_theta(cameras: Camera, theta: jax.Array) -> Camera:
    return cameras._replace(**{FIELD[letter]: theta[..., i] * UNIT[letter] for i, letter in enumerate(LETTERS)})


def theta_from_params(params: jax.Array, args: SolveArgs) -> jax.Array:
    base = theta_of(args.base)
    return jnp.where(args.slot >= 0, params[jnp.clip(args.slot, 0, params.shape[0] - 1)], base)


def _lens(theta_camera: jax.Array, fixed: Camera) -> Optics:
    """One camera's optics from its 9 parameters."""
    return optics(with_theta(fixed, theta_camera))


def _point_cameras(points: PointArrays, n_images: int) -> jax.Array:
    """``(n, 2, n_images)``: one-hot rows selecting each point's two cameras."""
    return jax.nn.one_hot(jnp.stack([points.image_a, points.image_b], axis=-1), n_images)


def _at_points(values, onehot: jax.Array):
    """Per-camera values gathered to the points, ``(n_cameras, ...) -> (n, 2, ...)``, as a product
    with the one-hot :func:`_point_cameras`: XLA fuses the producers of a gather into it (a
    rotation's trigonometry, the polynomial's range...), computing them once per point instead of
    once per camera; it leaves a matrix product alone. Exact for finite values."""
    return jax.tree_util.tree_map(lambda v: jnp.einsum("npc,c...->np...", onehot.astype(v.dtype), v), values)


def _point_lenses(lenses: Optics, fixed: Camera, points: PointArrays, onehot: jax.Array, config: SolveConfig):
    """Each point's two cameras as ``(lens type, optics)``, optics fields ``(n, ...)``, from the
    rig's per-camera optics and the points' :func:`_point_cameras`."""
    lens = _at_points(lenses, onehot)
    if config.projection is not None:  # a rig of one lens type: only that branch is traced
        types = (config.projection,) * 2
    else:
        types = (fixed.projection[points.image_a], fixed.projection[points.image_b])
    return tuple((types[k], jax.tree_util.tree_map(lambda field: field[:, k], lens)) for k in range(2))


@partial(jax.custom_jvp, nondiff_argnums=(4,))
def _rig_objective(theta: jax.Array, fixed: Camera, points: PointArrays, canvas: Equirect, config: SolveConfig):
    """``(n_points, 4)`` residuals of the rig with parameters ``theta`` ``(n_images, 9)``."""
    onehot = _point_cameras(points, theta.shape[0])
    camera_a, camera_b = _point_lenses(jax.vmap(_lens)(theta, fixed), fixed, points, onehot, config)
    res = pair_residuals(camera_a, camera_b, points.xy_a, points.xy_b, points.kind, canvas)
    return objective_residuals(res.transfer, res, points.kind, config.objective, config.lines)


def _point_blocks(theta: jax.Array, fixed: Camera, points: PointArrays, canvas: Equirect, config: SolveConfig):
    """The ``(n, 4)`` residuals of the points, their derivatives along the stage's letters
    (``config.letters``) of the point's two cameras, ``(2, n, 4, letters)``, and the cameras as
    one-hot rows ``(n, 2, cameras)`` (:func:`_point_cameras`)."""
    # Chain rule in two levels: per point, the residuals' derivatives along the local coordinates
    # of its two cameras (rigjax.optimiser.point_jacobian); per camera, how its letters move its local
    # coordinates.
    lenses = jax.vmap(_lens)(theta, fixed)
    onehot = _point_cameras(points, theta.shape[0])  # (n, 2, cameras)
    camera_a, camera_b = _point_lenses(lenses, fixed, points, onehot, config)
    # Only along the stage's letters: the intrinsics they move (k) and the turn.
    intrinsics = tuple(_INTRINSIC_OF[letter] for letter in config.letters if letter in _INTRINSIC_OF)
    value, jac = pair_jacobian(
        camera_a, camera_b, points.xy_a, points.xy_b, points.kind, canvas, config.objective, config.lines, intrinsics
    )
    d_lens = jax.tree_util.tree_map(lambda d: d[..., letter_columns(config)], jax.vmap(jax.jacfwd(_lens))(theta, fixed))
    local = jax.vmap(partial(local_from_letters, intrinsics=intrinsics))(lenses, d_lens)  # (cameras, k + 3, letters)
    images = (points.image_a, points.image_b)
    # (n, 4, letters) each; as a sum of broadcast products, which XLA fuses (a batched dot of
    # 4 x k by k x letters blocks costs several times more on CPU)
    letters = [sum(jac[s][k][..., None] * local[images[s]][:, None, k] for k in range(jac.shape[1])) for s in range(2)]
    return value, jnp.stack(letters), onehot.astype(theta.dtype)


def _dense(letters: jax.Array, onehot: jax.Array) -> jax.Array:
    """``(n, 4, cameras, letters)``: each point's derivatives along the stage's letters of every
    camera, zero outside its two cameras. A sum of broadcast products, which XLA fuses (as one
    ``einsum`` over both sides it became a batched matrix product and a transpose)."""
    return sum(jnp.einsum("nrj,nc->nrcj", letters[s], onehot[:, s]) for s in range(2))


def letter_columns(config: SolveConfig) -> list[int]:
    """The stage's letters as columns of ``theta``."""
    return [LETTERS.index(letter) for letter in config.letters]


@_rig_objective.defjvp
def _rig_objective_jvp(config, primals, tangents):
    # The dense block of every point makes the JVP one matrix product, and so the Jacobian along
    # all parameters (jaxopt's LM materialises it every step). The tangent gathered per point from a
    # per-camera table makes one JVP cheaper but the materialised Jacobian and a whole solve slower
    # (docs/design/optimiser.md; the figures are in CHANGELOG.md).
    value, letters, onehot = _point_blocks(*primals, config)
    dense = _dense(letters, onehot)
    return value, jnp.einsum("nrcj,cj->nr", dense, tangents[0][:, letter_columns(config)])


def stage_residuals(params: jax.Array, args: SolveArgs, config: SolveConfig, strategy: str | None = None) -> jax.Array:
    """The stage's residual vector. ``strategy`` picks the point residual of one of libpano13's
    strategies (``"distance"``, then ``"sphere"``) for ``objective="hugin"``."""
    theta = theta_from_params(params, args)
    kind = config.objective if strategy is None else strategy
    r = _rig_objective(theta, args.base, args.points, args.canvas, config._replace(objective=kind))
    pairs = [_weighted_pairs(r, args)]
    if args.group_weight.shape[0]:
        pairs.append(_line_pairs(theta, args, config, kind))
    r = _robust_pairs(jnp.concatenate(pairs), args, config).reshape(-1)
    if config.objective == "hugin":
        r = r * _fov_factor(theta, args)
    return r


def _weighted_pairs(point_residuals: jax.Array, args: SolveArgs) -> jax.Array:
    """``(n, 4) -> (2 n, 2)``: the points' 2-D residuals, times their weights."""
    return (point_residuals * args.weight[:, None]).reshape(-1, 2)


def _line_pairs(theta: jax.Array, args: SolveArgs, config: SolveConfig, kind: str) -> jax.Array:
    """``(rows, 2)``: the straight-line rows' residuals (few rows: plain autodiff over all cameras)."""
    d = straight_line_residuals(with_theta(args.base, theta), args.groups, args.canvas, config.projection)
    if kind == "distance":  # libpano13's strategy 1: one number per point
        d = jnp.stack([safe_hypot(d[:, 0], d[:, 1])[0], jnp.zeros_like(d[:, 0])], axis=-1)
    return d * args.group_weight[:, None]


def _robust_pairs(pair: jax.Array, args: SolveArgs, config: SolveConfig) -> jax.Array:
    """2-D residuals ``(m, 2)`` rescaled by the robust loss (rigjax.optimiser.residuals.robust_scale)."""
    norm = jnp.sqrt(jnp.sum(pair**2, axis=-1))
    return pair * robust_scale(norm, config.robust, args.robust_scale)[..., None]


def _fov_factor(theta: jax.Array, args: SolveArgs) -> jax.Array:
    """libpano13's FOV stabilisation (reference section 4.2) for ``objective="hugin"``: every
    residual grows as the mean hfov of all images shrinks below its value at the start."""
    mean_hfov = jnp.mean(jnp.abs(theta[:, LETTERS.index("V")])) * UNIT["V"]
    return jnp.maximum(1.0, jnp.mean(args.base.hfov) / mean_hfov)


def _camera_blocks(d_rows: jax.Array, rows: jax.Array, points: PointArrays, n_images: int):
    """``sum_k D_k^T D_k`` ``(cameras x letters, cameras x letters)`` and ``sum_k D_k^T u_k``
    ``(cameras x letters,)`` over the points ``k``, ``D_k`` a point's 4 rows along the letters of
    every camera (its two cameras' ``d_rows`` ``(2, n, 4, letters)``, zeros elsewhere) and ``u_k`` its
    ``rows`` ``(n, 4)``.

    Each point's products are formed over its two cameras' letters only (and ``u``), then summed
    by pair of cameras: on a 6-camera rig's ``VBYPR`` stage 4 x 11^2 multiply-adds a point instead
    of the 4 x 30^2 of ``D^T D`` over all cameras' letters (two thirds of whose entries are zero).
    """
    block = jnp.concatenate([d_rows[0], d_rows[1], rows[..., None]], axis=-1)  # (n, 4, 2 letters + 1)
    products = sum(block[:, r, :, None] * block[:, r, None, :] for r in range(block.shape[1]))
    return sum_by_pair(products, points.image_a, points.image_b, n_images)


def sum_by_pair(products: jax.Array, image_a: jax.Array, image_b: jax.Array, n_images: int):
    """Each point's products ``(n, 2 L + 1, 2 L + 1)`` over ``[letters of camera a, letters of
    camera b, residual]`` summed into the rig's ``(cameras x L, cameras x L)`` matrix and
    ``(cameras x L,)`` vector (the last row's first ``2 L`` entries), by pair of cameras."""
    n_letters = (products.shape[-1] - 1) // 2
    by_pair = jax.ops.segment_sum(products, image_a * n_images + image_b, n_images * n_images)
    by_pair = by_pair.reshape(n_images, n_images, *products.shape[1:])  # [camera a, camera b]
    a, b = slice(0, n_letters), slice(n_letters, 2 * n_letters)
    # Camera a's and b's own blocks go on the diagonal, their cross terms to (a, b) and (b, a).
    diagonal = by_pair[:, :, a, a].sum(axis=1) + by_pair[:, :, b, b].sum(axis=0)  # (cameras, letters, letters)
    hessian = by_pair[:, :, a, b] + jnp.swapaxes(by_pair[:, :, b, a], 0, 1)  # (cameras, cameras, letters, letters)
    hessian = hessian + jnp.eye(n_images, dtype=products.dtype)[:, :, None, None] * diagonal[:, None]
    gradient = by_pair[:, :, a, -1].sum(axis=1) + by_pair[:, :, b, -1].sum(axis=0)  # (cameras, letters)
    size = n_images * n_letters
    return jnp.swapaxes(hessian, 1, 2).reshape(size, size), gradient.reshape(size)


def normal_equations(params: jax.Array, args: SolveArgs, config: SolveConfig, strategy: str | None = None):
    """``(r, J^T J, J^T r)``: :func:`stage_residuals` at ``params``, and the Gauss-Newton model from
    its Jacobian ``J`` along ``params``, without forming ``J``.

    The points' part is summed from each point's rows along the letters of its two cameras
    (:func:`_point_blocks`, :func:`_camera_blocks`) and mapped to the parameters by ``T``, the
    one-hot map from parameters to letters (``args.slot``): ``T^T (sum_k D_k^T D_k) T``. The robust
    loss acts on each 2-D residual through its own 2 x 2 derivative; the straight-line rows (few)
    are differentiated along the parameters directly; ``objective="hugin"``'s FOV factor ``f``
    (one number) enters in closed form: with ``u`` the residuals before it,
    ``J = f J_u + u (grad f)^T``.
    """
    theta = theta_from_params(params, args)
    kind = config.objective if strategy is None else strategy
    value, letters, _ = _point_blocks(theta, args.base, args.points, args.canvas, config._replace(objective=kind))
    n, n_letters = letters.shape[1], letters.shape[-1]
    pairs = _weighted_pairs(value, args)  # (2 n, 2)
    d_pairs = (letters * args.weight[:, None, None]).reshape(2, 2 * n, 2, n_letters)  # along each side's letters
    u, d_u = _robust_pairs(pairs, args, config), _robust_chain(pairs, d_pairs, args, config)
    hessian, gradient = _camera_blocks(d_u.reshape(2, n, 4, n_letters), u.reshape(n, 4), args.points, theta.shape[0])
    letter_index = args.slot[:, jnp.asarray(letter_columns(config))].reshape(-1)
    to_params = (letter_index[:, None] == jnp.arange(params.shape[0])).astype(params.dtype)  # T
    hessian, gradient, residuals = to_params.T @ hessian @ to_params, to_params.T @ gradient, [u]
    if args.group_weight.shape[0]:
        lines = lambda p: (_line_pairs(theta_from_params(p, args), args, config, kind),) * 2  # noqa: E731
        d_lines, line_pairs = jax.jacfwd(lines, has_aux=True)(params)  # (rows, 2, params), (rows, 2)
        u_lines = _robust_pairs(line_pairs, args, config)
        d_u_lines = _robust_chain(line_pairs, d_lines, args, config)
        hessian += jnp.einsum("mia,mib->ab", d_u_lines, d_u_lines)
        gradient += jnp.einsum("mia,mi->a", d_u_lines, u_lines)
        residuals.append(u_lines)
    r = jnp.concatenate(residuals).reshape(-1)
    if config.objective == "hugin":
        f, d_f = jax.value_and_grad(lambda p: _fov_factor(theta_from_params(p, args), args))(params)
        squared = jnp.sum(r**2)
        hessian = (
            f**2 * hessian + f * (jnp.outer(gradient, d_f) + jnp.outer(d_f, gradient)) + squared * jnp.outer(d_f, d_f)
        )
        gradient = f**2 * gradient + f * squared * d_f
        r = f * r
    return r, hessian, gradient


def _robust_chain(pairs: jax.Array, d_pairs: jax.Array, args: SolveArgs, config: SolveConfig) -> jax.Array:
    """Derivatives ``(..., m, 2, k)`` of 2-D residuals ``pairs`` ``(m, 2)`` carried through the
    robust loss (:func:`_robust_pairs`): each pair's own 2 x 2 derivative applied."""
    if config.robust is None:
        return d_pairs
    derivative = jax.vmap(jax.jacfwd(lambda pair: _robust_pairs(pair[None], args, config)[0]))(pairs)
    return jnp.einsum("mij,...mjk->...mik", derivative, d_pairs)


@jax.jit(static_argnames=("projection",))
def point_metrics(cameras: Camera, points: PointArrays, canvas: Equirect, weight: jax.Array, projection: int | None):
    """Transfer and sphere RMS (px) over the normal points in use, and the per-point residuals.

    A function of the cameras, not of a stage's parameters: compiled once per rig shape.
    """
    res = point_residuals(cameras, points, canvas, projection)
    normal = (points.kind == NORMAL) & (weight > 0)
    return rms(res.transfer, normal, per_point=2), rms(res.sphere, normal), res.transfer, res.sphere


def point_error(transfer: jax.Array, xp=jnp) -> jax.Array:
    """Each point's error, px: the larger of its two transfer errors (``transfer`` ``(n, 4)``,
    :func:`point_metrics`' per-point residuals; ``xp=np`` for host arrays)."""
    return xp.maximum(xp.hypot(transfer[:, 0], transfer[:, 1]), xp.hypot(transfer[:, 2], transfer[:, 3]))


def median_point_error(transfer: jax.Array, points: PointArrays, weight: jax.Array) -> jax.Array:
    """The median :func:`point_error` over the normal points in use, as ``numpy.median`` takes it;
    0 without such points."""
    return masked_median(point_error(transfer), (points.kind == NORMAL) & (weight > 0))


def masked_median(values: jax.Array, use: jax.Array) -> jax.Array:
    """The median of ``values`` where ``use``, as ``numpy.median`` takes it; 0 where none is used."""
    count = jnp.sum(use)
    ordered = jnp.sort(jnp.where(use, values, jnp.inf))
    middle = 0.5 * (ordered[jnp.maximum((count - 1) // 2, 0)] + ordered[count // 2])
    return jnp.where(count > 0, middle, 0.0)
