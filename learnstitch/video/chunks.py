"""A clip cut into chunks of frames, each stitched on its own: the unit :mod:`learnstitch.video.batch`
hands to this machine or to a Ray cluster's actors (:mod:`learnstitch.video.cluster`).

A chunk is one of the video path's segments (:mod:`learnstitch.video.pipeline`): a function of its
own frames and the ``prime`` frames before it (the temporal filter is reset at the chunk's first
frame and run over those first), so a chunk stitched anywhere, in any order, gives the frames one
machine gives. It is written as its segment in ``out/NAME.mp4.parts/`` (under a name of its own,
renamed into place when complete) and then recorded as done (``chunk-K.json``: its frames, where the
footage stopped, its seconds), so a rerun, or a chunk run again after its worker was lost, never
writes a segment twice and skips what is done.

A clip's plan (its layout, offsets, frame count and chunks) is made once, by the caller, so every
worker stitches the same frames; the workers read the clips and write the segments through a file
system they all see (docs/learnstitch/cluster.md).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import av

import rigjax
from rigjax.errors import ConfigError

from .pipeline import VideoStitch, check_settings, clip_count, encode_segments, fingerprint
from .sink import SEGMENT_FRAMES, Encoding, Segments, replace_atomically, settings_of
from .source import VideoError, first_frame
from .sync import footage_layout

# What stops one clip and not the batch: bad input (VideoError included), a file system's error, a
# stream FFmpeg cannot read
CLIP_ERRORS = (ConfigError, OSError, av.FFmpegError)
CHUNK_FRAMES = SEGMENT_FRAMES  # a segment: Ray's cost per chunk against its stitch, docs/results/stitch_batch.md
PRIME = 4  # frames run through the temporal filter before a chunk (as stitch_video's segments)


@dataclass(frozen=True)
class Clip:
    """One clip of the rig: its file (side by side) or files (one per camera, the ``i`` lines'
    order, ``offsets`` frames into each; None: from their audio) and the MP4 it becomes."""

    videos: tuple[str, ...]
    output: str
    offsets: tuple[int, ...] | None = None


@dataclass(frozen=True)
class BatchJob:
    """What every chunk of a batch is stitched with: the rig's ``.pto`` (a path every worker
    reads), :meth:`VideoStitch.prepare`'s ``options`` (``mode``, ``width``, ``model``,
    ``time_s``, ``temporal``, ``depth_every``, ``config``, ``device``), the seconds to stitch
    (``duration``, None: to the end), the ``encoding``, the clip whose audio is kept
    (``audio``), the chunking and the ``threads`` each chunk's stitch uses (torch's, OpenCV's
    and the encoder's: a chunk's frames do not depend on the machine that stitched it)."""

    project: str
    options: dict = field(default_factory=dict)
    duration: float | None = None
    encoding: Encoding = field(default_factory=Encoding)
    audio: int | None = 0
    chunk_frames: int = CHUNK_FRAMES
    prime: int = PRIME
    threads: int = 1

    def __post_init__(self) -> None:
        """The settings checked here, once, before a clip is planned or a worker started."""
        if self.chunk_frames < 1 or self.prime < 0 or self.threads < 1:
            raise ConfigError(
                f"chunk_frames and threads must be >= 1 and prime >= 0, got {self.chunk_frames}, {self.threads}, "
                f"{self.prime}"
            )
        options = self.options
        check_settings(options.get("mode", "depth"), options.get("width"), options.get("depth_every", 1))
        model = options.get("model")
        if model not in (None, "sweep") and not Path(model).is_file():
            raise ConfigError(f"--checkpoint {model}: no such file")

    def pinned(self) -> Encoding:
        """The encoding with the encoder's threads pinned to the job's."""
        return dataclasses.replace(self.encoding, threads=self.threads)


@dataclass(frozen=True)
class Chunk:
    """Frames ``start .. end - 1`` of a clip (its chunk ``k``), written as segment ``k`` of ``folder``."""

    clip: Clip  # with its offsets found
    k: int
    start: int
    end: int
    folder: str

    @property
    def record(self) -> Path:
        return Path(self.folder) / f"chunk-{self.k:05d}.json"


@dataclass
class ClipPlan:
    """A clip's chunks and which of them are done."""

    clip: Clip
    first: int  # its first stitched frame
    count: int
    rate: Fraction
    segments: Segments
    chunks: list[Chunk]
    audio: tuple[str, float] | None  # the file whose audio is kept and the clip's start in it, seconds
    notes: list[str]
    done: dict[int, dict] = field(default_factory=dict)  # chunk -> its record

    @property
    def missing(self) -> list[Chunk]:
        return [c for c in self.chunks if c.k not in self.done]


def plan_clip(job: BatchJob, clip: Clip, project: rigjax.Project) -> ClipPlan:
    """``clip`` cut into chunks, its offsets found (from the audio where not given), its folder
    of segments prepared (a rerun of other settings is refused, naming them) and its done chunks
    read; a :class:`VideoError` naming the file where it cannot be stitched."""
    found, notes = footage_layout(project, clip.videos, clip.offsets)
    first = first_frame(float(job.options.get("time_s", 0.0)), found.rate)
    if not all(info.frames for info in found.infos):  # a container that states no length: count its packets
        found = found._replace(infos=[i._replace(frames=i.frames or _packets_in(i.path)) for i in found.infos])
    count = clip_count(found, first, job.duration)
    if not count:  # no frame in any packet
        raise VideoError(f"{found.infos[0].path}: no video frame")
    clip = Clip(clip.videos, clip.output, tuple(found.offsets))
    settings = settings_of(
        project=hashlib.sha256(Path(job.project).read_bytes()).hexdigest(),
        videos=[fingerprint(v) for v in clip.videos],
        options={k: str(v) for k, v in sorted(job.options.items())},
        offsets=list(clip.offsets),
        duration=job.duration,
        encoding=job.pinned(),
        chunk_frames=job.chunk_frames,
        prime=job.prime,
    )
    segments = Segments(parts_folder(clip.output), job.chunk_frames, settings)
    if not any(segments.folder.glob("chunk-*.json")):  # nothing done: a run of other settings (a typo) is replaced
        (segments.folder / "manifest.json").unlink(missing_ok=True)
    segments.open(resume=True)  # a batch goes on from what is done; other settings are refused
    chunks = [
        Chunk(
            clip, k, first + k * job.chunk_frames, first + min(count, (k + 1) * job.chunk_frames), str(segments.folder)
        )
        for k in range(math.ceil(count / job.chunk_frames))
    ]
    audio = None
    if job.audio is not None:
        if not 0 <= job.audio < len(found.infos):
            raise ConfigError(f"--audio: a clip's index 0..{len(found.infos) - 1}, got {job.audio}")
        info = found.infos[job.audio]
        if info.audio:
            audio = (info.path, (first + found.offsets[job.audio]) / float(found.rate))
    plan = ClipPlan(clip, first, count, found.rate, segments, chunks, audio, notes)
    for chunk in chunks:
        if chunk.record.exists():
            record = json.loads(chunk.record.read_text())
            if record["frames"] == 0 or segments.path(chunk.k).exists():
                plan.done[chunk.k] = record
    return plan


def parts_folder(output: str | os.PathLike) -> Path:
    """Where a clip's chunks are kept until its MP4 is joined (as ``stitch --video``'s segments)."""
    output = Path(output)
    return output.with_name(output.name + ".parts")


def _packets_in(path: str) -> int:
    """The video packets of ``path``: its frame count where the container states none."""
    with av.open(path) as container:
        stream = container.streams.video[0]
        return sum(1 for packet in container.demux(stream) if packet.size)


def prepare_clip(job: BatchJob, clip: Clip) -> VideoStitch:
    """The stitch of one clip's chunks (its offsets found by :func:`plan_clip`), threads pinned."""
    from ..worker import setup_worker

    setup_worker(
        opencv_threads=job.threads, torch_threads=job.threads if job.options.get("mode") != "template" else None
    )
    return VideoStitch.prepare(job.project, clip.videos, offsets=clip.offsets, **job.options)


def stitch_chunk(job: BatchJob, chunk: Chunk, stitch: VideoStitch) -> dict:
    """``chunk`` stitched by ``stitch`` (:func:`prepare_clip` of its clip), its segment renamed
    into place, then its record written: what the record says (``frames``, ``stopped``: where the
    footage ended within the chunk, ``seconds``, of which ``warmup`` before its first frame's
    stitch: :func:`~learnstitch.video.pipeline.encode_segments`)."""
    started = time.perf_counter()
    segments = Segments(Path(chunk.folder), job.chunk_frames, {})
    timing: dict[str, float] = {}
    frames, stopped = encode_segments(
        stitch, segments, chunk.start, chunk.end, job.prime, job.pinned(), lambda n: None, timing
    )
    record = {
        "frames": frames,
        "stopped": list(stopped) if stopped is not None and chunk.start + frames < chunk.end else None,
        "seconds": round(time.perf_counter() - started, 3),
        "warmup": round(timing.get("warmup", 0.0), 3),
    }
    partial = chunk.record.with_name(f"{chunk.record.name}.{uuid.uuid4().hex[:12]}.partial")
    partial.write_text(json.dumps(record))
    replace_atomically(partial, chunk.record)
    return record


Done = Callable[[ClipPlan, Chunk, dict, list[str]], None]  # a chunk's record and its set-up's notes
Failed = Callable[[ClipPlan, str], None]  # a clip that cannot be stitched, and why


def run_local(job: BatchJob, plans: list[ClipPlan], done: Done, failed: Failed) -> int:
    """Every missing chunk stitched in this process, clip by clip, in order (one set-up per clip);
    none is lost (0)."""
    for plan in plans:
        if not plan.missing:
            continue
        try:
            stitch = prepare_clip(job, plan.clip)
            for chunk in plan.missing:
                done(plan, chunk, stitch_chunk(job, chunk, stitch), stitch.notes)
        except CLIP_ERRORS as error:  # this clip cannot be stitched; the others go on
            failed(plan, str(error))
    return 0
