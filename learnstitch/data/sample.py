"""Synthetic fisheye triplets with true parallax and the ground-truth panorama seen from the rig's centre.

A sample is drawn from one integer seed: a street scene (:mod:`learnstitch.data.scene`), a jittered
rig (:mod:`learnstitch.data.rig`), per-camera gain, vignetting and noise. The three fisheyes are ray
cast from the cameras' own centres (so near objects really move between views); the panorama is
ray cast from the centre. Same seed, same sample, bit for bit, on CPU.

Configuration (the ``data:`` section of ``configs/stitch/*.yaml``)::

    data:
      fisheye_size: 512        # square fisheye images, pixels
      pano_width: 1024         # 2:1 equirectangular panorama
      distance: 0.2            # camera centres from the panorama centre, metres
      hfov: 185.0              # lens hfov across the image width, degrees
      circle_deg: 185.0        # field of view inside the image circle
      angle_jitter_deg: 2.0    # yaw, pitch, roll of each camera, uniform +-
      hfov_jitter_deg: 1.0
      gain_jitter: 0.15        # per-camera gain, uniform 1 +- s, s uniform in [0, gain_jitter] per sample
      vignetting: 0.3          # most brightness lost at the circle's edge (uniform in [0, this] per sample)
      noise_std: 0.01          # Gaussian noise on the fisheyes (0-1 scale)
      rig: tri                 # or random: a rig drawn per sample (learnstitch.data.rigs.random_shape)
      cameras: [2, 6]          # random rigs: fewest and most cameras
      max_distance: 0.5        # random rigs: centres up to this far out, metres
      hfov_range: [150, 200]   # random rigs: the lens's hfov (its image circle's too), degrees
      tri_share: 0.25          # random rigs: the share of samples that are the rig above instead

With ``rig: random`` a sample is, with probability ``tri_share``, the three-fisheye rig's sample of
its seed (the keys above), and otherwise a ring of fisheyes of the drawn shape at ``fisheye_size``
with the same lens and sensor draws (:func:`learnstitch.data.rigs.render_rig`); the keys above then
also say which rig the validation and the tests of the three-fisheye split use.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from rigjax.config import typed_from_dict
from rigjax.errors import ConfigError

from .rig import RigSample, fisheye_rays, nominal_cameras, pano_rays, sample_rig, unwarp_grids
from .scene import render, sample_scene


@dataclass(frozen=True)
class SynthConfig:
    fisheye_size: int = 128
    pano_width: int = 256
    distance: float = 0.2
    hfov: float = 185.0
    circle_deg: float = 185.0
    angle_jitter_deg: float = 2.0
    hfov_jitter_deg: float = 1.0
    gain_jitter: float = 0.15
    vignetting: float = 0.3
    noise_std: float = 0.01
    rig: str = "tri"
    cameras: tuple[int, ...] = (2, 6)
    max_distance: float = 0.5
    hfov_range: tuple[float, ...] = (150.0, 200.0)
    tri_share: float = 0.25

    @property
    def pano_height(self) -> int:
        return self.pano_width // 2

    def __post_init__(self) -> None:
        if self.fisheye_size < 8 or self.pano_width < 16 or self.pano_width % 2:
            raise ConfigError(
                f"impossible sizes: fisheye_size {self.fisheye_size} (>= 8), pano_width {self.pano_width} (even, >= 16)"
            )
        if not 0.0 <= self.distance < 5.0:
            raise ConfigError(f"distance must be in [0, 5) metres, got {self.distance!r}")
        if not 90.0 < self.circle_deg <= 360.0 or not 90.0 < self.hfov <= 360.0:
            raise ConfigError(f"hfov and circle_deg must be in (90, 360], got {self.hfov!r}, {self.circle_deg!r}")
        for name in ("angle_jitter_deg", "hfov_jitter_deg", "gain_jitter", "vignetting", "noise_std"):
            if not getattr(self, name) >= 0.0:
                raise ConfigError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        if self.rig not in ("tri", "random"):
            raise ConfigError(f"rig must be 'tri' or 'random', got {self.rig!r}")
        low, high = (self.cameras + (0, 0))[:2]
        if len(self.cameras) != 2 or not 2 <= low <= high <= 8:
            raise ConfigError(f"cameras must be [fewest, most] with 2 <= fewest <= most <= 8, got {list(self.cameras)}")
        low, high = (self.hfov_range + (0.0, 0.0))[:2]
        if len(self.hfov_range) != 2 or not 90.0 < low <= high <= 360.0:
            raise ConfigError(f"hfov_range must be [low, high] within (90, 360], got {list(self.hfov_range)}")
        if not 0.0 <= self.max_distance < 2.0 or not 0.0 <= self.tri_share <= 1.0:
            raise ConfigError(
                f"max_distance must be in [0, 2) metres and tri_share in [0, 1], got {self.max_distance!r}, "
                f"{self.tri_share!r}"
            )

    @classmethod
    def from_dict(cls, values: dict[str, Any], where: str = "data") -> SynthConfig:
        return typed_from_dict(cls, values, where)


@dataclass(frozen=True)
class Sample:
    """One rig's images (three fisheyes, or a random rig's N). Images are float32 in [0, 1], channels first."""

    seed: int
    fisheyes: torch.Tensor  # (N, 3, S, S)
    fisheye_masks: torch.Tensor  # (N, S, S) bool: inside the image circle
    pano: torch.Tensor  # (3, H, W) ground truth from the centre
    depth: torch.Tensor  # (H, W) metres along the ray from the centre, inf for the sky
    rig: RigSample
    circle_deg: float  # the field of view inside each image circle, degrees


def make_sample(config: SynthConfig, seed: int, device: torch.device | str = "cpu") -> Sample:
    """Render the sample of ``seed`` (see the module docstring) on ``device`` (the ray casting;
    the camera maps and random draws are on the CPU). Bit-for-bit reproducible on the CPU."""
    if config.rig == "random":
        return _random_rig_sample(config, seed, device)
    rng = np.random.default_rng([int(seed), 0x5EED])
    scene = sample_scene(int(seed)).to(device)
    rig = sample_rig(
        rng, config.fisheye_size, config.hfov, config.distance, config.angle_jitter_deg, config.hfov_jitter_deg
    )
    rays, inside, theta = fisheye_rays(rig.cameras, config.circle_deg)

    def tensor(values, dtype=torch.float32):
        return torch.as_tensor(values, dtype=dtype).to(device)

    fisheyes, masks = render_fisheyes(scene, rig, rays, inside, theta, rng, config, device)
    pano, depth = render(scene, torch.zeros(3, device=device), tensor(pano_rays(config.pano_width, config.pano_height)))
    return Sample(
        int(seed),
        fisheyes.permute(0, 3, 1, 2).contiguous(),
        masks,
        pano.permute(2, 0, 1).contiguous(),
        depth,
        rig,
        config.circle_deg,
    )


def _random_rig_sample(config: SynthConfig, seed: int, device) -> Sample:
    """The sample of ``seed`` of a ``rig: random`` config (see the module docstring)."""
    from .rigs import random_shape, render_rig

    rng = np.random.default_rng([int(seed), 0x816A])
    if rng.uniform() < config.tri_share:
        return make_sample(dataclasses.replace(config, rig="tri"), seed, device)
    shape = random_shape(rng, config.fisheye_size, config)
    drawn = render_rig(shape, seed, config.pano_width, config, config.angle_jitter_deg, config.hfov_jitter_deg, device)
    return Sample(int(seed), drawn.fisheyes, drawn.masks, drawn.pano, drawn.depth, drawn.rig, shape.hfov)


def render_fisheyes(scene, rig: RigSample, rays, inside, theta, rng: np.random.Generator, config: SynthConfig, device):
    """What each camera of ``rig`` (of one image size) sees of ``scene`` from its own centre:
    ``(N, S, S, 3)`` in [0, 1] and ``(N, S, S)`` masks, with :func:`fisheye_rays`'s ``rays``,
    ``inside`` and ``theta``, and the lens and sensor of ``config`` drawn from ``rng``."""

    def tensor(values, dtype=torch.float32):
        return torch.as_tensor(values, dtype=dtype).to(device)

    n, height, width = inside.shape
    masks = tensor(inside, torch.bool)
    fisheyes = torch.zeros(n, height, width, 3, device=device)
    for k in range(n):
        fisheyes[k][masks[k]], _ = render(scene, tensor(rig.centres[k]), tensor(rays[k])[masks[k]])
    # Lens and sensor: gain, vignetting towards the circle's edge, noise. The gain jitter's and the
    # vignetting's strengths are drawn per sample in [0, configured] (after the noise, so that the
    # other draws stay those of a fixed strength): a clean camera is inside the distribution.
    spread = rng.uniform(-1.0, 1.0, n)
    noise = tensor(rng.standard_normal(fisheyes.shape)) * config.noise_std
    gain_strength, vignetting = rng.uniform(0.0, 1.0, 2) * (config.gain_jitter, config.vignetting)
    gain = tensor(1.0 + gain_strength * spread)
    falloff = 1.0 - vignetting * tensor(np.clip(theta / (config.circle_deg / 2.0), 0.0, 1.0)) ** 2
    fisheyes = (fisheyes * gain[:, None, None, None] * falloff[..., None] + noise).clamp(0.0, 1.0) * masks[..., None]
    return fisheyes, masks


def unwarp(fisheyes: torch.Tensor, grids: torch.Tensor) -> torch.Tensor:
    """Resample fisheyes ``(..., 3, C, S, S)`` onto the panorama through ``grids`` ``(3, H, W, 2)``
    (:func:`nominal_unwarp_grids`): bilinear, zeros outside each image."""
    batch = fisheyes.shape[:-4]
    flat = fisheyes.reshape(-1, *fisheyes.shape[-3:])
    grid = grids.expand(*batch, *grids.shape).reshape(-1, *grids.shape[1:]) if batch else grids
    out = torch.nn.functional.grid_sample(
        flat, grid.to(flat), mode="bilinear", padding_mode="zeros", align_corners=False
    )
    return out.reshape(*fisheyes.shape[:-2], *grids.shape[1:3])


def nominal_unwarp_grids(config: SynthConfig) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The unwarping grids of the rig's design (the network's inputs), with masks and angles."""
    return unwarp_grids(
        nominal_cameras(config.fisheye_size, config.hfov), (config.pano_width, config.pano_height), config.circle_deg
    )
