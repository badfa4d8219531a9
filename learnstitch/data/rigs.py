"""Synthetic rigs of other shapes than the three-fisheye rig, at full resolution: what the
full-resolution stitcher (:mod:`learnstitch.fullres`) is judged on.

A :class:`RigShape` is a ring of identical circular fisheyes (Hugin ``f2``, equidistant) around the
vertical axis, camera ``k`` at yaw ``yaws[k]`` with its centre ``distance`` along its optical axis;
each camera's yaw, pitch and roll jitter by ``+-angle_jitter_deg`` and its hfov by
``+-hfov_jitter_deg``, as the three-fisheye rig's do (:mod:`learnstitch.data.rig`). A sample of a
shape is the street scene of its seed with seam objects in the shape's own seams (midway between
neighbouring cameras), ray cast into every camera from its centre with the lens and sensor of a
:class:`~learnstitch.data.sample.SynthConfig`, and the ground-truth panorama and its depth from the
rig's centre.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch

from rigjax import Camera, Projection

from .rig import RigSample, fisheye_rays, jittered, pano_rays
from .sample import SynthConfig, render_fisheyes
from .scene import Scene, render, sample_scene


@dataclass(frozen=True)
class RigShape:
    """A ring of circular fisheyes; see the module docstring."""

    yaws: tuple[float, ...]  # degrees, + to the right of +z
    size: int  # square images, pixels
    hfov: float  # degrees across the image width (the image circle's too)
    distance: float  # each centre from the rig's centre, metres, along its optical axis

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
            dtype=np.float64,
            xp=np,
        )

    def centres(self) -> np.ndarray:
        """``(N, 3)`` world metres: ``distance`` along each nominal axis."""
        yaw = np.radians(np.asarray(self.yaws, np.float64))
        return self.distance * np.stack([np.sin(yaw), np.zeros_like(yaw), np.cos(yaw)], axis=-1)


# The rigs of the full-resolution evaluation: three 185-degree fisheyes 0.2 and 0.4 m out (the
# training rig's shape at eight times its size), a dual fisheye whose lenses are 3 cm apart, and a
# ring of four 150-degree fisheyes 0.1 m out.
FULLRES_RIGS = {
    "tri_d02": RigShape(yaws=(0.0, 120.0, 240.0), size=1024, hfov=185.0, distance=0.2),
    "tri_d04": RigShape(yaws=(0.0, 120.0, 240.0), size=1024, hfov=185.0, distance=0.4),
    "dual": RigShape(yaws=(0.0, 180.0), size=1024, hfov=190.0, distance=0.015),
    "ring4": RigShape(yaws=(0.0, 90.0, 180.0, 270.0), size=768, hfov=150.0, distance=0.1),
}


class RigRender(NamedTuple):
    """A sample of a :class:`RigShape`."""

    rig: RigSample  # the true cameras (jittered) and their centres
    fisheyes: torch.Tensor  # (N, 3, S, S) in [0, 1]
    pano: torch.Tensor  # (3, H, W) the truth from the rig's centre
    depth: torch.Tensor  # (H, W) metres along each panorama ray, inf for the sky
    scene: Scene


def render_rig(
    shape: RigShape,
    seed: int,
    pano_width: int,
    photometry: SynthConfig,
    angle_jitter_deg: float = 2.0,
    hfov_jitter_deg: float = 1.0,
) -> RigRender:
    """The sample of ``seed`` of ``shape``, its panorama ``pano_width`` wide (2:1), with the gain,
    vignetting and noise of ``photometry`` (its other keys unused). Same seed, same sample."""
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
    fisheyes, _ = render_fisheyes(scene, rig, rays, inside, theta, rng, lens, "cpu")
    pano, depth = render(
        scene, torch.zeros(3), torch.as_tensor(pano_rays(pano_width, pano_width // 2), dtype=torch.float32)
    )
    return RigRender(rig, fisheyes.permute(0, 3, 1, 2).contiguous(), pano.permute(2, 0, 1).contiguous(), depth, scene)
