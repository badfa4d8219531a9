"""A rig prepared once, its frames stitched one after another.

:meth:`Stitcher.prepare` does what depends on the rig alone: each camera's sight table through
rigjax's lens model (:mod:`learnstitch.fullres.sight`; the image circles the rig measured from its
first images), the output's size and the depth source. Calling the stitcher with a frame's images
(one ``(h_i, w_i, 3)`` uint8 RGB array per camera, in the rig's order) runs the per-frame work:
the working depth, the colour correction, the depth refined by the full-resolution inputs'
agreement (:mod:`learnstitch.fullres.refine`) and the full-resolution render
(:mod:`learnstitch.fullres.render`). A video stitches every frame through one prepared stitcher;
a still is one call.

Where the working depth comes from is a *depth source*, called once per frame with the frame's
inputs (:class:`Frame`) and the render settings:

- :class:`PlaneSweep`: the inputs swept over inverse-depth planes at ``render.working_width``
  (:func:`~learnstitch.fullres.depth.sweep_depth`); no parallax to find when every centre is at the
  origin, so the depth is zero (a rotation-only stitch);
- :class:`NetworkDepth`: a rig-aware network's depth and blend weights at its own canvas, through
  the rig's centres, passed in every call (:func:`~learnstitch.fullres.depth.network_depth`);
- :class:`GivenDepth`: a depth the caller has: at the working size, or at the output's with which
  inputs see each pixel's point (the depth oracle).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple, Protocol

import cv2
import numpy as np
import torch

from rigjax.errors import ConfigError

from ..network.photometry import fit_photometry
from .config import RenderConfig
from .depth import Depth, network_depth, sweep_depth, upsample_canvas, working_images, working_views
from .refine import level_widths, refine_depth
from .render import Photometry, render_frame
from .rig import Rig
from .sight import SightTables, sight_tables


class Stitched(NamedTuple):
    """A full-resolution panorama and what made it."""

    pano: np.ndarray  # (H, W, 3) uint8 RGB
    covered: np.ndarray  # (H, W) bool: some input sees the pixel (at its depth or at infinity)
    inverse_depth: torch.Tensor  # (h, w) the working inverse depth, 1 / metres (refined: the finest level's canvas)
    exposure: torch.Tensor  # (N,) each input's fitted log exposure (zeros without photometry)
    vignetting: torch.Tensor  # (2,) the lens's fitted vignetting coefficients b, c of log V(r) = b r^2 + c r^4
    seconds: dict[str, float]  # wall time of each stage of this frame
    # (H, W) the inverse depth each output pixel was rendered at, 1 / metres (0: at infinity), where
    # the stitcher was asked to keep it (Stitcher.keep_depth)
    rendered_depth: torch.Tensor | None = None
    # (H, W) in [0, 1]: the refinement's confidence in that depth (learnstitch.fullres.refine), brought
    # up bilinearly, where it was kept and the depth refined
    confidence: torch.Tensor | None = None


class Frame:
    """One frame's inputs ``(3, h_i, w_i)`` float32 in [0, 1] and the rig's sight ``tables``; its
    pyramid levels for a working width (:func:`~learnstitch.fullres.depth.working_images`) are
    each made once, whoever asks, from the nearest finer level made. ``pixels``: the same inputs as given, ``(h_i, w_i, 3)``
    uint8 RGB, where the caller has them."""

    def __init__(self, images: list[torch.Tensor], tables: SightTables, pixels: Sequence[np.ndarray] | None = None):
        self.images, self.tables, self.pixels = images, tables, pixels
        self._pyramid: list[dict[int, torch.Tensor]] = [{} for _ in images]  # each input's levels made

    def working(self, width: int) -> list[tuple[torch.Tensor, float]]:
        """The inputs at the pyramid levels of a working canvas ``width`` pixels around."""
        return working_images(self.images, self.tables, width, self._pyramid)


class DepthSource(Protocol):
    """Where a frame's depth comes from (module docstring); ``label`` names it in reports."""

    label: str

    def __call__(self, frame: Frame, config: RenderConfig) -> Depth: ...


@dataclass(frozen=True)
class PlaneSweep:
    """The plane sweep of the inputs at ``render.working_width`` (zero with every centre at the origin)."""

    label: str = "the plane sweep"

    def __call__(self, frame: Frame, config: RenderConfig) -> Depth:
        zeros = torch.zeros(config.working_width // 2, config.working_width)
        if not bool(frame.tables.centres.any()):  # every camera at the centre: nothing for a depth to do
            return Depth(zeros)
        inputs, masks, _ = working_views(frame.working(config.working_width), frame.tables, zeros)
        return Depth(sweep_depth(inputs, masks, frame.tables.centres, config))


@dataclass(frozen=True)
class NetworkDepth:
    """A rig-aware network's depth and blend weights on its own ``canvas`` (its config's
    ``data.pano_width``), the rig's centres given in every call."""

    model: torch.nn.Module
    canvas: int
    label: str = "a rig-aware network"

    def __call__(self, frame: Frame, config: RenderConfig) -> Depth:
        return network_depth(self.model, frame.working(self.canvas), frame.tables, self.canvas)


@dataclass(frozen=True)
class GivenDepth:
    """A depth the caller has: ``working`` ``(h, w)`` (2:1, 1 / metres) and, optionally, each input's
    share of a blend there ``shares`` ``(N, h, w)``; or ``full`` ``(H, W)`` at the output's size and,
    optionally, ``visibility`` ``(N, H, W)``: which inputs see each pixel's point (the depth oracle;
    without it, the renderer's occlusion test says, :mod:`learnstitch.fullres.occlusion`)."""

    working: torch.Tensor | None = None
    full: torch.Tensor | None = None
    visibility: torch.Tensor | None = None
    shares: torch.Tensor | None = None
    label: str = "a given depth"

    def __post_init__(self) -> None:
        if (self.working is None) == (self.full is None):
            raise ConfigError(
                "GivenDepth takes a working-size depth or a full-size one (with its visibility), one of them"
            )
        if self.working is not None and self.visibility is not None:
            raise ConfigError("GivenDepth: visibility goes with a full-size depth (full=...), not a working-size one")
        if self.full is not None and self.shares is not None:
            raise ConfigError("GivenDepth: shares go with a working-size depth, not a full-size one (give visibility)")

    def __call__(self, frame: Frame, config: RenderConfig) -> Depth:
        if self.full is None:
            return Depth(self.working, shares=self.shares)
        return Depth(reduce_depth(self.full, config.working_width), full=self.full, visibility=self.visibility)


def reduce_depth(inverse_depth: torch.Tensor, width: int) -> torch.Tensor:
    """A full-size inverse depth at a working ``width``: each working pixel's nearest surface (the
    largest inverse depth of the output pixels it covers)."""
    factor = max(1, inverse_depth.shape[-1] // width)
    reduced = torch.nn.functional.max_pool2d(inverse_depth[None, None].float(), factor)[0, 0]
    return torch.nn.functional.interpolate(reduced[None, None], size=(width // 2, width), mode="nearest")[0, 0]


def float_images(images: Sequence[np.ndarray], undo: Sequence | None = None) -> list[torch.Tensor]:
    """``(h, w, 3)`` uint8 RGB images as ``(3, h, w)`` float32 in [0, 1], channels-last in memory
    (a view of ``(h, w, 3)``: reshape, not ``view``); with ``undo``
    (:attr:`~learnstitch.fullres.rig.Rig.undo`), each image's stated photometry undone, in the same
    OpenCV multiply that makes the floats; channels-last, as grid_sample reads them fastest."""
    out = []
    for k, image in enumerate(images):
        image, factor = np.ascontiguousarray(image), undo[k] if undo else None
        if factor is None:
            pixels = image.astype(np.float32)
            np.multiply(pixels, np.float32(1.0 / 255.0), out=pixels)
        else:
            pixels = cv2.multiply(image, factor, scale=1.0 / 255.0, dtype=cv2.CV_32F)
        out.append(torch.from_numpy(pixels).permute(2, 0, 1))
    return out


class Stitcher:
    """A rig prepared for stitching (:meth:`prepare`); ``stitcher(images)`` stitches one frame."""

    def __init__(self, rig: Rig, tables: SightTables, width: int, config: RenderConfig, depth: DepthSource):
        self.rig, self.tables, self.width, self.config, self.depth = rig, tables, width, config, depth
        self.seconds: dict[str, float] = {}  # the preparation's wall time
        # What a frame's fitted colour correction becomes before it is applied (a video smooths it
        # over time: learnstitch.video.temporal); None: as fitted.
        self.photometry_filter: Callable[[Photometry], Photometry] | None = None
        self.keep_depth = False  # whether each panorama comes with the depth it was rendered at (Stitched)
        # What a frame's refined depth becomes before it is rendered (a video filters it over time:
        # learnstitch.video.temporal); None: as refined.
        self.depth_filter: Callable[[Depth], Depth] | None = None

    @classmethod
    def prepare(
        cls,
        rig: Rig,
        width: int | None = None,
        config: RenderConfig | None = None,
        depth: DepthSource | None = None,
        *,
        circle_deg: np.ndarray | None = None,
    ) -> Stitcher:
        """A stitcher of ``rig``'s frames into panoramas ``width`` pixels wide (default: its
        project's ``p`` line), 2:1, with the ``render:`` settings ``config`` and the working depth
        from ``depth`` (default :class:`PlaneSweep`). ``circle_deg`` ``(N,)``: the cameras' image
        circles (default: the rig's, measured from its images by
        :func:`~learnstitch.fullres.rig.load_rig`, at most a circular fisheye's hfov)."""
        config = config or RenderConfig()
        width = int(width or rig.width)
        if width < 16 or width % 2:
            raise ConfigError(f"the panorama's width must be even and >= 16, got {width}")
        started = time.perf_counter()
        table_width = max(8, 2 * round(config.table_scale * width / 2))
        circle_px = None if circle_deg is not None else rig.circle_px
        tables = sight_tables(rig.cameras, rig.centres, table_width, circle_deg, circle_px, rig.crops)
        stitcher = cls(rig, tables, width, config, depth or PlaneSweep())
        stitcher.seconds["tables"] = time.perf_counter() - started
        return stitcher

    def __call__(
        self,
        images: Sequence[np.ndarray] | None = None,
        *,
        depth: DepthSource | None = None,
        photometry: Photometry | None = None,
    ) -> Stitched:
        """The panorama of one frame: ``images``, one ``(h_i, w_i, 3)`` uint8 RGB array per camera
        in the rig's order, each its camera's size (default: the rig's own images); ``depth``
        replaces the prepared depth source for this frame, ``photometry`` the fitted colour
        correction (a video holds a key frame's between key frames)."""
        images = self.rig.images if images is None else list(images)
        seconds: dict[str, float] = {}
        return self.render(*self.measure(images, depth=depth, photometry=photometry, seconds=seconds), seconds=seconds)

    def render(
        self, frame: Frame, found: Depth, photometry: Photometry | None, *, seconds: dict[str, float] | None = None
    ) -> Stitched:
        """The panorama of a frame :meth:`measure` measured (its three results, in order); the
        render's wall time goes into ``seconds``. Reads nothing a later :meth:`measure` changes: a
        video renders one frame while it measures the next."""
        seconds = {} if seconds is None else seconds
        clock = time.perf_counter()
        used = torch.empty(self.width // 2, self.width) if self.keep_depth else None
        pano, covered = render_frame(frame.images, self.tables, self.width, self.config, found, photometry, used)
        seconds["render"] = time.perf_counter() - clock
        fitted = photometry or Photometry.none(self.tables.count)
        confidence = None
        if self.keep_depth and found.confidence is not None:
            confidence = upsample_canvas(found.confidence, self.width)
        return Stitched(pano, covered, found.working, fitted.exposure, fitted.vignetting, seconds, used, confidence)

    def measure(
        self,
        images: Sequence[np.ndarray],
        *,
        depth: DepthSource | None = None,
        photometry: Photometry | None = None,
        seconds: dict[str, float] | None = None,
    ) -> tuple[Frame, Depth, Photometry | None]:
        """What a frame's render needs, without the render: its :class:`Frame`, its working depth and
        its colour correction (``photometry`` where given, else fitted as the config says and passed
        through :attr:`photometry_filter`; None: none). The wall time of each stage goes into ``seconds``."""
        self.check(images)
        seconds = {} if seconds is None else seconds
        clock = time.perf_counter()

        def lap(stage: str) -> None:
            nonlocal clock
            now = time.perf_counter()
            seconds[stage] = now - clock
            clock = now

        frame = Frame(float_images(images, self.rig.undo), self.tables, images)
        found = (depth or self.depth)(frame, self.config)
        if self.config.blend != "network":
            found = found._replace(shares=None)
        lap("depth")
        if photometry is None and self.config.photometry == "fitted":
            colours, alpha, radius = working_views(frame.working(found.working.shape[-1]), self.tables, found.working)
            exposure, vignetting = fit_photometry(colours[None], alpha[None], radius[None])  # colours: zero unseen
            photometry = Photometry(exposure[0], vignetting[0])
            if self.photometry_filter is not None:
                photometry = self.photometry_filter(photometry)
            lap("photometry")
        # A depth with a confidence is refined already (a video's, carried between key frames).
        if self.refines(depth) and found.full is None and found.confidence is None:
            found = self.refine(frame, found, photometry)
            if self.depth_filter is not None:
                found = self.depth_filter(found)
            lap("refine")
        return frame, found, photometry

    def refines(self, depth: DepthSource | None = None) -> bool:
        """Whether a frame's working depth from ``depth`` (default the prepared source) is refined
        (:meth:`refine`): ``render.refine_levels`` above 0, cameras apart, and not a depth the
        caller gives (:class:`GivenDepth`: stitched through as given)."""
        given = isinstance(depth or self.depth, GivenDepth)
        return self.config.refine_levels > 0 and bool(self.tables.centres.any()) and not given

    def refine(self, frame: Frame, found: Depth, photometry: Photometry | None) -> Depth:
        """``found``'s working depth refined at finer sizes by the inputs' agreement
        (:mod:`learnstitch.fullres.refine`): the finest level's depth becomes the working depth the
        renderer brings up, with its confidence (a network's blend shares brought up to it)."""
        widths = level_widths(self.config, self.width, found.working.shape[-1])
        refined = refine_depth(frame.working, self.tables, found.working, photometry, self.config, widths)
        shares = None if found.shares is None else upsample_canvas(found.shares, widths[-1])
        return found._replace(working=refined.inverse_depth, shares=shares, confidence=refined.confidence)

    def still(self, images: Sequence[np.ndarray] | None = None) -> Stitched:
        """One frame (the call above), the preparation's time in its ``seconds`` too: a still's."""
        stitched = self(images)
        return stitched._replace(seconds={**self.seconds, **stitched.seconds})

    def check(self, images: Sequence[np.ndarray]) -> None:
        """Raise :class:`ConfigError` unless ``images`` are one uint8 RGB image per camera, each its size."""
        cameras, count = self.rig.cameras, self.tables.count
        if len(images) != count:
            raise ConfigError(f"the rig has {count} cameras, {len(images)} images were given")
        for k, image in enumerate(images):
            wanted = (int(cameras.height[k]), int(cameras.width[k]), 3)
            if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.shape != wanted:
                got = f"{image.dtype} {image.shape}" if isinstance(image, np.ndarray) else type(image).__name__
                name = self.rig.names[k] if k < len(self.rig.names) else f"image {k}"
                raise ConfigError(f"{name}: expected a {wanted[1]} x {wanted[0]} uint8 RGB image, got {got}")


def stitch_rig(rig: Rig, *args, **kwargs) -> Stitched:
    """The panorama of ``rig``'s own images: :meth:`Stitcher.prepare` (the arguments are its) and
    one call, the preparation's time in ``seconds`` too."""
    return Stitcher.prepare(rig, *args, **kwargs).still()
