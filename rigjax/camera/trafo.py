"""Image pixel <-> panorama pixel, and the batch transform behind ``rigjax trafo``.

Convention: both sides in Hugin pixel coordinates (pixel centres at integers, y down); see
:mod:`rigjax.camera.model` and :mod:`rigjax.camera.panorama`. ``valid`` flags as in :func:`img_to_ray` and
:func:`ray_to_img`.
"""

from __future__ import annotations

import jax
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from .model import Camera, img_to_ray, optics_at, optics_img_to_ray, optics_ray_to_img, padded_size, ray_to_img
from .panorama import Equirect, pano_to_ray, ray_to_pano


def img_to_pano(
    camera: Camera, canvas: Equirect, img_xy: Float[ArrayLike, "... 2"]
) -> tuple[Float[Array, "... 2"], Bool[Array, ...]]:
    """Image pixel -> panorama pixel (Hugin's ``pano_trafo`` forward direction)."""
    ray, valid = img_to_ray(camera, img_xy)
    return ray_to_pano(canvas, ray), valid


def pano_to_img(
    camera: Camera, canvas: Equirect, pano_xy: Float[ArrayLike, "... 2"]
) -> tuple[Float[Array, "... 2"], Bool[Array, ...]]:
    """Panorama pixel -> image pixel (Hugin's ``pano_trafo -r``)."""
    return ray_to_img(camera, pano_to_ray(canvas, pano_xy))


@jax.jit
def transform_batch(cameras: Camera, canvas: Equirect, image: Int[Array, " n"], xy: Float[Array, "n 2"], reverse):
    """Point ``k`` of ``xy`` from image ``image[k]`` to the panorama (``reverse``: the other way),
    with whether it has a position there: what :func:`transform_points` compiles.

    Persisted through XLA's compilation cache only, not as an export (rigjax.compiled): tracing
    this small function costs a later ``rigjax trafo`` less than loading an export does on its
    first run (docs/design/optimiser.md)."""
    camera = optics_at(cameras, image)  # optics once per camera, not per point

    def forward():
        ray, valid = optics_img_to_ray(*camera, xy)
        return ray_to_pano(canvas, ray), valid

    return jax.lax.cond(reverse, lambda: optics_ray_to_img(*camera, pano_to_ray(canvas, xy)), forward)


def transform_points(
    cameras: Camera, canvas: Equirect, image: np.ndarray, xy: np.ndarray, *, reverse: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Transform points of many images in one compiled call; ``image[k]`` is point k's image.

    The batch is padded to a power of two so that inputs of similar size reuse one compilation.
    """
    n = len(xy)
    size = padded_size(n)
    dtype = cameras.hfov.dtype
    image_p = np.zeros(size, np.int32)
    image_p[:n] = image
    xy_p = np.zeros((size, 2), dtype)
    xy_p[:n] = xy
    out, valid = transform_batch(cameras, canvas, image_p, xy_p, np.asarray(reverse))
    return np.asarray(out)[:n], np.asarray(valid)[:n]
