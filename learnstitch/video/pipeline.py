"""A rig's clip stitched into a 360 video: decode, stitch and encode overlapped, memory flat in the
clip's length (``learnstitch stitch --rig rig.pto --video clip.mp4 -o pano.mp4``).

:class:`VideoStitch` is the part that depends on the rig and the footage, made once: the layout
of the files (:mod:`learnstitch.video.source`), and either the template remap
(:mod:`learnstitch.video.template`, ``mode="template"``) or the full-resolution stitcher with its
depth source (:func:`learnstitch.inference.prepare_project`, ``mode="depth"``), its working depth
filtered over time (:mod:`learnstitch.video.temporal`). :func:`video_panoramas` yields the stitched
frames to a caller that keeps them; :func:`stitch_video` encodes them in segments
(:mod:`learnstitch.video.sink`) and joins them into one file with the source's audio and the
spherical metadata. The decoder runs in a thread ahead of the stitch and the encoder in one behind
it; both hold a few frames at most. In the depth-aware mode the render runs in a thread between
them: frame ``t`` renders while frame ``t + 1`` is measured (its depth and colour correction).

The temporal state (the previous frame's depth and colour correction) restarts at every segment's
first frame, after ``prime`` frames before it have been run through the filter, so a segment is a
function of the frames from ``prime`` before it to its end: a resumed run, or a segment stitched
on another machine, gives the frames an uninterrupted run gives.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from fractions import Fraction
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import av
import cv2
import numpy as np

import rigjax
from rigjax.errors import ConfigError

from ..fullres.config import RenderConfig
from .colour import Colour, colour_of, from_rgb, panorama_colour, to_rgb
from .sink import SEGMENT_FRAMES, AudioSource, Encoding, Segments, SegmentWriter, join, settings_of
from .source import Footage, Layout, Stopped, VideoError, first_frame, frames_in, rgb_images
from .stabilise import SIGMA_S, Steady, check_seconds, output_turns
from .sync import footage_layout
from .template import Template, prepare_template

if TYPE_CHECKING:  # the depth-aware mode's modules (torch, JAX) load when it is asked for
    import torch

    from ..fullres.depth import Depth
    from ..fullres.render import Photometry
    from ..fullres.stitcher import Frame, Stitcher
    from .temporal import TemporalDepth, TemporalPhotometry
    from .turns import Turns

    Measured = tuple[Frame, Depth, Photometry | None]  # Stitcher.measure's result: what a render needs

MODES = ("depth", "template")

# A video's render settings unless it is given its own: the defaults, the depth refined to a
# quarter of the output's width (512 for a 2048-wide video; stills: half): the finest level is most
# of the refinement's cost, which a video pays every frame (docs/design/video.md measures both).
VIDEO_RENDER = RenderConfig(refine_scale=0.25)


class VideoStitch:
    """A rig's footage prepared for stitching, frame by frame (module docstring). Build it with
    :meth:`prepare`; ``video_stitch(frames)`` stitches one rig frame (one decoded frame per file)
    into an output :class:`av.VideoFrame`."""

    def __init__(self, layout: Layout, mode: str, width: int, notes: list[str]):
        self.layout, self.mode, self.width, self.notes = layout, mode, width, notes
        self.template: Template | None = None
        self.stitcher: Stitcher | None = None
        self.temporal: TemporalDepth | None = None
        self.photometry: TemporalPhotometry | None = None
        self.depth_every = 1  # a key frame, whose depth and colour correction are estimated, every this many
        self._since_key, self._held = 0, None  # frames since the reset; the last key frame's colour correction
        self.first = 0  # the clip's first stitched frame
        self.colour: Colour | None = None  # the panoramas' (:mod:`learnstitch.video.colour`), from the first file's
        self.project: rigjax.Project | None = None
        self.steady: Steady | None = None  # --stabilise (:meth:`stabilise`)
        self.opened: Footage | None = None  # decoding from the first frame on (:meth:`footage`)

    @classmethod
    def prepare(
        cls,
        project: rigjax.Project | str | os.PathLike,
        videos: Sequence[str | os.PathLike],
        *,
        mode: str = "depth",
        width: int | None = None,
        model: str | Path | None = None,
        offsets: Sequence[int] | None = None,
        time_s: float = 0.0,
        temporal: bool = True,
        depth_every: int = 1,
        config: RenderConfig | None = None,
        device: str | torch.device = "cpu",
        template_cache: bool | str | os.PathLike = True,
        keep_decoding: bool = False,
    ) -> VideoStitch:
        """``project``'s rig (a ``.pto`` as ``rigjax calibrate`` writes it) over the clips
        ``videos`` (one side-by-side clip, or one per camera in the ``i`` lines' order, ``offsets``
        frames into each; None: found from their audio where each has some, else 0), ``mode``
        ``"depth"`` (``model``: the depth source, as for stills: None the shipped network,
        ``"sweep"``, or a checkpoint) or ``"template"``, into panoramas ``width`` wide (default the
        ``p`` line's), from the frame on screen at ``time_s`` seconds (:attr:`first`; the rig's
        image circles are measured on it). With ``temporal``, the depth and colour correction are
        filtered over time (:mod:`learnstitch.video.temporal`), and estimated on every
        ``depth_every``-th frame only (key frames; between them the depth is carried through the
        camera's turn and the colour correction held). ``template_cache``: where the template
        mode keeps its maps for the next clip of the rig (True: :func:`~learnstitch.video.template.default_cache`;
        False: nowhere). ``keep_decoding``: the decoder that read the first frame runs on, ahead of
        :meth:`footage` from that frame (:meth:`close` stops it where no footage reads it)."""
        if not isinstance(project, rigjax.Project):
            project = rigjax.load_project(project)
        width = int(width or project.panorama.width)
        check_settings(mode, width, depth_every)
        found_layout, notes = footage_layout(project, videos, offsets)
        stitch = cls(found_layout, mode, width, notes)
        stitch.project = project
        stitch.first = first_frame(time_s, found_layout.rate)
        frames = stitch.first_frames(stitch.first, keep_decoding)
        try:
            images = rgb_images(frames, found_layout)
            stitch.colour = panorama_colour(colour_of(frames[0]))
            config = config or VIDEO_RENDER
            if mode == "template":
                stitch.template, cached = prepare_template(
                    project, images, width, config.table_scale, template_cache, shared=bool(found_layout.shared)
                )
                notes.append(
                    "template stitch: a fixed remap through the calibration, no depth"
                    + (" (its maps from the cache)" if cached else "")
                )
            else:
                from ..inference import prepare_project
                from .temporal import TemporalDepth, TemporalPhotometry

                prepared = prepare_project(project, width, model, images=images, config=config, device=device)
                stitch.stitcher = prepared.stitcher
                notes.extend(prepared.notes)
                if temporal:
                    stitch.photometry = TemporalPhotometry()
                    stitch.stitcher.photometry_filter = stitch.photometry
                    stitch.depth_every = depth_every
                    if prepared.rig.has_centres:
                        stitch.temporal = TemporalDepth(prepared.stitcher.depth, prepared.stitcher.tables)
                        stitch.stitcher.depth = stitch.temporal
                        stitch.stitcher.depth_filter = stitch.temporal.refined
        except BaseException:  # the decoder stopped, its files closed
            stitch.close()
            raise
        return stitch

    @property
    def rate(self) -> Fraction:
        return self.layout.rate

    def stabilise(self, turns: bool | str | os.PathLike | Turns, count: int | None, sigma_s: float = SIGMA_S) -> None:
        """Turn every panorama from here on as :mod:`learnstitch.video.stabilise` says, by
        ``turns``: True measures them on the ``count`` frames from :attr:`first` (None: to the
        end; :func:`~learnstitch.video.turns.footage_turns`), a path reads them
        (``learnstitch turns``' CSV), or a :class:`~learnstitch.video.turns.Turns`."""
        from .turns import footage_turns, read_turns

        check_seconds(sigma_s)
        end = None if count is None else self.first + count
        if turns is True:
            started = time.perf_counter()
            turns = footage_turns(self.project, self.layout, self.first, count)
            end = int(turns.frames[-1]) + 1  # where the footage stopped decoding, if before
            lost = int(turns.lost.sum())
            self.notes.append(
                f"stabilised: the turns of {len(turns.frames)} frames measured in {time.perf_counter() - started:.1f} s"
                + (f" ({lost} frames lost: each kept the turn before)" if lost else "")
            )
        elif isinstance(turns, (str, os.PathLike)):
            turns = read_turns(turns)
        end = int(turns.frames[-1]) + 1 if end is None else end  # a clip of unknown length: what they cover
        missing = sorted(set(range(self.first, end)) - set(int(t) for t in turns.frames))
        if missing:
            raise VideoError(
                f"--stabilise: the turns have no frame {missing[0]} ({len(missing)} frames of "
                f"{self.first}-{end - 1} missing; they cover {turns.frames[0]}-{turns.frames[-1]}): measure "
                "them over the stitched range (learnstitch turns --time, --duration)"
            )
        self.steady = Steady(output_turns(turns, float(self.rate), sigma_s), self.colour)

    def steadied(self, t: int, pano):
        """Frame ``t``'s panorama (RGB or a frame) as --stabilise turns it; itself without."""
        return pano if self.steady is None else self.steady(t, pano)

    def first_frames(self, first: int, keep: bool = False) -> list[av.VideoFrame]:
        """The decoded frames of rig frame ``first``: a :class:`VideoError` if there is none. With
        ``keep`` the decoder goes on from there, ahead of :meth:`footage` (:meth:`close` stops it)."""
        footage = Footage(self.layout, first, None if keep else 1)
        item = footage.peek()
        if keep and item is not None:
            self.opened = footage
            return item[1]
        footage.close()
        if item is not None:
            return item[1]
        info = self.layout.infos[0]
        raise VideoError(
            f"{info.path}: no frame at {first / float(self.rate):.3f} s (frame {first}; the clip has "
            f"{info.frames} frames, {info.frames / float(self.rate):.3f} s)"
        )

    @property
    def filtered(self) -> bool:
        """Whether frames depend on the frames before them (the temporal filter)."""
        return self.temporal is not None or self.photometry is not None

    def reset(self) -> None:
        """Forget the temporal state: the next frame is stitched as if it were the clip's first."""
        for state in (self.temporal, self.photometry):
            if state is not None:
                state.reset()
        self._since_key, self._held = 0, None

    def prime(self, frames: Sequence[av.VideoFrame]) -> None:
        """Run one rig frame through the temporal filter without rendering it."""
        if self.filtered:
            self.measure(frames)

    def measure(self, frames: Sequence[av.VideoFrame]) -> Measured:
        """What the depth-aware render of one rig frame needs (:meth:`Stitcher.measure`): its
        images, its working depth (filtered over time) and its colour correction. On a key frame
        both are estimated and the colour correction held; between key frames the depth filter is
        told not to estimate and the held correction is used. Call it for every frame in order."""
        key = self._since_key % self.depth_every == 0
        if self.temporal is not None:
            self.temporal.estimate = key
        held = None if key else self._held
        measured = self.stitcher.measure(rgb_images(frames, self.layout), photometry=held)
        if self.stitcher.config.photometry == "fitted":
            self._held = measured[2]
        self._since_key += 1
        return measured

    def render(self, measured: Measured) -> np.ndarray:
        """The ``(H, W, 3)`` uint8 RGB panorama of a measured frame (:meth:`measure`'s result); it
        may run while the next frame is measured."""
        return self.stitcher.render(*measured).pano

    def __call__(self, frames: Sequence[av.VideoFrame]) -> av.VideoFrame:
        """The panorama of one rig frame as a 4:2:0 frame in :attr:`colour`, tagged."""
        if self.template is not None:
            return self.template(frames, self.colour)
        return from_rgb(self.panorama(frames), self.colour)

    def panorama(self, frames: Sequence[av.VideoFrame]) -> np.ndarray:
        """The ``(H, W, 3)`` uint8 RGB panorama of one rig frame."""
        if self.template is not None:
            return to_rgb(self.template(frames, self.colour), self.colour)
        return self.render(self.measure(frames))

    def footage(self, first: int, count: int | None) -> Footage:
        """The rig's frames ``first .. first + count - 1`` (None: to the end): the footage
        :meth:`first_frames` left decoding where it starts there (once), else a new one."""
        opened, self.opened = self.opened, None
        if opened is not None and opened.first == first:
            opened.count = count
            return opened
        if opened is not None:
            opened.close()
        return Footage(self.layout, first, count)

    def close(self) -> None:
        """The decoder :meth:`prepare` left running (``keep_decoding``) stopped, if no footage read it."""
        if self.opened is not None:
            self.opened.close()
            self.opened = None

    def count(self, duration: float | None) -> int | None:
        """Frames from :attr:`first` to the end of ``duration`` seconds or of the shortest file
        (:func:`clip_count`)."""
        return clip_count(self.layout, self.first, duration)


def check_settings(mode: str, width: int | None, depth_every: int) -> None:
    """:meth:`VideoStitch.prepare`'s own settings checked (``width`` None: the project's, later)."""
    if depth_every < 1:
        raise ConfigError(f"depth_every must be >= 1, got {depth_every}")
    if mode not in MODES:
        raise ConfigError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    if width is not None and (width < 16 or width % 4):
        raise ConfigError(f"--width must be a multiple of 4 and >= 16 (4:2:0 video of a 2:1 panorama), got {width}")


def clip_count(layout: Layout, first: int, duration: float | None) -> int | None:
    """The rig's frames from ``first`` to the end of ``duration`` seconds (None: no limit) or of
    the shortest file (None: the files do not say): a :class:`VideoError` when there are none."""
    rate = float(layout.rate)
    available = [info.frames - off - first for info, off in zip(layout.infos, layout.offsets)]
    known = [a for a, info in zip(available, layout.infos) if info.frames]
    count = min(known) if known else None
    if duration is not None:
        wanted = frames_in(duration, layout.rate)
        count = wanted if count is None else min(count, wanted)
    if count is not None and count <= 0:
        info = layout.infos[0]
        raise VideoError(
            f"{info.path}: no frame from {first / rate:.3f} s"
            + (f" for {duration} s" if duration is not None else "")
            + f" (the clip has {info.frames} frames, {info.frames / rate:.3f} s)"
        )
    return count


def video_panoramas(
    project: rigjax.Project | str | os.PathLike,
    videos: Sequence[str | os.PathLike],
    *,
    duration: float | None = None,
    stabilise: bool | str | os.PathLike | Turns = False,
    stabilise_seconds: float = SIGMA_S,
    **options,
) -> Iterator[tuple[int, np.ndarray]]:
    """The stitched frames of a clip as ``(frame index, (H, W, 3) uint8 RGB)`` for ``duration``
    seconds (None: to the end); ``options``: :meth:`VideoStitch.prepare`'s (``time_s`` the start);
    ``stabilise``: :meth:`VideoStitch.stabilise`'s turns (False: none), the heading smoothed over
    ``stabilise_seconds``. One frame is kept at a time; the temporal filter runs on from frame to frame."""
    check_seconds(stabilise_seconds)
    with contextlib.closing(VideoStitch.prepare(project, videos, keep_decoding=True, **options)) as stitch:
        count = stitch.count(duration)
        if stabilise:
            stitch.stabilise(stabilise, count, stabilise_seconds)
        for t, frames in stitch.footage(stitch.first, count):
            yield t, stitch.steadied(t, stitch.panorama(frames))


class VideoReport(NamedTuple):
    """What :func:`stitch_video` wrote."""

    output: Path
    frames: int  # frames in the written file
    stitched: int  # frames this run stitched (fewer after a resume)
    seconds: float  # this run's wall time, preparation and join included
    rate: Fraction
    size: tuple[int, int]  # width, height
    audio: bool  # whether the file has the source's audio
    notes: list[str]
    warnings: list[str]

    @property
    def fps(self) -> float:
        """Frames stitched a second, over the whole run."""
        return self.stitched / self.seconds if self.seconds > 0 else 0.0

    def summary(self) -> str:
        """What ``learnstitch stitch --video`` prints: its notes, warnings and a last line."""
        width, height = self.size
        audio = "with the source's audio" if self.audio else "no audio"
        done = (
            f"{self.output}: {self.frames} frames {width} x {height} at {float(self.rate):.3f} fps, {audio}, 360 "
            f"metadata; stitched {self.stitched} frames in {self.seconds:.1f} s ({self.fps:.2f} fps)"
        )
        return "\n".join([*self.notes, *(f"warning: {w}" for w in self.warnings), done])


def fingerprint(path: str | os.PathLike) -> dict:
    stat = os.stat(path)
    return {"path": os.path.abspath(path), "bytes": stat.st_size, "modified": int(stat.st_mtime)}


def stitch_video(
    project: rigjax.Project | str | os.PathLike,
    videos: Sequence[str | os.PathLike],
    output: str | os.PathLike,
    *,
    duration: float | None = None,
    encoding: Encoding | None = None,
    audio: int | None = 0,
    segment_frames: int = SEGMENT_FRAMES,
    resume: bool = False,
    prime: int = 4,
    progress: bool = False,
    stabilise: bool | str | os.PathLike | Turns = False,
    stabilise_seconds: float = SIGMA_S,
    **options,
) -> VideoReport:
    """A clip stitched into the 360 video ``output`` (MP4; module docstring): ``videos`` through
    ``project``, ``options`` :meth:`VideoStitch.prepare`'s (``mode``, ``width``, ``model``,
    ``offsets``, ``time_s``, ``temporal``, ``config``, ``device``), ``duration`` seconds (None: to
    the end), encoded with ``encoding`` (default :class:`~learnstitch.video.sink.Encoding`),
    the audio of clip ``audio`` (None: none) copied. Written in segments of ``segment_frames``
    frames in ``output.parts/``; ``resume`` continues a run of the same settings killed midway.
    ``prime``: frames before each segment the temporal filter is run over. ``progress``: a bar
    on stderr. ``stabilise``, ``stabilise_seconds``: as :func:`video_panoramas`'."""
    from tqdm import tqdm

    started = time.perf_counter()
    check_seconds(stabilise_seconds)
    encoding = encoding or Encoding()
    if segment_frames < 1 or prime < 0:
        raise ConfigError(f"segment_frames must be >= 1 and prime >= 0, got {segment_frames}, {prime}")
    output = Path(output)
    if output.suffix.lower() not in (".mp4", ".mov", ".m4v"):
        raise ConfigError(f"{output}: the 360 video is written as MP4 (.mp4, .mov or .m4v), not {output.suffix!r}")
    # the decoder that reads the first frame runs on into the stitch; closed here if it does not
    with contextlib.closing(VideoStitch.prepare(project, videos, keep_decoding=True, **options)) as stitch:
        if audio is not None and not 0 <= audio < len(stitch.layout.infos):
            raise ConfigError(f"--audio: a clip's index 0..{len(stitch.layout.infos) - 1}, got {audio}")
        count = stitch.count(duration)
        project_path = project.path if isinstance(project, rigjax.Project) else os.fspath(project)
        settings = settings_of(
            project=hashlib.sha256(Path(project_path).read_bytes()).hexdigest() if project_path else None,
            videos=[fingerprint(v) for v in videos],
            options={k: str(v) for k, v in sorted(options.items())},
            offsets=stitch.layout.offsets,
            colour=list(stitch.colour),
            duration=duration,
            encoding=encoding,
            segment_frames=segment_frames,
            prime=prime,
            **({"stabilise": [_turns_source(stabilise), stabilise_seconds]} if stabilise else {}),  # older runs resume
        )
        segments = Segments(output.with_name(output.name + ".parts"), segment_frames, settings)
        done = segments.open(resume)
        if stabilise:  # after the settings are checked: measuring the turns reads the whole clip
            stitch.stabilise(stabilise, count, stabilise_seconds)
        rate, first = stitch.rate, stitch.first
        start = first + done * segment_frames
        warnings: list[str] = []
        stitched = 0
        end = None if count is None else first + count
        if end is None or start < end:
            bar = tqdm(total=count, initial=start - first, unit="frame", desc=output.name, disable=not progress)
            try:
                stitched, stopped = encode_segments(stitch, segments, start, end, prime, encoding, bar.update)
            finally:
                bar.close()
            reached = start + stitched
            if stopped is not None and (
                end is None and stopped.reason != "the stream ends" or end is not None and reached < end
            ):
                warnings.append(stopped_warning(stopped, rate, reached - 1))
    source = stitch.layout.infos[audio] if audio is not None and stitch.layout.infos[audio].audio else None
    sound = None if source is None else (source.path, (first + stitch.layout.offsets[audio]) / float(rate))
    frames = join_segments(segments, segments.complete(), rate, output, sound, (stitch.layout.infos[0].path, first))
    size = (stitch.width, stitch.width // 2)
    return VideoReport(
        output, frames, stitched, time.perf_counter() - started, rate, size, sound is not None, stitch.notes, warnings
    )


def stopped_warning(stopped: Stopped, rate: Fraction, last: int) -> str:
    """The warning of a clip whose footage stopped before its range ended, its video ending at frame ``last``."""
    return (
        f"{stopped.path}: frame {stopped.frame} ({stopped.frame / float(rate):.3f} s): {stopped.reason}; "
        f"the video ends at frame {last}"
    )


def join_segments(
    segments: Segments,
    complete: list[Path],
    rate: Fraction,
    output: Path,
    audio: tuple[str, float] | None,
    first: tuple[str, int],
    expected: int | None = None,
) -> int:
    """A clip's ``complete`` segments (in order, each ``segments.segment_frames`` long but the
    last) joined into ``output`` with the audio of file ``audio[0]`` from ``audio[1]`` seconds
    over the frames joined (None: none), then their folder removed; returns the frames.
    ``first``: the clip's first file and frame, named where no frame could be decoded;
    ``expected``: the frames the segments must hold (their records'), checked before the join."""
    if not complete:
        raise VideoError(f"{first[0]}: no frame could be decoded from frame {first[1]}")
    frames = frames_in_segments(complete)
    if expected is not None and frames != expected:
        raise VideoError(f"{segments.folder}: the segments hold {frames} frames, their records {expected}")
    kept = None if audio is None else AudioSource(audio[0], audio[1], frames / float(rate))
    join(complete, [Fraction(k * segments.segment_frames) / rate for k in range(len(complete))], output, kept)
    shutil.rmtree(segments.folder)
    return frames


def encode_segments(
    stitch: VideoStitch,
    segments: Segments,
    start: int,
    end: int | None,
    prime: int,
    encoding: Encoding,
    advance: Callable[[int], object],
    timing: dict[str, float] | None = None,
) -> tuple[int, Stopped | None]:
    """Rig frames ``start .. end - 1`` (None: to the end) stitched and encoded, segment by segment,
    the encoder in a thread behind the stitch (and in the depth-aware mode, the render in a thread
    between them: frame ``t`` renders while frame ``t + 1`` is measured, each on half of torch's
    threads); the temporal filter reset
    at each segment's first frame and primed on the ``prime`` frames before it. Returns the frames
    stitched and where the footage stopped (:attr:`Footage.stopped`). ``timing`` gets
    ``"warmup"``: the seconds before the first frame's stitch began (the decoders opened and seeked,
    the frames before ``start`` decoded and run through the filter)."""
    entered = time.perf_counter()
    first, rate = stitch.first, stitch.rate
    begin = max(first, start - (prime if stitch.filtered else 0))  # the frames before start prime the filter
    footage = stitch.footage(begin, None if end is None else end - begin)
    recent: deque = deque(maxlen=prime)
    writer: SegmentWriter | None = None
    pending: deque[Future] = deque()
    rendering: Future | None = None
    stitched = 0
    with (
        ThreadPoolExecutor(1, thread_name_prefix="encode") as encoder,
        _render_pool(stitch.template is None) as renderer,
        _measure_threads() if stitch.template is None else _remap_threads(),
    ):
        try:
            for t, frames in footage:
                if t >= start and (t - first) % segments.segment_frames == 0:
                    if writer is not None:
                        pending.append(encoder.submit(writer.close))
                    k = (t - first) // segments.segment_frames
                    writer = SegmentWriter(
                        segments.path(k), t - first, stitch.width, stitch.width // 2, rate, encoding, stitch.colour
                    )
                    stitch.reset()
                    for earlier in recent:
                        stitch.prime(earlier)
                    if timing is not None:
                        timing.setdefault("warmup", time.perf_counter() - entered)
                if t >= start:
                    if stitch.template is not None:
                        panorama = stitch.template(frames, stitch.colour)
                        pending.append(encoder.submit(_write_steadied, writer, stitch, t, panorama))
                    else:  # the render and the encoder each a thread behind, in order (one worker each)
                        measured = stitch.measure(frames)  # while the previous frame renders
                        if rendering is not None:  # two measured frames at most: that one and this one
                            rendering.result()
                        rendering = renderer.submit(stitch.render, measured)
                        pending.append(encoder.submit(_write_rendered, writer, stitch, t, rendering))
                    while len(pending) > 3:  # a few frames in flight: memory flat in the clip's length
                        pending.popleft().result()
                    stitched += 1
                    advance(1)
                recent.append(frames)
            if writer is not None:
                pending.append(encoder.submit(writer.close))
            while pending:
                pending.popleft().result()
        except BaseException:
            for future in pending:
                future.cancel()
            if writer is not None:
                encoder.submit(writer.abandon).result()
            raise
    return stitched, footage.stopped


def _render_pool(depth_aware: bool) -> ThreadPoolExecutor:
    """The render's thread; in the depth-aware mode with half of torch's threads (rounded down),
    set in the thread itself: torch's width is each thread's own."""
    if not depth_aware:
        return ThreadPoolExecutor(1, thread_name_prefix="render")
    import torch

    half = max(1, torch.get_num_threads() // 2)
    return ThreadPoolExecutor(1, thread_name_prefix="render", initializer=torch.set_num_threads, initargs=(half,))


def _measure_threads() -> contextlib.AbstractContextManager:
    """The calling thread, which measures while the render runs beside it, on the other half of
    torch's threads (rounded up): the two at full width oversubscribe the cores."""
    import torch

    return _threads(torch.get_num_threads, torch.set_num_threads, lambda n: max(1, n - n // 2))


def _remap_threads() -> contextlib.AbstractContextManager:
    """The template's remaps (and ``--stabilise``'s turn on the encoder's thread) on half of
    OpenCV's threads (rounded down, at least one: one on two cores): the decoder's and the encoder's
    threads keep the cores busy, and a remap split over every core only adds its pool's hand-offs
    (CHANGELOG). OpenCV's count is the process's: one clip is stitched at a time."""
    return _threads(cv2.getNumThreads, cv2.setNumThreads, lambda n: max(1, n // 2))


@contextlib.contextmanager
def _threads(get: Callable[[], int], put: Callable[[int], object], narrowed: Callable[[int], int]) -> Iterator[None]:
    """A library's thread count narrowed for the block, put back after."""
    threads = get()
    put(narrowed(threads))
    try:
        yield
    finally:
        put(threads)


def _turns_source(turns) -> object:
    """How --stabilise's turns came, for a resume's settings."""
    if turns is True:
        return "measured"
    if isinstance(turns, (str, os.PathLike)):
        return fingerprint(turns)
    return hashlib.sha256(np.ascontiguousarray(turns.rotations).tobytes()).hexdigest()


def _write_steadied(writer: SegmentWriter, stitch: VideoStitch, t: int, panorama) -> None:
    writer.write(stitch.steadied(t, panorama))


def _write_rendered(writer: SegmentWriter, stitch: VideoStitch, t: int, rendered: Future) -> None:
    _write_steadied(writer, stitch, t, rendered.result())


def frames_in_segments(segments: list[Path]) -> int:
    total = 0
    for path in segments:
        with av.open(str(path)) as container:
            total += container.streams.video[0].frames
    return total
