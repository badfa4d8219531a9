"""The working depth refined at finer sizes by the full-resolution inputs' agreement.

A network's depth on its 256-wide canvas is imprecise where the output's pixels are not: an
inverse depth half a plane off moves a road point 2 m away five pixels of a 2048-wide panorama and
less than one of the canvas. This stage searches, around that depth, the inverse depth at which
the inputs that see a point agree, coarse to fine, on ``render.refine_levels`` canvases up to
``render.refine_scale`` of the output's width (at most ``render.refine_max_width``), each half the
next (256, 512 and 1024 for a 2048-wide output by default; 512, 1024 and 2048 for an 8K one). The finest level's depth is the working depth the renderer brings up
(:mod:`learnstitch.fullres.render`: bilinearly, and at its depth edges the neighbour the inputs
agree best at), with a confidence per pixel.

At each level, with ``q`` the depth so far brought up bilinearly (the working depth at the first)
and ``s`` the level's step (the plane spacing ``max_inverse_depth / (depth_planes - 1)`` at the
first level, halved at each next):

1. the hypotheses ``q + k s``, ``k = -K .. K`` (``K = render.refine_steps`` at the first level, 1 at
   the next: what the parabola left uncertain), warp the inputs, read at the level's pyramid level
   (:func:`learnstitch.fullres.depth.working_images`) and colour-corrected by the frame's fitted
   correction; each pixel costs the variance of the colours of the inputs that see its point,
   truncated at ``refine_truncation`` (robust: an occluder or a specular spot costs no more than
   that); only the pixels two or more inputs see at ``q`` are sampled at the other hypotheses, and
   after the first level only those the level before saw so, and a pixel around (the rest keep
   ``q``, and the guide the level before's);
2. each hypothesis's cost is aggregated edge-aware by a guided filter (He, Sun and Tang, 2010) of
   radius ``refine_radius`` whose guide is the inputs' mean at ``q``: its windows follow the
   image's edges, so a pole's cost does not bleed into the wall behind it;
3. the cost relative to its mean over the hypotheses, plus ``refine_prior`` times the squared
   offset ``(k s)`` in plane spacings (a pull toward ``q``: where the inputs cannot tell, the
   depth stays), picks a hypothesis, and a parabola through it and its neighbours the inverse depth
   between them (the sweep's rule, :func:`learnstitch.fullres.depth.subplane_minimum`);
4. the pixel's **confidence** is how far its least relative cost lies below the mean (``1 - least /
   mean``, in ``[0, 1]``), zero where fewer than two inputs see the point at any hypothesis; a
   pixel below ``refine_min_confidence`` keeps ``q``, with confidence 0.

Where one input alone sees, nothing can be matched: the depth there is the working depth's.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import cv2
import torch

from ..network.photometry import correction
from .config import RenderConfig
from .depth import pano_rays, sample_views, subplane_minimum, upsample_canvas
from .render import Photometry
from .sight import SightTables

# The guided filter's regulariser, in squared colour units: edges fainter than about its square root are smoothed over.
_GUIDE_EPSILON = 1e-3


class Refined(NamedTuple):
    """A depth refined at the finest level: ``(h, w)`` each, ``h = w / 2``."""

    inverse_depth: torch.Tensor  # 1 / metres (0 at infinity)
    confidence: torch.Tensor  # in [0, 1]: 0 where the inputs did not tell (fewer than two see, or a flat cost)


def level_widths(config: RenderConfig, width: int, start: int = 0) -> list[int]:
    """The refinement's canvas widths for an output ``width`` pixels wide, coarse to fine: the
    finest ``refine_scale`` of it (at most ``refine_max_width``), and at least the ``start``
    depth's width (a refinement ends no coarser than it began) up to the output's, each coarser
    half the next (even, at least 16)."""
    finest = min(max(min(config.refine_scale * width, config.refine_max_width), start), width)
    widths = [max(16, 2 * round(finest / 2))]
    for _ in range(config.refine_levels - 1):
        widths.insert(0, max(16, 2 * round(widths[0] / 4)))
    return widths


def refine_depth(
    levels: Callable[[int], list[tuple[torch.Tensor, float]]],
    tables: SightTables,
    prior: torch.Tensor,
    photometry: Photometry | None,
    config: RenderConfig,
    widths: list[int],
) -> Refined:
    """The inverse depth refined from ``prior`` ``(h, w)`` (the working depth) on canvases
    ``widths`` (coarse to fine), by the inputs at each width's pyramid level (``levels(width)``:
    :meth:`learnstitch.fullres.stitcher.Frame.working`) with the colour correction ``photometry``
    (None: as they are); see the module docstring. What a level found is kept as its change to
    ``prior``, brought up with it: where no level changes it, the result is ``prior`` brought up
    bilinearly (a level narrower than ``prior`` does not blur it; the finest should be no narrower,
    :func:`level_widths`). The confidence is the finest level's."""
    spacing = config.max_inverse_depth / (config.depth_planes - 1)
    prior = prior.float()
    change = torch.zeros_like(prior)
    step, reach = spacing, config.refine_steps
    q, confidence = prior, torch.zeros_like(prior)
    active, guide = None, None
    for width in widths:
        start = upsample_canvas(prior, width)
        q = start + upsample_canvas(change, width)
        if active is not None:  # only where the level before had two inputs to match, and a pixel around
            active, guide = upsample_canvas(active, width) > 0, upsample_canvas(guide, width)
        offsets = torch.arange(-reach, reach + 1, dtype=torch.float32) * step
        cost, valid, guide, seen = _costs(
            levels(width), tables, q, offsets, photometry, config.refine_truncation, active, guide, config.tile_pixels
        )
        active = _box(seen[None], 1)[0]
        cost = _guided_filter(guide, cost, config.refine_radius)
        relative = cost / cost.mean(dim=0, keepdim=True).clamp_min(1e-12)
        score = relative + config.refine_prior * (offsets / spacing)[:, None, None] ** 2
        found = q + subplane_minimum(score, offsets)
        confidence = (1.0 - relative.min(dim=0).values).clamp(0.0, 1.0) * valid
        keep = confidence < config.refine_min_confidence
        q = torch.where(keep, q, found).clamp_min(0.0)
        change = q - start
        confidence = confidence.masked_fill(keep, 0.0)
        # The next level searches half a step either side: what the parabola left uncertain.
        step, reach = step / 2.0, 1
    return Refined(q, confidence)


def _costs(
    shrunk: list[tuple[torch.Tensor, float]],
    tables: SightTables,
    q: torch.Tensor,
    offsets: torch.Tensor,
    photometry: Photometry | None,
    truncation: float,
    active: torch.Tensor | None = None,
    guide: torch.Tensor | None = None,
    chunk: int = 262144,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Each hypothesis ``q + offset``'s cost ``(K, h, w)`` (the variance of the inputs that see
    the point, truncated at ``truncation``, which is also the cost where fewer than two see it),
    whether two or more inputs see the point at every hypothesis ``(h, w)`` (float), the guide:
    the grey of the inputs' mean at ``q``, and whether two or more see the point at ``q`` (float). Hypotheses other than ``q`` itself are sampled only
    where two or more inputs see the point at ``q``; ``q`` itself only where ``active`` ``(h, w)``
    (None: everywhere), the ``guide`` given ``(h, w)`` kept elsewhere; ``chunk`` points sampled at a
    time (bounds the memory at any width)."""
    height, width = q.shape
    rays, flat = pano_rays(width, height).reshape(-1, 3), q.reshape(-1)
    costs = torch.full((len(offsets), height * width), truncation)
    centre = len(offsets) // 2
    index = torch.arange(height * width) if active is None else active.reshape(-1).nonzero()[:, 0]
    rays, flat = rays[index], flat[index]
    variance, twice, mean = _spread(shrunk, tables, rays, flat, photometry, chunk)
    guide = torch.zeros(height * width) if guide is None else guide.reshape(-1).clone()
    guide[index] = mean.mean(dim=0)
    costs[centre, index] = torch.where(twice, variance.clamp(max=truncation), truncation)
    pick, rays, flat = index[twice], rays[twice], flat[twice]
    valid = torch.ones(len(pick), dtype=torch.bool)
    for k, offset in enumerate(offsets.tolist()):
        if k != centre:
            variance, seen, _ = _spread(shrunk, tables, rays, flat + offset, photometry, chunk)
            costs[k, pick] = torch.where(seen, variance.clamp(max=truncation), truncation)
            valid &= seen
    everywhere, twice = torch.zeros(height * width), torch.zeros(height * width)
    everywhere[pick], twice[pick] = valid.float(), 1.0
    return (
        costs.reshape(-1, height, width),
        everywhere.reshape(height, width),
        guide.reshape(height, width),
        twice.reshape(height, width),
    )


def _spread(
    shrunk: list[tuple[torch.Tensor, float]],
    tables: SightTables,
    rays: torch.Tensor,
    q: torch.Tensor,
    photometry: Photometry | None,
    chunk: int,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """At the points at inverse depth ``q`` ``(M,)`` along ``rays`` ``(M, 3)``: the colour variance
    over the inputs that see each point (summed over the channels) ``(M,)``, whether two or more do
    ``(M,)`` and their mean colour ``(3, M)``; ``chunk`` points at a time."""
    parts = []
    for begin in range(0, max(len(q), 1), chunk):
        colours, masks, radius = sample_views(shrunk, tables, rays[begin : begin + chunk], q[begin : begin + chunk])
        if photometry is not None:
            factor = correction(photometry.exposure[None], photometry.vignetting[None], radius[None])[0]
            colours = colours * factor[:, None]
        count = masks.sum(dim=0)
        mean = colours.sum(dim=0) / count.clamp_min(1.0)  # colours are zero where unseen
        variance = (colours * colours).sum(dim=(0, 1)) / count.clamp_min(1.0) - (mean * mean).sum(dim=0)
        parts.append((variance, count >= 2, mean))
    return tuple(torch.cat(part, dim=-1) for part in zip(*parts))


def _box(x: torch.Tensor, radius: int) -> torch.Tensor:
    """The mean of ``x`` ``(C, h, w)`` over a ``2 radius + 1`` square around each pixel of an
    equirectangular canvas: columns wrap around, rows are clamped at the poles (OpenCV's box
    filter, channels-last)."""
    side = 2 * radius + 1
    pixels = cv2.copyMakeBorder(x.permute(1, 2, 0).contiguous().numpy(), 0, 0, radius, radius, cv2.BORDER_WRAP)
    box = cv2.boxFilter(pixels, -1, (side, side), borderType=cv2.BORDER_REPLICATE)[:, radius:-radius]
    return torch.from_numpy(box.reshape(*box.shape[:2], -1)).permute(2, 0, 1)


def _guided_filter(guide: torch.Tensor, x: torch.Tensor, radius: int) -> torch.Tensor:
    """``x`` ``(C, h, w)`` filtered by the grey ``guide`` ``(h, w)``: per window, the least-squares
    line ``x ~ a guide + b``, its coefficients averaged over the windows covering a pixel (He,
    Sun and Tang, *Guided image filtering*, 2010); radius 0: ``x`` unchanged."""
    if radius <= 0:
        return x
    g = guide[None]
    stats = _box(torch.cat([g, g * g, x, x * g]), radius)
    mean_g, mean_gg = stats[:1], stats[1:2]
    count = x.shape[0]
    mean_x, mean_xg = stats[2 : 2 + count], stats[2 + count :]
    a = (mean_xg - mean_g * mean_x) / (mean_gg - mean_g * mean_g + _GUIDE_EPSILON)
    b = mean_x - a * mean_g
    coefficients = _box(torch.cat([a, b]), radius)
    return coefficients[:count] * g + coefficients[count:]
