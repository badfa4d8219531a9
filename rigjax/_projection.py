"""Lens projections of the PanoTools model: ideal image plane <-> ray in the camera frame.

Convention:
    Ideal coordinates ``(x, y)`` are pixels of the *undistorted* image, relative to the distortion
    centre, x right, y down. The camera frame is x right, y down, z forward (the optical axis).
    ``theta`` is the angle between a ray and the optical axis. The focal length ``f`` (pixels) comes
    from the hfov ``v`` and the full image width ``W`` (reference §2):

    ==  =====================  ====================  ======================
    f   projection             focal length          radius r(theta)
    ==  =====================  ====================  ======================
    0   rectilinear            W / (2 tan(v/2))      f tan(theta)
    2   circular fisheye       W / v                 f theta
    3   full-frame fisheye     W / v                 f theta
    4   equirectangular        W / v                 lon = x / f, lat = y / f
    8   orthographic           W / (2 sin(v/2))      f sin(theta)
    10  stereographic          W / (4 tan(v/4))      2 f tan(theta / 2)
    21  equisolid              W / (4 sin(v/4))      2 f sin(theta / 2)
    ==  =====================  ====================  ======================

Validity: a point is invalid where the projection is not one-to-one: rectilinear rays at or
behind 90 degrees, orthographic rays beyond 90 degrees (and image radii beyond ``f``), equisolid
image radii beyond ``2 f``, equidistant image radii beyond ``pi f``, equirectangular latitudes
beyond 90 degrees.
"""

from __future__ import annotations

from enum import IntEnum

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float


class Projection(IntEnum):
    """Image projection codes of a ``.pto`` ``i`` line (``f`` token)."""

    RECTILINEAR = 0
    CIRCULAR_FISHEYE = 2
    FULL_FRAME_FISHEYE = 3
    EQUIRECTANGULAR = 4
    ORTHOGRAPHIC = 8
    STEREOGRAPHIC = 10
    EQUISOLID = 21


SUPPORTED_PROJECTIONS: tuple[int, ...] = tuple(int(p) for p in Projection)

_RECT, _CIRC, _FF, _EQR, _ORTHO, _STEREO, _EQSOLID = SUPPORTED_PROJECTIONS


def _is_equidistant(proj):
    return (proj == _CIRC) | (proj == _FF)


def focal_length(projection: ArrayLike, width: ArrayLike, hfov_deg: ArrayLike) -> Float[Array, "..."]:
    """Focal length in pixels from the projection code, full image width and hfov (degrees)."""
    v = jnp.deg2rad(jnp.asarray(hfov_deg))
    w = jnp.asarray(width, v.dtype)
    proj = jnp.asarray(projection)
    return jnp.select(
        [proj == _RECT, proj == _ORTHO, proj == _STEREO, proj == _EQSOLID],
        [
            w / (2.0 * jnp.tan(v / 2.0)),
            w / (2.0 * jnp.sin(v / 2.0)),
            w / (4.0 * jnp.tan(v / 4.0)),
            w / (4.0 * jnp.sin(v / 4.0)),
        ],
        w / v,
    )


def safe_hypot(x: Array, y: Array) -> tuple[Array, Array]:
    """``(hypot(x, y), hypot > 0)`` with a finite gradient at the origin (double-``where``)."""
    r2 = x * x + y * y
    pos = r2 > 0.0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, r2, 1.0)), 0.0), pos


def ideal_to_ray(
    projection: ArrayLike, focal: ArrayLike, x: ArrayLike, y: ArrayLike
) -> tuple[Float[Array, "... 3"], Bool[Array, "..."]]:
    """Ideal image coordinates (px, from the distortion centre) -> unit ray in the camera frame."""
    proj = jnp.asarray(projection)
    x, y = jnp.asarray(x), jnp.asarray(y)
    r, pos = safe_hypot(x, y)
    t = r / focal
    # theta(r) for the radially symmetric lenses. Outside a branch's domain its argument is
    # replaced by 0 (double-where), so that neither its value nor, in reverse mode, the zero
    # cotangent times an infinite derivative can poison the selected branch.
    t_ortho = jnp.where(t <= 1.0, t, 0.0)
    t_eqsolid = jnp.where(t <= 2.0, t, 0.0)
    theta = jnp.select(
        [proj == _RECT, proj == _ORTHO, proj == _STEREO, proj == _EQSOLID],
        [jnp.arctan(t), jnp.arcsin(t_ortho), 2.0 * jnp.arctan(t / 2.0), 2.0 * jnp.arcsin(t_eqsolid / 2.0)],
        t,
    )
    # sin(theta) / r, which tends to 1/f at the axis for every projection.
    sin_over_r = jnp.where(pos, jnp.sin(theta) / jnp.where(pos, r, 1.0), 1.0 / focal)
    radial = jnp.stack([sin_over_r * x, sin_over_r * y, jnp.cos(theta)], axis=-1)
    radial_ok = jnp.select(
        [proj == _ORTHO, proj == _EQSOLID, _is_equidistant(proj)],
        [t <= 1.0, t <= 2.0, theta <= jnp.pi],
        jnp.ones_like(t, bool),
    )

    lon, lat = x / focal, y / focal
    clat = jnp.cos(lat)
    equirect = jnp.stack([clat * jnp.sin(lon), jnp.sin(lat), clat * jnp.cos(lon)], axis=-1)
    equirect_ok = jnp.abs(lat) <= jnp.pi / 2.0

    is_eqr = proj == _EQR
    ray = jnp.where(is_eqr[..., None], equirect, radial)
    valid = jnp.where(is_eqr, equirect_ok, radial_ok)
    return ray, valid


def ray_to_ideal(
    projection: ArrayLike, focal: ArrayLike, ray: Float[ArrayLike, "... 3"]
) -> tuple[Float[Array, "... 2"], Bool[Array, "..."]]:
    """Ray in the camera frame (any length > 0) -> ideal image coordinates (px, from the centre)."""
    proj = jnp.asarray(projection)
    ray = jnp.asarray(ray)
    ux, uy, uz = ray[..., 0], ray[..., 1], ray[..., 2]
    s, pos = safe_hypot(ux, uy)
    theta = jnp.arctan2(s, uz)
    # r(theta) / f for the radially symmetric lenses; the tangents get a safe argument (0) at and
    # beyond their poles, where the ray is invalid anyway (double-where, as above).
    theta_rect = jnp.where(theta < jnp.pi / 2.0, theta, 0.0)
    theta_stereo = jnp.where(theta < jnp.pi, theta, 0.0)
    r_over_f = jnp.select(
        [proj == _RECT, proj == _ORTHO, proj == _STEREO, proj == _EQSOLID],
        [jnp.tan(theta_rect), jnp.sin(theta), 2.0 * jnp.tan(theta_stereo / 2.0), 2.0 * jnp.sin(theta / 2.0)],
        theta,
    )
    # r / hypot(ux, uy); at the axis r -> f * theta and hypot -> |u| sin(theta).
    norm = jnp.sqrt(s * s + uz * uz)
    k = jnp.where(pos, focal * r_over_f / jnp.where(pos, s, 1.0), focal / jnp.where(norm > 0, norm, 1.0))
    radial = jnp.stack([k * ux, k * uy], axis=-1)
    radial_ok = jnp.select(
        [proj == _RECT, proj == _ORTHO, proj == _STEREO],
        [theta < jnp.pi / 2.0, theta <= jnp.pi / 2.0, theta < jnp.pi],
        jnp.ones_like(theta, bool),
    )

    lon = jnp.arctan2(ux, uz)
    lat = jnp.arctan2(uy, safe_hypot(ux, uz)[0])
    equirect = jnp.stack([focal * lon, focal * lat], axis=-1)

    is_eqr = proj == _EQR
    xy = jnp.where(is_eqr[..., None], equirect, radial)
    # Straight behind the lens (theta -> pi) the image direction is undefined; within a few ulps
    # of it the direction is round-off, so such rays are flagged rather than mapped at random.
    eps = jnp.finfo(s.dtype).eps
    radial_ok = radial_ok & ((s > 64.0 * eps * norm) | (uz > 0.0))
    valid = jnp.where(is_eqr, jnp.ones_like(radial_ok), radial_ok) & (norm > 0)
    return xy, valid
