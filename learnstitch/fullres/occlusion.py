"""Which inputs see each point of a panorama's depth: a z-buffer around each camera.

A panorama pixel's point lies at inverse depth ``q`` along its ray ``w`` (1 / metres from the
rig's centre). Camera ``i``, at ``c_i``, looks at it along ``w - q c_i``, from a distance of
``|w - q c_i| / q``; where a nearer surface crosses that sight line, the camera's image shows the
nearer surface there, and blending it in ghosts the occluder over what lies behind it. Which
surface is nearer is in the depth itself: every pixel's point is binned by its direction from
``c_i`` into an equirectangular buffer around the camera, keeping the largest nearness (inverse
distance) of each bin, and a point is **hidden** from camera ``i`` where its nearness is below
``1 - tolerance`` times its bin's largest (a surface seen obliquely spans a range of depths within
one bin; the tolerance keeps it from hiding itself). Points at infinity (``q = 0``) are hidden
behind any surface in their direction.

The buffer is coarser than the panorama (``scale`` of its width): a near surface, seen from a
camera nearer to it than the rig's centre is, covers more of the camera's view than of the
panorama's, and its binned points must leave no gaps through which what lies behind would show.
The renderer (:mod:`learnstitch.fullres.render`) blends only the inputs that are not hidden, and
where every input that sees a point is hidden from it (a point no camera sees, which the depth
still places there), the inputs that see its direction as before.
"""

from __future__ import annotations

import torch

from ..network.sweep import component_points
from .depth import pano_rays


def unoccluded(
    centres: torch.Tensor, inverse_depth: torch.Tensor, scale: float, tolerance: float, rows: int
) -> torch.Tensor:
    """``(N, H, W)`` bool: whether each camera's sight line (``centres`` ``(N, 3)``, world metres)
    to each pixel's point of ``inverse_depth`` ``(H, W)`` meets no nearer surface of that depth
    (module docstring). ``rows``: the panorama rows binned at a time; besides the result, the
    memory is the cameras' buffers (``N`` float32 ``scale W x scale W / 2``) and one such tile."""
    height, width = inverse_depth.shape
    buffer_width = max(8, 2 * round(scale * width / 2))
    tiles = range(0, height, rows)
    nearest = torch.zeros(len(centres), buffer_width * (buffer_width // 2))
    centres = centres.float()
    for row0 in tiles:  # every point into its bin around each camera, then each point against its bin
        rays = pano_rays(width, height, row0, min(rows, height - row0)).reshape(-1, 3)
        for k, centre in enumerate(centres):
            nearest[k].scatter_reduce_(0, *_binned(centre, rays, inverse_depth, row0, buffer_width), "amax")
    out = torch.empty(len(centres), height, width, dtype=torch.bool)
    for row0 in tiles:
        rays = pano_rays(width, height, row0, min(rows, height - row0)).reshape(-1, 3)
        for k, centre in enumerate(centres):
            index, nearness = _binned(centre, rays, inverse_depth, row0, buffer_width)
            out[k, row0 : row0 + rows] = (nearness >= nearest[k, index] * (1.0 - tolerance)).reshape(-1, width)
    return out


def _binned(
    centre: torch.Tensor, rays: torch.Tensor, inverse_depth: torch.Tensor, row0: int, buffer_width: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """The buffer bin ``(M,)`` of each point of the panorama rows from ``row0`` whose ``rays``
    ``(M, 3)`` are given, as camera ``centre`` sees it, and its nearness to the camera ``(M,)``
    (1 / metres; 0 at infinity)."""
    width = inverse_depth.shape[1]
    q = inverse_depth[row0 : row0 + len(rays) // width].reshape(-1).float()
    x, y, z = (torch.addcmul(rays[:, k], q, centre[k], value=-1.0) for k in range(3))
    nearness = q / torch.sqrt(x * x + y * y + z * z)
    point = component_points(x, y, z)  # longitude over pi, latitude over pi / 2: both in [-1, 1]
    column = ((point[:, 0] + 1.0) * (0.5 * buffer_width)).long().clamp_(0, buffer_width - 1)
    row = ((point[:, 1] + 1.0) * (0.25 * buffer_width)).long().clamp_(0, buffer_width // 2 - 1)
    return row * buffer_width + column, nearness
