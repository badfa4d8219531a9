"""Synthetic frames of a consumer dual-fisheye 360 camera, with their truth: what ``rigjax calibrate
--template configs/rig/dual_fisheye.yaml`` is judged on (``benchmarks/dual_fisheye.py``) and what
``learnstitch demo --dual`` writes for a new user to calibrate.

Two circular fisheyes back to back (Hugin ``f2``), one lens for both, each lens's centre a little
in front of the camera's middle along its axis, both images side by side in one frame (left: camera
0). The street scene of a seed (:func:`learnstitch.data.scene.sample_scene`, a near object in each
of the seams at 90 and 270 degrees, 0.5-3 m from the camera) is ray cast from each lens's centre,
and Hugin's photometric model (:mod:`rigjax.camera.photometry`) is applied to its light: each
image's exposure value and white balance, one vignetting polynomial ``1 + Vb r^2`` for both lenses;
then noise and 8 bits. A sequence is the camera turning on the spot by ``turn_deg`` a frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import numpy as np
import torch

import rigjax
from rigjax import Camera

from .rig import fisheye_rays
from .scene import render, sample_scene

# Near objects stand 0.1-2.6 m beyond the scene's rig circle (0.4 m): 0.5-3 m from the camera.
NEAR_RANGE = (0.1, 2.6)


@dataclass(frozen=True)
class DualTruth:
    """A dual-fisheye camera as drawn: its cameras in the first frame, the lenses' centres
    (metres, the first frame's world), each image's exposure value ``Eev`` and white balance
    ``(Er, Eb)``, and the lenses' vignetting ``Vb``."""

    cameras: Camera  # (2,) NumPy fields
    centres: np.ndarray  # (2, 3)
    exposure_value: np.ndarray  # (2,)
    white_balance: np.ndarray  # (2, 2)
    vignetting_b: float

    def relative(self) -> Camera:
        """The cameras in camera 0's frame (camera 0 at yaw, pitch and roll 0, as a calibration
        anchored on it reports them)."""
        with jax.enable_x64(True):
            c = self.cameras
            world = np.asarray(rigjax.world_from_cam(c.yaw, c.pitch, c.roll), np.float64)
            ypr = np.asarray(rigjax.ypr_from_world_from_cam(world[0].T @ world), np.float64)
        return c._replace(yaw=ypr[:, 0], pitch=ypr[:, 1], roll=ypr[:, 2])

    def project(self, names: tuple[str, str], panorama_width: int = 4096) -> rigjax.Project:
        """The truth as a project of the frame's two halves (``names``), in camera 0's frame
        (:meth:`relative`): the true lenses (hfov, ``a``, ``b``, ``c``, ``d``, ``e``), exposure values relative to camera 0's, white balance
        and vignetting, and the centres as ``#-rigjax centre`` lines; no control points."""
        c = self.relative()
        size = int(c.width[0])
        images = [
            rigjax.Image(
                width=size,
                height=size,
                projection=2,
                hfov=float(c.hfov[k]),
                yaw=float(c.yaw[k]),
                pitch=float(c.pitch[k]),
                roll=float(c.roll[k]),
                a=float(c.a[k]),
                b=float(c.b[k]),
                c=float(c.c[k]),
                d=float(c.d[k]),
                e=float(c.e[k]),
                filename=names[k],
                exposure_value=float(self.exposure_value[k] - self.exposure_value[0]),
                white_balance_red=float(self.white_balance[k, 0]),
                white_balance_blue=float(self.white_balance[k, 1]),
                vignetting_b=self.vignetting_b,
            )
            for k in range(2)
        ]
        with jax.enable_x64(True):
            c0 = self.cameras
            world_from_0 = np.asarray(rigjax.world_from_cam(c0.yaw[0], c0.pitch[0], c0.roll[0]), np.float64)
        panorama = rigjax.PanoramaLine(width=panorama_width, height=panorama_width // 2, projection=2, hfov=360.0)
        return rigjax.Project.new(panorama, images).replace(centres=self.centres @ world_from_0)


def draw_dual(
    seed: int,
    size: int = 1440,
    hfov_range: tuple[float, float] = (189.0, 191.0),
    separation_range: tuple[float, float] = (0.02, 0.03),
    angle_jitter_deg: float = 2.0,
    b: float = -0.01,
) -> DualTruth:
    """The camera of ``seed``: hfov uniform in ``hfov_range`` (one lens for both), each lens's yaw,
    pitch and roll within ``angle_jitter_deg`` of back to back, the lenses ``separation_range``
    metres apart along their axis, K2 ``b``; camera 1's exposure within 0.5 EV of camera 0's (both
    darker than the scene by about half a stop, so that little clips), its white balance within
    7 %, the vignetting's ``Vb`` in -0.5..-0.1. Same seed, same camera."""
    rng = np.random.default_rng([int(seed), 47])
    jitter = rng.uniform(-angle_jitter_deg, angle_jitter_deg, (3, 2))
    hfov = rng.uniform(*hfov_range)
    cameras = Camera.create(
        projection=2,
        width=float(size),
        height=float(size),
        hfov=np.full(2, hfov),
        b=np.full(2, b),
        yaw=np.array([0.0, 180.0]) + jitter[0],
        pitch=jitter[1],
        roll=jitter[2],
        dtype=np.float64,
        xp=np,
    )
    half = rng.uniform(*separation_range) / 2.0
    exposure = np.array([0.5, 0.5 + rng.uniform(-0.5, 0.5)])
    white_balance = np.array([[1.0, 1.0], rng.uniform(0.93, 1.07, 2)])
    centres = np.array([[0.0, 0.0, half], [0.0, 0.0, -half]])
    return DualTruth(cameras, centres, exposure, white_balance, float(rng.uniform(-0.5, -0.1)))


def render_dual_frames(
    seed: int, truth: DualTruth, frames: int = 1, turn_deg: float = 72.0, noise_std: float = 0.01
) -> list[np.ndarray]:
    """``frames`` side-by-side frames ``(S, 2 S, 3)`` uint8 of ``truth`` in the street scene of
    ``seed``, the camera turned by ``turn_deg`` about the vertical from one frame to the next (the
    first: as drawn, a near object in each seam)."""
    scene = sample_scene(int(seed), seam_yaws_deg=(90.0, 270.0), near_range=NEAR_RANGE)
    size = int(truth.cameras.width[0])
    xy = np.stack(np.meshgrid(np.arange(size), np.arange(size)), -1).astype(np.float64)
    r2 = ((xy - (size - 1) / 2.0) ** 2).sum(-1) / (2.0 * (size / 2.0) ** 2)  # Hugin's r^2, in half diagonals
    rng = np.random.default_rng([int(seed), 4747])
    out = []
    for f in range(frames):
        turn = math.radians(turn_deg * f)  # about the vertical: yaw is a camera's outermost rotation
        cameras = truth.cameras._replace(yaw=truth.cameras.yaw + turn_deg * f)
        rotation = np.array([[math.cos(turn), 0, math.sin(turn)], [0, 1, 0], [-math.sin(turn), 0, math.cos(turn)]])
        centres = truth.centres @ rotation.T
        rays, inside, _ = fisheye_rays(cameras, float(cameras.hfov[0]))
        halves = []
        for k in range(2):
            light = np.zeros((size, size, 3))
            colour, _ = render(
                scene,
                torch.as_tensor(centres[k], dtype=torch.float32),
                torch.as_tensor(rays[k][inside[k]], dtype=torch.float32),
            )
            light[inside[k]] = colour.double().numpy()
            gain = (1.0 + truth.vignetting_b * r2) * 2.0 ** -truth.exposure_value[k]
            balance = np.array([truth.white_balance[k, 0], 1.0, truth.white_balance[k, 1]])
            pixels = light * gain[..., None] * balance + rng.normal(0.0, noise_std, light.shape)
            halves.append(np.round(255 * np.clip(pixels, 0.0, 1.0) * inside[k][..., None]).astype(np.uint8))
        out.append(np.concatenate(halves, axis=1))
    return out
