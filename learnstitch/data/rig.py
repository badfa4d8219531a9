"""The three-fisheye rig of learnstitch, through rigjax's camera model (the maps below take a rig of
any number of cameras of one image size; the sampled rig has three).

Convention: rigjax's world frame (x right, y down, z forward; :mod:`learnstitch.data.scene`) with the
panorama centre at the origin. Camera ``k`` faces outward at nominal yaw ``120 k`` degrees, its
centre at distance ``d`` along its optical axis, ``d * (sin yaw, 0, cos yaw)``. Lenses are
equidistant circular fisheyes (Hugin ``f2``) of ``hfov`` across the image width, whose image
circle shows the rays within ``circle_deg / 2`` of the axis; pixels outside it are black and
masked. Pixel coordinates are Hugin's (``(0, 0)`` the centre of the top-left pixel); grids for
``torch.nn.functional.grid_sample`` use ``align_corners=False``, on which pixel ``x`` is
``(x + 0.5) / W * 2 - 1``.

Every map between pixels and rays is rigjax's (:func:`rigjax.img_to_ray`,
:func:`rigjax.ray_to_img`, :func:`rigjax.pano_to_ray`), so a sample's ``.pto`` opens in rigjax
and Hugin with exactly the geometry the renderer used. They are computed in float64 whatever
JAX's global setting, so that a sample does not depend on it.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache, partial

import jax
import jax.numpy as jnp
import numpy as np
import torch

import rigjax
from rigjax import Camera, Equirect, Projection


@dataclass(frozen=True)
class RigSample:
    """One draw of the rig: the true cameras (orientation and hfov jittered) and their centres."""

    cameras: Camera  # (N,) rigjax cameras, numpy fields
    centres: np.ndarray  # (N, 3) world metres

    def project(self, canvas_size: tuple[int, int], filenames: tuple[str, ...]) -> rigjax.Project:
        """A Hugin project of the true cameras, their centres (``#-rigjax centre`` lines, which
        Hugin keeps as comments) and an equirectangular 360-degree canvas of ``canvas_size``
        ``(width, height)``."""
        width, height = canvas_size
        cams = self.cameras
        images = [
            rigjax.Image(
                width=int(cams.width[k]),
                height=int(cams.height[k]),
                projection=int(cams.projection[k]),
                hfov=float(cams.hfov[k]),
                yaw=float(cams.yaw[k]),
                pitch=float(cams.pitch[k]),
                roll=float(cams.roll[k]),
                filename=filenames[k],
            )
            for k in range(len(filenames))
        ]
        pano = rigjax.PanoramaLine(width=width, height=height, hfov=360.0, projection=2)
        return rigjax.Project.new(pano, images).replace(centres=np.asarray(self.centres, np.float64))


def nominal_cameras(size: int, hfov: float) -> Camera:
    """The rig's design: yaw 0, 120, 240; no pitch, roll or distortion."""
    yaw = np.array([0.0, 120.0, 240.0])
    return Camera(
        projection=np.full(3, int(Projection.CIRCULAR_FISHEYE), np.int32),
        width=np.full(3, float(size)),
        height=np.full(3, float(size)),
        hfov=np.full(3, float(hfov)),
        a=np.zeros(3),
        b=np.zeros(3),
        c=np.zeros(3),
        d=np.zeros(3),
        e=np.zeros(3),
        yaw=np.where(yaw > 180.0, yaw - 360.0, yaw),
        pitch=np.zeros(3),
        roll=np.zeros(3),
    )


def sample_rig(
    rng: np.random.Generator, size: int, hfov: float, distance: float, angle_jitter_deg: float, hfov_jitter_deg: float
) -> RigSample:
    """The nominal rig with yaw, pitch and roll each uniform in ``+-angle_jitter_deg`` and hfov in
    ``+-hfov_jitter_deg``; centres at ``distance`` along the nominal axes."""
    return RigSample(
        jittered(nominal_cameras(size, hfov), rng, angle_jitter_deg, hfov_jitter_deg), nominal_centres(distance)
    )


def jittered(nominal: Camera, rng: np.random.Generator, angle_jitter_deg: float, hfov_jitter_deg: float) -> Camera:
    """``nominal`` (NumPy fields) with each yaw, pitch and roll moved uniformly
    within ``+-angle_jitter_deg`` and each hfov within ``+-hfov_jitter_deg``: one draw of
    ``(4, N)`` from ``rng``."""
    jitter = rng.uniform(-1.0, 1.0, (4, len(nominal.yaw)))
    return nominal._replace(
        yaw=nominal.yaw + angle_jitter_deg * jitter[0],
        pitch=nominal.pitch + angle_jitter_deg * jitter[1],
        roll=nominal.roll + angle_jitter_deg * jitter[2],
        hfov=nominal.hfov + hfov_jitter_deg * jitter[3],
    )


def cameras_with(size: int, angles: dict) -> Camera:
    """A rig's cameras with hfov, yaw, pitch and roll from ``angles`` (lists of one value per
    camera, degrees: a sample's ``sample.json`` ``cameras``), the rest as designed: circular
    fisheyes of ``size`` pixels, no distortion."""
    fields = {k: np.asarray(angles[k], np.float64) for k in ("hfov", "yaw", "pitch", "roll")}
    return Camera.create(
        projection=int(Projection.CIRCULAR_FISHEYE),
        width=float(size),
        height=float(size),
        dtype=np.float64,
        xp=np,
        **fields,
    )


def nominal_centres(distance: float) -> np.ndarray:
    """``(3, 3)`` camera centres, world metres: ``distance`` along each nominal optical axis."""
    yaw = np.radians(nominal_cameras(8, 180.0).yaw)
    return distance * np.stack([np.sin(yaw), np.zeros(3), np.cos(yaw)], axis=-1)


def pixel_grid(width: int, height: int) -> np.ndarray:
    """``(height, width, 2)`` Hugin pixel coordinates ``(x, y)`` of every pixel."""
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    return np.stack([x, y], axis=-1)


def _axes(cameras: Camera) -> jax.Array:
    return jax.vmap(lambda c: c.world_from_cam[:, 2])(cameras)  # optical axes, world


def _degrees_from_axis(cos_theta) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.asarray(cos_theta, np.float64), -1.0, 1.0)))


def _each_camera(fn, cameras: Camera, x: jax.Array, *, own: bool = False):
    """``fn(camera, x)`` for each camera (``own``: ``fn(camera_k, x[k])``), stacked. An unrolled
    loop rather than ``vmap``: under ``vmap`` the lens type is an array and rigjax evaluates every
    lens type's branch and selects (several times the work of the one lens type this rig has)."""
    count = len(cameras.yaw)
    outputs = [fn(jax.tree_util.tree_map(lambda v, k=k: v[k], cameras), x[k] if own else x) for k in range(count)]
    return jax.tree_util.tree_map(lambda *v: jnp.stack(v), *outputs)


@jax.jit
def _fisheye_rays(cameras: Camera, xy: jax.Array):
    rays, valid = _each_camera(rigjax.img_to_ray, cameras, xy)
    cos_theta = jnp.einsum("k...i,ki->k...", rays, _axes(cameras)) / jnp.linalg.norm(rays, axis=-1)
    return rays, valid, cos_theta


def fisheye_rays(cameras: Camera, circle_deg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World ray of every pixel of each camera, ``(N, H, W, 3)``; which pixels lie inside the
    image circle, ``(N, H, W)``; and each pixel's angle from the optical axis in degrees. The
    cameras share one image size."""
    width, height = int(cameras.width[0]), int(cameras.height[0])
    with jax.enable_x64(True):
        rays, valid, cos_theta = _fisheye_rays(_jax_cameras(cameras), jnp.asarray(pixel_grid(width, height)))
    theta = _degrees_from_axis(cos_theta)
    return np.array(rays, np.float64), np.asarray(valid) & (theta <= circle_deg / 2.0), theta


@partial(jax.jit, static_argnums=(0, 1))
def _pano_rays(width: int, height: int):
    xy = jnp.asarray(pixel_grid(width, height))  # a constant of the compiled function
    return rigjax.pano_to_ray(Equirect.create(width, height, 360.0), xy)


@lru_cache(maxsize=4)
def _pano_rays_cached(width: int, height: int) -> np.ndarray:
    with jax.enable_x64(True):
        return np.array(_pano_rays(width, height), np.float64)


def pano_rays(width: int, height: int) -> np.ndarray:
    """``(H, W, 3)`` unit world rays of an equirectangular 360 x 180 canvas (rigjax's); computed
    once per size (every sample of a config casts the same panorama rays), a fresh copy each call."""
    return _pano_rays_cached(width, height).copy()


@jax.jit
def _image_maps(cameras: Camera, rays: jax.Array):
    xy, valid = _each_camera(rigjax.ray_to_img, cameras, rays, own=True)  # rays (N, H, W, 3): camera k's own
    return xy, valid, jnp.einsum("k...i,ki->k...", rays, _axes(cameras)) / jnp.linalg.norm(rays, axis=-1)


def fisheye_grids(
    cameras: Camera, rays: np.ndarray, circle_deg: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Where each camera (of one image size) sees world directions ``rays`` ``(N, H, W, 3)``
    (camera ``k`` its own).

    Returns ``grid`` ``(N, H, W, 2)``, the fisheye points for ``grid_sample(align_corners=False)``;
    ``mask`` ``(N, H, W)``, the directions inside the image circle and the image; and ``theta``
    ``(N, H, W)``, the angle from the camera's axis in degrees. Outside its mask a grid points far
    outside the image, where ``grid_sample`` gives zeros.
    """
    with jax.enable_x64(True):
        xy, valid, cos_theta = _image_maps(_jax_cameras(cameras), jnp.asarray(rays, jnp.float64))
    theta = _degrees_from_axis(cos_theta)
    size = np.array([float(cameras.width[0]), float(cameras.height[0])])
    grid = (np.asarray(xy, np.float64) + 0.5) / size * 2.0 - 1.0
    mask = np.asarray(valid) & (theta <= circle_deg / 2.0) & np.all(np.abs(grid) <= 1.0, axis=-1)
    grid = np.where(mask[..., None], grid, 2.0)
    return (
        torch.as_tensor(grid, dtype=torch.float32),
        torch.as_tensor(mask),
        torch.as_tensor(theta, dtype=torch.float32),
    )


def unwarp_grids(
    cameras: Camera, pano_size: tuple[int, int], circle_deg: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Sampling grids that resample each fisheye onto the full panorama canvas
    (:func:`fisheye_grids` of the panorama's rays, ``(N, H, W, ...)``)."""
    width, height = pano_size
    rays = pano_rays(width, height)
    return fisheye_grids(cameras, np.broadcast_to(rays, (len(cameras.yaw), *rays.shape)), circle_deg)


def _jax_cameras(cameras: Camera) -> Camera:
    return jax.tree_util.tree_map(jnp.asarray, cameras)


def feather_weights(theta_deg: torch.Tensor, mask: torch.Tensor, circle_deg: float) -> torch.Tensor:
    """Blend weights ``(N, H, W)`` that fall to 0 at each image circle's edge, normalised to sum to
    1 where any camera sees (0 elsewhere)."""
    w = ((circle_deg / 2.0 - theta_deg).clamp_min(0.0) * mask).to(torch.float32)
    total = w.sum(dim=0, keepdim=True)
    return torch.where(total > 0, w / total.clamp_min(1e-12), torch.zeros_like(w))
