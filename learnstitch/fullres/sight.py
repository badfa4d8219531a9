"""Where each camera of a rig sees a world direction, at full resolution, through rigjax's camera model.

A rig's camera ``i`` (any lens rigjax models, any image size) at centre ``c_i`` sees the scene
point of panorama ray ``w`` at inverse depth ``q`` (1 / metres from the rig's centre; 0 at
infinity) along ``v_i = w - q c_i``, at image pixel ``ray_to_img(camera_i, v_i)``. Evaluating
rigjax's lens model for every output pixel, plane and camera would cost more than the sampling it
feeds, so each camera's map is tabulated once, over a grid of directions covering the sphere, and
read back bilinearly: the map from direction to image pixel is smooth (the table's interpolation
error is a few thousandths of a pixel at the default density: ``tests/learnstitch/test_fullres.py``).

Convention. The table's nodes are the directions of longitude ``-pi + 2 pi j / W_t`` (``j = 0 ..
W_t``, both ends the same meridian) and latitude ``-pi/2 + pi i / H_t`` (``i = 0 .. H_t``, both
poles included), with rigjax's axes (longitude ``atan2(x, z)``, latitude ``atan2(y, hypot(x,
z))``, ``+`` right and down), so any direction lies between nodes and ``grid_sample`` reads them
with ``align_corners=True`` and no wrapping. Image pixels are Hugin's (``(0, 0)`` the centre of the
top-left pixel). A camera sees a direction when rigjax maps it (at all four nodes around it), it
falls inside the image (``-0.5 .. size - 0.5``) and, for a circular fisheye (``f2``), within its
circle: ``circle_deg / 2`` of the optical axis (by default half the hfov, as Hugin crops it), less
the sqrt 2 pixels where a bilinear sample would read the black beyond the circle; and, where its
``i`` line has a crop (``S``, :class:`rigjax.Image`), within the circle that crop bounds, less as
much: the circle centred in the crop, which need not be the lens's axis (Hugin's form of a
dual-fisheye template, both lenses' images the whole frame).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import torch
import torch.nn.functional as F

import rigjax
from rigjax import Camera, Projection
from rigjax.camera.lenses import focal_length
from rigjax.pto.records import crop_circle

from ..network.sweep import component_points

# A direction is mapped when all four table nodes around it are (bilinear weight of the mapped ones).
_WHOLE = 0.999


class SightTables(NamedTuple):
    """Each camera's tabulated map from world direction to image pixel, and what the renderer
    needs of its lens: ``N`` cameras."""

    xy_ok: torch.Tensor  # (N, 3, H_t + 1, W_t + 1): image x, y and 1 where rigjax maps the node, else 0
    size: torch.Tensor  # (N, 2) image width, height, pixels
    axis: torch.Tensor  # (N, 3) optical axes, world
    cos_half: torch.Tensor  # (N,) cosine of the largest angle from the axis a camera sees (its circle)
    half_deg: torch.Tensor  # (N,) that angle, degrees
    focal: torch.Tensor  # (N,) pixels per radian at the image centre

    centres: torch.Tensor  # (N, 3) camera centres, world metres
    crop: torch.Tensor  # (N, 3) each image's crop circle: centre x, y and radius, pixels (radius inf: no crop)

    @property
    def count(self) -> int:
        return int(self.size.shape[0])

    @property
    def inset_deg(self) -> torch.Tensor:
        """``(N,)`` degrees inside a circular fisheye's circle where a bilinear sample first reads no
        pixel beyond it (its 2 x 2 footprint reaches sqrt 2 pixels out, at the image centre's
        scale); 0 for other lenses (their image frame, not a circle, ends what they see)."""
        inset = torch.rad2deg(math.sqrt(2.0) / self.focal)
        return torch.where(self.half_deg < 180.0, inset, torch.zeros_like(inset))


def circle_half_angles(cameras: Camera, circle_deg: np.ndarray | None = None) -> np.ndarray:
    """``(N,)`` degrees: the largest angle from its axis each camera sees. ``circle_deg`` ``(N,)``
    gives the circles; by default a circular fisheye's is its hfov (Hugin's crop), other lenses'
    are unbounded (180: the image frame bounds what they see)."""
    projection = np.asarray(cameras.projection)
    if circle_deg is None:
        circle_deg = np.where(projection == int(Projection.CIRCULAR_FISHEYE), np.asarray(cameras.hfov), 360.0)
    return np.minimum(np.asarray(circle_deg, np.float64), 360.0) / 2.0


@jax.jit
def _table(camera: Camera, rays: jax.Array):
    """One camera's image pixel of every ray and whether rigjax maps it ``(..., 3)`` (computed in
    float64, kept in float32), its optical axis and its focal length: one compiled program per
    table size (no eager operations, each of which would compile a program of its own in every
    process)."""
    xy, ok = rigjax.ray_to_img(camera, rays)
    axis = rigjax.world_from_cam(camera.yaw, camera.pitch, camera.roll)[:, 2]
    xy_ok = jnp.concatenate([jnp.where(ok[..., None], xy, 0.0), ok[..., None].astype(xy.dtype)], axis=-1)
    return xy_ok.astype(jnp.float32), axis, focal_length(camera.projection, camera.width, camera.hfov)


def node_rays(table_width: int) -> np.ndarray:
    """``(H_t + 1, W_t + 1, 3)`` float64 unit directions of the table's nodes (``H_t = W_t / 2``)."""
    height = table_width // 2
    lon = -np.pi + 2.0 * np.pi * np.arange(table_width + 1) / table_width
    lat = -0.5 * np.pi + np.pi * np.arange(height + 1) / height
    lat, lon = np.meshgrid(lat, lon, indexing="ij")
    return np.stack([np.cos(lat) * np.sin(lon), np.sin(lat), np.cos(lat) * np.cos(lon)], axis=-1)


def sight_tables(
    cameras: Camera,
    centres: np.ndarray,
    table_width: int,
    circle_deg: np.ndarray | None = None,
    circle_px: np.ndarray | None = None,
    crops: Sequence[tuple[int, int, int, int] | None] | None = None,
) -> SightTables:
    """The :class:`SightTables` of ``cameras`` (a batched rigjax camera, ``N`` of them) at
    ``centres`` ``(N, 3)`` (world metres), tabulated ``table_width`` nodes around (even).
    ``circle_deg`` ``(N,)``: the cameras' circles (:func:`circle_half_angles`); ``circle_px``
    ``(N,)``: where a circular fisheye's content ends, pixels from its distortion centre
    (:func:`learnstitch.fullres.rig.image_circle_px`; NaN: not measured), which narrows its circle
    to the angle the lens maps that radius to. ``crops``: each image's crop ``(left, right, top,
    bottom)`` or None (the ``i`` lines' ``S``), as a circular fisheye's crop bounds it: the circle
    centred at ``((left + right) / 2, (top + bottom) / 2)`` of half the crop's shorter side.

    Each camera's table is one call of rigjax's ``ray_to_img`` in float64 (compiled once per
    table size; a rig of the same table size does not recompile)."""
    if table_width < 8 or table_width % 2:
        raise ValueError(f"table_width must be even and >= 8, got {table_width}")
    count = len(np.asarray(cameras.yaw))
    rays = node_rays(table_width)
    xy_ok = torch.empty(count, 3, *rays.shape[:2])
    axes, focal = [], []
    with jax.enable_x64(True):
        for k in range(count):
            camera = Camera(
                *(
                    np.asarray(np.asarray(v)[k], np.int32 if name == "projection" else np.float64)
                    for name, v in zip(Camera._fields, cameras)
                )
            )
            table, axis, f = _table(camera, rays)
            xy_ok[k] = torch.from_numpy(np.array(table)).permute(2, 0, 1)
            axes.append(np.asarray(axis))
            focal.append(float(f))
    half = circle_half_angles(cameras, circle_deg)
    for k in range(count) if circle_px is not None else ():
        if np.isfinite(circle_px[k]):
            centre = (np.array([cameras.width[k], cameras.height[k]]) / 2.0 - 0.5) + np.array(
                [cameras.d[k], cameras.e[k]]
            )
            half[k] = min(half[k], _angle_at_radius(xy_ok[k], rays, axes[k], centre, float(circle_px[k])))
    return SightTables(
        xy_ok=xy_ok,
        size=torch.as_tensor(
            np.stack([np.asarray(cameras.width), np.asarray(cameras.height)], -1), dtype=torch.float32
        ),
        axis=torch.as_tensor(np.stack(axes), dtype=torch.float32),
        cos_half=torch.as_tensor(np.cos(np.radians(half)), dtype=torch.float32),
        half_deg=torch.as_tensor(half, dtype=torch.float32),
        focal=torch.tensor(focal, dtype=torch.float32),
        centres=torch.as_tensor(np.asarray(centres, np.float64).reshape(count, 3), dtype=torch.float32),
        crop=torch.tensor(
            [(0.0, 0.0, math.inf) if c is None else crop_circle(c) for c in (crops or [None] * count)],
            dtype=torch.float32,
        ),
    )


def _angle_at_radius(
    xy_ok: torch.Tensor, rays: np.ndarray, axis: np.ndarray, centre: np.ndarray, radius: float
) -> float:
    """Degrees from the optical axis at which a radially symmetric lens images ``radius`` pixels
    from its distortion ``centre``: a line fitted to the table's nodes (image points ``xy_ok``
    ``(3, H_t + 1, W_t + 1)``, directions ``rays``) that land within two pixels of that radius;
    180 where none do (nothing to narrow)."""
    xy, mapped = xy_ok[:2].numpy(), xy_ok[2].numpy() > _WHOLE
    r = np.hypot(xy[0] - centre[0], xy[1] - centre[1])
    near = mapped & (np.abs(r - radius) <= 2.0)
    if near.sum() < 8:
        return 180.0
    angle = np.degrees(np.arccos(np.clip(rays[near] @ axis, -1.0, 1.0)))
    # the line through radii centred on the one asked for: its value there is the intercept, and
    # the fit is well conditioned (radii of hundreds of pixels spread over four are not)
    _, at_radius = np.polyfit(r[near] - radius, angle, 1)
    return float(at_radius)


class Views(NamedTuple):
    """What each camera sees along its sight lines to ``M`` points: ``(N, ...)``."""

    xy: torch.Tensor  # (N, M, 2) image pixels (Hugin's convention)
    visible: torch.Tensor  # (N, M) bool: mapped, inside the image, its circle and its crop's circle
    feather: torch.Tensor  # (N, M) blend weight, degrees from the nearest edge of what it sees (0 where not visible)
    radius: torch.Tensor  # (N, M) angle from the axis over the circle's half-angle (0 on the axis, 1 at the circle)


def views(
    tables: SightTables, rays: torch.Tensor, inverse_depth: torch.Tensor, scales: torch.Tensor | None = None
) -> Views:
    """Each camera's :class:`Views` of the points at ``inverse_depth`` ``(M,)`` along unit
    panorama rays ``rays`` ``(M, 3)``: camera ``i`` looks along ``rays - q c_i``.

    ``scales`` ``(N,)``: each camera is read from its image shrunk this many times (a box-filtered
    pyramid level, :func:`sample_images`), whose pixels near the circle already average the black
    beyond it: a bilinear sample there reaches ``1.5 sqrt 2`` shrunk pixels out (its footprint and
    the box's), and the circle's inset grows to that. Default: the full-size images.

    The feather weight is the smaller of the angle to the circle's edge and the angles to the image
    frame's nearest edge and to the crop's circle (their distances in pixels over the focal length),
    so that it falls to 0 wherever what a camera sees ends; for a circular fisheye inscribed in its image it is
    ``circle_deg / 2 - theta``, the weight of :func:`learnstitch.data.rig.feather_weights`.
    """
    # Each component (N, M) of the directions to the points, not unit, contiguous.
    x, y, z = (
        torch.addcmul(ray[None], inverse_depth[None], centre[:, None], value=-1.0)
        for ray, centre in zip(rays.T, tables.centres.T)
    )
    grid = component_points(x, y, z)[:, None]  # (N, 1, M, 2) points of the tables' grid
    read = F.grid_sample(tables.xy_ok, grid, mode="bilinear", padding_mode="border", align_corners=True)[:, :, 0]
    xy, mapped = read[:, :2].transpose(1, 2), read[:, 2] > _WHOLE  # (N, M, 2), (N, M)
    px, py = read[:, 0], read[:, 1]  # (N, M) each, contiguous
    axis = tables.axis.T[:, :, None]  # (3, N, 1)
    along = x * axis[0] + y * axis[1] + z * axis[2]
    cos_theta = (along / torch.sqrt(x * x + y * y + z * z)).clamp_(-1.0, 1.0)
    width, height = tables.size[:, 0, None], tables.size[:, 1, None]
    # Pixels to the frame's nearest edge.
    edge = torch.minimum(torch.minimum(px, width - 1.0 - px), torch.minimum(py, height - 1.0 - py)).add_(0.5)
    theta = torch.rad2deg(torch.arccos(cos_theta))
    circle = tables.half_deg[:, None] - theta  # degrees inside the circle
    # Near the circle a bilinear sample reads the black beyond it: not seen there.
    # A pyramid level's bilinear sample reaches further: 1.5 sqrt 2 of its pixels (its footprint and the box's).
    widen = 1.0 if scales is None else torch.where(scales > 1.0, 1.5 * scales, 1.0)
    inset = tables.inset_deg * widen
    visible = mapped & (edge >= 0.0) & (cos_theta >= tables.cos_half[:, None]) & (circle >= inset[:, None])
    margin = torch.minimum(circle, torch.rad2deg(edge / tables.focal[:, None]))
    if torch.isfinite(tables.crop[:, 2]).any():  # an i line with a crop (S): within its circle too
        # Degrees inside the crop's circle (infinite without one), less the same inset as the lens's circle.
        off = torch.hypot(px - tables.crop[:, None, 0], py - tables.crop[:, None, 1])
        cropped = torch.rad2deg((tables.crop[:, None, 2] - off) / tables.focal[:, None])
        crop_inset = torch.rad2deg(math.sqrt(2.0) / tables.focal) * widen
        visible = visible & (cropped >= crop_inset[:, None])
        margin = torch.minimum(margin, cropped)
    feather = torch.where(visible, margin.clamp_min(0.0), torch.zeros_like(margin))
    return Views(xy, visible, feather, theta / tables.half_deg[:, None])


def sample_images(
    images: list[torch.Tensor], xy: torch.Tensor, visible: torch.Tensor, scale: float = 1.0
) -> torch.Tensor:
    """``(N, C, M)`` bilinear samples of ``images`` (camera ``i``'s ``(C, h_i, w_i)``) at image
    pixels ``xy`` ``(N, M, 2)`` of the full-size images, zero where not ``visible``. ``scale``:
    the images are the full-size ones shrunk by this factor (a pyramid level: full-size pixel
    ``x`` is ``(x + 0.5) / scale - 0.5`` there)."""
    out = torch.empty(len(images), images[0].shape[0], xy.shape[1], dtype=images[0].dtype, device=xy.device)
    for k, image in enumerate(images):
        # grid_sample's point of full-size pixel x: ((x + 0.5) / scale + ... ) as a * x + b
        a = 2.0 / (scale * torch.tensor([image.shape[-1], image.shape[-2]], dtype=xy.dtype, device=xy.device))
        grid = torch.addcmul(0.5 * a - 1.0, xy[k], a)[None, None]
        sampled = F.grid_sample(image[None], grid, mode="bilinear", padding_mode="border", align_corners=False)
        torch.mul(sampled[0, :, 0], visible[k], out=out[k])
    return out
