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
3. the output is rendered in tiles of whole rows, ``render.tile_pixels`` pixels at most: each
   pixel's inverse depth ``q`` brought up from the working canvas (:func:`learnstitch.fullres.depth.upsample`, edge pixels
   choosing by the full-resolution inputs' agreement), every **full-resolution** input sampled
   along ``w - q c_i`` and the inputs feather-blended (weights falling to 0 at the edge of what
   each sees, :func:`learnstitch.fullres.sight.views`); where no input sees along the depth's
   sight lines (the blind spot a near depth opens under a rig), the pixel is rendered at
   infinity, as the rotation-only stitch draws it.

With every centre at the origin the depth changes nothing and this is the rotation-only stitch of
the rig's calibration; given the true depth and which inputs see each point it is the depth
oracle (``tests/learnstitch/test_fullres.py`` checks both).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
import torch

from rigjax.errors import ConfigError

from ..network.photometry import correction, fit_photometry
from .config import RenderConfig
from .depth import Working, bring_up, pano_rays, sweep_depth, upsample, working_images, working_views
from .rig import Rig
from .sight import SightTables, sample_images, sight_tables, views

# With render.blend: network, each input's weight is its feather times its network share plus this.
_SHARE_FLOOR = 1e-3


class Stitched(NamedTuple):
    """A full-resolution panorama and what made it."""

    pano: np.ndarray  # (H, W, 3) uint8 RGB
    covered: np.ndarray  # (H, W) bool: some input sees the pixel (at its depth or at infinity)
    inverse_depth: torch.Tensor  # (h, w) the working canvas's inverse depth, 1 / metres
    exposure: torch.Tensor  # (N,) each input's fitted log exposure (zeros without photometry)
    vignetting: torch.Tensor  # (2,) the lens's fitted vignetting coefficients b, c of log V(r) = b r^2 + c r^4
    seconds: dict[str, float]  # wall time of each stage


def float_images(rig: Rig) -> list[torch.Tensor]:
    """The rig's images as ``(3, h, w)`` float32 in [0, 1]."""
    return [torch.from_numpy(image).permute(2, 0, 1).float().div_(255.0) for image in rig.images]


def stitch_rig(
    rig: Rig,
    width: int | None = None,
    config: RenderConfig | None = None,
    *,
    working_depth: torch.Tensor | Callable[[Callable[[int], list], SightTables], torch.Tensor | Working] | None = None,
    inverse_depth: torch.Tensor | None = None,
    visibility: torch.Tensor | None = None,
    circle_deg: np.ndarray | None = None,
) -> Stitched:
    """The panorama of ``rig``, ``width`` pixels wide (default: its project's ``p`` line), 2:1.

    ``working_depth`` ``(h, w)`` (2:1, 1 / metres) replaces the sweep's working-size depth, or
    computes it from the inputs' pyramid levels for a working width (a function of the width:
    :func:`~learnstitch.fullres.depth.working_images`, made once per width) and the rig's
    :class:`~learnstitch.fullres.sight.SightTables` (a network's:
    :func:`~learnstitch.fullres.depth.network_depth`, whose blend weights ``render.blend: network``
    reads); ``inverse_depth`` ``(H, W)`` at the
    output's size replaces both the working depth and its upsampling, and ``visibility``
    ``(N, H, W)`` then says which inputs see each pixel's point (the depth oracle).
    ``circle_deg`` ``(N,)``: the cameras' image circles (default: the rig's, measured from its
    images by :func:`~learnstitch.fullres.rig.load_rig`, at most a circular fisheye's hfov). See
    the module docstring.
    """
    config = config or RenderConfig()
    width = int(width or rig.width)
    if width < 16 or width % 2:
        raise ConfigError(f"the panorama's width must be even and >= 16, got {width}")
    seconds: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(stage: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        seconds[stage] = seconds.get(stage, 0.0) + now - clock
        clock = now

    images = float_images(rig)
    table_width = max(8, 2 * round(config.table_scale * width / 2))
    tables = sight_tables(
        rig.cameras, rig.centres, table_width, circle_deg, None if circle_deg is not None else rig.circle_px
    )
    lap("tables")
    n = tables.count
    shrunk: dict[int, list] = {}  # the inputs' pyramid levels for a working width, made once

    def working(width: int) -> list:
        if width not in shrunk:
            shrunk[width] = working_images(images, tables, width)
        return shrunk[width]

    shares = None  # each input's share of a network's blend at the working size
    if callable(working_depth):
        working_depth = working_depth(working, tables)
        if isinstance(working_depth, Working):
            working_depth, shares = working_depth
        lap("depth")
    if config.blend != "network":
        shares = None
    if inverse_depth is None and working_depth is None:
        if np.any(rig.centres):
            zeros = torch.zeros(config.working_width // 2, config.working_width)
            inputs, masks, _ = working_views(working(config.working_width), tables, zeros)
            working_depth = sweep_depth(inputs, masks, tables.centres, config)
        else:  # every camera at the centre: no parallax, nothing for a depth to do
            working_depth = torch.zeros(config.working_width // 2, config.working_width)
        lap("depth")
    if working_depth is None:  # a full-size depth given: the photometry reads it at the working size
        working_depth = _reduce(inverse_depth, config.working_width)
    exposure, vignetting = torch.zeros(n), torch.zeros(2)
    if config.photometry == "fitted":
        colours, alpha, radius = working_views(working(working_depth.shape[-1]), tables, working_depth)
        fitted = fit_photometry(colours[None], alpha[None], radius[None])  # colours are zero where unseen
        exposure, vignetting = fitted[0][0], fitted[1][0]
        lap("photometry")
    pano, covered = _render(
        images, tables, width, config, working_depth, inverse_depth, visibility, shares, exposure, vignetting
    )
    lap("render")
    return Stitched(pano, covered, working_depth, exposure, vignetting, seconds)


def _reduce(inverse_depth: torch.Tensor, width: int) -> torch.Tensor:
    """A full-size inverse depth at a working ``width``: each working pixel's nearest surface (the
    largest inverse depth of the output pixels it covers)."""
    factor = max(1, inverse_depth.shape[-1] // width)
    reduced = torch.nn.functional.max_pool2d(inverse_depth[None, None].float(), factor)[0, 0]
    return torch.nn.functional.interpolate(reduced[None, None], size=(width // 2, width), mode="nearest")[0, 0]


def _render(
    images: list[torch.Tensor],
    tables: SightTables,
    width: int,
    config: RenderConfig,
    working_depth: torch.Tensor,
    full_depth: torch.Tensor | None,
    visibility: torch.Tensor | None,
    shares: torch.Tensor | None,
    exposure: torch.Tensor,
    vignetting: torch.Tensor,
) -> tuple[np.ndarray, np.ndarray]:
    height = width // 2
    pano = np.zeros((height, width, 3), np.uint8)
    covered = np.zeros((height, width), bool)
    fitted = config.photometry == "fitted"
    # Working pixels of parallax per unit of inverse depth: the widest baseline's, in radians, times
    # the working canvas's pixels per radian. In working pixels, an edge is the same set of pixels
    # at any output size (in output pixels, a smooth surface's gentle slope would count as an edge
    # at 8K and not at 2K).
    reach = float(tables.centres.norm(dim=-1).max()) * working_depth.shape[-1] / (2.0 * math.pi)
    threshold = reach / config.edge_parallax_px if config.edge_parallax_px > 0 else 0.0

    def colours_at(
        rays: torch.Tensor, q: torch.Tensor, weight_of=None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        seen = views(tables, rays, q)
        rgb = sample_images(images, seen.xy, seen.visible)  # (N, 3, M)
        if fitted:
            rgb = rgb * correction(exposure[None], vignetting[None], seen.radius[None])[0][:, None]
        weight = seen.feather if weight_of is None else seen.feather * weight_of
        return rgb, weight, seen.visible

    tile_rows = max(1, config.tile_pixels // width)
    for row0 in range(0, height, tile_rows):
        rows = min(tile_rows, height - row0)
        rays = pano_rays(width, height, row0, rows).reshape(-1, 3)
        given = None if visibility is None else visibility[:, row0 : row0 + rows].reshape(tables.count, -1).float()
        if full_depth is not None:
            q = full_depth[row0 : row0 + rows].reshape(-1).float()
        else:
            up = upsample(working_depth, width, height, row0, rows, threshold)
            q = up.value
            if up.edge.any():
                q = q.clone()
                q[up.edge] = _pick(up.candidates[:, up.edge], up.weights[:, up.edge], rays[up.edge], colours_at)
            if shares is not None:  # a little of the feather alone: an input the network gave nothing still counts
                given = bring_up(shares, up) + _SHARE_FLOOR
        rgb, weight, _ = colours_at(rays, q, given)
        total = weight.sum(dim=0)
        out = (rgb * weight[:, None]).sum(dim=0) / total.clamp_min(1e-12)
        blind = total <= 0
        if blind.any():  # nothing sees along the depth's sight lines: the pixel at infinity
            rgb0, weight0, _ = colours_at(rays[blind], torch.zeros(int(blind.sum())))
            out[:, blind] = (rgb0 * weight0[:, None]).sum(dim=0) / weight0.sum(dim=0).clamp_min(1e-12)
            total = total.clone()
            total[blind] = weight0.sum(dim=0)
        tile = (out.clamp(0.0, 1.0) * 255.0 + 0.5).to(torch.uint8).T.reshape(rows, width, 3)
        pano[row0 : row0 + rows] = tile.numpy()
        covered[row0 : row0 + rows] = (total > 0).reshape(rows, width).numpy()
    return pano, covered


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
