"""The ``render:`` section of ``configs/stitch/*.yaml``: how a rig is stitched at full resolution
(:mod:`learnstitch.fullres`). Every key is optional; a checkpoint's config carries its own."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from rigjax.config import typed_from_dict
from rigjax.errors import ConfigError


@dataclass(frozen=True)
class RenderConfig:
    """Full-resolution stitching: the depth at a working size, every input resampled at the output's."""

    working_width: int = 512  # the working panorama's width (2:1), where the depth is estimated
    depth_planes: int = 32  # inverse-depth planes of the working-size sweep
    max_inverse_depth: float = 2.0  # the nearest plane, 1 / metres (the farthest is at infinity)
    cost_window: int = 5  # box the sweep's matching cost is averaged over, working pixels (odd)
    # The sweep's preference for far planes where the cost tells little: added to the relative
    # cost (1 on average) from 0 at infinity to this at the nearest plane
    far_prior: float = 0.5
    # Output pixels whose four working-size neighbours' depths differ by more than this parallax
    # (working-canvas pixels: the refined depth's finest canvas where it is refined) pick one of them
    # by the full-resolution inputs' agreement; the rest interpolate. 0: every pixel interpolates
    edge_parallax_px: float = 0.25
    table_scale: float = 0.5  # the sight tables' nodes around the sphere over the output's width
    tile_pixels: int = 262144  # output pixels rendered at a time, in whole rows (bounds the memory at any width)
    photometry: str = "fitted"  # "fitted": exposures and vignetting fitted in the overlaps; "none"
    # How the inputs that see a point are blended: "feather", each by how far inside what it sees
    # the point lies; "network", that times the input's share in a network's own blend at the
    # working size, brought up bilinearly (where a network gives the depth; the sweep has none)
    blend: str = "feather"
    # Given a depth at the output's size, an input whose sight line to a pixel's point meets a nearer
    # surface of that depth first is not blended there (learnstitch.fullres.occlusion): the point's
    # inverse distance below 1 - this times the nearest's; 0: every input that sees its direction
    occlusion_tolerance: float = 0.1
    occlusion_scale: float = 0.5  # the occlusion test's buffer around each camera over the output's width
    # The working depth refined by the full-resolution inputs' agreement (learnstitch.fullres.refine)
    # on this many canvases, the finest refine_scale of the output's width, each coarser half the
    # next; 0: the working depth brought up as it is
    refine_levels: int = 3
    refine_scale: float = 0.5
    refine_max_width: int = 2048  # the finest canvas's width at most (an 8K output refines to 2048, not 4096)
    # Hypotheses each side of the depth so far at the first level, a plane spacing apart; each next
    # level one each side, half the step before
    refine_steps: int = 2
    refine_radius: int = 2  # the guided filter's radius that aggregates each hypothesis's cost, canvas pixels
    refine_truncation: float = 0.01  # the colour variance a pixel's cost is truncated at (colours in [0, 1])
    # The pull toward the depth a level starts from: times the squared offset in plane spacings
    refine_prior: float = 0.3
    refine_min_confidence: float = 0.05  # below this a pixel keeps the depth so far

    def __post_init__(self) -> None:
        if self.working_width < 16 or self.working_width % 2:
            raise ConfigError(f"working_width must be even and >= 16, got {self.working_width!r}")
        if self.depth_planes < 2 or not self.max_inverse_depth > 0.0:
            raise ConfigError(
                f"depth_planes must be >= 2 and max_inverse_depth > 0, got {self.depth_planes!r}, "
                f"{self.max_inverse_depth!r}"
            )
        if self.cost_window < 1 or self.cost_window % 2 == 0:
            raise ConfigError(f"cost_window must be odd and >= 1, got {self.cost_window!r}")
        if self.far_prior < 0.0 or self.edge_parallax_px < 0.0:
            raise ConfigError(
                f"far_prior and edge_parallax_px must be >= 0, got {self.far_prior!r}, {self.edge_parallax_px!r}"
            )
        if not 0.0 < self.table_scale <= 4.0 or self.tile_pixels < 1:
            raise ConfigError(
                f"table_scale must be in (0, 4] and tile_pixels >= 1, got {self.table_scale!r}, {self.tile_pixels!r}"
            )
        if self.photometry not in ("fitted", "none"):
            raise ConfigError(f"photometry must be 'fitted' or 'none', got {self.photometry!r}")
        if not 0.0 <= self.occlusion_tolerance < 1.0:
            raise ConfigError(f"occlusion_tolerance must be in [0, 1), got {self.occlusion_tolerance!r}")
        if not 0.0 < self.occlusion_scale <= 2.0:
            raise ConfigError(f"occlusion_scale must be in (0, 2], got {self.occlusion_scale!r}")
        if self.refine_levels < 0:
            raise ConfigError(f"refine_levels must be >= 0 (0: the depth not refined), got {self.refine_levels!r}")
        if not 0.0 < self.refine_scale <= 1.0:
            raise ConfigError(f"refine_scale must be in (0, 1], got {self.refine_scale!r}")
        if self.refine_max_width < 16 or self.refine_max_width % 2:
            raise ConfigError(f"refine_max_width must be even and >= 16, got {self.refine_max_width!r}")
        if self.refine_steps < 1:
            raise ConfigError(f"refine_steps must be >= 1, got {self.refine_steps!r}")
        if self.refine_radius < 0:
            raise ConfigError(f"refine_radius must be >= 0, got {self.refine_radius!r}")
        if not self.refine_truncation > 0.0:
            raise ConfigError(f"refine_truncation must be > 0, got {self.refine_truncation!r}")
        if self.refine_prior < 0.0:
            raise ConfigError(f"refine_prior must be >= 0, got {self.refine_prior!r}")
        if not 0.0 <= self.refine_min_confidence < 1.0:
            raise ConfigError(f"refine_min_confidence must be in [0, 1), got {self.refine_min_confidence!r}")
        if self.blend not in ("feather", "network"):
            raise ConfigError(f"blend must be 'feather' or 'network', got {self.blend!r}")


def render_with(config: RenderConfig, overrides: dict | None, where: str = "--render") -> RenderConfig:
    """``config`` with some keys replaced (``learnstitch stitch --render KEY=VALUE``), checked as a
    config file's ``render:`` keys are: an unknown key or a bad value is refused naming it."""
    if not overrides:
        return config
    return typed_from_dict(RenderConfig, {**dataclasses.asdict(config), **overrides}, where)
