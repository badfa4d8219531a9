"""The stitching network: multi-homography warps, a displacement map that refines them, and weight
maps that blend them (the multi-homography stitcher of Song et al., SPL 2021, and its 360-degree
successor WSSN, ECCV 2022).

For three unwarped inputs ``I_i`` with masks ``M_i`` (:mod:`learnstitch.data.datasets`) the network predicts,
per input, K homographies ``H_ik`` (as four-corner offsets), a displacement ``D_ik`` per pixel and a
weight logit ``l_ik`` per pixel, and outputs::

    G_ik = grid(H_ik) + D_ik                         # sampling grid of warp k of input i
    P    = sum_ik exp(l_ik) g_i S(I_i, G_ik) / sum_ik exp(l_ik) S(M_i, G_ik)

where ``S`` samples with wrap-around (:func:`learnstitch.network.warp.sample_wrapped`). The inputs are
zero outside their masks, so this is a softmax over the 3 K warps restricted to the pixels each
warp sees (premultiplied-alpha blending); where no warp sees a pixel the panorama is 0. ``g_i`` is
a gain map per input (``exp(max_log_gain * tanh)``, in panorama pixels), a photometric correction
as in WSSN's colour-correction variants: the cameras' gains and vignetting differ, and where two
inputs overlap no choice of warps and weights alone can undo that.

Architecture: a shared encoder (stride-2 stages of two convolutions with ELU) applied to each
input (RGB and mask); per-scale features concatenated across the inputs; a regressor on the
deepest features (two convolutions, average pooling, a linear layer to ``3 K x 4 x 2`` offsets,
bounded by ``max_corner_offset * tanh``); a decoder (bilinear upsampling, skip connections) with
heads for the displacement (``max_displacement * tanh``, normalised units), the weight logits
and the gains. The regressor's linear layer and the heads start at zero: the untrained network
samples every input where it is (identity warps, gain 1) and blends the inputs that see a pixel
equally.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from rigjax.errors import ConfigError

from .warp import homographies_from_corners, homography_grids, sample_wrapped

N_INPUTS = 3


@dataclass(frozen=True)
class ModelConfig:
    """The ``model:`` section of ``configs/stitch/*.yaml``."""

    warp: str = "homography"  # "homography" (StitchNet) or "depth" (the rig-aware DepthStitchNet)
    # The fisheyes are unwarped at the rig's design ("nominal") or at its calibration ("calibrated":
    # a sample's own cameras, a user's calibrated .pto)
    inputs: str = "nominal"
    homographies: int = 5  # K, warps per input (homography warp)
    widths: tuple[int, ...] = (16, 32, 64, 96, 128)  # encoder channels per stride-2 stage
    regressor_width: int = 128
    head_width: int = 16  # channels of the full-resolution decoder layer feeding the heads
    max_corner_offset: float = 0.25  # bound of each corner's offset, normalised units (2 = canvas)
    max_displacement: float = 0.1  # bound of the displacement map, normalised units
    # Colour correction: "maps", per-input gain maps from a head (bound max_log_gain; 0: none);
    # "fitted", exposures and vignetting fitted to the overlaps (learnstitch.network.photometry;
    # warp: depth)
    photometry: str = "maps"
    max_log_gain: float = 0.5  # bound of the per-input gain maps' log; 0: no gain head
    wrap: float = 0.25  # how far a warp may read across the +-180 degree edge, fraction of the width
    # The depth warp's (learnstitch.network.depth):
    depth_planes: int = 32  # inverse-depth planes of the sweep
    max_inverse_depth: float = 1.0  # the nearest plane, 1 / metres (the farthest is at infinity)
    max_rotation_deg: float = 5.0  # bound of each input's residual rotation
    cost_window: int = 5  # box the matching cost is averaged over, pixels (odd)
    # A smooth fill the network may blend each pixel towards (the blind spot under the rig, which
    # no input sees; warp: depth)
    fill: bool = False
    # The far plane's matching cost where each input sees a plane's point, joined to the cost volume
    # (warp: depth): high at a near occluder's own plane, where its ghosts lie
    # (learnstitch.network.sweep.ghost_cost)
    ghost_cost: bool = False
    # The first surface along each panorama ray (warp: depth): the nearest plane where two inputs'
    # own rays end (learnstitch.network.sweep.ray_ends), joined to the cost volume; a learnt share of
    # each pixel's depth probability moves there, so that a near occluder both cameras see past in
    # its own direction can be drawn in front
    first_surface: bool = False
    # At inference (eval mode, warp: depth), the depth replaced by that first surface wherever it is
    # more than this many planes nearer than the network's; 0: off. Changes no weight
    surface_rule: float = 0.0
    # With surface_rule, the rule's first surface cleared of specks (learnstitch.network.sweep.
    # supported_planes) and grown this many pixels out into where only one input's ray ends, at a
    # plane within one of its neighbour's (grown_planes: hysteresis); 0: the rule alone
    surface_grow: int = 0
    # How the per-input features meet (warp: depth): "concat", side by side (a rig of a fixed
    # number of cameras in a fixed order); "pooled", their mean and maximum over the inputs, so
    # that one network stitches rigs of any number of cameras in any order (inputs: calibrated,
    # max_rotation_deg: 0: the calibration is the rig's)
    pooling: str = "concat"

    def __post_init__(self) -> None:
        if self.warp not in ("homography", "depth"):
            raise ConfigError(f"warp must be 'homography' or 'depth', got {self.warp!r}")
        if self.inputs not in ("nominal", "calibrated"):
            raise ConfigError(f"inputs must be 'nominal' or 'calibrated', got {self.inputs!r}")
        if self.photometry not in ("maps", "fitted"):
            raise ConfigError(f"photometry must be 'maps' or 'fitted', got {self.photometry!r}")
        if self.photometry == "fitted" and self.warp != "depth":
            raise ConfigError("photometry: fitted needs warp: depth (it fits one warp per input)")
        for key in ("fill", "ghost_cost", "first_surface"):
            if getattr(self, key) and self.warp != "depth":
                raise ConfigError(f"{key}: true needs warp: depth")
        if not self.surface_rule >= 0.0:
            raise ConfigError(f"surface_rule must be >= 0 (planes; 0: off), got {self.surface_rule!r}")
        if self.surface_rule > 0 and self.warp != "depth":
            raise ConfigError("surface_rule > 0 needs warp: depth")
        if not (isinstance(self.surface_grow, int) and self.surface_grow >= 0):
            raise ConfigError(f"surface_grow must be an integer >= 0 (pixels; 0: off), got {self.surface_grow!r}")
        if self.surface_grow > 0 and not self.surface_rule > 0:
            raise ConfigError("surface_grow > 0 needs surface_rule > 0 (it grows the rule's first surface)")
        if self.pooling not in ("concat", "pooled"):
            raise ConfigError(f"pooling must be 'concat' or 'pooled', got {self.pooling!r}")
        if self.pooling == "pooled" and (
            self.warp != "depth" or self.inputs != "calibrated" or self.max_rotation_deg != 0.0
        ):
            raise ConfigError(
                "pooling: pooled needs warp: depth, inputs: calibrated and max_rotation_deg: 0 (a rig of any "
                f"cameras is stitched at its calibration), got warp: {self.warp}, inputs: {self.inputs}, "
                f"max_rotation_deg: {self.max_rotation_deg}"
            )
        if (
            self.depth_planes < 2
            or not self.max_inverse_depth > 0.0
            or self.cost_window < 1
            or not self.cost_window % 2
        ):
            raise ConfigError(
                f"depth_planes must be >= 2, max_inverse_depth > 0 and cost_window odd; got {self.depth_planes!r}, "
                f"{self.max_inverse_depth!r}, {self.cost_window!r}"
            )
        if not 0.0 <= self.max_rotation_deg <= 45.0:
            raise ConfigError(f"max_rotation_deg must be in [0, 45], got {self.max_rotation_deg!r}")
        if self.homographies < 1 or any(w < 1 for w in self.widths) or self.regressor_width < 1 or self.head_width < 1:
            raise ConfigError(f"homographies, widths, regressor_width and head_width must be >= 1, got {self}")
        if not 0.0 <= self.max_corner_offset <= 0.5:
            raise ConfigError(
                f"max_corner_offset must be in [0, 0.5] (a convex warp of the canvas), got {self.max_corner_offset!r}"
            )
        if (
            not 0.0 <= self.max_displacement <= 1.0
            or not 0.0 <= self.wrap <= 1.0
            or not 0.0 <= self.max_log_gain <= 1.0
        ):
            raise ConfigError(
                f"max_displacement, max_log_gain and wrap must be in [0, 1], got {self.max_displacement!r}, "
                f"{self.max_log_gain!r}, {self.wrap!r}"
            )

    @property
    def stride(self) -> int:
        """Input heights and widths must be multiples of this."""
        return 2 ** len(self.widths)


class StitchOutput(NamedTuple):
    pano: torch.Tensor  # (B, 3, H, W)
    coverage: torch.Tensor  # (B, H, W): sum of the warped masks' weights, > 0 where any warp sees
    weights: torch.Tensor  # (B, N, K, H, W): each warp's share of every panorama pixel
    # The homography warp's (model.warp: homography):
    input_from_output: torch.Tensor | None = None  # (B, N, K, 3, 3) homographies, normalised coordinates
    displacement: torch.Tensor | None = None  # (B, N, K, H, W, 2) normalised units
    # The rig-aware warp's (model.warp: depth, learnstitch.network.depth):
    inverse_depth: torch.Tensor | None = None  # (B, H, W) 1 / metres from the panorama centre
    rotations: torch.Tensor | None = None  # (B, N, 3, 3) each input's residual rotation
    # ... and, when asked (forward(planes=True)), the depth distribution and what the inputs show at
    # each plane (learnstitch.network.sweep.plane_colours), for the loss's plane term:
    plane_probabilities: torch.Tensor | None = None  # (B, P, H, W), sums to 1 over the planes
    plane_colours: torch.Tensor | None = None  # (B, 3, P, H, W)
    plane_seen: torch.Tensor | None = None  # (B, P, H, W) 1 where an input sees the plane's point
    plane_cost: torch.Tensor | None = None  # (B, P, H, W) the relative matching cost the depth reads
    plane_overlap: torch.Tensor | None = None  # (B, P, H, W) 1 where two or more inputs see the plane's point
    # With model.first_surface: each pixel's first surface (inverse depth, -1 where it has none) and
    # the logit of the share of its depth probability moved there
    surface_depth: torch.Tensor | None = None  # (B, H, W)
    surface_logit: torch.Tensor | None = None  # (B, H, W)


def conv(cin: int, cout: int, kernel: int = 3, stride: int = 1) -> nn.Conv2d:
    return nn.Conv2d(cin, cout, kernel, stride=stride, padding=kernel // 2)


class Encoder(nn.Module):
    """Stride-2 stages (kernel 7, 5, then 3) of two convolutions with ELU; features of every stage."""

    def __init__(self, widths: tuple[int, ...], in_channels: int = 4):
        super().__init__()
        stages, cin = [], in_channels
        for i, cout in enumerate(widths):
            kernel = (7, 5)[i] if i < 2 else 3
            stages.append(nn.Sequential(conv(cin, cout, kernel, 2), nn.ELU(), conv(cout, cout), nn.ELU()))
            cin = cout
        self.stages = nn.ModuleList(stages)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        features = []
        for stage in self.stages:
            x = stage(x)
            features.append(x)
        return features


class Decoder(nn.Module):
    """From the deepest concatenated features back to full resolution, with skip connections.

    ``extra_channels``: a full-resolution map (the rig-aware warp's matching cost) joined to every
    skip connection, average-pooled to its scale.
    """

    def __init__(
        self, widths: tuple[int, ...], head_width: int, skip_factor: int, in_channels: int, extra_channels: int = 0
    ):
        super().__init__()
        self.up, self.merge = nn.ModuleList(), nn.ModuleList()
        cin = widths[-1] * skip_factor
        for width in reversed(widths[:-1]):
            self.up.append(nn.Sequential(conv(cin, width), nn.ELU()))
            self.merge.append(nn.Sequential(conv(width + width * skip_factor + extra_channels, width), nn.ELU()))
            cin = width
        self.up.append(nn.Sequential(conv(cin, head_width), nn.ELU()))
        self.merge.append(
            nn.Sequential(conv(head_width + in_channels * skip_factor + extra_channels, head_width), nn.ELU())
        )

    def forward(
        self, features: list[torch.Tensor], inputs: torch.Tensor, extra: torch.Tensor | None = None
    ) -> torch.Tensor:
        x = features[-1]
        skips = list(reversed(features[:-1])) + [inputs]
        for up, merge, skip in zip(self.up, self.merge, skips):
            x = up(F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False))
            if extra is not None:
                skip = torch.cat([skip, F.adaptive_avg_pool2d(extra, skip.shape[-2:])], dim=1)
            x = merge(torch.cat([x, skip], dim=1))
        return x


def regressor(in_channels: int, width: int) -> nn.Sequential:
    """Global parameters from the deepest features: two convolutions, then average pooling."""
    return nn.Sequential(
        conv(in_channels, width),
        nn.ELU(),
        conv(width, width, stride=2),
        nn.ELU(),
        nn.AdaptiveAvgPool2d(1),
        nn.Flatten(),
    )


def zero_init(*layers: nn.Module | None) -> None:
    """Zero weights and biases: a head that starts at its neutral output."""
    for layer in layers:
        if layer is not None:
            nn.init.zeros_(layer.weight)
            nn.init.zeros_(layer.bias)


def check_inputs(inputs: torch.Tensor, masks: torch.Tensor, count: int | None, stride: int) -> None:
    """Raise :class:`ConfigError` for inputs of the wrong count (``None``: any) or size."""
    n = inputs.shape[1] if count is None and inputs.ndim == 5 else count
    if inputs.ndim != 5 or inputs.shape[1:3] != (n, 3) or masks.shape != inputs.shape[:2] + inputs.shape[3:]:
        raise ConfigError(
            f"expected inputs (B, {count or 'N'}, 3, H, W) and masks (B, {count or 'N'}, H, W), "
            f"got {tuple(inputs.shape)} and {tuple(masks.shape)}"
        )
    height, width = inputs.shape[-2:]
    if height % stride or width % stride:
        raise ConfigError(f"input size {width} x {height} is not a multiple of the encoder's stride {stride}")


class StitchNet(nn.Module):
    """Three unwarped inputs ``(B, 3, 3, H, W)`` and masks ``(B, 3, H, W)`` to a panorama.

    ``H`` and ``W`` must be multiples of ``config.stride``. Mixed precision, when the caller
    enables autocast, covers the convolutions only: the warps and the blend run in float32.
    """

    def __init__(self, config: ModelConfig = ModelConfig()):
        super().__init__()
        self.config = config
        k, widths = config.homographies, config.widths
        self.encoder = Encoder(widths)
        self.regressor = regressor(widths[-1] * N_INPUTS, config.regressor_width)
        self.corners = nn.Linear(config.regressor_width, N_INPUTS * k * 8)
        self.decoder = Decoder(widths, config.head_width, N_INPUTS, in_channels=4)
        self.displacement_head = conv(config.head_width, N_INPUTS * k * 2)
        self.weight_head = conv(config.head_width, N_INPUTS * k)
        self.gain_head = conv(config.head_width, N_INPUTS) if config.max_log_gain > 0 else None
        zero_init(self.corners, self.displacement_head, self.weight_head, self.gain_head)

    def forward(
        self, inputs: torch.Tensor, masks: torch.Tensor, *, gain: bool = True, centres: torch.Tensor | None = None
    ) -> StitchOutput:
        """The panorama of ``inputs`` and ``masks``; ``gain=False`` switches the gain maps off (gain 1).
        ``centres``: unused: this network has no geometry; accepted so that every network is called alike."""
        check_inputs(inputs, masks, N_INPUTS, self.config.stride)
        batch, n, _, height, width = inputs.shape
        masks = masks.to(inputs.dtype)
        x = torch.cat([inputs, masks[:, :, None]], dim=2)  # (B, 3, 4, H, W)
        per_input = self.encoder(x.reshape(batch * n, 4, height, width))
        features = [f.reshape(batch, n * f.shape[1], *f.shape[-2:]) for f in per_input]
        corners = self.corners(self.regressor(features[-1]))
        head = self.decoder(features, x.reshape(batch, n * 4, height, width))
        displacement, logits = self.displacement_head(head), self.weight_head(head)
        gain = self.gain_head(head) if self.gain_head is not None and gain else None
        with torch.autocast(inputs.device.type, enabled=False):  # geometry and blend in float32
            return self._warp_and_blend(
                x.float(), corners.float(), displacement.float(), logits.float(), None if gain is None else gain.float()
            )

    def _warp_and_blend(
        self,
        x: torch.Tensor,
        corners: torch.Tensor,
        displacement: torch.Tensor,
        logits: torch.Tensor,
        gain: torch.Tensor | None,
    ) -> StitchOutput:
        batch, n, _, height, width = x.shape
        k = self.config.homographies
        offsets = self.config.max_corner_offset * torch.tanh(corners)
        input_from_output = homographies_from_corners(offsets.reshape(batch, n, k, 4, 2))
        displacement = self.config.max_displacement * torch.tanh(displacement)
        displacement = displacement.reshape(batch, n, k, 2, height, width).permute(0, 1, 2, 4, 5, 3)
        logits = logits.reshape(batch, n, k, height, width)
        gain = gain_maps(gain, self.config.max_log_gain, x[:, :, 3])

        grids = homography_grids(input_from_output, height, width) + displacement  # (B, 3, K, H, W, 2)
        # Warp RGB and mask together: K grids per input, one grid_sample per input.
        warped = sample_wrapped(
            x.reshape(batch * n, 4, height, width), grids.reshape(batch * n, k * height, width, 2), self.config.wrap
        )
        warped = warped.reshape(batch, n, 4, k, height, width)  # (B, 3, RGB + mask, K, H, W)
        pano, coverage, weights = blend(warped[:, :, :3], warped[:, :, 3], logits, gain)
        return StitchOutput(pano, coverage, weights, input_from_output, displacement)


def corrects_colour(model: nn.Module) -> bool:
    """Whether ``model`` corrects colour (gain maps, or fitted photometry): whether ``gain=False``
    (no correction) changes its panorama."""
    return getattr(model, "gain_head", None) is not None or model.config.photometry == "fitted"


def gain_maps(raw: torch.Tensor | None, max_log_gain: float, like: torch.Tensor) -> torch.Tensor:
    """``(B, N, H, W)`` gains ``exp(max_log_gain tanh(raw))`` of a gain head's output; without a gain
    head (``raw`` None: the config has none, or the caller switched gains off), ones like ``like``."""
    if raw is None:
        return torch.ones_like(like)
    return torch.exp(max_log_gain * torch.tanh(raw))


def blend(
    rgb: torch.Tensor, alpha: torch.Tensor, logits: torch.Tensor, gain: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The panorama of warped inputs: a softmax of ``logits`` ``(B, N, K, H, W)`` over the warps
    that see each pixel, times each input's ``gain`` ``(B, N, H, W)``.

    ``rgb`` ``(B, N, 3, K, H, W)`` is premultiplied by the warped masks ``alpha`` ``(B, N, K, H, W)``
    (the inputs are 0 outside them). Returns the panorama ``(B, 3, H, W)``, the coverage (the
    weights' sum before normalising; 0 where no warp sees, where the panorama is 0) and each
    warp's normalised weight ``(B, N, K, H, W)``.
    """
    # Shifted by the largest logit of a pixel (no gradient needed: the softmax does not depend on it).
    masked = logits.masked_fill(alpha <= 0, float("-inf"))
    top = masked.detach().amax(dim=(1, 2), keepdim=True)
    e = torch.exp(masked - torch.where(torch.isfinite(top), top, 0.0))
    coverage = (e * alpha).sum(dim=(1, 2))
    norm = 1.0 / coverage.clamp_min(1e-6)
    pano = ((e * gain[:, :, None])[:, :, None] * rgb).sum(dim=(1, 3)) * norm[:, None]
    return pano, coverage, e * alpha * norm[:, None, None]


def parameter_count(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
