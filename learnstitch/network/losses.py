"""Training losses: ``L = beta * L_pixel + (1 - beta) * L_SSIM [+ depth_weight * L_depth]
[+ plane_weight * L_plane] [+ class_weight * L_class] [+ surface_weight * L_surface]``.

``L_pixel`` is the L1 distance (``pixel: l1``) or the VGG-16 perceptual loss (``pixel:
perceptual``): the L1 distance between VGG-16 feature maps after each of its five blocks (the
max-pool outputs, as WSSN taps them), weighted per block, on ImageNet-normalised RGB in [0, 1].
``L_SSIM = 1 - SSIM`` with kornia's 11 x 11 Gaussian window (kornia's ``ssim_loss`` would return
``(1 - SSIM) / 2``, so the metric is used directly). ``beta = 1`` drops the SSIM term.
``L_surface`` (``model.first_surface`` only, off by default): :func:`surface_loss`.
``L_depth`` (the rig-aware warp only, off by default) is the L1 distance between the predicted
inverse depth and the truth's, both clipped to the sweep's range ``[0, model.max_inverse_depth]``.
``L_plane`` (the rig-aware warp only, off by default) is the expected error of its depth
distribution: at each pixel, the probability of each inverse-depth plane times the L1 distance
(mean over the channels) between what the inputs show at that plane and the truth, 1 at a plane
no input sees. Unlike the panorama's loss, whose gradient only reaches depths near the predicted
one, it scores every plane: where the inputs agree at two depths (a thin pole in front of a wall
that both cameras see past), it tells the nearer surface that the truth shows from the far one.
``L_class`` (the rig-aware warp only, off by default) is the cross-entropy of the depth
distribution against the truth's inverse depth, split between its two nearest planes, over the
pixels where two or more inputs see the truth's plane (where matching can find the depth). The
expected errors above saturate: a plane the network gives no probability gets no gradient, so a
network sure of the far background at a thin pole's pixels stays sure; the cross-entropy's
gradient at the true plane is ``p - 1`` however small ``p`` is.

VGG-16 is defined here with torchvision's parameter names (``features.0.weight`` ...
``features.28.bias``), so torchvision's ImageNet file ``vgg16-397923af.pth`` loads as it is; the
package never downloads it: the config names the file (``loss.vgg_weights``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from rigjax.errors import ConfigError

from .model import ModelConfig, StitchOutput

# torchvision's configuration "D": channels per convolution, "M" for a 2 x 2 max-pool.
_VGG16 = (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512, "M")
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


@dataclass(frozen=True)
class LossConfig:
    """The ``loss:`` section of ``configs/stitch/*.yaml``."""

    pixel: str = "l1"  # "l1" or "perceptual"
    beta: float = 0.4  # weight of the pixel term; 1 - beta on 1 - SSIM
    vgg_weights: str | None = None  # torchvision's vgg16-397923af.pth (or any state dict of that layout)
    vgg_block_weights: tuple[float, ...] = (0.0, 0.0, 0.2, 0.3, 0.5)  # per VGG block, as WSSN
    depth_weight: float = 0.0  # supervision of the rig-aware warp's inverse depth by the truth's; 0: none
    plane_weight: float = 0.0  # the rig-aware warp's expected error over its depth planes; 0: none
    class_weight: float = 0.0  # cross-entropy of the rig-aware warp's depth planes against the truth's; 0: none
    # Binary cross-entropy of the first surface's share (model.first_surface) against whether that
    # surface lies within one plane of the truth; 0: none
    surface_weight: float = 0.0

    def __post_init__(self) -> None:
        for key in ("depth_weight", "plane_weight", "class_weight", "surface_weight"):
            if not getattr(self, key) >= 0.0:
                raise ConfigError(f"{key} must be >= 0, got {getattr(self, key)!r}")
        if self.pixel not in ("l1", "perceptual"):
            raise ConfigError(f"pixel must be 'l1' or 'perceptual', got {self.pixel!r}")
        if not 0.0 <= self.beta <= 1.0:
            raise ConfigError(f"beta must be in [0, 1], got {self.beta!r}")
        if len(self.vgg_block_weights) != 5 or min(self.vgg_block_weights) < 0:
            raise ConfigError(f"vgg_block_weights must be 5 non-negative numbers, got {list(self.vgg_block_weights)}")


class VGG16Features(nn.Module):
    """torchvision's ``vgg16().features`` layout; ``forward`` returns the five max-pool outputs
    of ImageNet-normalised RGB in [0, 1] ``(N, 3, H, W)``. Frozen (no gradients to its weights)."""

    def __init__(self):
        super().__init__()
        layers, cin = [], 3
        for v in _VGG16:
            if v == "M":
                layers.append(nn.MaxPool2d(2, 2))
            else:
                layers += [nn.Conv2d(cin, v, 3, padding=1), nn.ReLU(inplace=False)]
                cin = v
        self.features = nn.Sequential(*layers)
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)
        self.requires_grad_(False)
        self.eval()

    def train(self, mode: bool = True) -> VGG16Features:
        return super().train(False)  # always in evaluation mode (it has no dropout or batch norm, but be explicit)

    def forward(self, rgb: torch.Tensor) -> list[torch.Tensor]:
        x = (rgb - self.mean) / self.std
        taps = []
        for layer in self.features:
            x = layer(x)
            if isinstance(layer, nn.MaxPool2d):
                taps.append(x)
        return taps


def load_vgg16(path: str | Path | None) -> VGG16Features:
    """VGG-16 features with the weights of a torchvision-layout state dict (``weights_only`` load)."""
    if path is None:
        raise ConfigError(
            "loss.pixel is 'perceptual' but loss.vgg_weights is not set: name a local copy of "
            "torchvision's ImageNet VGG-16 state dict (vgg16-397923af.pth, 528 MB); learnstitch never downloads it"
        )
    path = Path(path)
    if not path.is_file():
        raise ConfigError(
            f"{path}: VGG-16 weights not found (loss.vgg_weights). Provide torchvision's ImageNet "
            "VGG-16 state dict vgg16-397923af.pth, or any state dict with keys features.0.weight ... features.28.bias"
        )
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises several types for a file that is not a state dict
        raise ConfigError(f"{path}: not a loadable state dict ({type(error).__name__}: {error})") from None
    features = {k[len("features.") :]: v for k, v in state.items() if k.startswith("features.")}
    model = VGG16Features()
    missing, unexpected = model.features.load_state_dict(features, strict=False)
    if missing or unexpected:
        raise ConfigError(
            f"{path}: not a VGG-16 state dict of torchvision's layout (missing features.{missing[:3]}, "
            f"unexpected {unexpected[:3]})"
        )
    return model


def ssim_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """``1 - mean SSIM`` of images in [0, 1] ``(N, 3, H, W)`` (11 x 11 Gaussian window, sigma 1.5)."""
    # kornia is imported where it is used: the full-resolution stitch never calls this, and the
    # import is a noticeable share of that command's start-up.
    import kornia

    return 1.0 - kornia.metrics.ssim(pred, target, 11, max_val=1.0).mean()


class StitchLoss(nn.Module):
    """``beta * L_pixel + (1 - beta) * (1 - SSIM)`` of a predicted panorama against the truth, and
    the depth terms whose weights are > 0 (the module docstring).

    ``max_inverse_depth`` and ``depth_planes``: the rig-aware network's sweep (``model.*``, which
    the depth terms read: the range the inverse depths are clipped to, and the planes evenly spaced
    in it, ``max_inverse_depth / (depth_planes - 1)`` apart). ``forward`` returns the total and its
    terms (tensors; logging them is the caller's business).
    """

    def __init__(
        self,
        config: LossConfig = LossConfig(),
        vgg: VGG16Features | None = None,
        *,
        max_inverse_depth: float = ModelConfig.max_inverse_depth,
        depth_planes: int = ModelConfig.depth_planes,
    ):
        super().__init__()
        self.config = config
        self.max_inverse_depth = max_inverse_depth
        self.spacing = max_inverse_depth / max(depth_planes - 1, 1)  # the sweep's planes apart
        if config.pixel == "perceptual" and config.beta > 0.0:
            self.vgg = vgg if vgg is not None else load_vgg16(config.vgg_weights)
        else:
            self.vgg = None

    def pixel(self, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        if self.vgg is None:
            return F.l1_loss(pred, target)
        terms = [
            w * F.l1_loss(a, b)
            for w, a, b in zip(self.config.vgg_block_weights, self.vgg(pred), self.vgg(target))
            if w > 0
        ]
        return torch.stack(terms).sum()

    def forward(
        self, output: StitchOutput, batch: Mapping[str, torch.Tensor]
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """The loss of the network's ``output`` against ``batch``: its panorama against the truth's
        ``batch["pano"]`` ``(B, 3, H, W)``, and the depth terms (:meth:`depth_terms`) against
        ``batch["inverse_depth"]`` ``(B, H, W)`` (the keys of :mod:`learnstitch.data.datasets`)."""
        beta = self.config.beta
        pred, target = output.pano, batch["pano"]
        terms = {}
        if beta > 0.0:
            terms["pixel"] = self.pixel(pred, target)
        if beta < 1.0:
            terms["ssim"] = ssim_loss(pred, target)
        total = beta * terms.get("pixel", 0.0) + (1.0 - beta) * terms.get("ssim", 0.0)
        for key, term in self.depth_terms(output, batch).items():
            terms[key] = term
            total = total + getattr(self.config, f"{key}_weight") * term
        return total, terms

    def depth_terms(self, output: StitchOutput, batch: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """The terms of the rig-aware network whose weights are > 0, unweighted: ``depth``, the L1
        distance of ``output.inverse_depth`` from the truth's, both clipped to ``[0,
        max_inverse_depth]``; ``plane`` (:func:`plane_loss`) of the ``plane_*`` fields; ``class``
        (:func:`plane_class_loss`) of the depth distribution where ``output.plane_overlap`` is 1;
        ``surface`` (:func:`surface_loss`) of the first surface. A :class:`ConfigError` where the
        output lacks what a term reads (the network predicts no depth, or has no first surface)."""
        config, m = self.config, self.max_inverse_depth
        needs_depth = "needs a network that predicts depth (model.warp: depth)"
        terms = {}
        if config.depth_weight > 0.0:
            if output.inverse_depth is None:
                raise ConfigError(f"loss.depth_weight > 0 {needs_depth}")
            truth = _truth_inverse_depth(batch, "depth_weight").clamp(0.0, m)
            terms["depth"] = F.l1_loss(output.inverse_depth.clamp(0.0, m), truth)
        if config.plane_weight > 0.0:
            planes = (output.plane_probabilities, output.plane_colours, output.plane_seen)
            if any(t is None for t in planes):
                raise ConfigError(f"loss.plane_weight > 0 {needs_depth}")
            terms["plane"] = plane_loss(*planes, batch["pano"])
        if config.class_weight > 0.0:
            if output.plane_probabilities is None or output.plane_overlap is None:
                raise ConfigError(f"loss.class_weight > 0 {needs_depth}")
            truth = _truth_inverse_depth(batch, "class_weight")
            terms["class"] = plane_class_loss(output.plane_probabilities, output.plane_overlap, truth, m)
        if config.surface_weight > 0.0:
            if output.surface_depth is None:
                raise ConfigError("loss.surface_weight > 0 needs model.first_surface: true")
            truth = _truth_inverse_depth(batch, "surface_weight").clamp(0.0, m)
            terms["surface"] = surface_loss(output.surface_depth, output.surface_logit, self.spacing, truth)
        return terms


def _truth_inverse_depth(batch: Mapping[str, torch.Tensor], weight: str) -> torch.Tensor:
    """``batch["inverse_depth"]``, which the term of ``loss.{weight}`` reads."""
    if batch.get("inverse_depth") is None:
        raise ConfigError(
            f"loss.{weight} > 0 reads the truth's inverse depth, batch['inverse_depth'] (B, H, W); "
            f"the batch holds {sorted(batch)}"
        )
    return batch["inverse_depth"]


def surface_loss(
    surface_depth: torch.Tensor, logit: torch.Tensor, spacing: float, target_inverse_depth: torch.Tensor
) -> torch.Tensor:
    """Binary cross-entropy of the first surface's share (``logit`` ``(B, H, W)``) against whether
    the first surface (``surface_depth`` ``(B, H, W)``, -1 where a pixel has none) lies within
    ``spacing`` (one plane) of ``target_inverse_depth``, over the pixels that have one; 0 without."""
    found = surface_depth >= 0.0
    if not found.any():
        return logit.sum() * 0.0
    right = ((surface_depth - target_inverse_depth).abs() <= spacing).to(logit.dtype)
    return F.binary_cross_entropy_with_logits(logit[found], right[found])


def plane_loss(
    probabilities: torch.Tensor, colours: torch.Tensor, seen: torch.Tensor, target: torch.Tensor
) -> torch.Tensor:
    """The mean over pixels of ``sum_p probabilities_p * error_p``: ``error_p`` the L1 distance
    (mean over channels) between ``colours`` at plane ``p`` and ``target`` ``(B, C, H, W)`` where
    ``seen``, 1 elsewhere."""
    error = (colours - target[:, :, None]).abs().mean(dim=1)
    error = torch.where(seen > 0, error, 1.0)
    return (probabilities * error).sum(dim=1).mean()


def plane_class_loss(
    probabilities: torch.Tensor, overlap: torch.Tensor, target_inverse_depth: torch.Tensor, max_inverse_depth: float
) -> torch.Tensor:
    """The mean, over the pixels where ``overlap`` ``(B, P, H, W)`` is 1 at the plane nearest the truth,
    of the cross-entropy ``-sum_p y_p log probabilities_p``: ``y`` puts the truth's inverse depth
    ``target_inverse_depth`` ``(B, H, W)`` (clipped to ``[0, max_inverse_depth]``) on the two planes
    around it, in proportion to its distance from each (planes evenly spaced from 0 to
    ``max_inverse_depth``); 0 without such pixels."""
    count = probabilities.shape[1]
    position = target_inverse_depth.clamp(0.0, max_inverse_depth) * ((count - 1) / max_inverse_depth)
    below = position.floor().clamp_max(count - 2)
    above_share = (position - below)[:, None]
    below = below.long()[:, None]
    log_p = probabilities.clamp_min(1e-30).log()
    cross = -((1.0 - above_share) * log_p.gather(1, below) + above_share * log_p.gather(1, below + 1))[:, 0]
    valid = overlap.gather(1, position.round().long()[:, None])[:, 0]
    return (cross * valid).sum() / valid.sum().clamp_min(1.0)
