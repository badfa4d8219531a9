"""A clip's working depth and colour correction filtered over time, so that seams hold still.

Stitched frame by frame, the depth of the same surface comes out a little different in every frame
(the sweep's planes, sensor noise), and the seam over a near object jumps from frame to frame;
the fitted exposures and vignetting wander the same way. :class:`TemporalDepth` blends each frame's
depth with the previous frame's filtered depth, recursively, where the scene did not change:

    q_t = q'_t + a (R q_{t-1} - q'_t),      a = strength exp(-(g_t - R g_{t-1})^2 / (2 s^2))

``q'_t`` the frame's own depth on the working canvas, ``g`` the canvas's grey level at infinity and
``R`` the camera's turn since the previous frame: a hand-held camera turns between frames and the
panorama turns with it, so the previous depth and grey are first carried through that turn. The
turn is estimated from the frames themselves (ORB features matched between the two canvases,
their directions aligned by a rotation, RANSAC over pairs; :func:`frame_turn`); where no turn can
be found the frame starts afresh. :class:`TemporalPhotometry` smooths the colour correction the
same way (an exponential moving average of the fitted exposures and vignetting).

Convention. ``R`` is ``prev_from_cur``: the previous frame's direction of what the current frame
sees along unit ray ``d`` is ``R d`` (rigjax's axes). Canvases are equirectangular, 2:1, pixel
centres at ``+0.5`` (:func:`learnstitch.fullres.depth.pano_rays`).
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from ..fullres.config import RenderConfig
from ..fullres.depth import Depth, pano_rays, working_views
from ..fullres.render import Photometry
from ..fullres.stitcher import DepthSource, Frame

# The filter's weight of the carried depth where the colour agrees, and the grey-level difference
# (0-1) at which it falls to exp(-1/2) of that.
STRENGTH, COLOUR_SIGMA = 0.8, 0.04
# Matches a turn needs (inliers of the RANSAC) and their tolerance, in working pixels.
_MIN_INLIERS, _INLIER_PX, _RANSAC_TRIES = 12, 1.5, 200
# The canvas the turn between frames is found on, at least (pixels around).
TURN_WIDTH = 512


def canvas_grey(frame: Frame, width: int, tables) -> tuple[torch.Tensor, torch.Tensor]:
    """The working canvas ``width`` wide at infinity: grey level ``(h, w)`` in [0, 1] (the mean of
    the inputs that see each pixel) and the share of pixels seen ``(h, w)``."""
    colours, masks, _ = working_views(frame.working(width), tables, torch.zeros(width // 2, width))
    seen = masks.sum(0)
    grey = colours.mean(1).sum(0) / seen.clamp_min(1e-6)
    return grey, (seen > 0).float()


def directions(width: int, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Unit rays ``(M, 3)`` of canvas pixel coordinates ``(x, y)`` (the module's convention)."""
    lon = (x + 0.5) / width * (2.0 * math.pi) - math.pi
    lat = (y + 0.5) / (width // 2) * math.pi - 0.5 * math.pi
    return np.stack([np.cos(lat) * np.sin(lon), np.sin(lat), np.cos(lat) * np.cos(lon)], -1)


def _kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation ``R`` minimising ``sum |R b_i - a_i|^2`` (``a``, ``b`` ``(M, 3)``)."""
    u, _, vt = np.linalg.svd(a.T @ b)
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def frame_turn(previous: np.ndarray, current: np.ndarray, seed: int = 0) -> np.ndarray | None:
    """``prev_from_cur`` ``(3, 3)`` between two grey canvases ``(h, w)`` uint8 (module docstring),
    or None where too few features agree on one."""
    width = current.shape[1]
    orb = cv2.ORB_create(nfeatures=1500, fastThreshold=10, edgeThreshold=15, patchSize=15)
    kp_prev, des_prev = orb.detectAndCompute(previous, None)
    kp_cur, des_cur = orb.detectAndCompute(current, None)
    if des_prev is None or des_cur is None or len(kp_prev) < _MIN_INLIERS or len(kp_cur) < _MIN_INLIERS:
        return None
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(des_prev, des_cur)
    if len(matches) < _MIN_INLIERS:
        return None
    p = np.array([kp_prev[m.queryIdx].pt for m in matches])
    c = np.array([kp_cur[m.trainIdx].pt for m in matches])
    a, b = directions(width, p[:, 0], p[:, 1]), directions(width, c[:, 0], c[:, 1])
    tolerance = 1.0 - math.cos(_INLIER_PX * 2.0 * math.pi / width)  # of 1 - cos(angle between directions)
    rng = np.random.default_rng(seed)
    best = np.zeros(len(a), bool)
    for _ in range(_RANSAC_TRIES):
        pick = rng.choice(len(a), 2, replace=False)
        rotation = _kabsch(a[pick], b[pick])
        inliers = 1.0 - np.einsum("mi,mi->m", b @ rotation.T, a) < tolerance
        if inliers.sum() > best.sum():
            best = inliers
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
    depth over consecutive frames (module docstring). :meth:`reset` before a frame that does not
    follow the previous one."""

    def __init__(self, inner: DepthSource, strength: float = STRENGTH, colour_sigma: float = COLOUR_SIGMA):
        self.inner, self.strength, self.colour_sigma = inner, strength, colour_sigma
        self.label = f"{inner.label}, filtered over time"
        self.turns: list[np.ndarray | None] = []  # the turn found for each frame since the reset
        self.reset()

    def reset(self) -> None:
        self._depth: torch.Tensor | None = None  # the previous frame's filtered depth
        self._grey: np.ndarray | None = None  # its grey canvas (uint8) the turn is found on
        self._working_grey: torch.Tensor | None = None  # its grey at the working size

    def __call__(self, frame: Frame, config: RenderConfig) -> Depth:
        found = self.inner(frame, config)
        depth = found.working
        height, width = depth.shape
        # The turn is found on a canvas of TURN_WIDTH (a small working canvas has too few features)
        grey, seen = canvas_grey(frame, max(width, TURN_WIDTH), frame.tables)
        grey8 = (grey.clamp(0, 1) * 255.0 + 0.5).to(torch.uint8).numpy()
        turn = None if self._grey is None else frame_turn(self._grey, grey8)
        self.turns.append(turn)
        if grey.shape[-1] != width:  # the working canvas's, each pixel the mean of those it covers
            grey, seen = (F.adaptive_avg_pool2d(m[None], (height, width))[0] for m in (grey, seen))
        if turn is not None:
            carried = carry(torch.stack([self._depth, self._working_grey]), turn)
            agree = torch.exp(-((grey - carried[1]) ** 2) / (2.0 * self.colour_sigma**2)) * (seen > 0.999)
            depth = depth + self.strength * agree * (carried[0] - depth)
            found = found._replace(working=depth)
        self._depth, self._grey, self._working_grey = depth, grey8, grey
        return found


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
