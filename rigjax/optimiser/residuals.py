"""Control-point residuals: the transfer error, libpano13's spherical distance, line points, and
robust reweighting.

Convention: control point ``k`` joins ``xy_a[k]`` in image ``image_a[k]`` and ``xy_b[k]`` in image
``image_b[k]`` (Hugin pixel coordinates). Residuals are in pixels:

* **transfer** (the literature's): ``xy_a`` goes through camera a to its ray and through camera b
  back into image b; the residual is the 2-D difference to ``xy_b``; and the same from b to a.
  Four numbers per point, ``(n, 4)``.
* **sphere** (libpano13's ``distSphere``, reference §4.1): both points to rays; the distance is the
  angle between them times ``K = W_p / hfov_p`` (panorama pixels per radian), with the components
  ``(K dlon sin(colat), K dcolat)`` that Hugin's second strategy minimises.
* **line points** (``t1``/``t2``): a vertical line keeps one panorama column (``X0 - X1``, wrapped
  on a 360-degree canvas); a horizontal line keeps one row (``Y0 - Y1``).
* **straight lines** (``t3`` and up, libpano13's ``distsqLine``): all control points of one ``t``
  lie on one straight line of the panorama. Each point is paired with the first other point of
  its ``t`` (in file order); of the four panorama points, the two farthest apart define a line and
  the residual is the signed distance of the other two from it, ``(d0, d1)`` panorama px.

Where a transform is undefined (beyond the distortion's invertible range, behind a lens), the
transfer residual falls back to ``f_b * angle`` along x so that the cost stays continuous and
still penalises the point.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from ..camera.lenses import safe_hypot
from ..camera.model import Camera, Optics, optics_at, optics_img_to_ray, optics_ray_to_img
from ..camera.panorama import Equirect, ray_to_pano

NORMAL, VERTICAL_LINE, HORIZONTAL_LINE = 0, 1, 2
FIRST_STRAIGHT_LINE = 3  # t3, t4, ...: one straight line each


class PointArrays(NamedTuple):
    """Control points as JAX arrays (the subset of :class:`rigjax.ControlPoints` a solve needs)."""

    image_a: Int[Array, " n"]
    image_b: Int[Array, " n"]
    xy_a: Float[Array, "n 2"]
    xy_b: Float[Array, "n 2"]
    kind: Int[Array, " n"]


def ray_angle(u: Array, v: Array) -> Array:
    """Angle between unit vectors, accurate near 0 and pi, with a finite gradient at 0."""
    cross = jnp.cross(u, v)
    sin, _ = safe_hypot(safe_hypot(cross[..., 0], cross[..., 1])[0], cross[..., 2])
    return jnp.arctan2(sin, jnp.sum(u * v, axis=-1))


class PointResiduals(NamedTuple):
    """Every residual of every control point, from one pass through the cameras."""

    transfer: Float[Array, "n 4"]  # px: image b predicted from a minus observed, then a from b
    sphere: Float[Array, " n"]  # libpano13's distance, panorama px
    sphere_components: Float[Array, "n 2"]  # (K dlon sin(colat), K dcolat), panorama px
    line: Float[Array, " n"]  # X0 - X1 (t1) or Y0 - Y1 (t2), panorama px; 0 for other kinds


def point_residuals(
    cameras: Camera, points: PointArrays, canvas: Equirect, projection: int | None = None
) -> PointResiduals:
    """All residuals of the control points (see the module docstring for their definitions).

    ``projection``: the lens type of every camera when the rig has one (only its branch is traced).
    """
    camera_a, camera_b = (optics_at(cameras, index, projection) for index in (points.image_a, points.image_b))
    return pair_residuals(camera_a, camera_b, points.xy_a, points.xy_b, points.kind, canvas)


def pair_residuals(
    camera_a: tuple[Array | int, Optics],
    camera_b: tuple[Array | int, Optics],
    xy_a: Array,
    xy_b: Array,
    kind: Array,
    canvas: Equirect,
) -> PointResiduals:
    """:func:`point_residuals` from each point's two cameras as ``(lens type, optics)``."""
    ray_a, ok_a = optics_img_to_ray(*camera_a, xy_a)
    ray_b, ok_b = optics_img_to_ray(*camera_b, xy_b)
    terms = ray_terms(ray_a, ray_b, kind, canvas)
    r_b = transfer(camera_b, ray_a, ok_a, xy_b, terms.angle)
    r_a = transfer(camera_a, ray_b, ok_b, xy_a, terms.angle)
    return PointResiduals(jnp.concatenate([r_b, r_a], axis=-1), terms.sphere, terms.sphere_components, terms.line)


def transfer(camera: tuple[Array | int, Optics], ray: Array, ok: Array, observed: Array, angle: Array) -> Array:
    """``(n, 2)`` px: a world ray seen by ``camera``, minus the observed pixel (``ok``: the ray is
    defined)."""
    predicted, ok_back = optics_ray_to_img(*camera, ray)
    return transfer_or_angle(predicted, ok & ok_back, observed, camera[1].focal, angle)


def transfer_or_angle(predicted: Array, ok: Array, observed: Array, focal: Array, angle: Array) -> Array:
    """``predicted - observed`` where the transfer is defined; elsewhere the angle between the two
    rays in the target camera's pixels, along x, which keeps the cost continuous and the point
    penalised."""
    angular = jnp.stack([focal * angle, jnp.zeros_like(angle)], axis=-1)
    return jnp.where(ok[..., None], jnp.where(ok[..., None], predicted, observed) - observed, angular)


class RayTerms(NamedTuple):
    """The residuals that depend on a point's two world rays only."""

    angle: Float[Array, " n"]  # radians between the rays
    sphere: Float[Array, " n"]
    sphere_components: Float[Array, "n 2"]
    line: Float[Array, " n"]


def ray_terms(ray_a: Array, ray_b: Array, kind: Array, canvas: Equirect) -> RayTerms:
    """libpano13's spherical distance and its components, and the line points' residual."""
    angle = ray_angle(ray_a, ray_b)
    k = canvas.pixels_per_radian

    def lon_colat(ray):
        horizontal, _ = safe_hypot(ray[..., 0], ray[..., 2])
        return jnp.arctan2(ray[..., 0], ray[..., 2]), jnp.arctan2(ray[..., 1], horizontal) + jnp.pi / 2.0

    lon_a, colat_a = lon_colat(ray_a)
    lon_b, colat_b = lon_colat(ray_b)
    dlon = jnp.remainder(lon_a - lon_b + jnp.pi, 2.0 * jnp.pi) - jnp.pi
    comp = jnp.stack([k * dlon * jnp.sin((colat_a + colat_b) / 2.0), k * (colat_a - colat_b)], axis=-1)

    # Line points, in the panorama's pixels (a 360-degree canvas wraps).
    pano_a, pano_b = ray_to_pano(canvas, ray_a), ray_to_pano(canvas, ray_b)
    dx = pano_a[..., 0] - pano_b[..., 0]
    full_circle = k * 2.0 * jnp.pi
    wraps = jnp.abs(canvas.hfov - 360.0) < 1e-9
    dx = jnp.where(wraps, jnp.remainder(dx + full_circle / 2.0, full_circle) - full_circle / 2.0, dx)
    dy = pano_a[..., 1] - pano_b[..., 1]
    line = jnp.select([kind == VERTICAL_LINE, kind == HORIZONTAL_LINE], [dx, dy], jnp.zeros_like(dx))
    return RayTerms(angle, k * angle, comp, line)


def objective_residuals(
    transfer: Array | None, terms: RayTerms | PointResiduals, kind: Array, objective: str, lines: bool
) -> Array:
    """The four numbers per point that an objective minimises: the transfer error, libpano13's
    spherical components (``"sphere"``) or its distance (``"distance"``), zero-padded; line points
    (``lines``) have their line residual instead. Linear in ``transfer`` and ``terms``, so it maps
    their derivatives too (extra leading axes allowed)."""
    zero = jnp.zeros_like(terms.sphere)
    if objective == "transfer":
        pair = transfer
    elif objective == "sphere":
        pair = jnp.stack([terms.sphere_components[..., 0], terms.sphere_components[..., 1], zero, zero], axis=-1)
    elif objective == "distance":
        pair = jnp.stack([terms.sphere, zero, zero, zero], axis=-1)
    else:
        raise ValueError(f"unknown point objective {objective!r}")
    if not lines:
        return pair
    return jnp.where((kind == NORMAL)[..., None], pair, jnp.stack([terms.line, zero, zero, zero], axis=-1))


ROBUST_LOSSES = (None, "huber", "cauchy")


def robust_scale(norm: Array, kind: str | None, scale: float | Array) -> Array:
    """Factor turning residuals of norm ``s`` into ones whose squared norm is ``rho(s^2)``.

    LM then minimises ``sum rho`` directly: Huber ``rho = s^2`` for ``s <= c`` and
    ``2 c s - c^2`` beyond; Cauchy ``rho = c^2 log(1 + s^2 / c^2)``. ``c`` is ``scale`` in px.
    ``kind`` is static, one compilation per loss: as data (selects, or a switch) it made every warm
    solve slower, robust or not (docs/design/optimiser.md). A ``scale`` of 0 switches the loss off
    (least squares, factor 1) in a program compiled for it: pruning's rounds share one program.
    """
    if kind is None:
        return jnp.ones_like(norm)
    on = scale > 0.0
    scale = jnp.where(on, scale, 1.0)
    safe = jnp.where(norm > 0.0, norm, 1.0)
    if kind == "huber":
        rho = jnp.where(norm <= scale, norm * norm, 2.0 * scale * norm - scale * scale)
    elif kind == "cauchy":
        rho = scale * scale * jnp.log1p((norm / scale) ** 2)
    else:
        raise ValueError(f"robust loss must be one of {ROBUST_LOSSES}, got {kind!r}")
    return jnp.where(on & (norm > 0.0), jnp.sqrt(rho) / safe, 1.0)


def rms(values: Array, mask: Array | None = None, per_point: int = 1) -> Array:
    """Root mean square over the points in ``mask`` of ``values`` (``(n,)`` or ``(n, m)``).

    ``per_point`` is how many pixels' worth of error one point holds (2 for a 2-D residual):
    the RMS is per pixel coordinate pair, i.e. ``sqrt(sum |r|^2 / (n * m / per_point))``.
    """
    values = values.reshape(values.shape[0], -1)
    if mask is None:
        mask = jnp.ones(values.shape[0], bool)
    count = jnp.maximum(jnp.sum(mask), 1) * values.shape[1] / per_point
    return jnp.sqrt(jnp.sum(jnp.where(mask[:, None], values**2, 0.0)) / count)


class LineGroups(NamedTuple):
    """Straight-line (``t3``+) control points, each with its partner: four image points per row,
    ``(own a, own b, partner a, partner b)``."""

    image: Int[Array, "n 4"]
    xy: Float[Array, "n 4 2"]


# For each of the six pairs of the four points (in libpano13's search order), the other two in
# ascending order.
_PAIRS = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))
_OTHERS = tuple(tuple(k for k in range(4) if k not in pair) for pair in _PAIRS)


def straight_line_residuals(
    cameras: Camera, groups: LineGroups, canvas: Equirect, projection: int | None = None
) -> Float[Array, "n 2"]:
    """``(d0, d1)`` panorama px of every straight-line row (see the module docstring)."""
    ray, _ = optics_img_to_ray(*optics_at(cameras, groups.image, projection), groups.xy)
    pano = ray_to_pano(canvas, ray)  # (n, 4, 2)
    pairs, others = jnp.asarray(_PAIRS), jnp.asarray(_OTHERS)
    squared = jnp.sum((pano[:, pairs[:, 0]] - pano[:, pairs[:, 1]]) ** 2, axis=-1)  # (n, 6)
    best = jnp.argmax(squared, axis=-1)  # the first of equal maxima, as libpano13
    ends = jnp.take_along_axis(pano, pairs[best][:, :, None], axis=1)  # (n, 2, 2)
    rest = jnp.take_along_axis(pano, others[best][:, :, None], axis=1)
    (x0, y0), (x1, y1) = ends[:, 0].T, ends[:, 1].T
    a, b = y1 - y0, x0 - x1
    c = y0 * (x1 - x0) - x0 * (y1 - y0)
    length, defined = safe_hypot(a, b)
    distance = (a[:, None] * rest[..., 0] + b[:, None] * rest[..., 1] + c[:, None]) / jnp.where(defined, length, 1.0)[
        :, None
    ]
    return jnp.where(defined[:, None], distance, 0.0)  # four coincident points: no line, no residual
