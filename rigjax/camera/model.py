"""A PanoTools camera as a JAX pytree, and the maps image pixel <-> world ray.

Convention:
    Image pixels ``img_xy`` are Hugin's: x right, y down, integer coordinates at pixel centres,
    ``(0, 0)`` the centre of the top-left pixel, so the image centre is ``(W/2 - 0.5, H/2 - 0.5)``
    of the *full, uncropped* image. The distortion centre is the image centre shifted by
    ``(d, e)`` pixels. World rays are unit vectors in the frame of :mod:`rigjax.camera.rotation`.

    image px --(-centre, -d/e)--> source px --(inverse radial)--> ideal px --(projection)-->
    camera ray --(world_from_cam)--> world ray, and back.

Every field of :class:`Camera` is an array; fields share a batch shape (``()`` for one camera,
``(n,)`` for a rig) and broadcast against the points' batch shape, so one function serves a
single camera, a per-point gather (``camera.take(image_idx)``), or ``jax.vmap`` over a rig.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from .distortion import distortion_scale, max_radius, undistort_radius
from .lenses import focal_length, ideal_to_ray, ray_to_ideal, safe_hypot
from .rotation import world_from_cam


class Camera(NamedTuple):
    """PanoTools camera parameters (Hugin ``i``-line letters in brackets).

    Attributes:
        projection: lens type code [``f``], see :class:`rigjax.Projection`.
        width, height: full image size in pixels [``w``, ``h``].
        hfov: horizontal field of view in degrees [``v``].
        a, b, c: radial polynomial coefficients [``a``, ``b``, ``c``]; ``b`` is the "lens K2".
        d, e: horizontal and vertical shift of the distortion centre, pixels [``d``, ``e``].
        yaw, pitch, roll: orientation in degrees [``y``, ``p``, ``r``].
    """

    projection: Int[Array, "*batch"]
    width: Float[Array, "*batch"]
    height: Float[Array, "*batch"]
    hfov: Float[Array, "*batch"]
    a: Float[Array, "*batch"]
    b: Float[Array, "*batch"]
    c: Float[Array, "*batch"]
    d: Float[Array, "*batch"]
    e: Float[Array, "*batch"]
    yaw: Float[Array, "*batch"]
    pitch: Float[Array, "*batch"]
    roll: Float[Array, "*batch"]

    @classmethod
    def create(
        cls,
        *,
        projection: ArrayLike,
        width: ArrayLike,
        height: ArrayLike,
        hfov: ArrayLike,
        a: ArrayLike = 0.0,
        b: ArrayLike = 0.0,
        c: ArrayLike = 0.0,
        d: ArrayLike = 0.0,
        e: ArrayLike = 0.0,
        yaw: ArrayLike = 0.0,
        pitch: ArrayLike = 0.0,
        roll: ArrayLike = 0.0,
        dtype=None,
        xp=jnp,
    ) -> Camera:
        """Build a camera (or a batch) from scalars or arrays, broadcast to one batch shape.
        ``xp=np`` builds host arrays (no device work: what a jitted call takes as data)."""
        floats = [width, height, hfov, a, b, c, d, e, yaw, pitch, roll]
        dtype = dtype or jnp.result_type(float)
        arrays = xp.broadcast_arrays(xp.asarray(projection, xp.int32), *(xp.asarray(v, dtype) for v in floats))
        return cls(*arrays)

    def take(self, index: ArrayLike) -> Camera:
        """Gather cameras by index along the batch axis (e.g. one camera per point)."""
        return jax.tree_util.tree_map(lambda field: field[index], self)

    @property
    def focal(self) -> Float[Array, "*batch"]:
        """Focal length in pixels (from ``projection``, ``width`` and ``hfov``)."""
        return focal_length(self.projection, self.width, self.hfov)

    @property
    def radius_scale(self) -> Float[Array, "*batch"]:
        """``R = min(width, height) / 2``, the radius that normalises the radial polynomial."""
        return jnp.minimum(self.width, self.height) / 2.0

    @property
    def world_from_cam(self) -> Float[Array, "*batch 3 3"]:
        return world_from_cam(self.yaw, self.pitch, self.roll)


class Optics(NamedTuple):
    """What every point of one camera shares, computed once per camera (:func:`optics`).

    The per-point maps below take these instead of a :class:`Camera`, so a rig's points do not
    recompute a rotation, a focal length or the polynomial's invertible range each.
    """

    focal: Float[Array, "*batch"]
    a: Float[Array, "*batch"]
    b: Float[Array, "*batch"]
    c: Float[Array, "*batch"]
    cx: Float[Array, "*batch"]  # distortion centre, image px
    cy: Float[Array, "*batch"]
    radius_scale: Float[Array, "*batch"]
    rho_max: Float[Array, "*batch"]  # end of the invertible range (no gradient)
    world_from_cam: Float[Array, "*batch 3 3"]

    def take(self, index: ArrayLike) -> Optics:
        return jax.tree_util.tree_map(lambda field: field[index], self)


def _finite(rho_max: Array) -> Array:
    # "No end" as the largest finite number: the same comparisons, and finite for the one-hot
    # products that spread a rig's optics over a rig's points (rigjax.optimiser.objective).
    return jnp.minimum(rho_max, jnp.finfo(rho_max.dtype).max)


def optics(camera: Camera) -> Optics:
    """A camera's shared quantities (any batch shape)."""
    return Optics(
        camera.focal,
        camera.a,
        camera.b,
        camera.c,
        camera.width / 2.0 - 0.5 + camera.d,
        camera.height / 2.0 - 0.5 + camera.e,
        camera.radius_scale,
        _finite(max_radius(camera.a, camera.b, camera.c)),
        camera.world_from_cam,
    )


def optics_at(cameras: Camera, index: ArrayLike, projection: int | None = None) -> tuple[Array | int, Optics]:
    """Per-point ``(lens type, optics)`` of a rig: the optics computed once per camera, then
    gathered by ``index``. ``projection``, the one lens type of every camera when the rig has one,
    is passed on as a Python int so that only its branch is traced."""
    lens = optics(cameras).take(index)
    return (cameras.projection[index] if projection is None else projection), lens


def padded_size(n: int) -> int:
    """Rows a batch of ``n`` points is padded to, so that batches of similar size share one
    compilation: the next power of two, at least 256."""
    return max(256, 1 << max(n - 1, 0).bit_length())


def map_points(fn, camera: Camera, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``fn(camera, points)`` (:func:`img_to_ray` or :func:`ray_to_img`) on an ``(n, k)`` array
    of points outside a jit region, padded to :func:`padded_size` rows; NumPy results of ``n`` rows."""
    points = np.asarray(points, float)
    padded = np.zeros((padded_size(len(points)), points.shape[1]))
    padded[: len(points)] = points
    out, valid = fn(camera, padded)
    return np.asarray(out)[: len(points)], np.asarray(valid)[: len(points)]


# Compiled, so that calls outside a jit region (matching, evaluation) reuse one executable per
# input shape: eagerly, the radius inversion's ``while_loop`` was compiled afresh on every call.
@jax.jit
def img_to_ray(camera: Camera, img_xy: Float[ArrayLike, "... 2"]) -> tuple[Float[Array, "... 3"], Bool[Array, ...]]:
    """Image pixel -> unit ray in the world frame (libpano13 ``SetInvMakeParams``).

    Returns ``(ray, valid)``. ``valid`` is False where the radial polynomial has no inverse or the
    lens does not map the point to a ray (see :mod:`rigjax.camera.lenses`); ``ray`` is finite there
    but meaningless.
    """
    return optics_img_to_ray(camera.projection, optics(camera), img_xy)


@jax.jit
def ray_to_img(camera: Camera, ray: Float[ArrayLike, "... 3"]) -> tuple[Float[Array, "... 2"], Bool[Array, ...]]:
    """World ray (any length > 0) -> image pixel (libpano13 ``SetMakeParams``).

    Returns ``(img_xy, valid)``. ``valid`` is False where the lens cannot see the ray (e.g. behind a
    rectilinear camera) or the ideal radius lies beyond the invertible range of the polynomial,
    where Hugin's own output is a ``1000 x`` scaled placeholder. Points that are valid may still lie
    outside the image frame.
    """
    return optics_ray_to_img(camera.projection, optics(camera), ray)


def _rotate(matrix: Array, vector: Array) -> Array:
    """``matrix @ vector`` over batch dims."""
    return jnp.einsum("...ij,...j->...i", matrix, vector)


def optics_img_to_ray(projection, lens: Optics, img_xy: Float[ArrayLike, "... 2"]):
    """:func:`img_to_ray` from a camera's :class:`Optics` and lens type."""
    ray_cam, ok = img_to_camera_ray(projection, lens, img_xy)
    return _rotate(lens.world_from_cam, ray_cam), ok


def optics_ray_to_img(projection, lens: Optics, ray: Float[ArrayLike, "... 3"]):
    """:func:`ray_to_img` from a camera's :class:`Optics` and lens type."""
    return camera_ray_to_img(projection, lens, _rotate(jnp.swapaxes(lens.world_from_cam, -1, -2), jnp.asarray(ray)))


def img_to_camera_ray(projection, lens: Optics, img_xy: Float[ArrayLike, "... 2"]):
    """Image pixel -> unit ray in the camera's own frame, and whether it is valid (the lens part
    of :func:`optics_img_to_ray`; ``lens.world_from_cam`` is not used)."""
    img_xy = jnp.asarray(img_xy)
    xs, ys = img_xy[..., 0] - lens.cx, img_xy[..., 1] - lens.cy
    rs, pos = safe_hypot(xs, ys)
    rho_src = rs / lens.radius_scale
    rho, radial_ok = undistort_radius(lens.a, lens.b, lens.c, rho_src, lens.rho_max)
    # rho / rho_src, which tends to 1 / P'(0) = 1 / d0 at the centre.
    d0 = distortion_scale(lens.a, lens.b, lens.c, 0.0)
    scale = jnp.where(pos, rho / jnp.where(pos, rho_src, 1.0), 1.0 / d0)
    ray_cam, proj_ok = ideal_to_ray(projection, lens.focal, scale * xs, scale * ys)
    return ray_cam, radial_ok & proj_ok


def camera_ray_to_img(projection, lens: Optics, ray_cam: Float[ArrayLike, "... 3"]):
    """Ray in the camera's own frame -> image pixel, and whether it is valid (the lens part of
    :func:`optics_ray_to_img`; ``lens.world_from_cam`` is not used)."""
    ideal, proj_ok = ray_to_ideal(projection, lens.focal, jnp.asarray(ray_cam))
    r_ideal, _ = safe_hypot(ideal[..., 0], ideal[..., 1])
    rho = r_ideal / lens.radius_scale
    radial_ok = rho < lens.rho_max
    scale = distortion_scale(lens.a, lens.b, lens.c, rho)
    img_xy = jnp.stack([scale * ideal[..., 0] + lens.cx, scale * ideal[..., 1] + lens.cy], axis=-1)
    return img_xy, proj_ok & radial_ok
