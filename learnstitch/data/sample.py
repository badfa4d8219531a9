"""Synthetic fisheye triplets with true parallax and the ground-truth panorama seen from the rig's centre.

A sample is drawn from one integer seed: a street scene (:mod:`learnstitch.data.scene`), a jittered
rig (:mod:`learnstitch.data.rig`), per-camera gain, vignetting and noise. The three fisheyes are ray
cast from the cameras' own centres (so near objects really move between views); the panorama is
ray cast from the centre. Same seed, same sample, bit for bit, on CPU.

The configuration, the ``data:`` section of ``configs/stitch/*.yaml``, is
:class:`learnstitch.data.config.SynthConfig`; with ``rig: random`` a sample is, with probability
``tri_share``, the three-fisheye rig's sample of its seed, and otherwise a ring of fisheyes of the
drawn shape (:func:`learnstitch.data.rigs.random_shape`, :func:`learnstitch.data.rigs.render_rig`)
with the same lens and sensor draws.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import torch

from .config import SynthConfig
from .rig import RigSample, fisheye_rays, nominal_cameras, pano_rays, sample_rig, unwarp_grids
from .rigs import random_shape, render_fisheyes, render_rig
from .scene import render, sample_scene

__all__ = ["Sample", "SynthConfig", "make_sample", "nominal_unwarp_grids", "unwarp"]


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
    rng = np.random.default_rng([int(seed), 0x816A])
    if rng.uniform() < config.tri_share:
        return make_sample(dataclasses.replace(config, rig="tri"), seed, device)
    shape = random_shape(rng, config.fisheye_size, config)
    drawn = render_rig(shape, seed, config.pano_width, config, config.angle_jitter_deg, config.hfov_jitter_deg, device)
    return Sample(int(seed), drawn.fisheyes, drawn.masks, drawn.pano, drawn.depth, drawn.rig, shape.hfov)


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
