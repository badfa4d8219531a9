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

import math
from collections.abc import Callable
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from .projections import SUPPORTED_PROJECTIONS

_RECT, _CIRC, _FF, _EQR, _ORTHO, _STEREO, _EQSOLID = SUPPORTED_PROJECTIONS


def focal_length(projection: ArrayLike, width: ArrayLike, hfov_deg: ArrayLike) -> Float[Array, ...]:
    """Focal length in pixels from the projection code, full image width and hfov (degrees)."""
    v = jnp.deg2rad(jnp.asarray(hfov_deg))
    w = jnp.asarray(width, v.dtype)
    variants = {
        _RECT: lambda: w / (2.0 * jnp.tan(v / 2.0)),
        _ORTHO: lambda: w / (2.0 * jnp.sin(v / 2.0)),
        _STEREO: lambda: w / (4.0 * jnp.tan(v / 4.0)),
        _EQSOLID: lambda: w / (4.0 * jnp.sin(v / 4.0)),
    }
    if isinstance(projection, (int, np.integer)):  # static lens type: only its formula
        return variants.get(int(projection), lambda: w / v)()
    proj = jnp.asarray(projection)
    return jnp.select([proj == code for code in variants], [f() for f in variants.values()], w / v)


def hfov_from_focal(projection: int, width: float, focal: float) -> float:
    """The hfov (degrees) of an image ``width`` pixels wide whose lens has focal length ``focal``
    pixels: :func:`focal_length`'s inverse. Raises ``ValueError`` where no hfov gives that focal
    length (an orthographic or equisolid image wider than its lens's whole field)."""
    ratio = float(width) / float(focal)
    laws = {
        _RECT: lambda: 2.0 * math.atan(ratio / 2.0),
        _ORTHO: lambda: 2.0 * math.asin(ratio / 2.0),
        _STEREO: lambda: 4.0 * math.atan(ratio / 4.0),
        _EQSOLID: lambda: 4.0 * math.asin(ratio / 4.0),
    }
    try:
        return math.degrees(laws.get(int(projection), lambda: ratio)())
    except ValueError:
        raise ValueError(f"no f{projection} lens of focal length {focal:g} px spans {width:g} px") from None


def safe_hypot(x: Array, y: Array) -> tuple[Array, Array]:
    """``(hypot(x, y), hypot > 0)`` with a finite gradient at the origin (double-``where``)."""
    r2 = x * x + y * y
    pos = r2 > 0.0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, r2, 1.0)), 0.0), pos


# Branch order for the dispatch below; circular and full-frame fisheyes share the equidistant one.
_BRANCH_OF_CODE = np.full(32, 1, np.int32)
for _branch, _codes in enumerate([(_RECT,), (_CIRC, _FF), (_EQR,), (_ORTHO,), (_STEREO,), (_EQSOLID,)]):
    _BRANCH_OF_CODE[list(_codes)] = _branch


def _dispatch(projection, branches, *operands):
    """Evaluate ``branches[lens](*operands)`` for each point's lens type.

    A lens type known at trace time (a Python or numpy integer) traces only its branch. One traced
    lens type for all points (a single camera, or inside ``jax.vmap`` over cameras, which JAX
    batches itself) runs only that branch with ``lax.switch``; an array of lens types (one camera
    per point) evaluates every branch and selects. Branches must stay finite, value and gradient,
    on inputs outside their domain, because ``select`` evaluates them there too.
    """
    if isinstance(projection, (int, np.integer)) or (isinstance(projection, np.ndarray) and projection.ndim == 0):
        return branches[_BRANCH_OF_CODE[int(projection)]](*operands)
    index = jnp.asarray(_BRANCH_OF_CODE)[jnp.clip(projection, 0, len(_BRANCH_OF_CODE) - 1)]
    if jnp.ndim(index) == 0:
        return jax.lax.switch(index, branches, *operands)
    outputs = [branch(*operands) for branch in branches]

    def select(*values):
        conditions = [jnp.expand_dims(index == k, tuple(range(index.ndim, values[0].ndim))) for k in range(len(values))]
        return jnp.select(conditions, values, jnp.zeros((), values[0].dtype))  # keeps bool masks bool

    return jax.tree_util.tree_map(select, *outputs)


# ---------------------------------------------------------------------------------------------
# The radially symmetric lenses as two laws: theta from t = r / f, and r / f from theta, each with
# where it is valid. Outside its domain a law's argument becomes 0 (double-where): under
# ``select`` no NaN value or gradient leaks from it into the branch that is selected.
def _everywhere(x):
    return jnp.ones(jnp.shape(x), bool)


class _Law(NamedTuple):
    theta_of: Callable  # t -> (theta, valid)
    radius_of: Callable  # theta -> (t, valid)


def _rect_theta(t):
    return jnp.arctan(t), _everywhere(t)


def _rect_radius(theta):
    ok = theta < jnp.pi / 2.0
    return jnp.tan(jnp.where(ok, theta, 0.0)), ok


def _ortho_theta(t):
    ok = t <= 1.0
    return jnp.arcsin(jnp.where(ok, t, 0.0)), ok


def _stereo_radius(theta):
    ok = theta < jnp.pi
    return 2.0 * jnp.tan(jnp.where(ok, theta, 0.0) / 2.0), ok


def _equisolid_theta(t):
    ok = t <= 2.0
    return 2.0 * jnp.arcsin(jnp.where(ok, t, 0.0) / 2.0), ok


_RECT_LAW = _Law(_rect_theta, _rect_radius)
_EQUIDISTANT_LAW = _Law(lambda t: (t, t <= jnp.pi), lambda theta: (theta, _everywhere(theta)))
_ORTHO_LAW = _Law(_ortho_theta, lambda theta: (jnp.sin(theta), theta <= jnp.pi / 2.0))
_STEREO_LAW = _Law(lambda t: (2.0 * jnp.arctan(t / 2.0), _everywhere(t)), _stereo_radius)
_EQUISOLID_LAW = _Law(_equisolid_theta, lambda theta: (2.0 * jnp.sin(theta / 2.0), _everywhere(theta)))


# ideal image plane -> ray. Each branch: (focal, x, y) -> (ray, valid).
def _radial_ray(law: _Law, focal, x, y):
    r, pos = safe_hypot(x, y)
    theta, valid = law.theta_of(r / focal)
    # sin(theta) / r, which tends to 1/f at the axis for every projection.
    sin_over_r = jnp.where(pos, jnp.sin(theta) / jnp.where(pos, r, 1.0), 1.0 / focal)
    return jnp.stack([sin_over_r * x, sin_over_r * y, jnp.cos(theta)], axis=-1), valid


def _equirect_ray(focal, x, y):
    lon, lat = x / focal, y / focal
    clat = jnp.cos(lat)
    return jnp.stack([clat * jnp.sin(lon), jnp.sin(lat), clat * jnp.cos(lon)], axis=-1), jnp.abs(lat) <= jnp.pi / 2.0


_IDEAL_TO_RAY = (
    partial(_radial_ray, _RECT_LAW),
    partial(_radial_ray, _EQUIDISTANT_LAW),
    _equirect_ray,
    partial(_radial_ray, _ORTHO_LAW),
    partial(_radial_ray, _STEREO_LAW),
    partial(_radial_ray, _EQUISOLID_LAW),
)


def ideal_to_ray(
    projection: ArrayLike, focal: ArrayLike, x: ArrayLike, y: ArrayLike
) -> tuple[Float[Array, "... 3"], Bool[Array, ...]]:
    """Ideal image coordinates (px, from the distortion centre) -> unit ray in the camera frame."""
    x, y = jnp.broadcast_arrays(jnp.asarray(x), jnp.asarray(y))
    focal = jnp.asarray(focal, x.dtype)
    return _dispatch(projection, _IDEAL_TO_RAY, focal, x, y)


# ---------------------------------------------------------------------------------------------
# ray in the camera frame -> ideal image plane. Each branch: (focal, ray) -> (xy, valid).
def _law_xy(law: _Law, focal, ray):
    ux, uy, uz = ray[..., 0], ray[..., 1], ray[..., 2]
    s, pos = safe_hypot(ux, uy)
    norm = jnp.sqrt(s * s + uz * uz)
    r_over_f, valid = law.radius_of(jnp.arctan2(s, uz))
    # Straight behind the lens (theta -> pi) the image direction is undefined; within a few ulps
    # of it the direction is round-off, so such rays are flagged rather than mapped at random.
    defined = ((s > 64.0 * jnp.finfo(s.dtype).eps * norm) | (uz > 0.0)) & (norm > 0.0)
    # r / hypot(ux, uy); at the axis r -> f * theta and hypot -> |u| sin(theta).
    k = jnp.where(pos, focal * r_over_f / jnp.where(pos, s, 1.0), focal / jnp.where(norm > 0, norm, 1.0))
    return jnp.stack([k * ux, k * uy], axis=-1), valid & defined


def _equirect_xy(focal, ray):
    ux, uy, uz = ray[..., 0], ray[..., 1], ray[..., 2]
    lon = jnp.arctan2(ux, uz)
    lat = jnp.arctan2(uy, safe_hypot(ux, uz)[0])
    norm = jnp.sqrt(ux * ux + uy * uy + uz * uz)
    return jnp.stack([focal * lon, focal * lat], axis=-1), norm > 0.0


_RAY_TO_IDEAL = (
    partial(_law_xy, _RECT_LAW),
    partial(_law_xy, _EQUIDISTANT_LAW),
    _equirect_xy,
    partial(_law_xy, _ORTHO_LAW),
    partial(_law_xy, _STEREO_LAW),
    partial(_law_xy, _EQUISOLID_LAW),
)


def ray_to_ideal(
    projection: ArrayLike, focal: ArrayLike, ray: Float[ArrayLike, "... 3"]
) -> tuple[Float[Array, "... 2"], Bool[Array, ...]]:
    """Ray in the camera frame (any length > 0) -> ideal image coordinates (px, from the centre)."""
    ray = jnp.asarray(ray)
    focal = jnp.asarray(focal, ray.dtype)
    return _dispatch(projection, _RAY_TO_IDEAL, focal, ray)
