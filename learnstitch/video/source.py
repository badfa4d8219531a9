"""A rig's footage decoded frame by frame (PyAV, FFmpeg's decoders): one side-by-side clip of a
dual-fisheye camera, or one file per camera, with offsets in frames.

Which part of which file is which camera:

- **one file, N images in the ``.pto``**: each frame is cut into N equal parts, left to right, the
  ``i`` lines' order; every ``i`` line must state the part's size (``frame width / N x frame
  height``), as the halves ``rigjax calibrate --template configs/rig/dual_fisheye.yaml`` writes;
  or every ``i`` line states the whole frame's size and each camera's image is the whole frame,
  Hugin's form of a dual-fisheye template: each lens's centre shifted into its part (``d``, ``e``)
  and its crop (``S``) bounding its circle;
- **N files**: file ``k`` is camera ``k`` (the ``i`` lines' order), its frames the size of its
  ``i`` line; frame ``t`` of the rig is frame ``t + offsets[k]`` of file ``k``.

Convention. Frame ``t`` of a file is the ``t``-th frame it shows (0 the first), at presentation
time ``start + t / rate``; ``--time T`` starts at the frame on screen at ``T`` seconds, ``floor(T
rate)``. Frames are ``(h, w, 3)`` uint8 RGB, or the decoder's own :class:`av.VideoFrame` for the
template mode, which remaps the YUV planes directly.

Bad input (a missing, unreadable or non-video file, files of different frame rates, a frame that
does not fit the ``.pto``, no frame in the range) is a :class:`VideoError` naming the file and both
values; a stream that ends early or stops decoding midway yields the frames before it and records
where it stopped in :attr:`Footage.stopped`.
"""

from __future__ import annotations

import math
import os
import queue
import threading
from collections.abc import Iterator, Sequence
from fractions import Fraction
from typing import TYPE_CHECKING, NamedTuple

import av
import numpy as np

from rigjax.errors import ConfigError

from .colour import to_rgb

if TYPE_CHECKING:
    import rigjax


class VideoError(ConfigError):
    """A clip that cannot be stitched as given; the message names the file and what was expected."""


class VideoInfo(NamedTuple):
    """What a file holds, read from its container."""

    path: str
    width: int
    height: int
    rate: Fraction  # frames per second
    frames: int  # the container's frame count, or its duration times the rate (0: unknown)
    codec: str
    audio: bool  # whether it has an audio stream
    pixel_format: str


def probe(path: str | os.PathLike[str]) -> VideoInfo:
    """The video stream of ``path``: a :class:`VideoError` naming the file if there is none."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise VideoError(f"{path}: no such video file")
    try:
        with av.open(path) as container:
            if not container.streams.video:
                raise VideoError(f"{path}: no video stream (streams: {[s.type for s in container.streams]})")
            stream = container.streams.video[0]
            rate = stream.average_rate or stream.guessed_rate or stream.base_rate
            if not rate:
                raise VideoError(f"{path}: the video stream states no frame rate")
            frames = int(stream.frames or 0)
            if not frames and stream.duration and stream.time_base:
                frames = int(round(float(stream.duration * stream.time_base * rate)))
            elif not frames and container.duration:
                frames = int(round(container.duration / av.time_base * float(rate)))
            context = stream.codec_context
            return VideoInfo(
                path,
                int(context.width),
                int(context.height),
                Fraction(rate),
                frames,
                context.name,
                bool(container.streams.audio),
                str(context.format.name if context.format else "unknown"),
            )
    except av.FFmpegError as error:
        raise VideoError(f"{path}: not a video FFmpeg can read ({error})") from None


class Layout(NamedTuple):
    """Which part of which file is each camera (module docstring)."""

    infos: list[VideoInfo]
    parts: int  # cameras per frame of each file: N for one side-by-side file, else 1
    offsets: list[int]  # per file, the frame of that file that is the rig's frame 0
    shared: int = 0  # N where each of N cameras' image is the one file's whole frame (Hugin's form), else 0

    @property
    def rate(self) -> Fraction:
        return self.infos[0].rate


def layout(
    paths: Sequence[str | os.PathLike[str]], sizes: Sequence[tuple[int, int]], offsets: Sequence[int] | None, label: str
) -> Layout:
    """The cameras of footage ``paths`` for a rig of images ``sizes`` (``(width, height)`` of each
    ``i`` line; ``label`` names the project): one side-by-side file or one file per camera."""
    infos = [probe(p) for p in paths]
    count = len(sizes)
    if len(infos) not in (1, count):
        raise VideoError(
            f"{label} has {count} images: give one side-by-side clip or {count} clips (one per camera), "
            f"got {len(infos)}"
        )
    for info in infos[1:]:
        if info.rate != infos[0].rate:
            raise VideoError(
                f"{info.path}: {float(info.rate):.3f} frames per second, but {infos[0].path} has "
                f"{float(infos[0].rate):.3f}: the rig's clips must share one frame rate"
            )
    shared = 0
    if len(infos) == 1 and count > 1:
        info = infos[0]
        whole = all(tuple(size) == (info.width, info.height) for size in sizes)
        if not whole and (
            len(set(sizes)) != 1 or info.width % count or (info.width // count, info.height) != tuple(sizes[0])
        ):
            stated = ", ".join(f"{w} x {h}" for w, h in sizes)
            raise VideoError(
                f"{info.path}: {info.width} x {info.height} frames do not cut into the {count} images of {label} "
                f"({stated} by its i lines): a side-by-side clip's frame is {count} equal parts, left to right, "
                "or every i line the whole frame (Hugin's form, each lens cropped by its S)"
            )
        parts, shared = (1, count) if whole else (count, 0)
    else:
        parts = 1
        for k, (info, size) in enumerate(zip(infos, sizes)):
            if (info.width, info.height) != tuple(size):
                raise VideoError(
                    f"{info.path}: {info.width} x {info.height} frames, but image {k} of {label} is "
                    f"{size[0]} x {size[1]} by its i line"
                )
    offsets = list(offsets) if offsets is not None else [0] * len(infos)
    if len(offsets) != len(infos) or any(o < 0 for o in offsets):
        raise VideoError(f"--offsets: one frame count >= 0 per clip ({len(infos)}), got {offsets}")
    return Layout(infos, parts, offsets, shared)


def rig_layout(
    project: rigjax.Project, paths: Sequence[str | os.PathLike[str]], offsets: Sequence[int] | None
) -> Layout:
    """:func:`layout` of ``project``'s images over ``paths``; Hugin's form (every ``i`` line the
    whole frame) only where each image has its crop (``S``) to keep it to its lens's circle."""
    label = str(project.path or "the project")
    sizes = [(int(i.width), int(i.height)) for i in project.images]
    found = layout(paths, sizes, offsets, label)
    uncropped = [k for k, image in enumerate(project.images) if image.crop is None]
    if found.shared and uncropped:
        raise VideoError(
            f"{label}: every i line states the whole {sizes[0][0]} x {sizes[0][1]} frame (Hugin's form), but "
            f"image {uncropped[0]} has no crop (S) to keep it to its lens's circle: give each image its crop"
        )
    return found


def first_frame(time_s: float, rate: Fraction) -> int:
    """The frame on screen at ``time_s`` seconds (this module's convention)."""
    if time_s < 0:
        raise ConfigError(f"--time must be >= 0 seconds, got {time_s}")
    return int(math.floor(time_s * float(rate) + 1e-9))


def frames_in(duration_s: float, rate: Fraction) -> int:
    """The frames shown within ``duration_s`` seconds at ``rate`` (none for a duration of 0 or less)."""
    return max(0, math.ceil(duration_s * float(rate) - 1e-9))


def split(frame: np.ndarray, parts: int) -> list[np.ndarray]:
    """A side-by-side frame ``(h, parts w, 3)`` cut into its ``parts`` images ``(h, w, 3)``, left to right."""
    width = frame.shape[1] // parts
    return [frame[:, k * width : (k + 1) * width] for k in range(parts)]


class Stopped(NamedTuple):
    """Where a file stopped giving frames before the range asked for ended."""

    path: str
    frame: int  # the rig's first frame that could not be read
    reason: str


def decode(path: str, first: int, rate: Fraction) -> Iterator[tuple[int, av.VideoFrame]]:
    """Frames ``first, first + 1, ...`` of the file's video stream as ``(frame index, frame)``
    (module docstring's convention), seeking to the key frame before ``first``; ends where the
    stream ends, or raises :class:`av.FFmpegError` where it cannot be decoded further."""
    with av.open(path) as container:
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"  # frame and slice threads: the decoder's own
        start = stream.start_time or 0
        tick = float(stream.time_base)

        def index_of(frame: av.VideoFrame) -> int:
            pts = frame.pts if frame.pts is not None else start
            return int(math.floor((pts - start) * tick * float(rate) + 0.5))

        if first > 0:  # seek a little before, to the key frame at or before the first frame
            target = start + int((first - 0.5) / float(rate) / tick)
            container.seek(max(start, target), stream=stream, backward=True)
        expected = first
        for frame in container.decode(stream):
            index = index_of(frame)
            if index < expected:
                continue
            while index > expected:  # a frame the stream skips (variable rate): show the next one in its place
                yield expected, frame
                expected += 1
            yield index, frame
            expected = index + 1


class Footage:
    """The rig's frames ``first .. first + count - 1`` (``count`` None: to the end) from ``layout``,
    decoded in a thread ahead of the caller (``ahead`` frames at most): iterate for ``(t, frames)``
    with one :class:`av.VideoFrame` per file. :attr:`stopped` says where and why the frames ended
    before ``count`` (a file's end, or a frame it cannot decode)."""

    def __init__(self, layout: Layout, first: int, count: int | None, ahead: int = 4):
        self.layout, self.first, self.count, self.ahead = layout, first, count, ahead
        self._stopped: Stopped | None = None
        self._started: tuple[Iterator, tuple[int, list[av.VideoFrame]] | None] | None = None

    def peek(self) -> tuple[int, list[av.VideoFrame]] | None:
        """The first rig frame (None: there is none), decoded by the thread that goes on decoding
        the next ones: iterating then starts with it, the decoder already ahead. :attr:`count`
        may still be set before iterating."""
        if self._started is None:
            decoded = self._decoded()
            self._started = (decoded, next(decoded, None))
        return self._started[1]

    def close(self) -> None:
        """The decoder :meth:`peek` started stopped and its files closed, if it was not read."""
        if self._started is not None:
            decoded, self._started = self._started[0], None
            decoded.close()

    @property
    def stopped(self) -> Stopped | None:
        """Where and why the frames ended before :attr:`count` (the decoder may have run on past it)."""
        stopped = self._stopped
        if stopped is None or self.count is not None and stopped.frame >= self.first + self.count:
            return None
        return stopped

    def __iter__(self) -> Iterator[tuple[int, list[av.VideoFrame]]]:
        if self._started is None:
            decoded, item = self._decoded(), None
        else:
            (decoded, item), self._started = self._started, None
        try:
            if item is not None and (self.count is None or self.count > 0):
                yield item
            for item in decoded:
                if self.count is not None and item[0] >= self.first + self.count:  # decoded before count was set
                    return
                yield item
        finally:
            decoded.close()

    def _decoded(self) -> Iterator[tuple[int, list[av.VideoFrame]]]:
        done = object()
        out: queue.Queue = queue.Queue(self.ahead)
        halt = threading.Event()

        def run() -> None:
            try:
                for item in self._frames():
                    while not halt.is_set():
                        try:
                            out.put(item, timeout=0.1)
                            break
                        except queue.Full:
                            continue
                    if halt.is_set():
                        return
            except BaseException as error:  # handed to the consumer, raised there
                out.put(error)
                return
            out.put(done)

        worker = threading.Thread(target=run, name="decode", daemon=True)
        worker.start()
        try:
            while (item := out.get()) is not done:
                if isinstance(item, BaseException):
                    raise item
                yield item
        finally:
            halt.set()
            worker.join()

    def _frames(self) -> Iterator[tuple[int, list[av.VideoFrame]]]:
        infos, offsets = self.layout.infos, self.layout.offsets
        streams = [decode(info.path, self.first + off, self.layout.rate) for info, off in zip(infos, offsets)]
        t = self.first
        while self.count is None or t < self.first + self.count:
            frames = []
            for info, stream in zip(infos, streams):
                try:
                    _, frame = next(stream)
                except StopIteration:
                    self._stopped = Stopped(info.path, t, "the stream ends")
                    return
                except av.FFmpegError as error:
                    self._stopped = Stopped(info.path, t, f"it cannot be decoded ({error})")
                    return
                frames.append(frame)
            yield t, frames
            t += 1


def rgb_images(frames: Sequence[av.VideoFrame], layout: Layout) -> list[np.ndarray]:
    """The cameras' ``(h, w, 3)`` uint8 RGB images of one rig frame (one decoded frame per file),
    each file's frame read in its colour as players read it (:mod:`learnstitch.video.colour`). In
    Hugin's form (``layout.shared``) every camera's image is the same array: read them, never write."""
    images = [to_rgb(frame) for frame in frames]
    if layout.shared:
        return images * layout.shared
    return split(images[0], layout.parts) if layout.parts > 1 else images
