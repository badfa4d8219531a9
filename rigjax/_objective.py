"""The rig objective: a stage's parameter vector -> cameras -> control-point residuals.

A rig's cameras are a ``(n_images, 9)`` array ``theta`` of the letters V A B C D E Y P R in
internal units (see :data:`rigjax._schedule.UNIT`); a stage's parameters fill the entries whose
``slot`` is >= 0. The parameter vector is padded to ``9 n + 9`` so that every stage and every
schedule of a rig shares one compilation; unused entries have zero Jacobian columns.

Each control point depends on two cameras only, so its Jacobian is a 4 x (2 x 9) block computed
once per evaluation (a custom JVP); the rig's Jacobian is then a gather and a small contraction,
cheap for any number of parameters (the sparse structure jaxls exploits).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp

from ._camera import Camera
from ._panorama import Equirect
from ._residuals import NORMAL, PointArrays, point_residuals, rms, robust_scale
from ._schedule import FIELD, UNIT

LETTERS = "VABCDEYPR"


class _Config(NamedTuple):
    """Static settings: a change recompiles (data never does)."""

    objective: str
    robust: str | None
    projection: int | None
    max_steps: int
    xtol: float
    ftol: float
    backend: str


class _Args(NamedTuple):
    base: Camera  # (n_images,) the cameras at the start of the stage
    slot: jax.Array  # (n_images, 9) int32, parameter index or -1
    points: PointArrays  # padded
    canvas: Equirect
    weight: jax.Array  # (n_padded,) 1 for points in the objective, 0 for points left out
    robust_scale: jax.Array
    cost_threshold: jax.Array  # sum of squared residuals at which a stage stops


def _theta_of(cameras: Camera) -> jax.Array:
    return jnp.stack([getattr(cameras, FIELD[letter]) / UNIT[letter] for letter in LETTERS], axis=-1)


def _with_theta(cameras: Camera, theta: jax.Array) -> Camera:
    return cameras._replace(**{FIELD[letter]: theta[..., i] * UNIT[letter] for i, letter in enumerate(LETTERS)})


def _theta(params: jax.Array, args: _Args) -> jax.Array:
    base = _theta_of(args.base)
    return jnp.where(args.slot >= 0, params[jnp.clip(args.slot, 0, params.shape[0] - 1)], base)


def _point_objective(theta_ab, fixed_ab: Camera, xy_a, xy_b, kind, canvas: Equirect, config: _Config):
    """The objective's four residuals of one control point, from the 2 x 9 parameters of its cameras."""
    cams = _with_theta(fixed_ab, theta_ab)
    point = PointArrays(jnp.zeros(1, jnp.int32), jnp.ones(1, jnp.int32), xy_a[None], xy_b[None], kind[None])
    res = point_residuals(cams, point, canvas, config.projection)
    pair = res.transfer[0] if config.objective == "transfer" else jnp.concatenate([res.sphere_components[0], jnp.zeros(2)])
    line = jnp.zeros(4, pair.dtype).at[0].set(res.line[0])
    return jnp.where(kind == NORMAL, pair, line)


@partial(jax.custom_jvp, nondiff_argnums=(4,))
def _rig_objective(theta: jax.Array, fixed: Camera, points: PointArrays, canvas: Equirect, config: _Config):
    """``(n_points, 4)`` residuals of the rig with parameters ``theta`` ``(n_images, 9)``."""
    theta_ab, fixed_ab = _per_point(theta, fixed, points)
    return jax.vmap(_point_objective, in_axes=(0, 0, 0, 0, 0, None, None))(
        theta_ab, fixed_ab, points.xy_a, points.xy_b, points.kind, canvas, config
    )


def _per_point(theta, fixed: Camera, points: PointArrays):
    pair = jnp.stack([points.image_a, points.image_b], axis=-1)  # (n, 2)
    return theta[pair], fixed.take(pair)


@_rig_objective.defjvp
def _rig_objective_jvp(config, primals, tangents):
    # Each point depends on its two cameras only: its 4 x (2 x 9) Jacobian is computed once, and
    # the JVP of the rig is a gather and a small contraction (cheap for any number of parameters).
    theta, fixed, points, canvas = primals
    dtheta = tangents[0]
    theta_ab, fixed_ab = _per_point(theta, fixed, points)

    def value_and_jacobian(t, f, xy_a, xy_b, kind):
        # One forward pass: the primal is shared by all 18 tangent directions (out_axes None).
        fn = lambda t_: _point_objective(t_, f, xy_a, xy_b, kind, canvas, config)  # noqa: E731
        basis = jnp.eye(t.size, dtype=t.dtype).reshape(-1, *t.shape)
        value, jac = jax.vmap(lambda v: jax.jvp(fn, (t,), (v,)), out_axes=(None, -1))(basis)
        return value, jac.reshape(value.shape + t.shape)

    value, jac = jax.vmap(value_and_jacobian)(theta_ab, fixed_ab, points.xy_a, points.xy_b, points.kind)
    dtheta_ab = dtheta[jnp.stack([points.image_a, points.image_b], axis=-1)]  # (n, 2, 9)
    return value, jnp.einsum("nrcj,ncj->nr", jac, dtheta_ab)


def _residuals(params: jax.Array, args: _Args, config: _Config) -> jax.Array:
    r = _rig_objective(_theta(params, args), args.base, args.points, args.canvas, config)
    pair = r.reshape(-1, 2, 2)
    norm = jnp.sqrt(jnp.sum(pair**2, axis=-1))
    pair = pair * robust_scale(norm, config.robust, args.robust_scale)[..., None]
    return (pair * args.weight[:, None, None]).reshape(-1)


@jax.jit(static_argnames=("projection",))
def _metrics(cameras: Camera, points: PointArrays, canvas: Equirect, weight: jax.Array, projection: int | None):
    """Transfer and sphere RMS (px) over the normal points in use, and the per-point residuals.

    A function of the cameras, not of a stage's parameters: compiled once per rig shape.
    """
    res = point_residuals(cameras, points, canvas, projection)
    normal = (points.kind == NORMAL) & (weight > 0)
    return rms(res.transfer, normal, per_point=2), rms(res.sphere, normal), res.transfer, res.sphere
