"""The panorama's inverse depth at a working size, and brought back to the output's.

Stage one of full-resolution stitching. The inputs are resampled onto a small equirectangular
canvas (``render.working_width``, 2:1) through their sight tables, each read from a box-filtered
level of its image whose pixels are about the working canvas's size, and swept over inverse-depth
planes through the rig's centres, as the rig-aware network sweeps them
(:mod:`learnstitch.network.sweep`; any number of cameras, in any order: the cost is the variance
of the inputs that see a point). Each working pixel takes the plane of least relative cost plus a
small preference for far planes, so a pixel the inputs cannot tell (one camera only, no texture)
stays at infinity, as a rotation-only stitch assumes. A plane is chosen, not averaged: a depth
that blends a near pole with its background resamples the background over the pole.

Stage two brings that depth to each output pixel (:func:`upsample`): bilinearly where the four
working pixels around it agree, and where they do not (a depth edge, whose parallax between them
exceeds ``render.edge_parallax_px`` working pixels) the one of the four at which the
full-resolution inputs agree best there (:mod:`learnstitch.fullres.render`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from ..network.depth import relative_cost
from ..network.sweep import inverse_depth_planes, matching_cost, sweep_points
from ..network.warp import sample_wrapped
from .config import RenderConfig
from .sight import SightTables, sample_images, views

# Planes swept at a time (bounds the memory of the sweep, whatever the plane count).
_PLANE_CHUNK = 8


def pano_rays(width: int, height: int, row0: int = 0, rows: int | None = None) -> torch.Tensor:
    """``(rows, width, 3)`` float32 unit world rays of rows ``row0 ..`` of a 360 x 180 equirectangular
    canvas ``width x height``: rigjax's (pixel centres, longitude ``atan2(x, z)``, latitude
    ``atan2(y, hypot(x, z))``, ``+`` right and down), computed in float64."""
    rows = height - row0 if rows is None else rows
    lon = (torch.arange(width, dtype=torch.float64) + 0.5) / width * (2.0 * math.pi) - math.pi
    lat = (torch.arange(row0, row0 + rows, dtype=torch.float64) + 0.5) / height * math.pi - 0.5 * math.pi
    # Separable: the trigonometry once per row and per column, the same float64 products as over a meshgrid.
    cos_lat, sin_lat = lat.cos()[:, None], lat.sin()[:, None]
    out = torch.empty(rows, width, 3, dtype=torch.float32)
    out[..., 0] = cos_lat * lon.sin()
    out[..., 1] = sin_lat.expand(rows, width)
    out[..., 2] = cos_lat * lon.cos()
    return out


def pixel_rays(width: int, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``(M, 3)`` float64 unit world rays of pixel coordinates ``(x, y)`` ``(M,)`` (any, not only
    pixel centres) of a ``width x width / 2`` equirectangular canvas, as :func:`pano_rays` maps
    pixel centres (pixel ``(0, 0)``'s centre at ``(0, 0)``)."""
    lon = (np.asarray(x, np.float64) + 0.5) / width * (2.0 * math.pi) - math.pi
    lat = (np.asarray(y, np.float64) + 0.5) / (width // 2) * math.pi - 0.5 * math.pi
    return np.stack([np.cos(lat) * np.sin(lon), np.sin(lat), np.cos(lat) * np.cos(lon)], -1).reshape(-1, 3)


def pyramid_level(tables: SightTables, width: int) -> list[int]:
    """Per camera, the box-filter level ``L`` (images shrunk ``2 ** L`` times) whose pixels are
    nearest in size to a panorama ``width`` pixels around."""
    per_radian = width / (2.0 * math.pi)
    return [max(0, round(math.log2(max(float(f), 1e-6) / per_radian))) for f in tables.focal]


def shrink(image: torch.Tensor, level: int) -> torch.Tensor:
    """``image`` ``(C, h, w)`` box-filtered ``2 ** level`` times smaller (pixel ``k`` the mean of
    full-size pixels ``k 2^L .. (k + 1) 2^L - 1``; a remainder of rows or columns dropped)."""
    if level <= 0:
        return image
    side = 2**level
    height, width = image.shape[-2] // side, image.shape[-1] // side
    pixels = image.permute(1, 2, 0)  # (h, w, C)
    if (
        pixels.is_contiguous()
        and image.device.type == "cpu"
        and image.dtype == torch.float32
        and height
        and width
        and not image.requires_grad
    ):
        # A decoded frame's image is channels-last (float_images): OpenCV's area resize by whole
        # boxes is avg_pool2d's mean, and runs over that layout without a copy.
        box = cv2.resize(pixels[: height * side, : width * side].numpy(), (width, height), interpolation=cv2.INTER_AREA)
        return torch.from_numpy(box.reshape(height, width, -1)).permute(2, 0, 1)
    return F.avg_pool2d(image[None], side)[0]


def working_images(
    images: list[torch.Tensor], tables: SightTables, width: int, pyramid: list[dict[int, torch.Tensor]] | None = None
) -> list[tuple[torch.Tensor, float]]:
    """Each input at its :func:`pyramid_level` for a working canvas ``width`` pixels around, with
    the factor it was shrunk by. ``pyramid``: each input's levels made so far (level -> image),
    filled in: a level is shrunk from the nearest finer level made, not from the full-size image
    (boxes of powers of two compose: the same means, to float round-off)."""
    pyramid = pyramid if pyramid is not None else [{} for _ in images]
    out = []
    for image, made, level in zip(images, pyramid, pyramid_level(tables, width)):
        if level not in made:
            below = max((m for m in made if m < level), default=0)
            made[level] = shrink(made.get(below, image), level - below)
        out.append((made[level], 2.0**level))
    return out


def working_views(
    shrunk: list[tuple[torch.Tensor, float]], tables: SightTables, inverse_depth: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The inputs (:func:`working_images`) warped onto the working canvas through its inverse depth
    ``(h, w)`` (zeros: the inputs at infinity, what the sweep reads): ``(N, 3, h, w)`` colours
    (zero where unseen), ``(N, h, w)`` masks (float) and lens radii (what
    :func:`learnstitch.network.photometry.fit_photometry` reads)."""
    n, (height, width) = tables.count, inverse_depth.shape
    colours, visible, radius = sample_views(
        shrunk, tables, pano_rays(width, height).reshape(-1, 3), inverse_depth.reshape(-1)
    )
    return colours.reshape(n, 3, height, width), visible.reshape(n, height, width), radius.reshape(n, height, width)


def sample_views(
    shrunk: list[tuple[torch.Tensor, float]], tables: SightTables, rays: torch.Tensor, inverse_depth: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The inputs (:func:`working_images`) sampled along their sight lines to the points at
    ``inverse_depth`` ``(M,)`` along unit rays ``(M, 3)``: ``(N, 3, M)`` colours (zero where
    unseen), ``(N, M)`` masks (float) and lens radii."""
    scales = torch.tensor([scale for _, scale in shrunk])
    seen = views(tables, rays, inverse_depth, scales)
    colours = torch.cat(
        [
            sample_images([image], seen.xy[k : k + 1], seen.visible[k : k + 1], scale)
            for k, (image, scale) in enumerate(shrunk)
        ]
    )
    return colours, seen.visible.float(), seen.radius


def sweep_depth(inputs: torch.Tensor, masks: torch.Tensor, centres: torch.Tensor, config: RenderConfig) -> torch.Tensor:
    """The working canvas's inverse depth ``(h, w)`` (1 / metres, 0 at infinity) from inputs ``(N, 3, h, w)`` and masks ``(N, h, w)`` of
    :func:`working_views` at infinity and camera centres ``(N, 3)``; see the module docstring."""
    n, _, height, width = inputs.shape
    planes = inverse_depth_planes(config.depth_planes, config.max_inverse_depth)
    rays = pano_rays(width, height)
    x = torch.cat([inputs, masks[:, None].to(inputs.dtype)], dim=1)  # (N, 4, h, w)
    wrap = 2.0 / width  # the canvas's +-180 degree edge: a bilinear sample reads a pixel across it
    costs, overlaps = [], []  # per chunk of planes
    for start in range(0, len(planes), _PLANE_CHUNK):
        chunk = planes[start : start + _PLANE_CHUNK]
        grid = sweep_points(rays, centres, chunk)  # (N, P, h, w, 2)
        swept = sample_wrapped(x, grid.reshape(n, -1, width, 2), wrap).reshape(n, 4, len(chunk), height, width)
        cost, overlap = matching_cost(swept[None, :, :3], swept[None, :, 3], config.cost_window)
        costs.append(cost)
        overlaps.append(overlap)
    cost, overlap = torch.cat(costs, dim=1), torch.cat(overlaps, dim=1)
    score = (relative_cost(cost, overlap) + config.far_prior * torch.linspace(0.0, 1.0, len(planes))[:, None, None])[0]
    return subplane_minimum(score, planes)


def subplane_minimum(score: torch.Tensor, planes: torch.Tensor) -> torch.Tensor:
    """``(h, w)``: the inverse depth of the least ``score`` ``(P, h, w)`` over evenly spaced
    ``planes``, between planes by the parabola through the best plane and its two neighbours (at
    the first or last plane, that plane)."""
    best = score.min(dim=0).indices  # argmin over the first dimension is several times slower on CPU
    inner = best.clamp(1, len(planes) - 2)
    left, mid, right = (score.gather(0, (inner + k)[None])[0] for k in (-1, 0, 1))
    curvature = left - 2.0 * mid + right
    shift = torch.where(curvature > 1e-9, 0.5 * (left - right) / curvature.clamp_min(1e-9), torch.zeros_like(mid))
    shift = torch.where(best == inner, shift.clamp(-0.5, 0.5), torch.zeros_like(shift))
    return planes[best] + shift * (planes[1] - planes[0])


class Upsampled(NamedTuple):
    """A working depth brought to ``M`` output pixels."""

    value: torch.Tensor  # (M,) bilinear
    candidates: torch.Tensor  # (4, M) the four working pixels around each output pixel
    weights: torch.Tensor  # (4, M) their bilinear weights
    index: torch.Tensor  # (4, M) those pixels' flat indices on the working canvas (row-major)
    edge: torch.Tensor  # (M,) bool: the candidates' parallax differs by more than the threshold


def upsample(
    working: torch.Tensor, width: int, height: int, row0: int, rows: int, parallax_per_inverse_depth: float
) -> Upsampled:
    """Working inverse depth ``(h, w)`` at output rows ``row0 .. row0 + rows`` of a ``width x
    height`` panorama (flattened, row-major). Convention: both canvases cover 360 x 180 degrees
    with pixel centres at ``(x + 0.5) / W``; columns wrap across +-180 degrees, rows clamp at the
    poles. ``parallax_per_inverse_depth``: the parallax, in whatever pixels the caller counts
    edges in (the renderer: working pixels over ``render.edge_parallax_px``), per unit of inverse
    depth; an output pixel is an ``edge`` where its candidates' parallax differs by more than 1."""
    h, w = working.shape
    u = (torch.arange(width, dtype=torch.float64) + 0.5) * (w / width) - 0.5
    v = (torch.arange(row0, row0 + rows, dtype=torch.float64) + 0.5) * (h / height) - 0.5
    x0, y0 = u.floor(), v.floor()
    fx, fy = (u - x0).float(), (v - y0).float()
    x0 = x0.long()
    xs = (x0 % w, (x0 + 1) % w)
    ys = (y0.long().clamp(0, h - 1), (y0.long() + 1).clamp(0, h - 1))
    index = torch.stack([(yy * w)[:, None] + xx[None, :] for yy in ys for xx in xs]).reshape(4, -1)
    candidates = working.reshape(-1)[index]
    wx, wy = (1.0 - fx, fx), (1.0 - fy, fy)
    weights = torch.stack([(wy[a][:, None] * wx[b][None, :]) for a in range(2) for b in range(2)]).reshape(4, -1)
    spread = candidates.amax(dim=0) - candidates.amin(dim=0)
    edge = spread * parallax_per_inverse_depth > 1.0
    return Upsampled((weights * candidates).sum(dim=0), candidates, weights, index, edge)


def upsample_canvas(maps: torch.Tensor, width: int) -> torch.Tensor:
    """Maps ``(..., h, w)`` on a 2:1 canvas brought to one ``width`` pixels wide, bilinearly, as
    :func:`upsample` brings them (columns wrapping around, rows clamped at the poles)."""
    shape, (h, w) = maps.shape[:-2], maps.shape[-2:]
    flat = maps.reshape(-1, h, w)
    factor = width // w
    if factor * w != width:  # not a whole factor: pixel by pixel
        up = upsample(flat[0], width, width // 2, 0, width // 2, 0.0)
        return bring_up(flat, up).reshape(*shape, width // 2, width)
    if factor == 1:
        return maps
    # A column wrapped onto each side, the whole brought up and the factor's columns cut off each side again.
    padded = F.pad(flat[None], (1, 1, 0, 0), mode="circular")
    up = F.interpolate(padded, scale_factor=factor, mode="bilinear", align_corners=False)[0, :, :, factor:-factor]
    return up.reshape(*shape, width // 2, width)


class Depth(NamedTuple):
    """A frame's depth as the renderer reads it (a depth source's result,
    :mod:`learnstitch.fullres.stitcher`): at the working size, or at the output's."""

    working: torch.Tensor  # (h, w) the working canvas's inverse depth, 1 / metres (2:1)
    shares: torch.Tensor | None = None  # (N, h, w) each input's share of a network's blend there
    full: torch.Tensor | None = None  # (H, W) at the output's size: replaces the working depth's upsampling
    visibility: torch.Tensor | None = None  # (N, H, W) which inputs see each pixel's point (with ``full``)
    confidence: torch.Tensor | None = (
        None  # (h, w) in [0, 1], with a refined working depth (learnstitch.fullres.refine)
    )


def network_depth(
    model: torch.nn.Module, shrunk: list[tuple[torch.Tensor, float]], tables: SightTables, width: int
) -> Depth:
    """A rig-aware network's (:class:`learnstitch.network.depth.DepthStitchNet`) inverse depth
    and blend weights on its own canvas (``width``: its config's ``data.pano_width``), from
    the inputs at that canvas's pyramid levels (:func:`working_images`) warped there at infinity
    through the rig's calibration (what a model of ``model.inputs: calibrated`` reads), with the
    rig's centres."""
    inputs, masks, _ = working_views(shrunk, tables, torch.zeros(width // 2, width))
    device = next(model.parameters()).device
    with torch.no_grad():
        out = model(inputs[None].to(device), masks[None].to(device), centres=tables.centres[None].to(device))
    shares = out.weights[0].float().sum(dim=1)  # over the depth warp and the fallback at infinity
    return Depth(out.inverse_depth[0].float().cpu(), shares=shares.cpu())


def bring_up(maps: torch.Tensor, up: Upsampled) -> torch.Tensor:
    """Working maps ``(C, h, w)`` on the canvas :func:`upsample` brought ``up`` from, at its output
    pixels: ``(C, M)``, bilinear with the same four pixels and weights."""
    return (maps.reshape(maps.shape[0], -1)[:, up.index] * up.weights).sum(dim=1)
