"""``learnstitch stitch --video ... --stabilise``: each panorama turned so that its horizon stays
where the rig's ``.pto`` puts it and its heading follows the camera's, smoothed over time.

From the camera's turn in every frame (:mod:`learnstitch.video.turns`: ``R_t`` takes the rig's
frame at frame ``t`` into its frame at the first), the output's frame at ``t`` is the first frame's
turned about the vertical by the camera's heading (the yaw of ``R_t``, unwrapped) smoothed with a
Gaussian of ``sigma_s`` seconds: ``O_t = Ry(smoothed yaw)``. The panorama's pixel of direction
``d`` in that frame shows the stitched panorama's direction ``R_t^T O_t d``. Pitch and roll are
taken out entirely: the horizon is as level as the first frame's, which is the ``.pto``'s (level
where the calibration's panorama is). A pan is kept, its shake smoothed away.

The panorama is resampled once more (bicubic, wrapping in longitude and across the poles); the turns of all the frames
are known before the first is stitched, so a frame's turn depends on its index alone and a resumed
or segmented run gives the frames an uninterrupted one gives.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import av
import cv2
import numpy as np

import rigjax
from rigjax.errors import ConfigError

from .colour import Colour, tag, to_yuv420, yuv_planes

if TYPE_CHECKING:
    from .turns import Turns

SIGMA_S = 1.0  # seconds: the heading's smoothing


def check_seconds(sigma_s: float) -> None:
    """A :class:`ConfigError` unless ``sigma_s`` is a smoothing of 0 seconds or more."""
    if not (isinstance(sigma_s, (int, float)) and math.isfinite(sigma_s) and sigma_s >= 0):
        raise ConfigError(f"--stabilise-seconds must be >= 0, got {sigma_s}")


def smoothed_heading(turns: Turns, rate: float, sigma_s: float = SIGMA_S) -> np.ndarray:
    """``(F,)`` the camera's heading (yaw of each turn, degrees, unwrapped) smoothed by a Gaussian of
    ``sigma_s`` seconds, the ends held."""
    check_seconds(sigma_s)
    heading = np.degrees(np.unwrap(np.radians(turns.ypr()[:, 0])))
    sigma = sigma_s * rate
    if sigma < 1e-3 or len(heading) == 1:
        return heading
    radius = int(math.ceil(3 * sigma))
    offsets = np.arange(-radius, radius + 1)
    kernel = np.exp(-0.5 * (offsets / sigma) ** 2)
    padded = np.pad(heading, radius, mode="edge")
    return np.convolve(padded, kernel / kernel.sum(), mode="valid")


def output_turns(turns: Turns, rate: float, sigma_s: float = SIGMA_S) -> dict[int, np.ndarray]:
    """Per frame index, the rotation ``R_t^T O_t`` (module docstring) taking a direction of the
    steadied panorama to the stitched one's."""
    import jax

    with jax.enable_x64(True):
        level = np.asarray(rigjax.world_from_cam(smoothed_heading(turns, rate, sigma_s), 0.0, 0.0), np.float64)
    steady = np.swapaxes(turns.rotations, -1, -2) @ level
    return {int(t): r for t, r in zip(turns.frames, steady)}


def _directions(width: int, height: int) -> np.ndarray:
    """``(3, height * width)`` float32 unit rays of an equirectangular canvas's pixel centres, row
    by row (as :func:`learnstitch.fullres.depth.pano_rays`, without torch)."""
    lon = (np.arange(width) + 0.5) / width * (2.0 * math.pi) - math.pi
    lat = (np.arange(height) + 0.5) / height * math.pi - 0.5 * math.pi
    cos_lat = np.cos(lat)[:, None]
    rays = [
        cos_lat * np.sin(lon)[None],
        np.broadcast_to(np.sin(lat)[:, None], (height, width)),
        cos_lat * np.cos(lon)[None],
    ]
    return np.stack([r.reshape(-1) for r in rays]).astype(np.float32)


class Steady:
    """The stabiliser of a clip's panoramas: ``steady(t, pano)`` turns frame ``t``'s panorama
    (``(h, w, 3)`` uint8 RGB, or a :class:`av.VideoFrame` in ``colour``, returned as 4:2:0) by
    ``rotations[t]`` (:func:`output_turns`). Called from one thread at a time."""

    def __init__(self, rotations: dict[int, np.ndarray], colour: Colour | None):
        self.rotations, self.colour = rotations, colour
        self._grids: dict[tuple[int, int], np.ndarray] = {}

    def maps(self, t: int, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
        """OpenCV's remap maps of frame ``t`` on a canvas ``width x height`` padded by
        :data:`_POLE_ROWS` rows above and below (:func:`_padded`)."""
        if t not in self.rotations:
            raise ConfigError(
                f"--stabilise: no turn for frame {t} (the turns cover frames {min(self.rotations)}-{max(self.rotations)})"
            )
        grid = self._grids.get((width, height))
        if grid is None:
            grid = self._grids[(width, height)] = _directions(width, height)
        rays = self.rotations[t].astype(np.float32) @ grid  # (3, n): one matrix product, rows contiguous
        x = np.arctan2(rays[0], rays[2])
        x *= width / (2.0 * math.pi)
        x += width / 2.0 - 0.5
        y = np.arcsin(np.clip(rays[1], -1.0, 1.0, out=rays[1]))
        y *= height / math.pi
        y += height / 2.0 - 0.5 + _POLE_ROWS
        return x.reshape(height, width), y.reshape(height, width)

    def _turn(self, maps: tuple[np.ndarray, np.ndarray], plane: np.ndarray) -> np.ndarray:
        return cv2.remap(_padded(plane), *maps, interpolation=cv2.INTER_CUBIC, borderMode=cv2.BORDER_WRAP)

    def __call__(self, t: int, pano: np.ndarray | av.VideoFrame) -> np.ndarray | av.VideoFrame:
        if isinstance(pano, np.ndarray):
            return self._turn(self.maps(t, pano.shape[1], pano.shape[0]), pano)
        luma, u, v = yuv_planes(to_yuv420(pano, self.colour))
        out = av.VideoFrame(pano.width, pano.height, "yuv420p")
        y_out, u_out, v_out = yuv_planes(out)
        y_out[...] = self._turn(self.maps(t, luma.shape[1], luma.shape[0]), luma)
        chroma = self._turn(self.maps(t, u.shape[1], u.shape[0]), np.dstack([u, v]))  # one map for both
        u_out[...], v_out[...] = chroma[..., 0], chroma[..., 1]
        return tag(out, self.colour)


_POLE_ROWS = 2  # rows a bicubic sample reaches beyond the canvas's top and bottom


def _padded(plane: np.ndarray) -> np.ndarray:
    """``plane`` (an equirectangular canvas, ``(h, w)`` or ``(h, w, c)``) with :data:`_POLE_ROWS`
    rows above and below, each the row it mirrors across the pole turned half way round: what lies
    beyond a pole, so that a sample near it reads the other side of the pole, never the opposite one."""
    half = plane.shape[1] // 2
    above = np.roll(plane[_POLE_ROWS - 1 :: -1], half, axis=1)
    below = np.roll(plane[: -_POLE_ROWS - 1 : -1], half, axis=1)
    return np.concatenate([above, plane, below])


__all__ = ["SIGMA_S", "Steady", "check_seconds", "output_turns", "smoothed_heading"]
