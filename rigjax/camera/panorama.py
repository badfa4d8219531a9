"""The equirectangular panorama canvas of a ``.pto`` ``p`` line: world ray <-> panorama pixel.

Convention (reference §2, §3): panorama pixels use Hugin's pixel-centre convention (x right,
y down, ``(0, 0)`` the centre of the top-left pixel). The canvas centre ``(W/2 - 0.5, H/2 - 0.5)``
is longitude = latitude = 0, the world's z axis. With ``D = W / hfov`` (pixels per radian):

    X = D * lon + W/2 - 0.5,   lon = atan2(ray_x, ray_z)             (+ = right, in [-pi, pi])
    Y = D * lat + H/2 - 0.5,   lat = atan2(ray_y, hypot(ray_x, ray_z)) (+ = below the horizon)

Any width, height and hfov are allowed (a 2:1, 360-degree canvas is the usual case); pixels
outside the canvas are still mapped.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .lenses import safe_hypot


class Equirect(NamedTuple):
    """An equirectangular panorama canvas: ``width``, ``height`` in pixels, ``hfov`` in degrees."""

    width: Float[Array, ""]
    height: Float[Array, ""]
    hfov: Float[Array, ""]

    @classmethod
    def create(cls, width: ArrayLike, height: ArrayLike, hfov: ArrayLike = 360.0, dtype=None, xp=jnp) -> Equirect:
        """``xp=np`` builds host arrays, as :meth:`rigjax.Camera.create`."""
        dtype = dtype or jnp.result_type(float)
        return cls(*(xp.asarray(v, dtype) for v in (width, height, hfov)))

    @property
    def pixels_per_radian(self) -> Float[Array, ""]:
        return self.width / jnp.deg2rad(self.hfov)


def ray_to_pano(canvas: Equirect, ray: Float[ArrayLike, "... 3"]) -> Float[Array, "... 2"]:
    """World ray (any length > 0) -> panorama pixel."""
    ray = jnp.asarray(ray)
    horizontal, _ = safe_hypot(ray[..., 0], ray[..., 2])
    lon = jnp.arctan2(ray[..., 0], ray[..., 2])
    lat = jnp.arctan2(ray[..., 1], horizontal)
    k = canvas.pixels_per_radian
    return jnp.stack([k * lon + canvas.width / 2.0 - 0.5, k * lat + canvas.height / 2.0 - 0.5], axis=-1)


def pano_to_ray(canvas: Equirect, pano_xy: Float[ArrayLike, "... 2"]) -> Float[Array, "... 3"]:
    """Panorama pixel -> unit world ray."""
    pano_xy = jnp.asarray(pano_xy)
    k = canvas.pixels_per_radian
    lon = (pano_xy[..., 0] - (canvas.width / 2.0 - 0.5)) / k
    lat = (pano_xy[..., 1] - (canvas.height / 2.0 - 0.5)) / k
    clat = jnp.cos(lat)
    return jnp.stack([clat * jnp.sin(lon), jnp.sin(lat), clat * jnp.cos(lon)], axis=-1)
