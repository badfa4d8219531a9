"""Remap tables between images and an equirectangular canvas, computed in JAX, for OpenCV.

Convention: a table ``maps`` of shape ``(H, W, 2)`` float32 holds, for every *destination* pixel
``(x, y)`` (Hugin's pixel centres, ``(0, 0)`` the top-left pixel's centre), the *source* pixel to
sample, in the same convention; this is what ``cv2.remap(src, maps[..., 0], maps[..., 1], ...)``
reads. ``valid`` is False where the source has nothing to give (behind the lens, beyond the
distortion's invertible range, outside the source frame); the table holds ``-1`` there, which
``cv2.remap`` with ``BORDER_CONSTANT`` turns into the border value.

The tables are computed a block of rows at a time by one compiled function per (block, width),
with the camera and canvas passed as arguments: a new rig of the same sizes does not recompile.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from ..camera.model import Camera, img_to_ray, ray_to_img
from ..camera.panorama import Equirect, pano_to_ray, ray_to_pano
from ..pto.records import crop_circle

BLOCK_PIXELS = 1 << 20  # pixels per compiled call: bounds memory (float64 temporaries) whatever the size


def _pixel_grid(row0, rows: int, width: int, dtype) -> Float[Array, "rows width 2"]:
    ys = row0 + jnp.arange(rows, dtype=dtype)
    xs = jnp.arange(width, dtype=dtype)
    return jnp.stack(jnp.meshgrid(xs, ys), axis=-1)


@partial(jax.jit, static_argnames=("rows", "width"))
def _pano_block(camera: Camera, canvas: Equirect, row0, rows: int, width: int, max_angle, crop):
    """For rows ``row0 .. row0 + rows`` of the canvas: the image pixel each one sees (invalid
    more than ``max_angle`` radians off the optical axis, or outside ``crop``: :func:`_crop_args`)."""
    ray = pano_to_ray(canvas, _pixel_grid(row0, rows, width, camera.hfov.dtype))
    img_xy, ok = ray_to_img(camera, ray)
    size = jnp.stack([camera.width, camera.height])
    ok = ok & jnp.all((img_xy >= -0.5) & (img_xy <= size - 0.5), axis=-1)
    ok = ok & (jnp.einsum("...i,i->...", ray, camera.world_from_cam[..., :, 2]) >= jnp.cos(max_angle))
    centre_x, centre_y, half_w, half_h, mode = crop[0], crop[1], crop[2], crop[3], crop[4]
    dx, dy = img_xy[..., 0] - centre_x, img_xy[..., 1] - centre_y
    in_rectangle = (jnp.abs(dx) <= half_w) & (jnp.abs(dy) <= half_h)
    in_circle = dx * dx + dy * dy <= jnp.minimum(half_w, half_h) ** 2
    ok = ok & jnp.where(mode == 0, True, jnp.where(mode == 1, in_circle, in_rectangle))
    return jnp.where(ok[..., None], img_xy, -1.0).astype(jnp.float32), ok


@partial(jax.jit, static_argnames=("rows", "width"))
def _image_block(camera: Camera, canvas: Equirect, row0, rows: int, width: int, max_angle):
    """For rows ``row0 .. row0 + rows`` of an image: the canvas pixel each one sees.

    Pixels whose ray is more than ``max_angle`` (radians) off the optical axis are invalid: that
    is the image circle of a circular fisheye.
    """
    ray, ok = img_to_ray(camera, _pixel_grid(row0, rows, width, camera.hfov.dtype))
    axis = camera.world_from_cam[..., :, 2]
    ok = ok & (jnp.einsum("...i,i->...", ray, axis) >= jnp.cos(max_angle))
    return jnp.where(ok[..., None], ray_to_pano(canvas, ray), -1.0).astype(jnp.float32), ok


def _blocked(block_fn, camera: Camera, canvas: Equirect, height: int, width: int, *extra):
    rows = max(1, min(height, BLOCK_PIXELS // max(width, 1)))
    maps = np.empty((height, width, 2), np.float32)
    valid = np.empty((height, width), bool)
    for row0 in range(0, height, rows):
        # The last block is computed at full size (rows past the end are discarded): one compilation.
        block_maps, block_ok = block_fn(camera, canvas, float(row0), rows, width, *extra)
        n = min(rows, height - row0)
        maps[row0 : row0 + n] = np.asarray(block_maps)[:n]
        valid[row0 : row0 + n] = np.asarray(block_ok)[:n]
    return maps, valid


def canvas_size(canvas: Equirect) -> tuple[int, int]:
    """``(width, height)`` of a canvas in whole pixels."""
    return int(round(float(canvas.width))), int(round(float(canvas.height)))


def _max_angle(camera: Camera, circle: bool):
    return jnp.deg2rad(camera.hfov / 2.0) if circle else jnp.asarray(np.pi, camera.hfov.dtype)


def _crop_args(crop: tuple[int, int, int, int] | None, circular: bool, dtype) -> Array:
    """A crop ``(left, right, top, bottom)`` (Hugin's ``S``) as the compiled block reads it: its
    centre and half sizes in pixel coordinates and its shape (0: none, 1: the circle inscribed in
    it, 2: the rectangle), as Hugin takes them: the circle's centre ``((left + right) / 2, ...)``
    (:func:`crop_circle`), the rectangle the whole pixels ``left .. right - 1``, ``top .. bottom - 1``."""
    if crop is None:
        return jnp.zeros(5, dtype)
    left, right, top, bottom = crop
    if circular:
        centre_x, centre_y, _ = crop_circle(crop)
    else:
        centre_x, centre_y = (left + right - 1) / 2.0, (top + bottom - 1) / 2.0
    return jnp.asarray([centre_x, centre_y, (right - left) / 2.0, (bottom - top) / 2.0, 1 if circular else 2], dtype)


def pano_maps(
    camera: Camera,
    canvas: Equirect,
    *,
    circle: bool = False,
    crop: tuple[int, int, int, int] | None = None,
    circular_crop: bool = False,
) -> tuple[Float[np.ndarray, "H W 2"], Bool[np.ndarray, "H W"]]:
    """For every canvas pixel, the pixel of one camera's image that sees the same ray.

    ``camera`` is one camera (batch shape ``()``). Used to render a panorama from images. With
    ``circle`` (a circular fisheye), rays more than half the hfov off the optical axis are invalid,
    the lens's circle; with ``crop`` (the image's ``S``, :class:`~rigjax.pto.records.Image`), pixels
    outside it are: the circle inscribed in it where ``circular_crop``
    (:attr:`~rigjax.pto.records.Image.circular_crop`), else the rectangle; a crop alone then bounds
    the lens, as Hugin's ``nona`` draws it.
    """
    width, height = canvas_size(canvas)
    max_angle = _max_angle(camera, circle and crop is None)
    crop_args = _crop_args(crop, circular_crop, camera.hfov.dtype)
    return _blocked(_pano_block, camera, canvas, height, width, max_angle, crop_args)


def image_maps(
    camera: Camera, canvas: Equirect, *, circle: bool = False
) -> tuple[Float[np.ndarray, "h w 2"], Bool[np.ndarray, "h w"]]:
    """For every pixel of one camera's image, the canvas pixel that sees the same ray.

    Used to render an image of a known rig from an environment at infinity. With ``circle``,
    pixels beyond half the hfov off the optical axis are invalid (a circular fisheye's circle).
    """
    width, height = int(camera.width), int(camera.height)
    return _blocked(_image_block, camera, canvas, height, width, _max_angle(camera, circle))
