"""The synthetic data's configuration: the ``data:`` section of ``configs/stitch/*.yaml``::

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

from dataclasses import dataclass
from typing import Any

from rigjax.config import typed_from_dict
from rigjax.errors import ConfigError


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
