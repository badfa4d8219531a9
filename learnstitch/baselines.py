"""Classical references for the stitching network, and the metrics they are judged by.

:func:`rotation_only_stitch` stitches a sample with the *true* camera orientations and lenses but
ignores the cameras' offsets from the centre: each fisheye is unwarped onto the panorama and the
three are feather-blended (weights falling to 0 at each image circle's edge). It is the best a
rotation-only calibration can do, so its error against the ground truth is the parallax the data
carries.
"""

from __future__ import annotations

import kornia
import torch

from ._rig import RigSample, feather_weights, unwarp_grids
from .synth import SynthConfig, unwarp


def rotation_only_stitch(fisheyes: torch.Tensor, rig: RigSample, config: SynthConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """``(3, H, W)`` panorama and ``(H, W)`` coverage mask from fisheyes ``(3, 3, S, S)``."""
    grids, masks, theta = unwarp_grids(rig.cameras, (config.pano_width, config.pano_height), config.circle_deg)
    warped = unwarp(fisheyes, grids)  # (3, 3, H, W)
    weights = feather_weights(theta, masks, config.circle_deg)
    return (warped * weights[:, None]).sum(dim=0), masks.any(dim=0)


def psnr(image: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """PSNR in dB of images in [0, 1] ``(..., C, H, W)`` over the pixels of ``mask`` ``(..., H, W)``,
    one value per image (``inf`` for identical images)."""
    error = (image - target) ** 2
    if mask is None:
        mask = torch.ones(error.shape[:-3] + error.shape[-2:], dtype=torch.bool, device=error.device)
    m = mask[..., None, :, :].to(error.dtype).expand_as(error)
    mse = (error * m).sum(dim=(-3, -2, -1)) / m.sum(dim=(-3, -2, -1)).clamp_min(1.0)
    return 10.0 * torch.log10(1.0 / mse)


def ssim(image: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """Mean SSIM (11 x 11 Gaussian window, sigma 1.5) per image over ``mask``."""
    batch = image.shape[:-3]
    a, b = image.reshape(-1, *image.shape[-3:]), target.reshape(-1, *target.shape[-3:])
    s = kornia.metrics.ssim(a, b, 11, max_val=1.0).mean(dim=1)  # (N, H, W)
    if mask is None:
        return s.mean(dim=(-2, -1)).reshape(batch)
    m = mask.reshape(-1, *mask.shape[-2:]).to(s.dtype)
    return ((s * m).sum(dim=(-2, -1)) / m.sum(dim=(-2, -1)).clamp_min(1.0)).reshape(batch)
