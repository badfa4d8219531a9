"""Every control point's residuals and their derivatives with respect to its two cameras, by the
chain rule through a few small maps instead of forward mode through the whole pair.

A camera moves in **local coordinates** (9): its focal length, ``a, b, c``, the distortion centre
``cx, cy`` (the :class:`rigjax.camera.model.Optics` its points share), and a small turn ``w`` about its
own axes, ``R -> R (I + [w]x)``. :func:`local_from_letters` converts a camera's letters
``V A B C D E Y P R`` to them, once per camera.

Per point, forward mode runs only through the lens maps of the camera frame, along the directions
that reach them: the image-to-ray map along the intrinsics, the ray-to-image map along its ray
(3) and the intrinsics, the ray-only terms (angle, spherical distance, line points) along the
two world rays (6). "The intrinsics" are those a stage moves (``V`` and ``B`` move ``focal`` and
``b``; an orientation stage moves none, and its camera-frame rays are constants): a subset of
:data:`INTRINSICS`. Rotations enter in closed form: ``d(R u)/dw_k = R (e_k x u)`` and
``d(R^T v)/dw_k = -(e_k x R^T v)``. (Pushing all 18 letters of both cameras through the whole
pair made XLA's CPU backend fuse it into one loop that redid the shared work for every entry of
the result: 2.6 of the Jacobian's 4-7 ms.)

Derivatives are laid out directions first, points next: ``(directions, n, ...)``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array

from ..camera.model import Optics, camera_ray_to_img, img_to_camera_ray
from ..camera.panorama import Equirect
from .residuals import objective_residuals, ray_terms, transfer_or_angle

INTRINSICS = ("focal", "a", "b", "c", "cx", "cy")


def local_from_letters(lens: Optics, dlens: Optics, intrinsics: tuple[str, ...]) -> Array:
    """``(k + 3, L)``: how a camera's local coordinates (the ``k`` ``intrinsics``, then the turn)
    move with its ``L`` letters, from its optics and their derivatives along the letters (each
    field with a trailing axis of ``L``)."""
    # [w]x = R^T dR, the turn in the camera's own frame.
    turn = jnp.einsum("ji,jkl->ikl", lens.world_from_cam, dlens.world_from_cam)
    return jnp.stack([*(getattr(dlens, name) for name in intrinsics), turn[2, 1], turn[0, 2], turn[1, 0]])


def _components(v: Array) -> tuple[Array, ...]:
    return tuple(v[..., j] for j in range(v.shape[-1]))


def _one_at_a_time(values: tuple[Array, ...]) -> tuple[Array, ...]:
    """Tangents that move one of ``values`` by 1 at a time: each with a leading axis of
    ``len(values)`` directions."""
    count = len(values)
    return tuple(jnp.zeros((count,) + v.shape, v.dtype).at[k].set(1.0) for k, v in enumerate(values))


def _along(fn, primals: tuple, directions: tuple):
    """``(value, derivatives, aux)`` of ``fn(*primals) -> (value, aux)``, its derivatives along
    each of ``directions`` (tangents with a leading axis)."""
    return jax.vmap(lambda *t: jax.jvp(fn, primals, t, has_aux=True), out_axes=(None, 0, None))(*directions)


def _rotate(matrix: Array, vector: Array) -> Array:
    """``matrix @ vector`` over batch dims, as elementwise products, which XLA fuses with the
    derivatives around them (as an ``einsum`` it made the Jacobian slower; the residuals
    alone, in :mod:`rigjax.camera.model`, are faster with the ``einsum``)."""
    return sum(matrix[..., :, k] * vector[..., None, k] for k in range(3))


def _turns(v: Array) -> Array:
    """``(3, n, 3)``: ``e_k x v`` for the three axes."""
    return jnp.cross(jnp.eye(3, dtype=v.dtype)[:, None, :], v[None])


def _with_intrinsics(lens: Optics, intrinsics: tuple[str, ...], values: tuple[Array, ...]) -> Optics:
    return lens._replace(**dict(zip(intrinsics, values)))


class _Ray(NamedTuple):
    ray: Array  # (n, 3) world ray
    ok: Array  # (n,)
    local: Array  # (k + 3, n, 3): its derivatives along the camera's local coordinates


def _world_ray(projection, lens: Optics, xy: Array, intrinsics: tuple[str, ...]) -> _Ray:
    matrix = lens.world_from_cam
    if intrinsics:

        def camera_ray(*values):
            return img_to_camera_ray(projection, _with_intrinsics(lens, intrinsics, values), xy)

        values = tuple(getattr(lens, name) for name in intrinsics)
        ray_cam, d_cam, ok = _along(camera_ray, values, _one_at_a_time(values))
        by_intrinsics = [_rotate(matrix, d_cam)]
    else:  # a stage of orientations only: the camera-frame rays are constants
        (ray_cam, ok), by_intrinsics = img_to_camera_ray(projection, lens, xy), []
    local = jnp.concatenate([*by_intrinsics, _rotate(matrix, _turns(ray_cam))])
    return _Ray(_rotate(matrix, ray_cam), ok, local)


def _transfer(
    projection, lens: Optics, source: _Ray, observed: Array, angle: Array, d_angle: Array, intrinsics: tuple[str, ...]
):
    """The transfer residual of ``source``'s ray into the camera ``lens`` and its derivatives
    ``(k + 3, n, 2)`` along the source camera's coordinates and along this camera's.
    ``d_angle``: the angle's derivatives along the source camera's and this camera's, ``(2, k + 3, n)``."""
    transpose = jnp.swapaxes(lens.world_from_cam, -1, -2)
    q = _rotate(transpose, source.ray)  # the ray in this camera's frame

    def image(*values):  # q's components, then the intrinsics
        lens_moved = _with_intrinsics(lens, intrinsics, values[3:])
        return camera_ray_to_img(projection, lens_moved, jnp.stack(values[:3], axis=-1))

    primals = (*_components(q), *(getattr(lens, name) for name in intrinsics))
    predicted, d_image, ok_back = _along(image, primals, _one_at_a_time(primals))
    by_q, by_intrinsics = d_image[:3], d_image[3:]  # (3, n, 2), (k, n, 2)

    def through_q(dq):  # (k, n, 3) -> (k, n, 2)
        return sum(by_q[j] * dq[..., j, None] for j in range(3))

    ok = source.ok & ok_back
    value = transfer_or_angle(predicted, ok, observed, lens.focal, angle)
    # Where the transfer is undefined the residual is (focal * angle, 0).
    zero = jnp.zeros_like(d_angle[0])
    focal_moves = jnp.zeros_like(d_angle[1])
    if "focal" in intrinsics:
        focal_moves = focal_moves.at[intrinsics.index("focal")].set(angle)
    fallback = [jnp.stack([lens.focal * d + extra, zero], axis=-1) for d, extra in zip(d_angle, (0.0, focal_moves))]
    exact = [through_q(_rotate(transpose, source.local)), jnp.concatenate([by_intrinsics, through_q(-_turns(q))])]
    return value, [jnp.where(ok[:, None], e, f) for e, f in zip(exact, fallback)]


def pair_jacobian(
    camera_a: tuple[Array | int, Optics],
    camera_b: tuple[Array | int, Optics],
    xy_a: Array,
    xy_b: Array,
    kind: Array,
    canvas: Equirect,
    objective: str,
    lines: bool,
    intrinsics: tuple[str, ...],
) -> tuple[Array, Array]:
    """The objective's ``(n, 4)`` residuals of the points (:func:`rigjax.optimiser.residuals.objective_residuals`)
    and their derivatives ``(2, k + 3, n, 4)`` along the local coordinates of camera a, then b:
    the ``k`` ``intrinsics`` (a subset of :data:`INTRINSICS`, in its order), then the turn."""
    a, b = _world_ray(*camera_a, xy_a, intrinsics), _world_ray(*camera_b, xy_b, intrinsics)

    def terms_of(*components):  # ray a's, then ray b's
        return ray_terms(jnp.stack(components[:3], axis=-1), jnp.stack(components[3:], axis=-1), kind, canvas), None

    primals = (*_components(a.ray), *_components(b.ray))
    terms, d_terms, _ = _along(terms_of, primals, _one_at_a_time(primals))

    def local(by_rays):  # along the two rays (6, n, ...) -> along both cameras (2, 9, n, ...)
        def side(by_ray, ray: _Ray):
            trailing = (None,) * (by_ray.ndim - 2)
            return sum(by_ray[j][None] * ray.local[(..., j) + trailing] for j in range(3))

        return jnp.stack([side(by_rays[:3], a), side(by_rays[3:], b)])

    d_local = jax.tree_util.tree_map(local, d_terms)
    if objective == "transfer":
        r_b, (db_a, db_b) = _transfer(*camera_b, a, xy_b, terms.angle, d_local.angle, intrinsics)
        r_a, (da_b, da_a) = _transfer(*camera_a, b, xy_a, terms.angle, d_local.angle[::-1], intrinsics)
        transfer, d_transfer = (
            jnp.concatenate([r_b, r_a], axis=-1),
            jnp.stack([jnp.concatenate([db_a, da_a], axis=-1), jnp.concatenate([db_b, da_b], axis=-1)]),
        )
    else:
        transfer = d_transfer = None
    return (
        objective_residuals(transfer, terms, kind, objective, lines),
        objective_residuals(d_transfer, d_local, kind, objective, lines),
    )
