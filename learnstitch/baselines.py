"""Classical references for the stitching network, and the metrics they are judged by.

Three stitch the classical way — each fisheye unwarped onto the panorama through a camera model
and the three feather-blended (weights falling to 0 at each image circle's edge), ignoring the
cameras' offsets from the centre — and differ in where the cameras come from:

* :func:`nominal_stitch`: the rig's design (what the network's inputs are unwarped with);
* :func:`rotation_only_stitch`: the *true* orientations and lenses. The best a rotation-only
  calibration can do, so its error against the ground truth is the parallax the data carries.
* :func:`calibrated_stitch`: orientations and hfov calibrated from the three images by rigjax
  (features, RANSAC, staged Levenberg-Marquardt and pruning: ``rigjax calibrate`` with the
  template ``configs/rig/tri_fisheye.yaml``), what a user without ground truth gets.

The fourth, :func:`depth_oracle_stitch`, knows the true depth of every panorama pixel: it
resamples each input along its own sight line to the pixel's scene point
(:mod:`learnstitch.data.visibility`), the most any warp of the inputs can do.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import kornia
import numpy as np
import torch
import torch.nn.functional as F

import rigjax
from rigjax import Camera
from rigjax.calibration.pipeline import calibrate_cameras

from .data.rig import RigSample, feather_weights, nominal_cameras, nominal_centres, pano_rays, unwarp_grids
from .data.sample import SynthConfig, unwarp
from .data.store import to_uint8
from .data.visibility import SightLines, grids_at_depth


def stitch_with_cameras(
    fisheyes: torch.Tensor, cameras: Camera, config: SynthConfig
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(3, H, W)`` panorama and ``(H, W)`` coverage mask from fisheyes ``(3, 3, S, S)`` seen by
    ``cameras`` (rigjax cameras, one per fisheye): unwarped and feather-blended."""
    grids, masks, theta = unwarp_grids(cameras, (config.pano_width, config.pano_height), config.circle_deg)
    return _feathered(fisheyes, grids, masks, theta, config), masks.any(dim=0)


def _feathered(fisheyes, grids, masks, theta, config: SynthConfig) -> torch.Tensor:
    """``(3, H, W)``: the fisheyes sampled through ``grids`` ``(3, H, W, 2)`` and feather-blended
    over ``masks`` by their angles ``theta`` from each axis."""
    return (unwarp(fisheyes, grids) * feather_weights(theta, masks, config.circle_deg)[:, None]).sum(dim=0)


def rotation_only_stitch(
    fisheyes: torch.Tensor, rig: RigSample, config: SynthConfig
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`stitch_with_cameras` with the sample's true cameras."""
    return stitch_with_cameras(fisheyes, rig.cameras, config)


def nominal_stitch(fisheyes: torch.Tensor, config: SynthConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`stitch_with_cameras` with the rig's design (no jitter known)."""
    return stitch_with_cameras(fisheyes, nominal_cameras(config.fisheye_size, config.hfov), config)


def depth_oracle_stitch(
    fisheyes: torch.Tensor, lines: SightLines, config: SynthConfig, fallback: torch.Tensor
) -> torch.Tensor:
    """``(3, H, W)``: each input sampled along its sight lines (:func:`learnstitch.data.visibility.sight_lines`:
    the true depth and cameras) and feather-blended over the inputs that see each point; in the
    blind spot, where none does, ``fallback`` (the true-rotation stitch)."""
    return torch.where(lines.seen, _feathered(fisheyes, lines.grid, lines.visible, lines.theta, config), fallback)


class CalibratedStitch(NamedTuple):
    """:func:`calibrated_stitch`'s panorama and coverage, the cameras it used, and why calibration
    failed (``None`` when it did not; the nominal rig was used instead); the camera centres the
    calibration held (zeros for a rotation-only calibration, or none), and its control points'
    scene points ``(n, 3)`` (metres, the calibration's frame; ``inf`` at infinity; none without a
    bundle adjustment), for a stitch that uses the rig's depth."""

    pano: torch.Tensor
    covered: torch.Tensor
    cameras: Camera
    failure: str | None
    centres: np.ndarray
    points: np.ndarray


def rig_template(template: rigjax.CalibrateConfig, config: SynthConfig) -> rigjax.CalibrateConfig:
    """``template`` for the data's rig: without centres of its own, it gets the rig's nominal
    centres (``config.distance`` along each nominal axis) and the bundle adjustment (objective
    ``reprojection``), which keeps the parallax of near matches instead of averaging it into the
    orientations; and, unless it has priors of its own, the rig's stated tolerances as priors: the
    hfov's standard deviation ``config.hfov_jitter_deg`` about the template's hfov (the data's
    lenses are within that of their nominal 185 degrees, as a lens's data sheet would say), the
    yaw's, pitch's and roll's ``config.angle_jitter_deg`` about the template's orientations (the
    mounting's tolerance, which sets the rig's orientation where the matches tell it weakly)."""
    if template.rig.centres is not None or template.optimise.centres is not None:
        return template
    centres = tuple(map(tuple, nominal_centres(config.distance).tolist()))
    priors = template.optimise.priors
    if not priors.as_dict():
        tolerances = {"v": config.hfov_jitter_deg} | dict.fromkeys("ypr", config.angle_jitter_deg)
        priors = dataclasses.replace(priors, **{k: sd for k, sd in tolerances.items() if sd > 0.0})
    return dataclasses.replace(
        template,
        rig=dataclasses.replace(template.rig, centres=centres),
        optimise=dataclasses.replace(template.optimise, objective="reprojection", priors=priors),
    )


def _world_from_cam(cameras: Camera) -> np.ndarray:
    with jax.enable_x64(True):  # float64 whatever JAX's global setting, as the rig's maps
        return np.asarray(rigjax.world_from_cam(cameras.yaw, cameras.pitch, cameras.roll), np.float64)


def rig_turn(cameras: Camera, reference: Camera) -> np.ndarray:
    """``(3, 3)``: the one rotation ``G`` that minimises ``sum_k |G R_k - R_ref_k|^2`` over the
    cameras' ``world_from_cam`` (Kabsch, closed form)."""
    estimated, truth = _world_from_cam(cameras), _world_from_cam(reference)
    u, _, vt = np.linalg.svd(np.einsum("kij,klj->il", truth, estimated))  # sum_k R_ref_k R_k^T
    return u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt


def align_rig(cameras: Camera, reference: Camera) -> Camera:
    """``cameras`` turned as a whole onto ``reference`` by :func:`rig_turn`.

    Images tell a rig's cameras relative to each other but not the rig's orientation in the
    world; comparing a calibration with the truth first removes that freedom, and only that.
    """
    return _turned(cameras, rig_turn(cameras, reference))


def _turned(cameras: Camera, turn: np.ndarray) -> Camera:
    with jax.enable_x64(True):
        ypr = rigjax.ypr_from_world_from_cam(turn @ _world_from_cam(cameras))
        yaw, pitch, roll = np.asarray(ypr, np.float64).T
    return cameras._replace(yaw=yaw, pitch=pitch, roll=roll)


def orientation_turns_deg(cameras: Camera, reference: Camera) -> np.ndarray:
    """``(n, 3)``: each camera's turn from the reference in degrees about the world's axes (half
    the skew part of ``R R_ref^T``: the small-angle rotation vector, in the axes of rigjax's
    reported turn covariance, ``BundleResult.turn_covariance``)."""
    m = _world_from_cam(cameras) @ np.swapaxes(_world_from_cam(reference), 1, 2)
    return np.degrees(0.5 * np.stack([m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]], -1))


def orientation_errors_deg(cameras: Camera, reference: Camera) -> np.ndarray:
    """Angle in degrees of the rotation between each camera's orientation and the reference's,
    from the chordal distance ``|A - B|_F = 2 sqrt(2) sin(angle / 2)`` (exact near 0)."""
    chord = np.linalg.norm(_world_from_cam(cameras) - _world_from_cam(reference), axis=(-2, -1))
    return np.degrees(2.0 * np.arcsin(np.clip(chord / (2.0 * np.sqrt(2.0)), 0.0, 1.0)))


def calibrated_stitch(
    fisheyes: torch.Tensor,
    config: SynthConfig,
    template: rigjax.CalibrateConfig,
    *,
    reference: Camera | None = None,
    seed: int = 0,
) -> CalibratedStitch:
    """Calibrate the rig from fisheyes ``(3, 3, S, S)`` (floats in [0, 1]) with rigjax and stitch
    with the calibrated cameras (:func:`stitch_with_cameras`).

    ``template``: the rig template (:func:`rigjax.load_template`; ``configs/rig/tri_fisheye.yaml``);
    without centres of its own it gets the data's (:func:`rig_template`).
    ``reference``: cameras to turn the calibrated rig onto as a whole (:func:`align_rig`; the
    true cameras, when judging against a ground truth drawn in the world frame); the centres and
    points turn with it. A rig that
    cannot be calibrated (:class:`rigjax.CalibrationError`: too few consistent matches) is
    stitched with the nominal cameras, and the failure is returned.
    """
    images = [to_uint8(f) for f in fisheyes]
    template = rig_template(template, config)
    failure, centres, points = None, np.zeros((3, 3)), np.zeros((0, 3))
    try:
        calibration = calibrate_cameras(images, template, names=[f"fisheye_{k}.png" for k in range(3)], seed=seed)
        cameras = calibration.project.cameras()
        cameras = cameras._replace(**{f: np.asarray(getattr(cameras, f)) for f in cameras._fields})
        if calibration.result.points is not None:  # the bundle adjustment's (a rotation-only result has none)
            centres, points = calibration.result.centres, calibration.result.points
    except rigjax.CalibrationError as error:
        cameras, failure = nominal_cameras(config.fisheye_size, config.hfov), str(error)
    if reference is not None:
        turn = rig_turn(cameras, reference)
        finite = np.all(np.isfinite(points), axis=1, keepdims=True)
        points = np.where(finite, np.where(finite, points, 0.0) @ turn.T, np.inf)
        cameras, centres = _turned(cameras, turn), centres @ turn.T
    pano, covered = stitch_with_cameras(fisheyes, cameras, config)
    return CalibratedStitch(pano, covered, cameras, failure, centres, points)


def inverse_depth_map(points: np.ndarray, width: int, height: int, sigma_deg: float = 3.0) -> torch.Tensor:
    """``(H, W)`` inverse depths (1 / m) of a panorama from scene points ``(n, 3)`` (metres, about
    the panorama's centre; ``inf`` rows at infinity): each pixel's the Gaussian-weighted mean
    (``sigma_deg`` in angle) of the points' inverse depths, shrunk towards 0 (infinity) where the
    points' weights sum to less than about one, so that directions far from every point are taken
    to be far away, as a rotation-only stitch takes every direction. Computed on a grid 4 times
    coarser and interpolated: the points are sparse anyway."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    points = points[np.all(np.isfinite(points), axis=1)]  # those at infinity: inverse depth 0, no weight
    distance = np.linalg.norm(points, axis=1)
    inverse = torch.as_tensor(1.0 / distance, dtype=torch.float32)
    directions = torch.as_tensor(points / distance[:, None], dtype=torch.float32)
    rays = torch.as_tensor(pano_rays(max(width // 4, 1), max(height // 4, 1)), dtype=torch.float32)
    weights = torch.exp((rays @ directions.T - 1.0) / math.radians(sigma_deg) ** 2)  # exp(-angle^2 / 2 sigma^2)
    coarse = (weights * inverse).sum(-1) / (weights.sum(-1) + 0.5)
    return F.interpolate(coarse[None, None], size=(height, width), mode="bilinear", align_corners=False)[0, 0]


def depth_stitch(
    fisheyes: torch.Tensor, cameras: Camera, centres: np.ndarray, inverse_depth: torch.Tensor, config: SynthConfig
) -> torch.Tensor:
    """``(3, H, W)``: each fisheye sampled along its own sight line to each panorama pixel's scene
    point at ``inverse_depth`` ``(H, W)`` (1 / m; 0: infinity) from ``centres`` ``(3, 3)``
    through ``cameras``, feather-blended over the inputs whose image circle holds it. With every
    inverse depth 0 it is :func:`stitch_with_cameras`. Occlusion is not known: an input that sees
    something nearer along that line still counts."""
    q = inverse_depth.to(torch.float64)
    depth = torch.where(q > 0.0, 1.0 / q.clamp_min(1e-12), torch.inf)
    _, grid, inside, theta = grids_at_depth(cameras, torch.as_tensor(np.asarray(centres, np.float64)), depth, config)
    return _feathered(fisheyes, grid, inside, theta, config)


def calibrated_depth_stitch(fisheyes: torch.Tensor, calibrated: CalibratedStitch, config: SynthConfig) -> torch.Tensor:
    """:func:`depth_stitch` with a calibration's cameras, centres and the inverse depths of its
    control points (:func:`inverse_depth_map`): the calibrated rig's parallax corrected where its
    matches lie, the seams. Without points (a failed or rotation-only calibration) it is the
    calibrated stitch itself."""
    q = inverse_depth_map(calibrated.points, config.pano_width, config.pano_height)
    return depth_stitch(fisheyes, calibrated.cameras, calibrated.centres, q, config)


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
