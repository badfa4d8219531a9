"""Rig templates for ``rigjax calibrate``: what a rig nominally is, and how to calibrate it.

A template is a YAML file (``configs/rig/ring6.yaml``, ``configs/rig/cube6.yaml``) with sections::

    rig:                       # required
      cameras: 6
      projection: 3            # lens type: 3 full-frame fisheye, 2 circular fisheye, ...
      hfov: 120.0              # nominal, degrees
      b: 0.0                   # nominal K2 (a and c are 0)
      shared_lens: false       # true: one lens for all cameras (hfov and a, b, c linked)
      orientations: [[0, 0, 0], [60, 0, 0], ...]   # nominal yaw, pitch, roll; omit for closed form
      overlaps: [[0, 1], [1, 2], ...]              # pairs to match; omit for every pair
      panorama_width: 4096
    features: {detector: sift, max_features: 4000, ratio: 0.8, mutual: true, max_points_per_pair: 400}
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
    orientations: tuple[tuple[float, float, float], ...] | None = None
    overlaps: tuple[tuple[int, int], ...] | None = None
    panorama_width: int = 4096


@dataclass(frozen=True)
class FeatureConfig:
    detector: str = "sift"
    max_features: int = 4000
    ratio: float = 0.8
    mutual: bool = True
    max_points_per_pair: int = 400  # RANSAC inliers kept as control points (a random, seeded subset)


@dataclass(frozen=True)
class RansacConfig:
    threshold_deg: float = 2.0
    iterations: int = 1000
    min_inliers: int = 15


@dataclass(frozen=True)
class CalibrateConfig:
    rig: RigTemplate
    features: FeatureConfig = field(default_factory=FeatureConfig)
    ransac: RansacConfig = field(default_factory=RansacConfig)
    levy: LevyConfig | None = field(default_factory=LevyConfig)  # None: plain LM from the start
    optimise: OptimiseConfig = field(default_factory=OptimiseConfig)


def _pairs_of_numbers(value: Any, where: str, length: int, kind: type) -> tuple[tuple, ...]:
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
                                                  "shared_lens": bool, "orientations": list, "overlaps": list,
                                                  "panorama_width": int})  # fmt: skip
    where = f"{source}: rig"
    if "cameras" not in rig or rig["cameras"] < 1:
        raise ConfigError(f"{where}.cameras: expected the number of cameras (>= 1), got {rig.get('cameras')!r}")
    n = rig["cameras"]
    if rig.get("projection", 3) not in SUPPORTED_PROJECTIONS:
        raise ConfigError(f"{where}.projection: expected one of {SUPPORTED_PROJECTIONS}, got {rig['projection']!r}")
    if not 0.0 < rig.get("hfov", 120.0) <= 360.0:
        raise ConfigError(f"{where}.hfov: expected degrees in (0, 360], got {rig['hfov']!r}")
    if rig.get("panorama_width", 4096) < 8:
        raise ConfigError(f"{where}.panorama_width: expected at least 8 pixels, got {rig['panorama_width']!r}")
    if "orientations" in rig:
        rig["orientations"] = _pairs_of_numbers(rig["orientations"], f"{where}.orientations", 3, float)
        if len(rig["orientations"]) != n:
            raise ConfigError(f"{where}.orientations: {len(rig['orientations'])} orientations for {n} cameras")
    if "overlaps" in rig:
        rig["overlaps"] = _pairs_of_numbers(rig["overlaps"], f"{where}.overlaps", 2, int)
        for a, b in rig["overlaps"]:
            if not (0 <= a < n and 0 <= b < n and a != b):
                raise ConfigError(f"{where}.overlaps: pair [{a}, {b}] is not two different cameras of 0..{n - 1}")
    features = _section(top.get("features"), f"{source}: features",
                        {"detector": str, "max_features": int, "ratio": float, "mutual": bool,
                         "max_points_per_pair": int})  # fmt: skip
    if features.get("detector", "sift") not in DETECTORS:
        raise ConfigError(f"{source}: features.detector must be one of {', '.join(DETECTORS)}, "
                          f"got {features['detector']!r}")  # fmt: skip
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
