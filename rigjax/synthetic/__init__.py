"""Synthetic rigs with known geometry, for tests, the demo and benchmarks.

:func:`cube_rig` builds the classic 6-camera rig (four cameras around the horizon, one up, one
down); :func:`control_points_from_truth` adds control points by projecting random world
directions into every pair of cameras that sees them, with pixel noise and wrong matches;
:func:`perturb` moves the cameras away from the truth to make start values;
:func:`render_images` renders what a rig's cameras see of a procedural environment at infinity
(:func:`procedural_environment`), so calibration from images has an exact truth.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..calibration.agreement import ray_angles_deg
from ..calibration.ransac import angle_between, rotation_from_bearings
from ..camera.model import img_to_ray, ray_to_img
from ..camera.panorama import Equirect
from ..camera.rotation import world_from_cam, ypr_from_world_from_cam
from ..pto.project import Project
from ..pto.records import ControlPoints, Image, OptVariable, PanoramaLine
from ..rendering.remap import image_maps
from .environment import procedural_environment

__all__ = [
    "align_to",
    "centres_on_axes",
    "control_points_from_scene",
    "control_points_from_truth",
    "cube_rig",
    "perturb",
    "procedural_environment",
    "ray_angles_deg",
    "ray_errors_arcmin",
    "render_images",
    "rig_from_orientations",
    "ring_rig",
    "scene_points",
    "vertical_lines_from_truth",
]

CUBE_ORIENTATIONS: tuple[tuple[float, float, float], ...] = (
    (0.0, 0.0, 0.0),
    (90.0, 0.0, 0.0),
    (180.0, 0.0, 0.0),
    (-90.0, 0.0, 0.0),
    (0.0, 90.0, 0.0),
    (0.0, -90.0, 0.0),
)


def rig_from_orientations(
    orientations,
    *,
    width: int = 1440,
    height: int = 1080,
    projection: int = 3,
    hfov: float = 123.0,
    b: float = -0.01,
    pano_width: int = 3600,
    orientation_jitter_deg: float = 0.0,
    seed: int = 0,
) -> Project:
    """Identical, unlinked cameras at nominal ``(yaw, pitch, roll)`` orientations (degrees) on a
    2:1, 360-degree canvas, with ``v`` lines for every orientation but camera 0's.

    ``orientation_jitter_deg`` adds seeded, uniformly distributed offsets to every yaw, pitch and
    roll, so that the rig is not exactly its nominal shape (as no real rig is).
    """
    rng = np.random.default_rng(seed)
    images = []
    for k, (yaw, pitch, roll) in enumerate(orientations):
        jitter = rng.uniform(-orientation_jitter_deg, orientation_jitter_deg, 3)
        images.append(
            Image(
                width=width,
                height=height,
                projection=projection,
                hfov=hfov,
                b=b,
                yaw=float(yaw + jitter[0]),
                pitch=float(pitch + jitter[1]),
                roll=float(roll + jitter[2]),
                filename=f"cam{k}.png",
            )
        )
    pano = PanoramaLine(width=pano_width, height=pano_width // 2, hfov=360.0, projection=2)
    variables = [OptVariable(name, k) for k in range(len(images)) for name in ("y", "p", "r") if k > 0]
    return Project.new(pano, images, variables=variables)


def cube_rig(**options) -> Project:
    """The 6-camera cube rig (four cameras around the horizon, one up, one down); ``options`` as
    :func:`rig_from_orientations`."""
    return rig_from_orientations(CUBE_ORIENTATIONS, **options)


def ring_rig(n: int = 6, **options) -> Project:
    """``n`` cameras around the horizon, ``360 / n`` degrees apart in yaw (camera 0 at yaw 0);
    ``options`` as :func:`rig_from_orientations`."""
    return rig_from_orientations([((360.0 * k / n + 180.0) % 360.0 - 180.0, 0.0, 0.0) for k in range(n)], **options)


def _rays_on_raster(project: Project, truth: Project, grid: int, off_axis_deg: tuple[float, float] | None = None):
    """Rays of both projects through a ``grid x grid`` raster of every image: ``(2, n, 3)``, which
    rays both can map (and, with ``off_axis_deg``, whose true ray lies that many degrees off its
    camera's optical axis), and each ray's image."""
    rays, ok, owner = [], [], []
    truth_axes = np.asarray(truth.cameras().world_from_cam)[..., :, 2]
    for k, image in enumerate(truth.images):
        ticks_x = (np.arange(grid) + 0.5) / grid * image.width - 0.5
        ticks_y = (np.arange(grid) + 0.5) / grid * image.height - 0.5
        xy = np.stack(np.meshgrid(ticks_x, ticks_y), -1).reshape(-1, 2)
        pair = [img_to_ray(p.cameras().take(k), xy) for p in (project, truth)]
        rays.append(np.stack([np.asarray(r) for r, _ in pair]))
        valid = np.asarray(pair[0][1]) & np.asarray(pair[1][1])
        if image.projection == 2:
            centre = np.array([image.width / 2 - 0.5, image.height / 2 - 0.5])
            valid &= np.linalg.norm(xy - centre, axis=1) <= image.width / 2
        if off_axis_deg is not None:
            angle = np.degrees(angle_between(rays[-1][1], truth_axes[k][None]))
            valid &= (angle >= off_axis_deg[0]) & (angle <= off_axis_deg[1])
        ok.append(valid)
        owner.append(np.full(len(xy), k))
    return np.concatenate(rays, axis=1), np.concatenate(ok), np.concatenate(owner)


def _truth_from_project(rays: np.ndarray, ok: np.ndarray) -> np.ndarray:
    return rotation_from_bearings(rays[0][ok], rays[1][ok])


def ray_errors_arcmin(
    project: Project, truth: Project, *, grid: int = 24, off_axis_deg: tuple[float, float] | None = None
) -> np.ndarray:
    """The largest angle (arcmin) between the rays of ``project`` and of ``truth`` over a
    ``grid x grid`` raster of every image's pixels, per image.

    Images at infinity cannot tell the rig's absolute orientation, so the rays are compared after
    the one rotation of the whole rig that fits them best (:func:`align_to`). Pixels that either
    model cannot map (beyond a circular fisheye's circle, for instance) are left out.
    ``off_axis_deg=(lo, hi)`` keeps only pixels whose true ray lies ``lo`` to ``hi`` degrees off
    the optical axis (the overlap ring of back-to-back fisheyes, say; the rotation is fitted there).
    """
    rays, ok, owner = _rays_on_raster(project, truth, grid, off_axis_deg)
    angle = np.degrees(angle_between(rays[0] @ _truth_from_project(rays, ok).T, rays[1])) * 60.0
    # An image none of whose raster pixels ``project`` can map (a diverged lens) is infinitely wrong.
    masks = (ok & (owner == k) for k in range(len(truth.images)))
    return np.array([angle[mask].max() if mask.any() else np.inf for mask in masks])


def environment_psnr(
    pano: np.ndarray, covered: np.ndarray, environment: np.ndarray, *, max_latitude_deg: float
) -> float:
    """PSNR (dB) of an equirectangular panorama against the ``environment`` it was rendered from
    (resized to the panorama's size), over the covered pixels within ``max_latitude_deg`` of the
    horizon. Render the panorama through :func:`align_to`'s rig, so that both share one frame."""
    height, width = pano.shape[:2]
    reference = cv2.resize(environment, (width, height), interpolation=cv2.INTER_AREA).astype(float)
    band = covered.copy()
    rows = int(round(height * (90.0 - max_latitude_deg) / 180.0))
    band[:rows], band[height - rows :] = False, False
    return float(10 * np.log10(255**2 / np.mean((pano.astype(float) - reference)[band] ** 2)))


def align_to(project: Project, truth: Project, *, grid: int = 24) -> Project:
    """``project`` with its whole rig turned by the rotation that best fits its rays to the truth's
    (what images at infinity leave free), e.g. to compare its panorama with the true one."""
    rays, ok, _ = _rays_on_raster(project, truth, grid)
    turn = _truth_from_project(rays, ok)
    cameras = project.cameras()
    ypr = np.asarray(
        ypr_from_world_from_cam(turn @ np.asarray(world_from_cam(cameras.yaw, cameras.pitch, cameras.roll)))
    )
    images = tuple(
        im.replace(yaw=float(y), pitch=float(p), roll=float(r)) for im, (y, p, r) in zip(project.images, ypr)
    )
    return project.replace(images=images)


def _seen(project: Project, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every world ray (``(n_rays, 3)``, or ``(n_images, n_rays, 3)``: each image's own) in every
    image: pixels ``(n_images, n_rays, 2)``, whether each lands inside the frame
    ``(n_images, n_rays)``, and the image sizes ``(n_images, 2)``."""
    rays = rays if rays.ndim == 3 else rays[None]
    xy, valid = ray_to_img(project.cameras().take(np.arange(len(project.images))[:, None]), rays)
    xy, valid = np.asarray(xy), np.asarray(valid)
    size = np.array([[im.width, im.height] for im in project.images], dtype=float)
    return xy, valid & np.all((xy >= -0.5) & (xy <= size[:, None, :] - 0.5), axis=-1), size


def control_points_from_truth(
    project: Project,
    n_directions: int = 2000,
    *,
    noise_px: float = 0.0,
    outlier_fraction: float = 0.0,
    seed: int = 0,
) -> Project:
    """Control points for every pair of images that sees one of ``n_directions`` random directions.

    Directions are uniform on the sphere (seeded); a direction makes a control point for each pair
    of images in which it lands inside the frame. ``noise_px`` adds Gaussian noise (standard
    deviation per coordinate, in pixels) to both ends. ``outlier_fraction`` of the points then get
    their second end moved to a uniformly random pixel of its image: wrong matches.
    """
    rng = np.random.default_rng(seed)
    rays = rng.normal(size=(n_directions, 3))
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    xy, seen, size = _seen(project, rays)
    first, second = np.triu_indices(len(project.images), k=1)
    pair, direction = np.nonzero(seen[first] & seen[second])  # (pair, direction) of every match
    a, b = first[pair], second[pair]
    xy_a = xy[a, direction] + rng.normal(scale=noise_px, size=(len(pair), 2)) if noise_px else xy[a, direction]
    xy_b = xy[b, direction] + rng.normal(scale=noise_px, size=(len(pair), 2)) if noise_px else xy[b, direction]
    wrong = rng.random(len(pair)) < outlier_fraction
    xy_b[wrong] = rng.uniform(0.0, 1.0, (int(wrong.sum()), 2)) * size[b[wrong]] - 0.5
    cps = ControlPoints(a, b, xy_a, xy_b, np.zeros(len(pair)))
    return project.replace(control_points=cps)


def centres_on_axes(project: Project, distance: float) -> np.ndarray:
    """``(n_images, 3)``: each camera's centre ``distance`` out along its optical axis, as on a rig
    whose cameras face outward from its middle (world frame: x right, y down, z forward)."""
    return distance * np.asarray(project.cameras().world_from_cam)[..., :, 2]


def scene_points(n: int, *, near: float = 1.0, far: float = 50.0, seed: int = 0) -> np.ndarray:
    """``(n, 3)`` points in uniformly random directions, log-uniformly ``near`` to ``far`` from the
    origin (seeded): a scene with parallax for :func:`control_points_from_scene`."""
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return directions * np.exp(rng.uniform(np.log(near), np.log(far), n))[:, None]


def control_points_from_scene(
    project: Project, centres: np.ndarray, points: np.ndarray, *, noise_px: float = 0.0, seed: int = 0
) -> tuple[Project, np.ndarray]:
    """Control points of scene points seen by cameras that sit apart: camera ``i`` at
    ``centres[i]`` sees point ``X`` along ``X - centres[i]``; each pair of images in whose frames a
    point lands makes a control point (seeded Gaussian noise of ``noise_px`` per coordinate). Returns
    the project and, per control point, the index of its scene point."""
    rng = np.random.default_rng(seed)
    points, centres = np.asarray(points, float), np.asarray(centres, float)
    xy, seen, _ = _seen(project, points[None] - centres[:, None])
    first, second = np.triu_indices(len(project.images), k=1)
    pair, index = np.nonzero(seen[first] & seen[second])
    a, b = first[pair], second[pair]
    noise = rng.normal(scale=noise_px, size=(2, len(pair), 2)) if noise_px else np.zeros((2, len(pair), 2))
    cps = ControlPoints(a, b, xy[a, index] + noise[0], xy[b, index] + noise[1], np.zeros(len(pair)))
    return project.replace(control_points=cps), index


def vertical_lines_from_truth(
    project: Project,
    n_lines: int = 4,
    points_per_line: int = 6,
    *,
    kind: int = 3,
    noise_px: float = 0.0,
    seed: int = 0,
) -> Project:
    """Line control points on vertical world lines (meridians), added to the project's own.

    A vertical line of the world is a straight vertical line of an equirectangular panorama.
    Each line is ``points_per_line`` directions at one random longitude, latitudes spread over
    +-60 degrees, each seen in a random image that sees it; consecutive directions pair up into
    control points. ``kind`` is the ``t`` of the first line: ``3`` gives straight lines ``t3``,
    ``t4``, ... (one ``t`` per line); ``1`` gives Hugin's vertical-line points ``t1`` for all.
    """
    if points_per_line < 2 or points_per_line % 2:
        raise ValueError(f"points_per_line must be an even number >= 2, got {points_per_line}")
    rng = np.random.default_rng(seed)
    rows: list[tuple[int, int, np.ndarray, np.ndarray, int]] = []
    for line in range(n_lines):
        lon = rng.uniform(-np.pi, np.pi)
        lat = np.radians(np.linspace(-60.0, 60.0, points_per_line)) + rng.uniform(-0.05, 0.05, points_per_line)
        rays = np.stack([np.cos(lat) * np.sin(lon), np.sin(lat), np.cos(lat) * np.cos(lon)], -1)
        xy, seen, _ = _seen(project, rays)
        if not np.all(seen.any(axis=0)):
            raise ValueError(f"line {line}: some of its directions are seen by no image")
        images = [int(rng.choice(np.flatnonzero(seen[:, k]))) for k in range(points_per_line)]
        ends = [xy[images[k], k] + rng.normal(scale=noise_px, size=2) for k in range(points_per_line)]
        t = kind + line if kind >= 3 else kind
        rows += [(images[k], images[k + 1], ends[k], ends[k + 1], t) for k in range(0, points_per_line, 2)]
    cps = project.control_points
    added = ControlPoints(*(np.array([row[i] for row in rows]) for i in range(5)))
    merged = ControlPoints(
        *(np.concatenate([getattr(cps, f), getattr(added, f)]) for f in ("image_a", "image_b", "xy_a", "xy_b", "kind"))
    )
    return project.replace(control_points=merged)


def perturb(
    project: Project,
    *,
    angle_deg: tuple[float, float] = (3.0, 20.0),
    hfov_offset_deg: tuple[float, float] = (3.0, 8.0),
    b: float | None = 0.0,
    anchor: int = 0,
    seed: int = 0,
) -> Project:
    """Start values away from the truth, as a user's nominal rig would be.

    Every image but the anchor has each of yaw, pitch and roll moved by a magnitude drawn
    uniformly from ``angle_deg``, with a random sign. The hfov of every image becomes the truth
    plus one offset, drawn from ``hfov_offset_deg`` with a random sign (a wrong nominal lens);
    ``b`` replaces every image's K2 (``None`` keeps it).
    """
    rng = np.random.default_rng(seed)
    hfov_offset = rng.uniform(*hfov_offset_deg) * rng.choice([-1.0, 1.0])
    images = []
    for k, image in enumerate(project.images):
        move = np.zeros(3) if k == anchor else rng.uniform(*angle_deg, 3) * rng.choice([-1.0, 1.0], 3)
        changes = dict(
            yaw=image.yaw + move[0],
            pitch=image.pitch + move[1],
            roll=image.roll + move[2],
            hfov=image.hfov + hfov_offset,
        )
        if b is not None:
            changes["b"] = b
        images.append(image.replace(**{k_: float(v) for k_, v in changes.items()}))
    return project.replace(images=tuple(images))


def render_images(
    project: Project, environment: np.ndarray, *, noise_std: float = 0.0, seed: int = 0
) -> list[np.ndarray]:
    """What each camera of ``project`` sees of an equirectangular ``environment`` at infinity.

    ``environment`` is an ``(H, 2H, 3)`` uint8 texture covering 360 x 180 degrees (see
    :func:`procedural_environment`). Circular fisheyes (``f2``) are black beyond half their hfov.
    ``noise_std`` adds seeded Gaussian sensor noise (grey levels). Returns ``(h, w, 3)`` uint8
    images in the project's order. With no parallax, the true rig maps every pixel exactly.
    """
    height, width = environment.shape[:2]
    if environment.ndim != 3 or width != 2 * height or environment.dtype != np.uint8:
        raise ValueError(
            f"environment must be an (H, 2H, 3) uint8 texture, got {environment.dtype} {environment.shape}"
        )
    canvas = Equirect.create(width, height, 360.0)
    cameras = project.cameras()
    rng = np.random.default_rng(seed)
    images = []
    for k, image in enumerate(project.images):
        maps, valid = image_maps(cameras.take(k), canvas, circle=image.projection == 2)
        pixels = cv2.remap(environment, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        if noise_std:
            pixels = (pixels + rng.normal(0.0, noise_std, pixels.shape)).clip(0, 255).astype(np.uint8)
        pixels[~valid] = 0
        images.append(pixels)
    return images
