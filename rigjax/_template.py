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
      overlaps: [[0, 1], [1, 2], ...]              # pairs to match; omit for every pair
      panorama_width: 4096
    features: {detector: sift, max_features: 4000, ratio: 0.8, mutual: true, max_points_per_pair: 400,
               seam_band_deg: null}   # degrees: match each pair in a band around its seam (needs orientations)
    ransac: {threshold_deg: 2.0, iterations: 1000, min_inliers: 15}
    levy: {candidates: 256, generations: 3, scale_deg: 10.0, beta: 1.5, starts: 8}   # or levy: false
    optimise: {schedule: YPR,VBYPR, ...}   # as configs/rig/default.yaml, prune included

Every section but ``rig`` is optional. Unknown keys and bad values are errors naming the file and key.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from os import PathLike
from typing import Any

from ._config import ConfigError, OptimiseConfig, _section, config_from_dict, read_yaml
from ._errors import RigjaxError
from ._features import DETECTORS
from ._levy import LevyConfig
from ._projection import SUPPORTED_PROJECTIONS


@dataclass(frozen=True)
class RigTemplate:
    cameras: int
    projection: int = 3
    hfov: float = 120.0
    b: float = 0.0
    shared_lens: bool = False
    side_by_side: bool = False
    orientations: tuple[tuple[float, float, float], ...] | None = None
    overlaps: tuple[tuple[int, int], ...] | None = None
    panorama_width: int = 4096

    def __post_init__(self) -> None:
        n = self.cameras
        if n < 1:
            raise RigjaxError(f"rig.cameras: expected the number of cameras (>= 1), got {n!r}")
        if self.projection not in SUPPORTED_PROJECTIONS:
            raise RigjaxError(f"rig.projection: expected one of {SUPPORTED_PROJECTIONS}, got {self.projection!r}")
        if not 0.0 < self.hfov <= 360.0:
            raise RigjaxError(f"rig.hfov: expected degrees in (0, 360], got {self.hfov!r}")
        if self.panorama_width < 8:
            raise RigjaxError(f"rig.panorama_width: expected at least 8 pixels, got {self.panorama_width!r}")
        if self.side_by_side and n % 2:
            raise RigjaxError(f"rig.side_by_side: each image holds two cameras, so cameras must be even, got {n}")
        if self.orientations is not None and len(self.orientations) != n:
            raise RigjaxError(f"rig.orientations: {len(self.orientations)} orientations for {n} cameras")
        for a, b in self.overlaps or ():
            if not (0 <= a < n and 0 <= b < n and a != b):
                raise RigjaxError(f"rig.overlaps: pair [{a}, {b}] is not two different cameras of 0..{n - 1}")


@dataclass(frozen=True)
class FeatureConfig:
    detector: str = "sift"
    max_features: int = 4000
    ratio: float = 0.8
    mutual: bool = True
    max_points_per_pair: int = 400  # RANSAC inliers kept as control points (a random, seeded subset)
    seam_band_deg: float | None = None  # match in a band this wide either side of each pair's seam

    def __post_init__(self) -> None:
        if self.detector not in DETECTORS:
            raise RigjaxError(f"features.detector must be one of {', '.join(DETECTORS)}, got {self.detector!r}")
        if self.max_features < 1 or self.max_points_per_pair < 1 or not 0.0 < self.ratio <= 1.0:
            raise RigjaxError("features: max_features and max_points_per_pair must be >= 1, ratio in (0, 1]")
        if self.seam_band_deg is not None and not 0.0 < self.seam_band_deg < 90.0:
            raise RigjaxError(f"features.seam_band_deg: expected degrees in (0, 90), got {self.seam_band_deg!r}")


@dataclass(frozen=True)
class RansacConfig:
    threshold_deg: float = 2.0
    iterations: int = 1000
    min_inliers: int = 15

    def __post_init__(self) -> None:
        if not (self.threshold_deg > 0 and self.iterations >= 1 and self.min_inliers >= 2):
            raise RigjaxError("ransac: threshold_deg must be > 0, iterations >= 1, min_inliers >= 2 "
                              "(a rotation needs 2 bearings)")  # fmt: skip


@dataclass(frozen=True)
class CalibrateConfig:
    rig: RigTemplate
    features: FeatureConfig = field(default_factory=FeatureConfig)
    ransac: RansacConfig = field(default_factory=RansacConfig)
    levy: LevyConfig | None = field(default_factory=LevyConfig)  # None: plain LM from the start
    optimise: OptimiseConfig = field(default_factory=OptimiseConfig)

    def __post_init__(self) -> None:
        if self.features.seam_band_deg is not None and self.rig.orientations is None:
            raise RigjaxError("features.seam_band_deg: the seam bands are placed with the nominal geometry, "
                              "so rig.orientations must be given")  # fmt: skip


def _rows_of_numbers(value: Any, where: str, length: int, kind: type) -> tuple[tuple, ...]:
    if not isinstance(value, list) or not value:
        raise ConfigError(f"{where}: expected a non-empty list of [{', '.join(['x'] * length)}] lists, got {value!r}")
    out = []
    for i, row in enumerate(value):
        ok = isinstance(row, list) and len(row) == length
        ok = ok and all(isinstance(v, (int, float) if kind is float else int) and not isinstance(v, bool) for v in row)
        if not ok:
            raise ConfigError(f"{where}[{i}]: expected a list of {length} {kind.__name__}s, got {row!r}")
        out.append(tuple(kind(v) for v in row))
    return tuple(out)


def template_from_dict(data: Any, source: str = "<template>") -> CalibrateConfig:
    """Validate a parsed YAML template into a :class:`CalibrateConfig`."""
    top = _section(data, source, {"rig": dict, "features": dict, "ransac": dict, "levy": (dict, bool),
                                  "optimise": dict})  # fmt: skip
    if "rig" not in top:
        raise ConfigError(f"{source}: the template has no 'rig' section (camera count, lens, orientations)")
    rig = _section(top["rig"], f"{source}: rig", {"cameras": int, "projection": int, "hfov": float, "b": float,
                                                  "shared_lens": bool, "side_by_side": bool, "orientations": list, "overlaps": list,
                                                  "panorama_width": int})  # fmt: skip
    where = f"{source}: rig"
    if "orientations" in rig:
        rig["orientations"] = _rows_of_numbers(rig["orientations"], f"{where}.orientations", 3, float)
    if "overlaps" in rig:
        rig["overlaps"] = _rows_of_numbers(rig["overlaps"], f"{where}.overlaps", 2, int)
    if "cameras" not in rig:
        raise ConfigError(f"{where}: no 'cameras' (the number of cameras)")
    features = _section(top.get("features"), f"{source}: features",
                        {"detector": str, "max_features": int, "ratio": float, "mutual": bool,
                         "max_points_per_pair": int, "seam_band_deg": (float, type(None))})  # fmt: skip
    ransac = _section(top.get("ransac"), f"{source}: ransac",
                      {"threshold_deg": float, "iterations": int, "min_inliers": int})  # fmt: skip
    levy_data = top.get("levy")
    levy = None if levy_data is False else _section(None if levy_data is True else levy_data, f"{source}: levy",
        {"candidates": int, "generations": int, "scale_deg": float, "beta": float, "starts": int,
         "cost_scale_px": float})  # fmt: skip
    try:
        return CalibrateConfig(
            rig=RigTemplate(**rig),
            features=FeatureConfig(**features),
            ransac=RansacConfig(**ransac),
            levy=None if levy is None else LevyConfig(**levy),
            optimise=config_from_dict(top.get("optimise") or {}, f"{source}: optimise"),
        )
    except ConfigError:
        raise
    except RigjaxError as exc:
        raise ConfigError(f"{source}: {exc}") from None


def load_template(path: str | PathLike[str]) -> CalibrateConfig:
    path = os.fspath(path)
    return template_from_dict(read_yaml(path, "template"), path)
