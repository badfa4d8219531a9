"""Which input sees each panorama pixel's scene point, from its own centre.

The ground truth is rendered from the rig's centre; the inputs from their cameras' centres ``c_i``.
Panorama pixel ``w`` (a unit direction) shows the scene point ``P = D w`` at the sample's depth
``D``; input ``i`` sees that point along ``P - c_i`` (the sky, at infinity, along ``w``) when the
direction lies inside its image circle and nothing nearer stands in the way: a ray cast from
``c_i`` reaches ``P``. A pixel no input sees is the **blind spot** (mostly the ground under the
rig): no warp of the inputs can recover it, so a metric of geometry is taken over the *seen*
pixels, and the blind spot's share is reported beside it.

These sight lines also give the depth-oracle stitch (:func:`learnstitch.baselines.depth_oracle_stitch`):
every input resampled along them through its true camera.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch

from .rig import fisheye_grids, pano_rays
from .sample import Sample, SynthConfig
from .scene import Scene, render, sample_scene

# A ray cast from a camera's centre "reaches" a point when it stops no nearer than this (relative and
# absolute, metres): float32 intersections of the same surface differ by far less.
REACH_RTOL, REACH_ATOL = 1e-3, 1e-3


class SightLines(NamedTuple):
    """Each input's view of the panorama's scene points, ``(N, H, W, ...)``."""

    directions: torch.Tensor  # (N, H, W, 3) unit world directions from each centre to the point
    grid: torch.Tensor  # (N, H, W, 2) where the true camera images them (grid_sample, align_corners=False)
    theta: torch.Tensor  # (N, H, W) degrees from the camera's axis
    visible: torch.Tensor  # (N, H, W) bool: inside the image circle and not occluded

    @property
    def seen(self) -> torch.Tensor:
        """``(H, W)`` bool: the pixels some input sees (the complement of the blind spot)."""
        return self.visible.any(dim=0)


def directions_to_points(rays: torch.Tensor, depth: torch.Tensor, centres: torch.Tensor) -> torch.Tensor:
    """``(N, H, W, 3)`` unit directions from each centre ``(N, 3)`` to the points ``depth * rays``
    (``rays`` ``(H, W, 3)`` unit, ``depth`` ``(H, W)``; an infinite depth gives the ray itself)."""
    finite = torch.isfinite(depth)[..., None]
    towards = torch.where(finite, torch.where(finite, depth[..., None], 0.0) * rays - centres[:, None, None], rays)
    return towards / towards.norm(dim=-1, keepdim=True)


def grids_at_depth(cameras, centres: torch.Tensor, depth: torch.Tensor, config: SynthConfig):
    """Where each camera (centres ``(N, 3)``) sees each panorama pixel's point at ``depth``
    ``(H, W)`` (metres, ``inf`` at infinity): ``(directions, grid, inside, theta)``, the unit
    directions ``(N, H, W, 3)`` from each centre and :func:`fisheye_grids` of them."""
    rays = torch.as_tensor(pano_rays(config.pano_width, config.pano_height))  # float64
    directions = directions_to_points(rays, depth.to(torch.float64), centres.to(torch.float64))
    return (directions, *fisheye_grids(cameras, directions.numpy(), config.circle_deg))


def sight_lines(sample: Sample, config: SynthConfig, scene: Scene | None = None) -> SightLines:
    """The :class:`SightLines` of ``sample`` (rendered with ``config``), ray cast in its scene
    (``scene``: the one it was rendered from, when not its seed's)."""
    scene = sample_scene(sample.seed) if scene is None else scene
    return rig_sight_lines(scene, sample.rig.cameras, sample.rig.centres, sample.depth, config.circle_deg)


def rig_sight_lines(scene: Scene, cameras, centres, depth: torch.Tensor, circle_deg: float) -> SightLines:
    """The :class:`SightLines` of a rig's ``cameras`` (of one image size, image circles of
    ``circle_deg``) at ``centres`` ``(N, 3)`` to the scene points at ``depth`` ``(H, W)`` (metres
    from the rig's centre along each panorama ray, ``inf`` at infinity), ray cast in ``scene``."""
    height, width = depth.shape
    rays = torch.as_tensor(pano_rays(width, height))  # float64
    depth = depth.cpu().to(torch.float64)
    centres = torch.as_tensor(np.asarray(centres), dtype=torch.float64)
    directions = directions_to_points(rays, depth, centres)
    grid, inside, theta = fisheye_grids(cameras, directions.numpy(), circle_deg)
    distance = torch.where(
        torch.isfinite(depth), (depth[..., None] * rays - centres[:, None, None]).norm(dim=-1), torch.inf
    )
    reached = torch.stack(
        [render(scene, centres[k].float(), directions[k].float())[1].to(torch.float64) for k in range(len(centres))]
    )
    unoccluded = torch.where(
        torch.isinf(distance), torch.isinf(reached), reached >= distance * (1.0 - REACH_RTOL) - REACH_ATOL
    )
    return SightLines(directions.float(), grid, theta, inside & unoccluded)
