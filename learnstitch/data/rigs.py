"""Synthetic rigs of other shapes than the three-fisheye rig: at full resolution, what the
full-resolution stitcher (:mod:`learnstitch.fullres`) is judged on, and drawn at random
(:func:`random_shape`), what a network of any rig is trained on.

A :class:`RigShape` is a ring of identical circular fisheyes (Hugin ``f2``, equidistant) around the
vertical axis, camera ``k`` at yaw ``yaws[k]`` with its centre ``distance`` along its optical axis;
each camera's yaw, pitch and roll jitter by ``+-angle_jitter_deg`` and its hfov by
``+-hfov_jitter_deg``, as the three-fisheye rig's do (:mod:`learnstitch.data.rig`). A sample of a
shape is the street scene of its seed with seam objects in the shape's own seams (midway between
neighbouring cameras), ray cast into every camera from its centre with the lens and sensor of a
:class:`~learnstitch.data.config.SynthConfig` (:func:`render_fisheyes`, which the three-fisheye
samples use too), and the ground-truth panorama and its depth from the rig's centre.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch

from rigjax import Camera, Projection

from .config import SynthConfig
from .rig import RigSample, fisheye_rays, jittered, pano_rays
from .scene import Scene, render, sample_scene


@dataclass(frozen=True)
class RigShape:
    """A ring of circular fisheyes; see the module docstring."""

    yaws: tuple[float, ...]  # degrees, + to the right of +z
    size: int  # square images, pixels
    hfov: float  # degrees across the image width (the image circle's too)
    distance: float  # each centre from the rig's centre, metres, along its optical axis
    pitches: tuple[float, ...] | None = None  # degrees, + up (Hugin's); None: all 0

    @property
    def seams(self) -> tuple[float, ...]:
        """The azimuths midway between neighbouring cameras, degrees."""
        yaws = sorted(y % 360.0 for y in self.yaws)
        return tuple((a + ((b - a) % 360.0) / 2.0) % 360.0 for a, b in zip(yaws, yaws[1:] + yaws[:1]))

    def nominal(self) -> Camera:
        """The design's cameras (NumPy fields): yaw as given, no pitch, roll or distortion."""
        yaw = np.array([(y + 180.0) % 360.0 - 180.0 for y in self.yaws])
        size = float(self.size)
        return Camera.create(
            projection=int(Projection.CIRCULAR_FISHEYE),
            width=size,
            height=size,
            hfov=self.hfov,
            yaw=yaw,
            pitch=np.zeros_like(yaw) if self.pitches is None else np.asarray(self.pitches, np.float64),
            dtype=np.float64,
            xp=np,
        )

    def axes(self) -> np.ndarray:
        """``(N, 3)`` the nominal optical axes, world unit vectors (rigjax's frame: y down)."""
        yaw = np.radians(np.asarray(self.yaws, np.float64))
        pitch = np.radians(np.zeros_like(yaw) if self.pitches is None else np.asarray(self.pitches, np.float64))
        return np.stack([np.sin(yaw) * np.cos(pitch), -np.sin(pitch), np.cos(yaw) * np.cos(pitch)], axis=-1)

    def centres(self) -> np.ndarray:
        """``(N, 3)`` world metres: ``distance`` along each nominal axis."""
        return self.distance * self.axes()


# The rigs of the full-resolution evaluation: three 185-degree fisheyes 0.2 and 0.4 m out (the
# training rig's shape at eight times its size), a dual fisheye whose lenses are 3 cm apart, and a
# ring of four 150-degree fisheyes 0.1 m out.
FULLRES_RIGS = {
    "tri_d02": RigShape(yaws=(0.0, 120.0, 240.0), size=1024, hfov=185.0, distance=0.2),
    "tri_d04": RigShape(yaws=(0.0, 120.0, 240.0), size=1024, hfov=185.0, distance=0.4),
    "dual": RigShape(yaws=(0.0, 180.0), size=1024, hfov=190.0, distance=0.015),
    "ring4": RigShape(yaws=(0.0, 90.0, 180.0, 270.0), size=768, hfov=150.0, distance=0.1),
}


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


def random_shape(rng: np.random.Generator, size: int, config: SynthConfig) -> RigShape:
    """A rig drawn for ``config.rig: random``: ``N`` cameras (uniform in ``config.cameras``) in a
    ring of even steps from a random start, each yaw moved by up to 15 % of a step and each pitch
    by up to 15 degrees (two cameras: back to back within 2 degrees, as dual-fisheye cameras are
    built); one lens for all, its hfov uniform in ``config.hfov_range`` above the ring's widest
    gap between neighbours plus 15 degrees (so that neighbours overlap and every direction of
    the horizon is seen); centres uniform in ``[0.01, config.max_distance]`` metres out along the
    axes."""
    count = int(rng.integers(config.cameras[0], config.cameras[1] + 1))
    step = 360.0 / count
    spread, tilt = (2.0 / step, 2.0) if count == 2 else (0.15, 15.0)
    yaws = rng.uniform(0.0, 360.0) + step * (np.arange(count) + rng.uniform(-spread, spread, count))
    pitches = rng.uniform(-tilt, tilt, count)
    gap = float(np.diff(np.sort(np.mod(yaws, 360.0)), append=np.mod(yaws, 360.0).min() + 360.0).max())
    low, high = config.hfov_range
    hfov = float(rng.uniform(min(max(low, gap + 15.0), high), high))
    distance = float(rng.uniform(0.01, max(config.max_distance, 0.01)))
    return RigShape(tuple(float(y) for y in yaws), size, hfov, distance, tuple(float(p) for p in pitches))


class RigRender(NamedTuple):
    """A sample of a :class:`RigShape`."""

    rig: RigSample  # the true cameras (jittered) and their centres
    fisheyes: torch.Tensor  # (N, 3, S, S) in [0, 1]
    pano: torch.Tensor  # (3, H, W) the truth from the rig's centre
    depth: torch.Tensor  # (H, W) metres along each panorama ray, inf for the sky
    scene: Scene
    masks: torch.Tensor  # (N, S, S) bool: inside each image circle


def render_rig(
    shape: RigShape,
    seed: int,
    pano_width: int,
    photometry: SynthConfig,
    angle_jitter_deg: float = 2.0,
    hfov_jitter_deg: float = 1.0,
    device: torch.device | str = "cpu",
) -> RigRender:
    """The sample of ``seed`` of ``shape``, its panorama ``pano_width`` wide (2:1), with the gain,
    vignetting and noise of ``photometry`` (its other keys unused), ray cast on ``device``. Same
    seed, same sample."""
    rng = np.random.default_rng([int(seed), 0x816])
    cameras = jittered(shape.nominal(), rng, angle_jitter_deg, hfov_jitter_deg)
    rig = RigSample(cameras, shape.centres())
    scene = sample_scene(int(seed), seam_yaws_deg=shape.seams)
    rays, inside, theta = fisheye_rays(cameras, shape.hfov)
    lens = SynthConfig(
        circle_deg=shape.hfov,
        gain_jitter=photometry.gain_jitter,
        vignetting=photometry.vignetting,
        noise_std=photometry.noise_std,
    )
    fisheyes, masks = render_fisheyes(scene.to(device), rig, rays, inside, theta, rng, lens, device)
    rays = torch.as_tensor(pano_rays(pano_width, pano_width // 2), dtype=torch.float32).to(device)
    pano, depth = render(scene.to(device), torch.zeros(3, device=device), rays)
    fisheyes, pano = fisheyes.permute(0, 3, 1, 2).contiguous(), pano.permute(2, 0, 1).contiguous()
    return RigRender(rig, fisheyes, pano, depth, scene, masks)
