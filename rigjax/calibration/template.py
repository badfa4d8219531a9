"""Rig templates for ``rigjax calibrate``: what a rig nominally is, and how to calibrate it.

A template is a YAML file (``configs/rig/ring6.yaml``, ``configs/rig/cube6.yaml``) with sections::

    rig:                       # required
      cameras: 6
      projection: 3            # lens type: 3 full-frame fisheye, 2 circular fisheye, ...
      hfov: 120.0              # nominal, degrees
      b: 0.0                   # nominal K2 (a and c are 0)
      shared_lens: false       # true: one lens for all cameras (hfov and a, b, c linked)
      side_by_side: false      # true: each image holds two cameras, left and right half (dual fisheye)
      orientations: [[0, 0, 0], [60, 0, 0], ...]   # nominal yaw, pitch, roll; omit for closed form
      centres: [[0, 0, 0.4], ...]                  # camera centres (rig frame); with optimise.objective
                                                   # reprojection, the cameras sit apart (parallax)
      overlaps: [[0, 1], [1, 2], ...]              # pairs to match; omit for every pair
      panorama_width: 4096
      lenses: [{v: 193.7, a: -0.28, b: 0.52, c: -0.14, d: 17.6, e: 25.5, crop: [-13, 651, -19, 668]}, ...]
                               # each camera's own lens to start from (hfov, a, b, c, shifts d, e in
                               # pixels, Hugin's crop S), in place of hfov and b; needs image_size
      image_size: [1920, 1920] # the camera images' width and height the lenses' pixels are of
    features: {detector: sift, max_features: 4000, ratio: 0.8, mutual: true, max_points_per_pair: 400,
               seam_band_deg: null,   # degrees: match each pair in a band around its seam (needs orientations)
               track_step_px: null,   # band px: track a grid through the band instead of matching features
               track_bias_px: 0.3}    # px: the tracks' regional bias the standard deviations allow for
    ransac: {threshold_deg: 2.0, iterations: 1000, min_inliers: 15}
    levy: {candidates: 256, generations: 3, scale_deg: 10.0, beta: 1.5, starts: 8}   # or levy: false
    optimise: {schedule: "YPR,VBYPR", ...}   # as configs/rig/optimise.yaml, prune included
    checks: {hfov_range: [170, 210], max_hfov_sd_deg: 1.0, max_turn_sd_deg: 0.5}   # what rigjax calibrate refuses
                                                 # (rigjax.calibration.checks)
    photometry: {fit: true, white_balance: true, vignetting: true, max_vignetting_sd: 0.02, max_rms_stops: 0.5}
                                                 # exposure etc. fitted in the overlaps (rigjax.calibration.exposure)
    motion: {schedule: "YPR,VDEYPR,VABCDEYPR", priors: {v: 5, a: 0.5, b: 0.5, c: 0.5, d: 30, e: 30}}
                                                 # several frames of a turning camera: each lens from its own
                                                 # motion (rigjax.calibration.motion); default: off

Every section but ``rig`` is optional. Unknown keys and bad values are errors naming the file and key
(:mod:`rigjax.config`).
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field
from os import PathLike
from typing import Any

from ..camera.projections import SUPPORTED_PROJECTIONS
from ..config import read_yaml, typed_from_dict
from ..errors import ConfigError, RigjaxError
from ..optimiser.config import OptimiseConfig, with_prune_default
from ..pto.records import Image
from .checks import ChecksConfig
from .features import DETECTORS
from .levy import LevyConfig
from .motion import MotionConfig


@dataclass(frozen=True)
class LensStart:
    """One camera's lens to start from: Hugin's ``v``, ``a``, ``b``, ``c``, the centre's shifts
    ``d``, ``e`` (pixels), crop ``S`` (``(left, right, top, bottom)``, pixels; None: none) and
    vignetting (``Vb``, ``Vc``, ``Vd``; its centre ``Vx``, ``Vy``), of an image of the template's
    ``image_size``. ``rigjax calibrate --start rig.pto`` fills these from a
    project (:func:`rigjax.calibration.start.with_start`)."""

    v: float
    a: float = 0.0
    b: float = 0.0
    c: float = 0.0
    d: float = 0.0
    e: float = 0.0
    crop: tuple[int, int, int, int] | None = None
    vignetting: tuple[float, float, float] = (0.0, 0.0, 0.0)  # Hugin's Vb, Vc, Vd
    vignetting_centre: tuple[float, float] = (0.0, 0.0)  # Hugin's Vx, Vy: pixels from the image's centre

    def __post_init__(self) -> None:
        if not 0.0 < self.v <= 360.0:
            raise RigjaxError(f"v: expected an hfov in degrees in (0, 360], got {self.v!r}")
        if self.crop is not None:  # checked as an i line's crop
            Image(1, 1, 2, crop=self.crop)


@dataclass(frozen=True)
class RigTemplate:
    cameras: int
    projection: int = 3
    hfov: float = 120.0
    b: float = 0.0
    shared_lens: bool = False
    side_by_side: bool = False
    orientations: tuple[tuple[float, float, float], ...] | None = None
    centres: tuple[tuple[float, float, float], ...] | None = None
    overlaps: tuple[tuple[int, int], ...] | None = None
    panorama_width: int = 4096
    lenses: tuple[LensStart, ...] | None = None  # each camera's lens, in place of hfov and b
    image_size: tuple[int, int] | None = None  # (width, height) of the images lenses' pixels are of

    def __post_init__(self) -> None:
        n = self.cameras
        if n < 1:
            raise RigjaxError(f"cameras: expected the number of cameras (>= 1), got {n!r}")
        if self.projection not in SUPPORTED_PROJECTIONS:
            raise RigjaxError(f"projection: expected one of {SUPPORTED_PROJECTIONS}, got {self.projection!r}")
        if not 0.0 < self.hfov <= 360.0:
            raise RigjaxError(f"hfov: expected degrees in (0, 360], got {self.hfov!r}")
        if self.panorama_width < 8:
            raise RigjaxError(f"panorama_width: expected at least 8 pixels, got {self.panorama_width!r}")
        if self.side_by_side and n % 2:
            raise RigjaxError(f"side_by_side: each image holds two cameras, so cameras must be even, got {n}")
        if self.orientations is not None and len(self.orientations) != n:
            raise RigjaxError(f"orientations: {len(self.orientations)} orientations for {n} cameras")
        if self.centres is not None and len(self.centres) != n:
            raise RigjaxError(f"centres: {len(self.centres)} centres for {n} cameras")
        for a, b in self.overlaps or ():
            if not (0 <= a < n and 0 <= b < n and a != b):
                raise RigjaxError(f"overlaps: pair [{a}, {b}] is not two different cameras of 0..{n - 1}")
        if self.lenses is not None:
            if len(self.lenses) != n:
                raise RigjaxError(f"lenses: {len(self.lenses)} lenses for {n} cameras")
            if self.image_size is None:
                raise RigjaxError("lenses: their shifts and crops are pixels of an image: give image_size")
            distinct = {(lens.v, lens.a, lens.b, lens.c) for lens in self.lenses}
            if self.shared_lens and len(distinct) > 1:
                raise RigjaxError(
                    "shared_lens: one lens for all cameras, but lenses gives them different v, a, b, c: "
                    "set shared_lens false, or give one lens"
                )
        if self.image_size is not None and min(self.image_size) < 1:
            raise RigjaxError(f"image_size: expected [width, height] pixels, got {list(self.image_size)!r}")


@dataclass(frozen=True)
class FeatureConfig:
    detector: str = "sift"
    max_features: int = 4000
    ratio: float = 0.8
    mutual: bool = True
    max_points_per_pair: int = 400  # RANSAC inliers kept as control points per frame (a random, seeded subset)
    seam_band_deg: float | None = None  # match in a band this wide either side of each pair's seam
    # With seam_band_deg: track a grid of this step (band px) from one band into the other
    # (rigjax.calibration.seam.track_in_seam_band) instead of matching features
    track_step_px: int | None = None
    # The tracks' regional bias the standard deviations allow for (px per coordinate, each 32-pixel
    # cell of a pair's tracks off together; bundle_adjust's cluster_error_px): measured against
    # ray-cast truth on learnstitch's validation rigs (benchmarks/track_errors.py)
    track_bias_px: float = 0.3
    # With track_step_px: after the calibration, track again this many times through the bands of
    # the calibrated cameras (far content aligned, no feature seeds) and calibrate again
    retrack: int = 0

    def __post_init__(self) -> None:
        if self.detector not in DETECTORS:
            raise RigjaxError(f"detector must be one of {', '.join(DETECTORS)}, got {self.detector!r}")
        if self.max_features < 1 or self.max_points_per_pair < 1 or not 0.0 < self.ratio <= 1.0:
            raise RigjaxError("max_features and max_points_per_pair must be >= 1, ratio in (0, 1]")
        if self.seam_band_deg is not None and not 0.0 < self.seam_band_deg < 90.0:
            raise RigjaxError(f"seam_band_deg: expected degrees in (0, 90), got {self.seam_band_deg!r}")
        if self.track_step_px is not None:
            if self.seam_band_deg is None:
                raise RigjaxError("track_step_px: tracking runs in the seam bands, so seam_band_deg must be given")
            if self.track_step_px < 1:
                raise RigjaxError(f"track_step_px: expected band pixels (>= 1), got {self.track_step_px!r}")
        if self.retrack < 0 or (self.retrack and self.track_step_px is None):
            raise RigjaxError(f"retrack: expected passes (>= 0) of tracking (track_step_px), got {self.retrack!r}")
        if not (math.isfinite(self.track_bias_px) and self.track_bias_px >= 0.0):
            raise RigjaxError(
                f"track_bias_px: expected a standard deviation in pixels (>= 0), got {self.track_bias_px!r}"
            )


@dataclass(frozen=True)
class RansacConfig:
    threshold_deg: float = 2.0
    iterations: int = 1000
    min_inliers: int = 15

    def __post_init__(self) -> None:
        if not (self.threshold_deg > 0 and self.iterations >= 1 and self.min_inliers >= 2):
            raise RigjaxError(
                "threshold_deg must be > 0, iterations >= 1, min_inliers >= 2 (a rotation needs 2 bearings)"
            )


@dataclass(frozen=True)
class PhotometryConfig:
    """Exposure, white balance and vignetting fitted in the overlaps after the geometry
    (:func:`rigjax.calibration.exposure.fit_exposure`)."""

    fit: bool = False
    white_balance: bool = True
    vignetting: bool = True
    max_vignetting_sd: float = 0.02  # a lens's V(r) known worse than this is held
    # Overlaps whose samples disagree by more than this (stops, RMS) under the best gains do not show
    # the same light (parallax, an undetermined lens): everything held; None: any fit kept
    max_rms_stops: float | None = 0.5

    def __post_init__(self) -> None:
        if not (math.isfinite(self.max_vignetting_sd) and self.max_vignetting_sd > 0.0):
            raise RigjaxError(f"max_vignetting_sd: expected a standard deviation (> 0), got {self.max_vignetting_sd!r}")
        if self.max_rms_stops is not None and not (math.isfinite(self.max_rms_stops) and self.max_rms_stops > 0.0):
            raise RigjaxError(f"max_rms_stops: expected stops (> 0) or null (no limit), got {self.max_rms_stops!r}")


@dataclass(frozen=True)
class CalibrateConfig:
    rig: RigTemplate
    features: FeatureConfig = field(default_factory=FeatureConfig)
    ransac: RansacConfig = field(default_factory=RansacConfig)
    levy: LevyConfig | None = field(default_factory=LevyConfig)  # None: plain LM from the start
    optimise: OptimiseConfig = field(default_factory=OptimiseConfig)
    # Objective reprojection: warn when a camera's yaw is known worse than this (1 standard deviation)
    warn_yaw_sd_deg: float = 0.1
    checks: ChecksConfig = field(default_factory=ChecksConfig)  # what a calibration may not leave undetermined
    photometry: PhotometryConfig = field(default_factory=PhotometryConfig)
    # Several frames of a turning camera: each lens calibrated from its own motion
    # (rigjax.calibration.motion); None: the frames' matches pool into one frame's calibration
    motion: MotionConfig | None = None

    def __post_init__(self) -> None:
        if self.optimise.objective == "reprojection" and self.optimise.centres is None and self.rig.centres is None:
            raise RigjaxError("optimise.objective reprojection needs the cameras' centres: give rig.centres")
        if self.features.seam_band_deg is not None and self.rig.orientations is None:
            raise RigjaxError(
                "features.seam_band_deg: the seam bands are placed with the nominal geometry, "
                "so rig.orientations must be given"
            )


def template_from_dict(data: Any, source: str = "<template>") -> CalibrateConfig:
    """Validate a parsed YAML template into a :class:`CalibrateConfig`."""
    if isinstance(data, dict):
        sections = {f.name for f in dataclasses.fields(CalibrateConfig)}
        if "rig" not in data and set(data) <= sections:  # unknown keys are named first
            raise ConfigError(f"{source}: the template has no 'rig' section (camera count, lens, orientations)")
        if isinstance(data.get("optimise"), dict):
            data = {**data, "optimise": with_prune_default(data["optimise"])}
    return typed_from_dict(CalibrateConfig, data, source)


def load_template(path: str | PathLike[str]) -> CalibrateConfig:
    path = os.fspath(path)
    return template_from_dict(read_yaml(path, "template"), path)
