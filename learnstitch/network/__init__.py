"""The stitching networks.

``warp`` (homographies from corner offsets, sampling across the panorama's seam), ``model``
(:class:`StitchNet`: homographies, displacement map and weight maps per input), ``sweep`` and
``depth`` (:class:`DepthStitchNet`, the rig-aware warp: a spherical sweep over inverse-depth
planes, a cost volume and its soft-argmin) and ``losses`` (L1, SSIM and VGG-16 perceptual).
"""

from __future__ import annotations

from torch import nn

from ..data.rig import nominal_centres
from ..data.sample import SynthConfig
from .depth import DepthStitchNet
from .model import ModelConfig, StitchNet


def build_model(model: ModelConfig, data: SynthConfig) -> nn.Module:
    """The network ``model.warp`` names, for the rig of ``data`` (its camera centres)."""
    if model.warp == "depth":
        return DepthStitchNet(model, nominal_centres(data.distance))
    return StitchNet(model)
