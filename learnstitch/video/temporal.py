"""A clip's working depth and colour correction filtered over time, so that seams hold still.

Stitched frame by frame, the depth of the same surface comes out a little different in every frame
(the sweep's planes, sensor noise), and the seam over a near object jumps from frame to frame;
the fitted exposures and vignetting wander the same way. :class:`TemporalDepth` blends each frame's
depth with the previous frame's filtered depth, recursively, where the scene did not change:

    q_t = q'_t + a (R q_{t-1} - q'_t),
    a = strength exp(-(g_t - R g_{t-1})^2 / (2 s^2)) exp(-(q'_t - R q_{t-1})^2 / (2 s_q^2))

``q'_t`` the frame's own depth on the working canvas, ``g`` the canvas's grey level at infinity and
``R`` the camera's turn since the previous frame: a hand-held camera turns between frames and the
panorama turns with it, so the previous depth and grey are first carried through that turn. The
second factor lets a change of depth larger than the estimates' own jitter through at once (a
near object moving across a seam as the camera walks) instead of dragging the old depth behind it. The
turn is estimated from the frames themselves (corners of one grey canvas at infinity,
:class:`TurnCanvas`, tracked into the next, their directions aligned by a rotation, RANSAC over
pairs; :func:`frame_turn`); where no turn can be found the frame starts afresh. Between key frames (a
video's ``depth_every``) no depth is estimated: the previous frame's is carried through the turn.
Where the stitcher refines the working depth by the inputs' agreement (:mod:`learnstitch.fullres.refine`),
the refined depth is filtered the same way at its own canvas's size (:meth:`TemporalDepth.refined`),
and it is what is carried between key frames (no refinement of their own). :class:`TemporalPhotometry`
smooths the colour correction the same way (an exponential moving average of the fitted exposures and vignetting).

Convention. ``R`` is ``prev_from_cur``: the previous frame's direction of what the current frame
sees along unit ray ``d`` is ``R d`` (rigjax's axes). Canvases are equirectangular, 2:1, pixel
centres at ``+0.5`` (:func:`learnstitch.fullres.depth.pano_rays`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from ..fullres.config import RenderConfig
from ..fullres.depth import Depth, pano_rays, pixel_rays, pyramid_level
from ..fullres.render import Photometry
from ..fullres.sight import SightTables, views
from ..fullres.stitcher import DepthSource, Frame

# The filter's weight of the carried depth where the colour and the depth agree, the grey-level
# difference (0-1) and the inverse depth difference (1 / metres) at which it falls to exp(-1/2) of
# that. The depth's is absolute, about one plane of the default sweep (32 planes up to 2 / m) and
# of the shipped network's: a sweep of coarser planes has its jumps of a plane let through.
STRENGTH, COLOUR_SIGMA, DEPTH_SIGMA = 0.8, 0.04, 0.06
# Matches a turn needs (inliers of the RANSAC) and their tolerance, in working pixels.
_MIN_INLIERS, _INLIER_PX, _RANSAC_TRIES = 12, 1.5, 200
# The corners tracked from the previous canvas: at most this many, of at least this share of the
# strongest's corner response, this far apart (pixels); tracked in windows of this many pixels
# over this many pyramid levels above the canvas (a reach of about 60 pixels, 40 degrees at 512
# around), and kept where tracking back returns within this many pixels.
_CORNERS, _CORNER_QUALITY, _CORNER_SPACING_PX, _CORNER_BLOCK = 600, 0.01, 6, 5
_TRACK_WINDOW, _TRACK_LEVELS, _RETURN_PX = 15, 3, 0.5
# The canvas the turn between frames is found on, at least (pixels around).
TURN_WIDTH = 512


class TurnCanvas:
    """A frame's grey level on an equirectangular canvas ``width`` around at infinity, what the turn
    between frames is found on: each camera's grey image box-filtered to its pyramid level for the
    canvas (:func:`learnstitch.fullres.depth.pyramid_level`) and remapped through maps made once
    per rig; the cameras that see a pixel blended by their feather weights (falling to 0 at the edge
    of what each sees, :func:`learnstitch.fullres.sight.views`), 0 where none does. Feathered, two
    cameras' different exposures make no step at the edge of an overlap: such a step, and the edge
    of what no camera sees, stay where they are in the canvas as the camera turns, and a corner
    tracked there would pull the turn found toward none. :attr:`mask` keeps corners clear of the
    unseen edge."""

    def __init__(self, tables: SightTables, width: int = TURN_WIDTH):
        height = width // 2
        self.levels = pyramid_level(tables, width)
        scales = torch.tensor([2.0**level for level in self.levels])
        seen = views(tables, pano_rays(width, height).reshape(-1, 3), torch.zeros(width * height), scales)
        self.maps, self.weights = [], []
        for k, level in enumerate(self.levels):
            xy = ((seen.xy[k] + 0.5) / 2.0**level - 0.5).numpy().reshape(height, width, 2)
            self.maps.append(cv2.convertMaps(xy[..., 0], xy[..., 1], cv2.CV_16SC2))
            self.weights.append(seen.feather[k].numpy().reshape(height, width).astype(np.float32))
        total = np.sum(self.weights, axis=0)
        self.seen = total > 0
        self.weights = [w / np.maximum(total, 1e-12) for w in self.weights]
        # Where corners are tracked from: seen, and a tracking window's half, a corner's block's half
        # and a pixel clear of what is not (uint8, as OpenCV takes masks).
        clear = 2 * (_TRACK_WINDOW // 2 + _CORNER_BLOCK // 2 + 1) + 1
        self.mask = cv2.erode(self.seen.astype(np.uint8), np.ones((clear, clear), np.uint8))

    def __call__(self, pixels: Sequence[np.ndarray]) -> np.ndarray:
        """``(h, w)`` uint8 grey canvas of a frame's ``(h_i, w_i, 3)`` uint8 RGB inputs."""
        out = np.zeros(self.seen.shape, np.float32)
        for image, level, maps, weight in zip(pixels, self.levels, self.maps, self.weights):
            grey = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
            if level:
                grey = cv2.resize(grey, (grey.shape[1] >> level, grey.shape[0] >> level), interpolation=cv2.INTER_AREA)
            out += weight * cv2.remap(grey, *maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def _kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation ``R`` minimising ``sum |R b_i - a_i|^2`` (``a``, ``b`` ``(..., M, 3)``; one per
    leading index)."""
    u, _, vt = np.linalg.svd(np.swapaxes(a, -1, -2) @ b)
    u[..., :, 2] *= np.sign(np.linalg.det(u @ vt))[..., None]
    return u @ vt


def frame_turn(
    previous: np.ndarray, current: np.ndarray, seed: int = 0, mask: np.ndarray | None = None
) -> np.ndarray | None:
    """``prev_from_cur`` ``(3, 3)`` between two grey canvases ``(h, w)`` uint8 (module docstring),
    or None where too few points agree on one. The previous canvas's corners (where ``mask``
    ``(h, w)`` uint8 is non-zero, if given: :attr:`TurnCanvas.mask`) are tracked into the
    current one (pyramidal Lucas-Kanade, sub-pixel) and kept where tracking them back returns them
    to within ``_RETURN_PX``; the current canvas is first scaled to the previous one's mean grey, so
    that a step of exposure does not read as motion."""
    width = current.shape[1]
    corners = cv2.goodFeaturesToTrack(
        previous, _CORNERS, _CORNER_QUALITY, _CORNER_SPACING_PX, mask=mask, blockSize=_CORNER_BLOCK
    )
    if corners is None or len(corners) < _MIN_INLIERS:
        return None
    mean = float(current.mean())
    if mean > 0:
        current = cv2.convertScaleAbs(current, alpha=float(previous.mean()) / mean)
    lk = {"winSize": (_TRACK_WINDOW, _TRACK_WINDOW), "maxLevel": _TRACK_LEVELS}
    tracked, found, _ = cv2.calcOpticalFlowPyrLK(previous, current, corners, None, **lk)
    back, returned, _ = cv2.calcOpticalFlowPyrLK(current, previous, tracked, None, **lk)
    kept = (found[:, 0] == 1) & (returned[:, 0] == 1) & (np.linalg.norm(back - corners, axis=-1)[:, 0] < _RETURN_PX)
    if kept.sum() < _MIN_INLIERS:
        return None
    p, c = corners[kept, 0].astype(np.float64), tracked[kept, 0].astype(np.float64)
    a, b = pixel_rays(width, p[:, 0], p[:, 1]), pixel_rays(width, c[:, 0], c[:, 1])
    tolerance = 1.0 - math.cos(_INLIER_PX * 2.0 * math.pi / width)  # of 1 - cos(angle between directions)
    # RANSAC over pairs, every try's rotation (Kabsch) at once; the first of the most inliers kept.
    rng = np.random.default_rng(seed)
    picks = np.stack([rng.choice(len(a), 2, replace=False) for _ in range(_RANSAC_TRIES)])
    rotations = _kabsch(a[picks], b[picks])  # (tries, 3, 3)
    inliers = 1.0 - np.einsum("mj,tij,mi->tm", b, rotations, a) < tolerance  # (tries, M)
    best = inliers[inliers.sum(axis=1).argmax()]
    if best.sum() < _MIN_INLIERS:
        return None
    for _ in range(2):  # refit on the inliers, then once more on the refit's
        rotation = _kabsch(a[best], b[best])
        best = 1.0 - np.einsum("mi,mi->m", b @ rotation.T, a) < tolerance
    return rotation if best.sum() >= _MIN_INLIERS else None


def carry(maps: torch.Tensor, prev_from_cur: np.ndarray) -> torch.Tensor:
    """Canvases ``(C, h, w)`` of the previous frame resampled (bilinear, wrapping in longitude)
    at the current frame's pixels through the turn ``prev_from_cur``."""
    channels, height, width = maps.shape
    rays = pano_rays(width, height).reshape(-1, 3).double() @ torch.from_numpy(prev_from_cur).T
    lon = torch.atan2(rays[:, 0], rays[:, 2])
    lat = torch.atan2(rays[:, 1], torch.hypot(rays[:, 0], rays[:, 2]))
    x = (lon + math.pi) / (2.0 * math.pi) * width - 0.5  # pixel coordinates of the previous canvas
    y = (lat + 0.5 * math.pi) / math.pi * height - 0.5
    padded = torch.cat([maps[..., -1:], maps, maps[..., :1]], dim=-1)  # one column of wrap each side
    grid = torch.stack([(x + 1.5) / (width + 2) * 2.0 - 1.0, (y + 0.5) / height * 2.0 - 1.0], -1).float()
    out = F.grid_sample(
        padded[None].float(), grid.reshape(1, height, width, 2), align_corners=False, padding_mode="border"
    )
    return out[0]


class TemporalDepth:
    """A depth source (:class:`learnstitch.fullres.stitcher.DepthSource`) that filters ``inner``'s
    depth over consecutive frames of a rig of sight ``tables`` (module docstring). Set
    :attr:`estimate` False for a frame between key frames: its depth is then the previous frame's
    carried through the turn, with no estimate of its own (where no turn is found, it estimates).
    :meth:`reset` before a frame that does not follow the previous one."""

    def __init__(
        self,
        inner: DepthSource,
        tables: SightTables,
        strength: float = STRENGTH,
        colour_sigma: float = COLOUR_SIGMA,
        depth_sigma: float = DEPTH_SIGMA,
    ):
        self.inner, self.strength, self.colour_sigma, self.depth_sigma = inner, strength, colour_sigma, depth_sigma
        self.label = f"{inner.label}, filtered over time"
        self.canvas = TurnCanvas(tables)
        self.estimate = True
        self.reset()

    def reset(self) -> None:
        self.turns: list[np.ndarray | None] = []  # the turn found for each frame since the reset
        self._previous: Depth | None = None  # the previous frame's filtered depth
        self._grey: np.ndarray | None = None  # its grey canvas the turn is found on
        self._working_grey: torch.Tensor | None = None  # that grey at the working size
        self._refined: Depth | None = None  # the previous frame's refined depth, filtered (:meth:`refined`)
        self._refined_grey: torch.Tensor | None = None  # its grey at the refined canvas's size

    def __call__(self, frame: Frame, config: RenderConfig) -> Depth:
        pixels = frame.pixels if frame.pixels is not None else [to_pixels(image) for image in frame.images]
        grey8 = self.canvas(pixels)
        turn = None if self._grey is None else frame_turn(self._grey, grey8, mask=self.canvas.mask)
        self.turns.append(turn)
        between = turn is not None and not self.estimate
        if between:  # between key frames: the previous depth, turned
            found = self._carried(turn)
        else:
            found = self.inner(frame, config)
        grey, seen = self._canvas_grey(grey8, found.working.shape)
        if turn is not None and self.estimate:
            found = found._replace(
                working=self._blend(found.working, grey, seen, self._previous, self._working_grey, turn)
            )
        self._previous, self._grey, self._working_grey = found, grey8, grey
        if between and self._refined is not None:  # the previous refined depth, turned: no refinement of its own
            self._refined = _turned(self._refined, turn)
            self._refined_grey, _ = self._canvas_grey(grey8, self._refined.working.shape)
            return self._refined
        return found

    def refined(self, found: Depth) -> Depth:
        """The frame's refined depth (:mod:`learnstitch.fullres.refine`; the stitcher calls this after
        refining what :meth:`__call__` gave, :attr:`learnstitch.fullres.stitcher.Stitcher.depth_filter`)
        filtered as the working depth is, at the refined canvas's size; between key frames
        :meth:`__call__` then carries it through the turn in place of the working depth."""
        grey, seen = self._canvas_grey(self._grey, found.working.shape)
        turn = self.turns[-1] if self.turns else None
        previous = self._refined
        if turn is not None and previous is not None and previous.working.shape == found.working.shape:
            found = found._replace(working=self._blend(found.working, grey, seen, previous, self._refined_grey, turn))
        self._refined, self._refined_grey = found, grey
        return found

    def _canvas_grey(self, grey8: np.ndarray, shape: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor]:
        """The turn canvas's grey ``grey8`` and where it is seen, at a canvas of ``shape``: box means
        where that is smaller, bilinear where larger (the refined depth's)."""
        both = torch.stack([torch.from_numpy(grey8).float() / 255.0, torch.from_numpy(self.canvas.seen).float()])
        if shape[-1] > both.shape[-1]:
            grey, seen = F.interpolate(both[None], size=tuple(shape), mode="bilinear", align_corners=False)[0]
        else:
            grey, seen = F.adaptive_avg_pool2d(both, tuple(shape))
        return grey, seen

    def _blend(
        self,
        depth: torch.Tensor,
        grey: torch.Tensor,
        seen: torch.Tensor,
        previous: Depth,
        previous_grey: torch.Tensor,
        turn: np.ndarray,
    ) -> torch.Tensor:
        """``depth`` blended with the ``previous`` frame's (its grey ``previous_grey``) carried through
        the ``turn``, where the two agree (the module docstring's rule)."""
        carried = carry(torch.stack([previous.working, previous_grey]), turn)
        change = ((grey - carried[1]) / self.colour_sigma) ** 2 + ((depth - carried[0]) / self.depth_sigma) ** 2
        agree = torch.exp(-0.5 * change) * (seen > 0.999)
        return depth + self.strength * agree * (carried[0] - depth)

    def _carried(self, turn: np.ndarray) -> Depth:
        return _turned(self._previous, turn)


def _turned(depth: Depth, turn: np.ndarray) -> Depth:
    """A working ``depth``, its confidence and blend shares (where it has them) carried through the ``turn``."""
    maps = [depth.working[None]]
    if depth.confidence is not None:
        maps.append(depth.confidence[None])
    if depth.shares is not None:
        maps.append(depth.shares)
    carried = carry(torch.cat(maps), turn)
    confidence = None if depth.confidence is None else carried[1]
    shares = None if depth.shares is None else carried[len(carried) - len(depth.shares) :]
    return depth._replace(working=carried[0], confidence=confidence, shares=shares)


def to_pixels(image: torch.Tensor) -> np.ndarray:
    """``(3, h, w)`` float in [0, 1] as ``(h, w, 3)`` uint8."""
    return (image.clamp(0, 1) * 255.0 + 0.5).to(torch.uint8).permute(1, 2, 0).numpy()


class TemporalPhotometry:
    """The colour correction smoothed over consecutive frames: an exponential moving average with
    ``keep`` of the previous frame's (module docstring)."""

    def __init__(self, keep: float = 0.8):
        self.keep = keep
        self.reset()

    def reset(self) -> None:
        self._previous: Photometry | None = None

    def __call__(self, fitted: Photometry) -> Photometry:
        if self._previous is not None:
            fitted = Photometry(*(self.keep * p + (1.0 - self.keep) * f for p, f in zip(self._previous, fitted)))
        self._previous = fitted
        return fitted
