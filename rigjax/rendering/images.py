"""Reading and writing a rig's images and video frames (OpenCV), with errors that name the file.

Images are ``(h, w, 3)`` uint8 RGB arrays throughout rigjax.
"""

from __future__ import annotations

import os
from os import PathLike

import cv2
import numpy as np

from ..errors import RigjaxError


class ImageError(RigjaxError):
    """An image that cannot be read or does not fit its camera; the message names the file."""


def read_image(path: str | PathLike[str]) -> np.ndarray:
    """An image file as ``(h, w, 3)`` uint8 RGB; a clear error when it cannot be read."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ImageError(f"{path}: no such image file")
    bgr = cv2.imread(path, cv2.IMREAD_COLOR)
    if bgr is None:
        raise ImageError(f"{path}: cannot read the image (not an image file OpenCV can decode)")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def write_image(path: str | PathLike[str], rgb: np.ndarray) -> None:
    """Write an RGB uint8 image; the format follows the suffix."""
    path = os.fspath(path)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    try:  # OpenCV returns False for some failures and raises for others (an unknown suffix)
        written = cv2.imwrite(path, cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR))
    except cv2.error:
        written = False
    if not written:
        raise ImageError(f"{path}: cannot write the image (unknown suffix or unwritable folder)")


def read_video_frame(path: str | PathLike[str], seconds: float) -> np.ndarray:
    """The frame of a video shown at ``seconds`` from its start, as RGB."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ImageError(f"{path}: no such video file")
    capture = cv2.VideoCapture(path)
    try:
        if not capture.isOpened():
            raise ImageError(f"{path}: cannot open the video (not a format OpenCV can decode)")
        frames = capture.get(cv2.CAP_PROP_FRAME_COUNT)
        fps = capture.get(cv2.CAP_PROP_FPS)
        if seconds < 0 or (fps > 0 and frames > 0 and seconds * fps >= frames):
            length = f"{frames / fps:.3f} s long" if fps > 0 else "of unknown length"
            raise ImageError(f"{path}: no frame at {seconds} s (the video is {length})")
        if fps > 0:  # the frame on screen at that time: seek by index (seeking by time rounds to the nearest)
            capture.set(cv2.CAP_PROP_POS_FRAMES, int(np.floor(seconds * fps + 1e-9)))
        else:
            capture.set(cv2.CAP_PROP_POS_MSEC, seconds * 1000.0)
        ok, bgr = capture.read()
        if not ok or bgr is None:
            raise ImageError(f"{path}: cannot decode a frame at {seconds} s")
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    finally:
        capture.release()


def read_video_frames(path: str | PathLike[str], every: int, count: int, start: float = 0.0) -> list[np.ndarray]:
    """Frames of a video as RGB: from ``start`` seconds on, every ``every``-th frame, at most
    ``count`` of them (fewer where the video ends first; none is an error)."""
    path = os.fspath(path)
    if every < 1 or count < 1:
        raise ImageError(f"{path}: every and count must be at least 1, got {every} and {count}")
    first = read_video_frame(path, start)  # checks the file, the format and the start
    capture = cv2.VideoCapture(path)
    try:
        fps = capture.get(cv2.CAP_PROP_FPS)
        index = int(np.floor(start * fps + 1e-9)) if fps > 0 else 0
        frames = [first]
        while len(frames) < count:
            index += every
            capture.set(cv2.CAP_PROP_POS_FRAMES, index)
            ok, bgr = capture.read()
            if not ok or bgr is None:
                break
            frames.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
        return frames
    finally:
        capture.release()
