"""Yaw, pitch and roll of the PanoTools model as rotation matrices.

Convention (reference §3): angles in degrees; the world frame at ``y = p = r = 0`` is the camera
frame (x right, y down, z forward). A camera ray ``u`` goes to the world as

    world_from_cam = Ry(yaw) @ Rx(pitch) @ Rz(roll)

with right-handed ``Rx, Ry, Rz``: +yaw turns the camera right, +pitch tilts the optical axis up,
+roll turns the image clockwise as seen from behind the camera. Angles are not canonicalised.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float


def world_from_cam(yaw_deg: ArrayLike, pitch_deg: ArrayLike, roll_deg: ArrayLike) -> Float[Array, "... 3 3"]:
    """Rotation taking camera-frame rays to the world frame; batch dims broadcast."""
    y, p, r = (jnp.deg2rad(jnp.asarray(v)) for v in (yaw_deg, pitch_deg, roll_deg))
    y, p, r = jnp.broadcast_arrays(y, p, r)
    cy, sy, cp, sp, cr, sr = jnp.cos(y), jnp.sin(y), jnp.cos(p), jnp.sin(p), jnp.cos(r), jnp.sin(r)
    # Ry(y) @ Rx(p) @ Rz(r), multiplied out.
    rows = [
        [cy * cr + sy * sp * sr, -cy * sr + sy * sp * cr, sy * cp],
        [cp * sr, cp * cr, -sp],
        [-sy * cr + cy * sp * sr, sy * sr + cy * sp * cr, cy * cp],
    ]
    return jnp.stack([jnp.stack(row, axis=-1) for row in rows], axis=-2)


def ypr_from_world_from_cam(matrix: Float[ArrayLike, "... 3 3"]) -> Float[Array, "... 3"]:
    """Yaw, pitch, roll in degrees of a rotation (the inverse of :func:`world_from_cam`).

    Pitch lies in [-90, 90]. Looking straight up or down (|pitch| = 90) only ``yaw - roll``
    (up) or ``yaw + roll`` (down) is defined; roll is then 0.
    """
    m = jnp.asarray(matrix)
    pitch = jnp.arcsin(jnp.clip(-m[..., 1, 2], -1.0, 1.0))
    cos_pitch = jnp.hypot(m[..., 1, 0], m[..., 1, 1])
    regular = cos_pitch > 1e-9
    yaw = jnp.where(regular, jnp.arctan2(m[..., 0, 2], m[..., 2, 2]), jnp.arctan2(-m[..., 2, 0], m[..., 0, 0]))
    roll = jnp.where(regular, jnp.arctan2(m[..., 1, 0], m[..., 1, 1]), 0.0)
    return jnp.rad2deg(jnp.stack([yaw, pitch, roll], axis=-1))
