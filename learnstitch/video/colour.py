"""The YUV matrix and range of a clip's frames as players read them, and the panoramas' own:
conversions to and from RGB through them, and the tags written with them.

A decoded frame states its matrix (FFmpeg's ``AVColorSpace``: 1 BT.709, 5 and 6 BT.601, 9 and 10
BT.2020, ...) and range (1 limited, 2 full) where its stream tags them. An untagged frame is read
as players read it: BT.709 from 1280 columns or 577 rows up, else BT.601 (mpv's and RetroArch's
rule), limited range unless its pixel format is a full-range ``yuvj`` one. FFmpeg's converter left
to itself reads an untagged frame as BT.601 and writes BT.601 without tags, which a player showing
HD as BT.709 shows shifted: (250, 90, 40) as (255, 100, 33).

The panoramas are in the source's matrix (the template stitch remaps the planes of a YUV source
as they are), BT.709 for an RGB source, limited range, and the file says so: its matrix, primaries
and transfer are tagged (copied from the source where it tags them). A rig's other files are
converted to the first's.
"""

from __future__ import annotations

from typing import NamedTuple

import av
import numpy as np

RGB, BT709, UNSPECIFIED, BT470BG, SMPTE170M = 0, 1, 2, 5, 6
LIMITED, FULL = 1, 2
# The primaries and transfer an untagged source's matrix implies (H.273's pairings).
_IMPLIED = {BT709: (1, 1), BT470BG: (5, 6), SMPTE170M: (6, 6)}
# FFmpeg's converter knows a matrix by its coefficient table, which PyAV names for these only.
_TABLE = {1: 1, 4: 4, 5: 5, 6: 5, 7: 7, 9: 9, 10: 9}


class Colour(NamedTuple):
    """A matrix, range, primaries and transfer, by FFmpeg's codes (module docstring)."""

    space: int
    range: int
    primaries: int
    trc: int


def colour_of(frame: av.VideoFrame) -> Colour:
    """A decoded frame's colour as players read it (module docstring)."""
    space = int(frame.colorspace)
    if space == UNSPECIFIED:
        space = BT709 if frame.width >= 1280 or frame.height > 576 else BT470BG
    full = frame.format.name.startswith("yuvj")
    value = int(frame.color_range) or (FULL if full else LIMITED)
    primaries, trc = _IMPLIED.get(space, (UNSPECIFIED, UNSPECIFIED))
    if int(frame.color_primaries) != UNSPECIFIED:
        primaries = int(frame.color_primaries)
    if int(frame.color_trc) != UNSPECIFIED:
        trc = int(frame.color_trc)
    return Colour(space, value, primaries, trc)


def panorama_colour(source: Colour) -> Colour:
    """The panoramas' colour for a source's: its matrix, primaries and transfer (BT.709 for RGB),
    limited range."""
    if source.space == RGB:
        return Colour(BT709, LIMITED, *_IMPLIED[BT709])
    return source._replace(range=LIMITED)


def to_rgb(frame: av.VideoFrame, colour: Colour | None = None) -> np.ndarray:
    """A frame's ``(h, w, 3)`` uint8 RGB, read in ``colour`` (default: :func:`colour_of` it)."""
    colour = colour or colour_of(frame)
    if colour.space == RGB:
        return frame.to_ndarray(format="rgb24")
    return frame.to_ndarray(format="rgb24", src_colorspace=_table(colour), src_color_range=colour.range)


def to_yuv420(frame: av.VideoFrame, target: Colour) -> av.VideoFrame:
    """A decoded frame (in its own colour, :func:`colour_of`) as limited-range 4:2:0 in ``target``'s
    matrix: the frame itself where it is that already, else a converted copy. Its tags are left as
    they are (:func:`tag` sets them)."""
    source = colour_of(frame)
    if frame.format.name == "yuv420p" and source.range == LIMITED and _table(source) == _table(target):
        return frame
    return frame.reformat(
        format="yuv420p",
        src_colorspace=_table(source),
        src_color_range=source.range,
        dst_colorspace=_table(target),
        dst_color_range=LIMITED,
    )


def from_rgb(rgb: np.ndarray, colour: Colour) -> av.VideoFrame:
    """An ``(h, w, 3)`` uint8 RGB panorama as a limited-range 4:2:0 frame in ``colour``, tagged."""
    frame = av.VideoFrame.from_ndarray(rgb, format="rgb24")
    return tag(frame.reformat(format="yuv420p", dst_colorspace=_table(colour), dst_color_range=LIMITED), colour)


def tag(frame: av.VideoFrame, colour: Colour) -> av.VideoFrame:
    """``frame`` tagged with ``colour`` (limited range): what a caller reading its colour finds."""
    frame.colorspace, frame.color_range = colour.space, LIMITED
    frame.color_primaries, frame.color_trc = colour.primaries, colour.trc
    return frame


def yuv_planes(frame: av.VideoFrame) -> list[np.ndarray]:
    """The Y, U and V planes of a 4:2:0 frame as writable ``(h, w)`` uint8 views of the frame's own
    memory (strided where its rows are padded beyond ``w``; chroma ``ceil(h / 2) x ceil(w / 2)``)."""
    views = []
    for p, plane in enumerate(frame.planes[:3]):
        w, h = (frame.width, frame.height) if p == 0 else ((frame.width + 1) // 2, (frame.height + 1) // 2)
        views.append(np.frombuffer(plane, np.uint8).reshape(h, plane.line_size)[:, :w])
    return views


def _table(colour: Colour) -> int:
    """FFmpeg's converter's coefficient table for a YUV matrix (BT.601's for RGB: unused there)."""
    return _TABLE.get(colour.space, BT470BG)
