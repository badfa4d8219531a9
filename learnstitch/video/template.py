"""The template stitch: a fixed remap of each frame through the rig's calibration, no depth.

Every output pixel reads the cameras that see its direction at infinity, feather-blended as the
full-resolution renderer blends them (:func:`learnstitch.fullres.sight.views` at inverse depth 0),
so a template frame is the rotation-only stitch of the ``.pto``: what Hugin's ``nona`` with a fixed
template, FFmpeg's ``v360`` and the cameras' own apps do for video. The maps are made once per
rig; each frame is then a few OpenCV remaps of the decoded YUV 4:2:0 planes (no conversion to RGB
and back): the camera seen best at each pixel over the whole canvas, the others only in the
overlaps, where the blend needs them.

Convention. The cameras' images lie side by side in one source plane, camera ``k`` from column
``x0_k`` (a side-by-side clip's frame as decoded; one file per camera, its planes joined), top
aligned. Luma sample ``(x, y)`` is Hugin's image pixel ``(x, y)``; chroma sample ``(i, j)`` of
4:2:0 sits at luma ``(2 i, 2 j + 0.5)`` (H.264's and HEVC's default chroma siting, "left"), on
the output as on the input. Pixels no camera sees are black (``Y = 16, U = V = 128``). The
panorama is in the source's matrix (:mod:`learnstitch.video.colour`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import av
import cv2
import numpy as np
import torch

from ..fullres.depth import pixel_rays
from ..fullres.sight import SightTables, views
from .colour import colour_of, to_yuv420

_BLACK = (16, 128, 128)  # limited-range black, per plane
_BAND_COLUMNS = 1024


class Layers(NamedTuple):
    """One plane's remap: ``primary`` the best-seen camera's float maps ``(x, y)`` over the whole
    canvas; ``band`` the flat indices ``(B,)`` of pixels two or more cameras see, laid out in rows of
    1024 (the last padded), ``maps`` the float maps of each camera that sees them there, by rank
    (layer 0 the primary), and ``weights`` ``(rows, 1024)`` float32 of each layer (0 in the padding
    and where a layer's camera does not see)."""

    primary: tuple[np.ndarray, np.ndarray]
    band: np.ndarray
    maps: list[tuple[np.ndarray, np.ndarray]]
    weights: list[np.ndarray]


def _layers(
    tables: SightTables, x0: np.ndarray, width: int, height: int, subsample: int, chunk: int = 1 << 18
) -> Layers:
    """The remap of a plane ``subsample`` times smaller than the ``width x height`` luma canvas."""
    w, h = width // subsample, height // subsample
    xs, ys = np.meshgrid(np.arange(w), np.arange(h))
    # Luma position of each sample (chroma siting), then the source plane's coordinates back.
    lx, ly = (xs * subsample).ravel(), (ys * subsample + (subsample - 1) / 2.0).ravel()
    count = tables.count
    coords, weight = np.empty((count, lx.size, 2), np.float32), np.empty((count, lx.size), np.float32)
    for start in range(0, lx.size, chunk):
        part = slice(start, start + chunk)
        rays = torch.from_numpy(pixel_rays(width, lx[part], ly[part])).float()
        seen = views(tables, rays, torch.zeros(rays.shape[0]))
        coords[:, part] = seen.xy.numpy()
        weight[:, part] = seen.feather.numpy()
    coords[..., 0] += x0[:, None]
    if subsample > 1:
        coords[..., 0] = coords[..., 0] / subsample
        coords[..., 1] = (coords[..., 1] - (subsample - 1) / 2.0) / subsample
    total = weight.sum(0)
    weight /= np.maximum(total, 1e-12)  # zero where no camera sees
    outside = np.float32(-1e4)  # reads the border value: black
    everywhere = np.arange(lx.size)
    best = weight.argmax(0)
    seen = total > 0
    primary = tuple(np.where(seen, coords[best, everywhere, i], outside).reshape(h, w) for i in (0, 1))
    band = np.flatnonzero((weight > 0).sum(0) >= 2)  # pixels two or more cameras see: blended
    order = np.argsort(-weight[:, band], axis=0, kind="stable")  # (N, B) their cameras by weight
    ranked = np.take_along_axis(weight[:, band], order, 0)
    layers = int((ranked > 0).sum(0).max()) if band.size else 0
    rows = -(-band.size // _BAND_COLUMNS)  # OpenCV remaps at most 32767 columns: the band as rows
    padding = (0, rows * _BAND_COLUMNS - band.size)
    maps, weights = [], []
    for rank in range(layers):
        used, xy = ranked[rank] > 0, coords[order[rank], band]
        mx, my = (np.pad(np.where(used, xy[:, i], outside), padding, constant_values=outside) for i in (0, 1))
        maps.append((mx.reshape(rows, _BAND_COLUMNS), my.reshape(rows, _BAND_COLUMNS)))
        weights.append(np.pad(ranked[rank], padding).astype(np.float32).reshape(rows, _BAND_COLUMNS))
    return Layers(primary, band, maps, weights)


def _remap(plane: np.ndarray, layers: Layers, black: int, out: np.ndarray) -> None:
    """``plane`` through ``layers`` into ``out`` (the canvas's plane, uint8)."""
    cv2.remap(plane, *layers.primary, cv2.INTER_LINEAR, dst=out, borderMode=cv2.BORDER_CONSTANT, borderValue=black)
    if not layers.band.size:
        return
    # The band's layers blended in turn: each step a weighted mean (rounded) of the mean so far and
    # the next layer, weighted by their shares; within a level of the exact mean for 2 or 3 layers.
    mixed, so_far = None, None
    for maps, weight in zip(layers.maps, layers.weights):
        read = cv2.remap(plane, *maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=black)
        if mixed is None:
            mixed, so_far = read, weight
        else:
            mixed = cv2.blendLinear(mixed, read, so_far, weight)
            so_far = so_far + weight
    out.reshape(-1)[layers.band] = mixed.reshape(-1)[: layers.band.size]


class Template:
    """A rig's template stitch into ``width x width / 2`` panoramas (module docstring), the cameras'
    images ``sizes`` ``(w_k, h_k)`` side by side in the source plane."""

    def __init__(self, tables: SightTables, sizes: Sequence[tuple[int, int]], width: int):
        if width % 4:
            raise ValueError(f"the template stitch's width must be a multiple of 4, got {width}")
        self.width, self.height = width, width // 2
        self.x0 = np.concatenate([[0], np.cumsum([w for w, _ in sizes])[:-1]]).astype(np.float32)
        self.luma = _layers(tables, self.x0, self.width, self.height, 1)
        self.chroma = _layers(tables, self.x0, self.width, self.height, 2)

    def __call__(self, frames: Sequence[av.VideoFrame]) -> av.VideoFrame:
        """The panorama of one rig frame (the decoded frames of its files, in order) as a YUV 4:2:0 frame."""
        planes = [_planes(f) for f in frames]
        out = av.VideoFrame(self.width, self.height, "yuv420p")
        for p, (layers, black) in enumerate(zip((self.luma, self.chroma, self.chroma), _BLACK)):
            source = planes[0][p] if len(planes) == 1 else _join([ps[p] for ps in planes])
            view = _plane_view(out, p)
            if view.flags.c_contiguous:
                _remap(source, layers, black, view)
            else:  # rows padded beyond the width: remapped beside, then copied in
                pixels = np.empty(view.shape, np.uint8)
                _remap(source, layers, black, pixels)
                view[...] = pixels
        return out


def _planes(frame: av.VideoFrame) -> list[np.ndarray]:
    """The Y, U and V planes of a frame (converted to limited-range 4:2:0 in its own matrix where it
    is not), as views."""
    frame = to_yuv420(frame, colour_of(frame))
    return [_plane_view(frame, p) for p in range(3)]


def _join(planes: list[np.ndarray]) -> np.ndarray:
    height = max(p.shape[0] for p in planes)
    return np.hstack([np.pad(p, ((0, height - p.shape[0]), (0, 0))) for p in planes])


def _plane_view(frame: av.VideoFrame, p: int) -> np.ndarray:
    """Plane ``p`` of a 4:2:0 frame as a writable ``(h, w)`` uint8 view of the frame's own memory
    (strided where its rows are padded beyond ``w``)."""
    plane = frame.planes[p]
    w, h = (frame.width, frame.height) if p == 0 else ((frame.width + 1) // 2, (frame.height + 1) // 2)
    return np.frombuffer(plane, np.uint8).reshape(h, plane.line_size)[:, :w]
