"""Full-resolution stitching of any calibrated rig: a depth at a working size, every input resampled
at the output's size along its own sight line.

For a rig of ``N >= 2`` cameras (any lens rigjax models, any image size; :mod:`learnstitch.fullres.rig`)
and an output panorama ``W x W / 2``:

1. each camera's map from world direction to image pixel is tabulated through rigjax's camera
   model (:mod:`learnstitch.fullres.sight`);
2. the panorama's inverse depth is estimated on a small working canvas
   (:mod:`learnstitch.fullres.depth`: a plane sweep of the inputs, or a depth given by the caller
   or a network), and with the fitted colour correction, each input's exposure and the lens's
   vignetting are fitted in the working canvas's overlaps (:mod:`learnstitch.network.photometry`);
   the working depth is then refined on finer canvases by the inputs' agreement
   (:mod:`learnstitch.fullres.refine`), the finest becoming the working depth;
3. the output is rendered in tiles of whole rows, ``render.tile_pixels`` pixels at most: each
   pixel's inverse depth ``q`` brought up from the working canvas (:func:`learnstitch.fullres.depth.upsample`, edge pixels
   choosing by the full-resolution inputs' agreement), every **full-resolution** input sampled
   along ``w - q c_i`` and the inputs feather-blended (weights falling to 0 at the edge of what
   each sees, :func:`learnstitch.fullres.sight.views`); where no input sees along the depth's
   sight lines (the blind spot a near depth opens under a rig), the pixel is rendered at
   infinity, as the rotation-only stitch draws it. Given a depth at the output's size (a depth
   the caller has), an input whose sight line to a pixel's point meets a nearer surface of that
   depth first is not blended there (:mod:`learnstitch.fullres.occlusion`); the working depth
   brought up is too coarse for that test (it cost the network's depth 0.1 dB on three fisheyes
   0.4 m out), so it blends every input that sees the point's direction.

Step 1 depends on the rig alone and step 2 on each frame: :mod:`learnstitch.fullres.stitcher` does
step 1 once per rig and step 2 per frame; this module renders one frame (step 3,
:func:`render_frame`).

With every centre at the origin the depth changes nothing and this is the rotation-only stitch of
the rig's calibration; given the true depth and which inputs see each point it is the depth
oracle (``tests/learnstitch/test_fullres.py`` checks both).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import torch

from ..network.photometry import correction
from .config import RenderConfig
from .depth import Depth, Upsampled, bring_up, pano_rays, upsample
from .occlusion import unoccluded
from .sight import SightTables, sample_images, views

# With render.blend: network, each input's weight is its feather times its network share plus this.
_SHARE_FLOOR = 1e-3


class Photometry(NamedTuple):
    """The colour correction of a frame's inputs (:mod:`learnstitch.network.photometry`)."""

    exposure: torch.Tensor  # (N,) each input's log exposure
    vignetting: torch.Tensor  # (2,) the lens's vignetting coefficients b, c of log V(r) = b r^2 + c r^4

    @classmethod
    def none(cls, count: int) -> Photometry:
        """No correction for ``count`` inputs."""
        return cls(torch.zeros(count), torch.zeros(2))


def render_frame(
    images: list[torch.Tensor],
    tables: SightTables,
    width: int,
    config: RenderConfig,
    depth: Depth,
    photometry: Photometry | None,
    used: torch.Tensor | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The panorama ``(H, W, 3)`` uint8 of ``images`` ``(3, h_i, w_i)`` (float32 in [0, 1]) through
    the rig's sight ``tables``, ``width`` pixels wide, with its ``covered`` mask ``(H, W)``: step 3 of
    the module docstring, tile by tile, at ``depth`` and with the ``photometry`` (``None``: none).
    ``used`` ``(H, W)``: filled with the inverse depth each pixel was rendered at (0 where it was
    rendered at infinity)."""
    height = width // 2
    pano = np.zeros((height, width, 3), np.uint8)
    covered = np.zeros((height, width), bool)
    # Working pixels of parallax per unit of inverse depth: the widest baseline's, in radians, times
    # the working canvas's pixels per radian. In working pixels, an edge is the same set of pixels
    # at any output size (in output pixels, a smooth surface's gentle slope would count as an edge
    # at 8K and not at 2K).
    reach = float(tables.centres.norm(dim=-1).max()) * depth.working.shape[-1] / (2.0 * math.pi)
    threshold = reach / config.edge_parallax_px if config.edge_parallax_px > 0 else 0.0

    def colours_at(rays: torch.Tensor, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        seen = views(tables, rays, q)
        rgb = sample_images(images, seen.xy, seen.visible)  # (N, 3, M)
        if photometry is not None:
            rgb = (
                rgb * correction(photometry.exposure[None], photometry.vignetting[None], seen.radius[None])[0][:, None]
            )
        return rgb, seen.feather, seen.visible

    tile_rows = max(1, config.tile_pixels // width)
    seeing, tested = depth.visibility, False  # given: the truth's (the depth oracle)
    if (
        seeing is None
        and depth.full is not None  # a depth at the output's size: the working one brought up is too coarse
        and config.occlusion_tolerance > 0.0
        and bool(tables.centres.any())
    ):
        seeing = unoccluded(tables.centres, depth.full, config.occlusion_scale, config.occlusion_tolerance, tile_rows)
        tested = True
    for row0 in range(0, height, tile_rows):
        rows = min(tile_rows, height - row0)
        rays = pano_rays(width, height, row0, rows).reshape(-1, 3)
        shares = None
        if depth.full is not None:
            q = depth.full[row0 : row0 + rows].reshape(-1).float()
        else:
            q, up = _brought_up(depth.working, width, height, row0, rows, rays, threshold, colours_at)
            if depth.shares is not None:  # a little of the feather alone: an input the network gave nothing counts
                shares = bring_up(depth.shares, up) + _SHARE_FLOOR
        rgb, weight, _ = colours_at(rays, q)
        if shares is not None:
            weight = weight * shares
        if seeing is not None:  # only the inputs that see the point
            visible = seeing[:, row0 : row0 + rows].reshape(len(images), -1).to(weight.dtype)
            if tested:  # where the test leaves the point to none, the inputs that see its direction
                visible = torch.where((weight * visible).sum(dim=0) <= 0, torch.ones_like(visible), visible)
            weight = weight * visible
        total = weight.sum(dim=0)
        out = (rgb * weight[:, None]).sum(dim=0) / total.clamp_min(1e-12)
        blind = total <= 0
        if blind.any():  # nothing sees along the depth's sight lines: the pixel at infinity
            rgb0, weight0, _ = colours_at(rays[blind], torch.zeros(int(blind.sum())))
            out[:, blind] = (rgb0 * weight0[:, None]).sum(dim=0) / weight0.sum(dim=0).clamp_min(1e-12)
            total = total.clone()
            total[blind] = weight0.sum(dim=0)
            q = torch.where(blind, 0.0, q)
        if used is not None:
            used[row0 : row0 + rows] = q.reshape(rows, width)
        tile = (out.clamp(0.0, 1.0) * 255.0 + 0.5).to(torch.uint8).T.reshape(rows, width, 3)
        pano[row0 : row0 + rows] = tile.numpy()
        covered[row0 : row0 + rows] = (total > 0).reshape(rows, width).numpy()
    return pano, covered


def _brought_up(
    working: torch.Tensor, width: int, height: int, row0: int, rows: int, rays, threshold: float, colours_at
) -> tuple[torch.Tensor, Upsampled]:
    """Rows ``row0 ..`` of the output's inverse depth ``(M,)``: the working depth brought up, edge
    pixels picked by the inputs' agreement (:func:`_pick`); and the bilinear bringing up."""
    up = upsample(working, width, height, row0, rows, threshold)
    q = up.value
    if up.edge.any():
        q = q.clone()
        q[up.edge] = _pick(up.candidates[:, up.edge], up.weights[:, up.edge], rays[up.edge], colours_at)
    return q, up


def _pick(candidates: torch.Tensor, weights: torch.Tensor, rays: torch.Tensor, colours_at) -> torch.Tensor:
    """For edge pixels (rays ``(E, 3)``), the candidate inverse depth ``(4, E)`` at which the
    full-resolution inputs that see the point agree best (least variance over them, two or more
    needed); where none is seen twice, the candidate of the largest bilinear weight ``(4, E)``."""
    k, e = candidates.shape
    rgb, _, visible = colours_at(rays.repeat(k, 1), candidates.reshape(-1))
    part = visible.to(rgb.dtype)  # (N, K E); rgb is zero where not visible
    count = part.sum(dim=0).clamp_min(1.0)
    mean = rgb.sum(dim=0) / count
    variance = (rgb * rgb).sum(dim=(0, 1)) / count - (mean * mean).sum(dim=0)
    variance = torch.where(part.sum(dim=0) >= 2, variance, torch.inf).reshape(k, e).T.contiguous()  # (E, K)
    best, nearest = variance.argmin(dim=1), weights.T.contiguous().argmax(dim=1)
    choice = torch.where(torch.isfinite(variance.amin(dim=1)), best, nearest)
    return candidates.gather(0, choice[None])[0]
