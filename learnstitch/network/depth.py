"""The rig-aware stitching network (``model.warp: depth``): one inverse-depth map shared by all
inputs instead of free 2-D displacements.

The rig's geometry is known — each camera's centre ``c_i`` and nominal orientation — so the
parallax of a panorama pixel has one degree of freedom, its inverse depth ``q``
(:mod:`learnstitch.network.sweep`). For inputs ``I_i`` (the fisheyes unwarped at the nominal
orientations) and masks ``M_i`` the network

1. encodes each input (the encoder of :class:`~learnstitch.network.model.StitchNet`) and regresses,
   from the deepest features, a residual rotation ``R_i`` per input (axis-angle, bounded by
   ``max_rotation_deg``): the cameras' orientation jitter, which the nominal unwarp leaves in;
2. sweeps every input over ``depth_planes`` inverse-depth planes in ``[0, max_inverse_depth]``
   through those rotations and measures the inputs' disagreement per plane where two or more see
   a pixel (:func:`~learnstitch.network.sweep.matching_cost`, no gradient: a fixed measurement),
   and with ``ghost_cost`` the cost at infinity where each input sees each plane's point
   (:func:`~learnstitch.network.sweep.ghost_cost`: a thin near occluder's ghosts, which tell its
   plane from the background both inputs see past it); with ``first_surface`` the nearest plane
   where two inputs' own rays end (the cost read along each input's rays,
   :func:`~learnstitch.network.sweep.ray_ends`): the first surface from the centre, which hides
   whatever the inputs see past it;
3. decodes the features together with the cost volume (joined to every skip connection) into
   per-plane logits ``head - s * cost / mean(cost)`` (``s`` learnt; the head starts at a prior
   for far planes, so the untrained network takes the cost's minimum where there is a clear one
   and infinity elsewhere); with ``first_surface`` a learnt share of each pixel's probability moves
   to its first surface; the soft-argmin of the planes' probabilities is ``q`` (with
   ``surface_rule``, at inference, the first surface wherever it is that many planes nearer);
4. samples input ``i`` along ``R_i normalize(w - q c_i)`` and blends the inputs with a softmax of
   weight logits, as :class:`StitchNet` does, times a colour correction: gain maps from a head
   (``photometry: maps``) or each input's exposure and the lens's vignetting fitted to the
   aligned overlaps (``photometry: fitted``, :mod:`learnstitch.network.photometry`).
   Each input is also warped at infinity, with weights ``exp(-30)`` below its depth warp's: where
   no input sees along the predicted depth's sight lines (the blind spot under the rig, where the
   depth is a guess), the panorama falls back to the true-rotation warp instead of a hole.

The panorama's rays (:func:`learnstitch.data.rig.pano_rays`, rigjax's) and the sweep's sampling
grids (:func:`~learnstitch.network.sweep.sweep_points`) depend on the rig only and are computed
once per canvas size; each step turns every input by its residual rotation (one resampling, at
infinity) and sweeps the turned inputs through those fixed grids. The camera centres are a
buffer outside the weights' state, and every call may pass its own (``forward(centres=...)``,
whose grids are then computed for that call): trained weights run on a rig of other dimensions.
Nothing assumes three cameras but the channel counts fixed at construction.

With ``model.pooling: pooled`` nothing does: the per-input features of every scale meet as their
mean and maximum over the inputs (an absent input, a batch's padding of a smaller rig, takes no
part), the cost is the inputs' variance, and each input's blending weight comes from the pooled
decoder's features beside that input's own pixels (one head shared by all inputs), so one set of
weights stitches rigs of any number of cameras, in any order, with the cameras' centres given per
sample (``forward(centres=...)``). The inputs are unwarped at the rig's calibration and turned by
no residual rotation.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from rigjax.errors import ConfigError

from ..data.rig import pano_rays
from .model import (
    Decoder,
    Encoder,
    ModelConfig,
    StitchOutput,
    blend,
    check_inputs,
    conv,
    gain_maps,
    regressor,
    zero_init,
)
from .photometry import correction, fit_photometry, lens_radius
from .sweep import (
    canvas_points,
    first_surface,
    ghost_cost,
    grown_planes,
    inverse_depth_planes,
    matching_cost,
    plane_colours,
    ray_ends,
    ray_points,
    rotate,
    rotation_matrices,
    supported_planes,
    surface_planes,
    sweep_points,
    towards,
)
from .warp import sample_wrapped

# The depth logits at the start: -s * relative cost with s = 16, so a clear minimum of the cost wins,
# plus a prior falling by 8 from the farthest plane to the nearest, so that a pixel without a
# minimum (no overlap, no texture) starts far away, as the rotation-only stitch assumes.
_INITIAL_SHARPNESS, _INITIAL_FAR_PRIOR = 16.0, 8.0
# The fallback warp's weight logits below the depth warp's: exp(-30), nothing where a depth warp sees.
_FALLBACK_LOGIT = 30.0
# The fill's share at the start: sigmoid(-4), about 2 %.
_INITIAL_FILL_LOGIT = -4.0
# The first surface's share at the start: sigmoid(-2), about 12 %.
_INITIAL_SURFACE_LOGIT = -2.0
# The inputs whose own rays must end at a plane's point for it to be a surface (a left-right check).
_SURFACE_VIEWS = 2
# surface_grow's seeds: the rule's first surface where at least this many others lie within two
# pixels at a plane within one of theirs (a speck of a false match has fewer).
_SEED_SUPPORT = 8
# The smooth fill reads the pixels the fill leaves alone, at least this much (a fill that takes every
# pixel reads them all).
_FILL_FLOOR = 1e-3


class _Encoded(NamedTuple):
    """:meth:`DepthStitchNet.encode`'s result."""

    x: torch.Tensor  # (B, N, 4, H, W) float32: each input's colour and mask
    features: list[torch.Tensor]  # every scale's features, pooled over the inputs or concatenated
    skip: torch.Tensor  # the decoder's full-resolution skip connection
    rotations: torch.Tensor | None  # (B, N, 3, 3) residual rotations (None: a network of any rig)
    present: torch.Tensor  # (B, N) bool: inputs that are not padding


class _Cues(NamedTuple):
    """:meth:`DepthStitchNet.measure`'s result: the sweep's measurements, ``(B, P, H, W)`` each."""

    extra: torch.Tensor  # (B, C, H, W) what the decoder reads beside its features
    relative: torch.Tensor  # the relative matching cost
    overlap: torch.Tensor  # 1 where two or more inputs see the plane's point
    shown: torch.Tensor | None  # (B, 3, P, H, W) what the inputs show at each plane, when asked
    seen: torch.Tensor | None  # where an input sees the plane's point, when asked
    first: torch.Tensor | None  # the first surface, one-hot over the planes (with a surface cue or rule)
    views: torch.Tensor | None  # how many inputs' own rays end at each plane's point (idem)


class _Depth(NamedTuple):
    """:meth:`DepthStitchNet.depth`'s result."""

    inverse_depth: torch.Tensor  # (B, H, W) 1 / metres
    probabilities: torch.Tensor | None  # (B, P, H, W) the planes' probabilities
    surface_depth: torch.Tensor | None  # (B, H, W) the first surface's inverse depth, -1 where none
    surface_logit: torch.Tensor | None  # (B, H, W) the logit of the share moved there


class DepthStitchNet(nn.Module):
    """Unwarped inputs ``(B, N, 3, H, W)`` and masks ``(B, N, H, W)`` of a rig with camera centres
    ``centres`` ``(N, 3)`` (world metres) to a panorama; see the module docstring."""

    def __init__(self, config: ModelConfig, centres: np.ndarray | torch.Tensor):
        super().__init__()
        self.config = config
        centres = torch.as_tensor(np.asarray(centres), dtype=torch.float32)
        n, widths, planes = centres.shape[0], config.widths, config.depth_planes
        self.pooled = config.pooling == "pooled"
        self.inputs = None if self.pooled else n  # None: any number
        self.encoder = Encoder(widths)
        self.regressor = None if self.pooled else regressor(widths[-1] * n, config.regressor_width)
        self.rotation = None if self.pooled else nn.Linear(config.regressor_width, n * 3)
        extra = planes + 1 + (planes if config.ghost_cost else 0) + (2 * planes if config.first_surface else 0)
        skip = 2 if self.pooled else n  # channels per input channel: mean and maximum, or one per input
        self.decoder = Decoder(widths, config.head_width, skip, in_channels=4, extra_channels=extra)
        self.depth_head = conv(config.head_width, planes)
        self.log_sharpness = nn.Parameter(torch.tensor(math.log(_INITIAL_SHARPNESS)))
        # Per-input heads: pooled, one output from the decoder's features and that input's pixels.
        per_input = (config.head_width + 4, 1) if self.pooled else (config.head_width, n)
        self.weight_head = conv(*per_input)
        maps = config.photometry == "maps" and config.max_log_gain > 0
        self.gain_head = conv(*per_input) if maps else None
        self.fill_head = conv(config.head_width, 1) if config.fill else None
        self.surface_head = conv(config.head_width, 1) if config.first_surface else None
        zero_init(self.rotation, self.depth_head, self.weight_head, self.gain_head, self.fill_head, self.surface_head)
        with torch.no_grad():
            self.depth_head.bias.copy_(-_INITIAL_FAR_PRIOR * torch.linspace(0.0, 1.0, planes))
            if self.fill_head is not None:
                self.fill_head.bias.fill_(_INITIAL_FILL_LOGIT)
            if self.surface_head is not None:
                self.surface_head.bias.fill_(_INITIAL_SURFACE_LOGIT)
        self.register_buffer("planes", inverse_depth_planes(planes, config.max_inverse_depth), persistent=False)
        self.register_buffer("centres", centres, persistent=False)
        self._rays: dict[tuple, torch.Tensor] = {}
        self._grids: dict[tuple, torch.Tensor] = {}
        self._ray_grids: dict[tuple, torch.Tensor] = {}
        # (centres, their canvas and kind, (grid, ray grid)) of the last centres given at inference: a clip's rig
        self._last_rig: tuple | None = None

    def rays(self, height: int, width: int) -> torch.Tensor:
        """The panorama's unit rays ``(H, W, 3)`` at this canvas size (computed once per size, device
        and dtype of the model, as are the grids below)."""
        key = (height, width, self.centres.device, self.centres.dtype)
        if key not in self._rays:
            self._rays[key] = torch.as_tensor(pano_rays(width, height), dtype=torch.float32, device=self.centres.device)
        return self._rays[key]

    def sweep_grid(self, height: int, width: int) -> torch.Tensor:
        """The sweep's sampling grids ``(N, P, H, W, 2)`` at this canvas size: where input ``i``,
        turned by its residual rotation, shows plane ``q``'s point along each panorama ray
        (:func:`~learnstitch.network.sweep.sweep_points`; computed once per rig)."""
        key = (height, width, self.centres.device, self.centres.dtype)
        if key not in self._grids:
            self._grids[key] = sweep_points(self.rays(height, width), self.centres, self.planes)
        return self._grids[key]

    def ray_grid(self, height: int, width: int) -> torch.Tensor:
        """Where the panorama sees each plane's point on each input's own rays ``(N, P, H, W, 2)``
        (:func:`~learnstitch.network.sweep.ray_points`; computed once per rig)."""
        key = (height, width, self.centres.device, self.centres.dtype)
        if key not in self._ray_grids:
            self._ray_grids[key] = ray_points(self.rays(height, width), self.centres, self.planes)
        return self._ray_grids[key]

    def forward(
        self,
        inputs: torch.Tensor,
        masks: torch.Tensor,
        *,
        gain: bool = True,
        inverse_depth: torch.Tensor | None = None,
        planes: bool = False,
        colours: bool = True,
        centres: torch.Tensor | None = None,
    ) -> StitchOutput:
        """The panorama of ``inputs`` and ``masks``. ``centres`` ``(B, N, 3)``: each sample's camera
        centres, world metres (an absent input's are any); a network of a fixed rig defaults to the
        rig it was built for, a network of any rig (``model.pooling: pooled``) needs them.
        ``gain=False`` switches the colour correction off; ``inverse_depth`` ``(B, H, W)`` replaces
        the predicted one (the depth oracle's warp); ``planes=True`` also returns the depth
        distribution, what the inputs show at each plane and the relative matching cost (the
        ``plane_*`` fields: the plane and class losses' inputs); ``colours=False`` leaves out what
        the inputs show (only the plane loss reads it)."""
        check_inputs(inputs, masks, self.inputs, self.config.stride)
        batch, n, _, height, width = inputs.shape
        encoded = self.encode(inputs, masks)
        x, rays = encoded.x, self.rays(height, width)
        fitted = self.config.photometry == "fitted" and gain
        rule = self.config.surface_rule if inverse_depth is None and not self.training else 0.0
        surfaces = self.surface_head is not None or rule > 0
        centres, grid, ray_grid = self.geometry(centres, batch, n, height, width, surfaces)

        with torch.autocast(inputs.device.type, enabled=False):
            # What the warps sample: colour and mask, and with fitted photometry each input's lens
            # radius, warped with it. Each input turned by its rotation at infinity (input i at
            # R_i w) is both what the sweep reads and the fallback warp below.
            sampled = torch.cat([x, lens_radius(x[:, :, 3], rays)[:, :, None]], dim=2) if fitted else x
            far = self.warp(sampled, torch.zeros_like(x[:, 0, 0]), encoded.rotations, centres)
        cues = self.measure(far[:, :, :4].detach(), x[:, :, 3], grid, ray_grid, planes and colours, surfaces)
        head = self.decoder(encoded.features, encoded.skip, cues.extra)
        depth = self.depth(head, cues, inverse_depth, planes, rule)
        pano, coverage, shares = self.compose(
            head, encoded, sampled, far, depth.inverse_depth, centres, gain=gain, fitted=fitted
        )
        return StitchOutput(
            pano,
            coverage,
            shares,
            inverse_depth=depth.inverse_depth,
            rotations=encoded.rotations,
            plane_probabilities=depth.probabilities if planes else None,
            plane_colours=cues.shown,
            plane_seen=cues.seen,
            plane_cost=cues.relative if planes else None,
            plane_overlap=cues.overlap if planes else None,
            surface_depth=depth.surface_depth,
            surface_logit=depth.surface_logit,
        )

    def encode(self, inputs: torch.Tensor, masks: torch.Tensor) -> _Encoded:
        """Step 1: each input with its mask ``(B, N, 4, H, W)`` encoded; the features of every scale
        pooled over the present inputs (``model.pooling: pooled``) or concatenated, with each input's
        residual rotation regressed from the deepest."""
        batch, n, _, height, width = inputs.shape
        x = torch.cat([inputs, masks.to(inputs.dtype)[:, :, None]], dim=2)  # (B, N, 4, H, W)
        per_input = self.encoder(x.reshape(batch * n, 4, height, width))
        present = masks.flatten(2).amax(dim=2) > 0  # (B, N): an absent input (padding) takes no part
        if self.pooled:
            features = [pool_inputs(f.reshape(batch, n, *f.shape[1:]), present) for f in per_input]
            skip, rotations = pool_inputs(x, present), None
        else:
            features = [f.reshape(batch, n * f.shape[1], *f.shape[-2:]) for f in per_input]
            angles = self.rotation(self.regressor(features[-1])).float().reshape(batch, n, 3)
            rotations = rotation_matrices(math.radians(self.config.max_rotation_deg) * torch.tanh(angles))
            skip = x.reshape(batch, n * 4, height, width)
        return _Encoded(x.float(), features, skip, rotations, present)

    def geometry(
        self, centres: torch.Tensor | None, batch: int, n: int, height: int, width: int, surfaces: bool
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """The centres ``(B, N, 3)`` a call stitches through, the sweep's grids and, where the first
        surface is wanted, the inputs' own rays' grids: the rig's, computed once per canvas size
        (``centres`` None, or those of the rig a network of a fixed rig was built for), or each
        sample's own ``(B N, P, H, W, 2)``."""
        if centres is None:
            if self.pooled:
                raise ConfigError(
                    "a network of any rig (model.pooling: pooled) stitches through each sample's camera centres: "
                    "pass centres (B, N, 3)"
                )
            grid = self.sweep_grid(height, width)
            return self.centres.expand(batch, n, 3), grid, self.ray_grid(height, width) if surfaces else None
        if tuple(centres.shape) != (batch, n, 3):
            raise ConfigError(
                f"centres must be (B, N, 3) = {(batch, n, 3)} for these inputs, got {tuple(centres.shape)}"
            )
        centres = centres.to(self.centres)
        if not self.pooled and bool((centres == self.centres).all()):  # the rig it was built for: its grids
            return self.geometry(None, batch, n, height, width, surfaces)
        last, shape = self._last_rig, (height, width, surfaces, centres.device, centres.dtype, centres.shape)
        if self.training or last is None or last[1] != shape or not torch.equal(last[0], centres):
            self._last_rig = None  # the old grids go before the new ones are built
            flat, rays = centres.reshape(batch * n, 3), self.rays(height, width)
            grids = sweep_points(rays, flat, self.planes), ray_points(rays, flat, self.planes) if surfaces else None
            if self.training:  # every batch its own rigs: nothing to keep
                return centres, *grids
            self._last_rig = last = (centres.detach().clone(), shape, grids)
        return centres, *last[2]

    def measure(
        self,
        far: torch.Tensor,
        masks: torch.Tensor,
        grid: torch.Tensor,
        ray_grid: torch.Tensor | None,
        colours: bool,
        surfaces: bool,
    ) -> _Cues:
        """Step 2, a fixed measurement (no gradient, float32): the inputs at infinity ``far`` ``(B,
        N, 4, H, W)`` (colour and mask) swept over the planes of ``grid``, their matching cost and
        what the decoder reads beside its features (relative cost, overlap, and with the config's
        cues the ghost cost and the first surface, from the inputs' ``masks`` ``(B, N, H, W)`` and
        ``ray_grid``); ``colours``: what the inputs show at each plane too."""
        with torch.no_grad(), torch.autocast(far.device.type, enabled=False):
            swept = self.sweep(far, grid)
            swept, swept_alpha = swept[:, :, :3], swept[:, :, 3]
            cost, overlap = matching_cost(swept, swept_alpha, self.config.cost_window)
            shown, seen = plane_colours(swept, swept_alpha) if colours else (None, None)
            relative = relative_cost(cost, overlap)
            extra = [relative, overlap.mean(dim=1, keepdim=True)]
            if self.config.ghost_cost:
                extra.append(self.ghosts(cost, overlap, swept_alpha, grid))
            first = views = None
            if surfaces:
                views = self.surface_views(cost, overlap, swept_alpha, masks, grid, ray_grid)
                evidence = views >= _SURFACE_VIEWS
                first = first_surface(evidence)
                if self.surface_head is not None:
                    extra += [evidence.float(), first]
            return _Cues(torch.cat(extra, dim=1), relative, overlap, shown, seen, first, views)

    def depth(
        self, head: torch.Tensor, cues: _Cues, inverse_depth: torch.Tensor | None, planes: bool, rule: float
    ) -> _Depth:
        """Step 3: the planes' probabilities from the decoder's ``head`` and the relative cost, a
        learnt share of them moved to the first surface, their soft-argmin (unless ``inverse_depth``
        is given) and, with a surface ``rule`` at inference, the first surface in front."""
        logits = self.depth_head(head).float() - self.log_sharpness.exp() * cues.relative
        probabilities = torch.softmax(logits, dim=1) if inverse_depth is None or planes else None
        surface_depth = surface_logit = None
        if self.surface_head is not None:
            at = surface_planes(cues.first)
            found = at >= 0
            surface_depth = torch.where(found, self.planes[at.clamp_min(0)], -1.0)
            surface_logit = self.surface_head(head).float()[:, 0]
            if probabilities is not None:
                # A learnt share of each pixel's probability moves to its first surface (none where it has none).
                taken = (torch.sigmoid(surface_logit) * found)[:, None]
                probabilities = probabilities + taken * (cues.first - probabilities)
        if inverse_depth is None:
            inverse_depth = (probabilities * self.planes[:, None, None]).sum(dim=1)  # soft-argmin
        if rule > 0:  # the first surface where it is nearer than the depth by more than `rule` planes
            inverse_depth = self.ruled_depth(inverse_depth, cues.first, cues.views, rule)
        return _Depth(inverse_depth, probabilities, surface_depth, surface_logit)

    def compose(
        self,
        head: torch.Tensor,
        encoded: _Encoded,
        sampled: torch.Tensor,
        far: torch.Tensor,
        inverse_depth: torch.Tensor,
        centres: torch.Tensor,
        *,
        gain: bool,
        fitted: bool,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Step 4: every input warped along the depth (and at infinity, ``far``, the fallback),
        colour corrected and blended by the weight heads: the panorama, its coverage and each warp's
        share (:func:`~learnstitch.network.model.blend`)."""
        x, present = encoded.x, encoded.present
        batch, n, _, height, width = x.shape
        # The heads run under the caller's autocast, like the decoder; what follows is in float32.
        weights = self.per_input(self.weight_head, head, x).reshape(batch, n, 1, height, width)
        raw_gain = (
            self.per_input(self.gain_head, head, x) if self.gain_head is not None and gain and not fitted else None
        )
        share = torch.sigmoid(self.fill_head(head).float()) if self.fill_head is not None else None

        with torch.autocast(x.device.type, enabled=False):
            # Two warps per input: at the predicted depth, and at infinity as a fallback that only
            # counts where no input sees the depth warp's sight lines (the blind spot under the rig).
            warped = torch.stack([self.warp(sampled, inverse_depth.float(), encoded.rotations, centres), far], dim=3)
            rgb, alpha = warped[:, :, :3], warped[:, :, 3]  # (B, N, 3, 2, H, W), (B, N, 2, H, W)
            if fitted:
                radius = warped[:, :, 4]
                exposure, vignetting = fit_photometry(rgb[:, :, :, 0], alpha[:, :, 0], radius[:, :, 0], present)
                rgb = rgb * correction(exposure, vignetting, radius)[:, :, None]
                gains = torch.ones_like(x[:, :, 3])
            else:
                gains = gain_maps(raw_gain, self.config.max_log_gain, x[:, :, 3])
            weights = torch.cat([weights, weights - _FALLBACK_LOGIT], dim=2)
            pano, coverage, shares = blend(rgb, alpha, weights, gains)
            if share is not None:
                confidence = (1.0 - share.detach()[:, 0]).clamp_min(_FILL_FLOOR) * (coverage > 0)
                pano = pano + share * (smooth_fill(pano, confidence) - pano)
        return pano, coverage, shares

    def per_input(self, layer: nn.Conv2d, head: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """A per-input head's ``(B, N, H, W)`` float32 output from the decoder's ``head`` ``(B, C, H, W)``:
        pooled, ``layer`` run on each input's pixels ``x`` ``(B, N, 4, H, W)`` beside ``head``;
        otherwise ``layer``'s channel ``i`` for input ``i``."""
        batch, n, _, height, width = x.shape
        if not self.pooled:
            return layer(head).float()
        joined = torch.cat([head[:, None].expand(batch, n, *head.shape[1:]), x.to(head.dtype)], dim=2)
        return layer(joined.flatten(0, 1)).float().reshape(batch, n, height, width)

    def warp(
        self,
        x: torch.Tensor,
        inverse_depth: torch.Tensor,
        rotations: torch.Tensor | None,
        centres: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Inputs ``x`` ``(B, N, C, H, W)`` sampled along ``R_i normalize(w - q c_i)`` for inverse
        depths ``q`` ``(B, H, W)``, rotations ``R_i`` ``(B, N, 3, 3)`` (``None``: none) and centres
        ``c_i`` ``(B, N, 3)`` (default the rig's): ``(B, N, C, H, W)``."""
        batch, n, channels, height, width = x.shape
        rays = self.rays(height, width)
        centres = self.centres.expand(batch, n, 3) if centres is None else centres
        along = towards(rays, inverse_depth[:, None], centres[:, :, None, None])  # (B, N, H, W, 3)
        grid = canvas_points(along if rotations is None else rotate(rotations, along))
        flat = x.reshape(batch * n, channels, height, width)
        return sample_wrapped(flat, grid.reshape(batch * n, height, width, 2), self.config.wrap).reshape(x.shape)

    def ghosts(
        self, cost: torch.Tensor, overlap: torch.Tensor, alpha: torch.Tensor, grid: torch.Tensor | None = None
    ) -> torch.Tensor:
        """``log(1 + g)``, ``g`` the cost at infinity over its mean where two inputs overlap, read
        where each input sees each plane's point (:func:`~learnstitch.network.sweep.ghost_cost`):
        ``(B, P, H, W)`` from the cost and overlap ``(B, P, H, W)`` of :func:`matching_cost`, the
        swept masks ``alpha`` ``(B, N, P, H, W)`` and the sweep's ``grid`` (:meth:`sweep`; default
        the rig's). The log: an occluder's ghosts reach tens of times the mean."""
        batch, n, _, height, width = alpha.shape
        far_overlap = overlap[:, 0].sum(dim=(-2, -1)).clamp_min(1.0)
        scale = (cost[:, 0].sum(dim=(-2, -1)) / far_overlap).clamp_min(1e-6)[:, None, None]
        at_infinity = (cost[:, 0] / scale)[:, None, None].expand(batch, n, 1, height, width)
        grid = self.sweep_grid(height, width) if grid is None else grid
        return torch.log1p(ghost_cost(self.sweep(at_infinity, grid)[:, :, 0], alpha))

    def ruled_depth(
        self, inverse_depth: torch.Tensor, first: torch.Tensor, views: torch.Tensor, rule: float
    ) -> torch.Tensor:
        """``model.surface_rule``: ``inverse_depth`` ``(B, H, W)`` replaced by the first surface
        ``first`` (one-hot, ``(B, P, H, W)``) wherever that is more than ``rule`` planes nearer; with
        ``surface_grow``, those places cleared of specks and grown into the planes where one input's
        own ray ends (``views`` ``(B, P, H, W)``, :meth:`surface_views`) as far as it says."""
        spacing = self.planes[-1] / max(len(self.planes) - 1, 1)
        beyond = inverse_depth.detach() / spacing + rule  # planes (indices) nearer than this count

        def nearer(planes: torch.Tensor) -> torch.Tensor:
            return torch.where(planes > beyond, planes, -1)

        chosen = nearer(surface_planes(first))
        if self.config.surface_grow > 0:
            seeds = supported_planes(chosen, len(self.planes), _SEED_SUPPORT)
            one_view = nearer(surface_planes(first_surface(views >= 1)))
            chosen = grown_planes(seeds, one_view, self.config.surface_grow)
        return torch.where(chosen >= 0, self.planes[chosen.clamp_min(0)], inverse_depth)

    def surface_views(
        self,
        cost: torch.Tensor,
        overlap: torch.Tensor,
        alpha: torch.Tensor,
        masks: torch.Tensor,
        grid: torch.Tensor,
        ray_grid: torch.Tensor,
    ) -> torch.Tensor:
        """``(B, P, H, W)``: how many inputs' own rays end (:func:`~learnstitch.network.sweep.ray_ends`)
        at each plane's point of each panorama ray, where they see it. Two or more are a left-right
        check, which a chance agreement of two views on repeated texture mostly fails. From the
        cost and overlap ``(B, P, H, W)`` of :func:`matching_cost`, the swept masks ``alpha`` ``(B,
        N, P, H, W)``, the inputs' masks ``(B, N, H, W)`` and the rig's ``grid`` and ``ray_grid``
        (:meth:`sweep_grid`, :meth:`ray_grid`, or each sample's own): the cost is read along every
        input's rays, each ray's end found, and the ends read back where each input sees each
        plane's point."""
        batch, n = alpha.shape[:2]
        volume = torch.stack([cost, overlap], dim=1)[:, None].expand(batch, n, *(2, *cost.shape[1:]))
        along = self.sample_planes(volume, ray_grid)
        sees = (along[:, :, 1] > 0.999) & (masks > 0.999)[:, :, None]
        ends = ray_ends(along[:, :, 0], sees).to(cost.dtype)
        found = self.sample_planes(ends[:, :, None], grid)[:, :, 0] > 0.5
        return (found & (alpha > 0.999)).sum(dim=1)

    def sample_planes(self, x: torch.Tensor, grid: torch.Tensor) -> torch.Tensor:
        """Maps ``x`` ``(B, N, C, P, H, W)``, one per input and plane, each sampled at its own
        input's and plane's grid (``(N, P, H, W, 2)``, or each sample's own ``(B N, P, H, W, 2)``):
        ``(B, N, C, P, H, W)``. :meth:`sweep` samples one map at every plane; this one map per plane."""
        batch, n, channels, planes, height, width = x.shape
        if grid.shape[0] != n:  # every sample its own rig
            flat = x.transpose(2, 3).reshape(batch * n * planes, channels, height, width)
            out = sample_wrapped(flat, grid.reshape(batch * n * planes, height, width, 2), self.config.wrap)
            return out.reshape(batch, n, planes, channels, height, width).transpose(2, 3)
        flat = x.permute(1, 3, 0, 2, 4, 5).reshape(n * planes, batch * channels, height, width)
        out = sample_wrapped(flat, grid.reshape(n * planes, height, width, 2), self.config.wrap)
        return out.reshape(n, planes, batch, channels, height, width).permute(2, 0, 3, 1, 4, 5)

    def sweep(self, x: torch.Tensor, grid: torch.Tensor) -> torch.Tensor:
        """Maps ``x`` ``(B, N, C, H, W)`` (each input's colour and mask, say) swept over the planes
        of ``grid`` ``(N, P, H, W, 2)`` (:meth:`sweep_grid`) or, each sample's own, ``(B N, P, H, W,
        2)``: ``(B, N, C, P, H, W)``. A batch's inputs from one camera share that camera's grid, so
        they are sampled together, as channels."""
        batch, n, channels, height, width = x.shape
        planes = grid.shape[1]
        if grid.shape[0] != n:  # every sample its own rig: each camera of the batch alone
            return self.sweep(x.reshape(1, batch * n, channels, height, width), grid).reshape(
                batch, n, channels, planes, height, width
            )
        swept = sample_wrapped(
            x.transpose(0, 1).reshape(n, batch * channels, height, width),
            grid.reshape(n, planes * height, width, 2),
            self.config.wrap,
        )
        return swept.reshape(n, batch, channels, planes, height, width).transpose(0, 1)


def pool_inputs(x: torch.Tensor, present: torch.Tensor) -> torch.Tensor:
    """Per-input maps ``x`` ``(B, N, C, h, w)`` pooled over the present inputs (``present``
    ``(B, N)`` bool; at least one per sample): ``(B, 2 C, h, w)``, their mean and their maximum.
    Symmetric in the inputs: their order does not matter. An absent input's maps are replaced by
    -1 for the maximum, the least an encoder's ELU or an input's pixel can be."""
    weight = present.to(x.dtype)[:, :, None, None, None]
    mean = (x * weight).sum(dim=1) / weight.sum(dim=1).clamp_min(1.0)
    top = torch.where(weight > 0, x, -torch.ones_like(x)).amax(dim=1)
    return torch.cat([mean, top], dim=1)


def smooth_fill(pano: torch.Tensor, confidence: torch.Tensor) -> torch.Tensor:
    """A smooth version of ``pano`` ``(B, C, H, W)`` that reads only its ``confidence`` ``(B, H, W)``
    (in ``[0, 1]``) pixels: a pull-push pyramid (Gortler et al., *The Lumigraph*, 1996). Pulled up
    by 2 x 2 means of ``confidence * pano`` and of ``confidence`` while both sides are even; pushed
    down as ``mean + (1 - confidence) * upsampled``, so a whole-confidence pixel keeps its value and
    a hole of any size gets the confident pixels around it, smoothly. The panorama wraps across its
    +-180 degree edge, and so does every level."""
    weight = confidence.to(pano.dtype)[:, None]
    levels = [(pano * weight, weight)]
    while all(size % 2 == 0 and size > 1 for size in levels[-1][0].shape[-2:]):
        levels.append(tuple(F.avg_pool2d(t, 2) for t in levels[-1]))
    total, weight = levels.pop()
    fill = total / weight.clamp_min(1e-6)
    for total, weight in reversed(levels):
        fill = total + (1.0 - weight) * _upsample_wrapped(fill)
    return fill


def _upsample_wrapped(x: torch.Tensor) -> torch.Tensor:
    """``x`` ``(B, C, H, W)`` bilinearly upsampled by 2, reading across the +-180 degree edge."""
    wrapped = torch.cat([x[..., -1:], x, x[..., :1]], dim=-1)
    return F.interpolate(wrapped, scale_factor=2, mode="bilinear", align_corners=False)[..., 2:-2]


def relative_cost(cost: torch.Tensor, overlap: torch.Tensor) -> torch.Tensor:
    """``(B, P, H, W)``: the cost over its mean across the planes where two inputs see the pixel;
    1 (no preference) at planes where fewer do, 0 at pixels no plane sees twice."""
    seen = overlap.sum(dim=1, keepdim=True)
    mean = (cost * overlap).sum(dim=1, keepdim=True) / seen.clamp_min(1e-6)
    return torch.where(seen > 0, (overlap * cost + (1.0 - overlap) * mean) / (mean + 1e-6), 0.0)
