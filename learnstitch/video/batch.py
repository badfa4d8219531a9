"""Many clips of one rig stitched chunk by chunk (``learnstitch batch --rig rig.pto a.mp4 b.mp4 -o
out/``): every clip planned and cut into chunks (:mod:`learnstitch.video.chunks`), the chunks that
are not done yet stitched on this machine one after the other, or by a pool of Ray actors across a
cluster (:mod:`learnstitch.video.cluster`), and each clip whose chunks are all done joined in order
without re-encoding, with the audio and the spherical metadata, as ``stitch --video`` writes it. A
clip that cannot be stitched is reported and the others go on.
"""

from __future__ import annotations

import functools
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import rigjax
from rigjax.errors import ConfigError

from .chunks import CLIP_ERRORS, BatchJob, Chunk, Clip, ClipPlan, Done, Failed, parts_folder, plan_clip, run_local
from .pipeline import join_segments, stopped_warning
from .source import Stopped


@dataclass
class ClipResult:
    """What became of one clip: its file, or the error that stopped it."""

    clip: Clip
    frames: int = 0  # in the written file
    chunks: int = 0  # all of its chunks
    stitched: int = 0  # chunks this run stitched
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    error: str | None = None
    skipped: bool = False  # its MP4 was there already, written by an earlier run

    def summary(self) -> str:
        if self.error is not None:
            return f"error: {self.error}"
        if self.skipped:
            return f"{self.clip.output}: written by an earlier run, skipped (remove it to stitch the clip again)"
        lines = [*(f"{self.clip.output}: {n}" for n in self.notes), *(f"warning: {w}" for w in self.warnings)]
        done = f"{self.clip.output}: {self.frames} frames, {self.stitched} of {self.chunks} chunks stitched by this run"
        return "\n".join([*lines, done])


@dataclass
class BatchReport:
    """:func:`stitch_batch`'s clips, its wall time and where it ran."""

    clips: list[ClipResult]
    seconds: float
    where: str  # "this machine", "a local Ray cluster" or "the Ray cluster at HOST:PORT"
    frames: int = 0  # frames stitched by this run (the chunks' own, warm-up aside)
    rerun: int = 0  # chunks run again after their worker was lost
    records: list[dict] = field(default_factory=list)  # this run's chunks' records, in the order they were done

    @property
    def failed(self) -> list[ClipResult]:
        return [c for c in self.clips if c.error is not None]

    def summary(self) -> str:
        written = len(self.clips) - len(self.failed)
        fps = self.frames / self.seconds if self.seconds > 0 else 0.0
        rerun = f", {self.rerun} chunks run again after their worker was lost" if self.rerun else ""
        last = (
            f"{written} of {len(self.clips)} clips written (on {self.where}); stitched {self.frames} frames "
            f"in {self.seconds:.1f} s ({fps:.2f} fps){rerun}"
        )
        return "\n".join([*(c.summary() for c in self.clips), last])


def finish_clip(plan: ClipPlan, result: ClipResult) -> None:
    """Join a clip whose chunks are all done into its MP4 (the frames up to where its footage
    stopped, a warning naming that frame), then remove its segments."""
    segments, frames = [], 0
    for chunk in plan.chunks:
        record = plan.done[chunk.k]
        if record["frames"]:
            segments.append(plan.segments.path(chunk.k))
            frames += record["frames"]
        if record["frames"] < chunk.end - chunk.start:
            stopped = record["stopped"] or (plan.clip.videos[0], chunk.start + record["frames"], "no frame")
            result.warnings.append(stopped_warning(Stopped(*stopped), plan.rate, plan.first + frames - 1))
            break
    first = (plan.clip.videos[0], plan.first)
    join_segments(plan.segments, segments, plan.rate, Path(plan.clip.output), plan.audio, first, frames)
    result.frames = frames


def stitch_batch(
    project: str | os.PathLike,
    clips: Sequence[Clip | str | os.PathLike | Sequence[str | os.PathLike]],
    out: str | os.PathLike | None = None,
    *,
    ray: str | None = None,
    workers: int | None = None,
    cpus_per_worker: float | None = None,
    gpus_per_worker: float = 0.0,
    progress: bool = False,
    **settings,
) -> BatchReport:
    """Clips of the rig ``project`` (a ``.pto`` path) stitched into 360 videos (module
    docstring). ``clips``: each a :class:`Clip`, or a clip's path (side by side) or paths (one per
    camera), written as ``out/NAME.mp4`` (NAME the first file's stem). ``ray``: None stitches on
    this machine; ``"auto"`` joins the running Ray cluster or starts a local one; an address
    (``host:port``) joins that cluster, with ``workers`` actors (None: as many as its CPUs hold)
    of ``cpus_per_worker`` CPUs (None: the job's ``threads``) and ``gpus_per_worker`` GPUs.
    ``settings``: :class:`BatchJob`'s fields (``project`` aside). A clip that cannot be stitched
    is reported in its :class:`ClipResult` and the others go on."""
    started = time.perf_counter()
    job = BatchJob(os.fspath(project), **settings)
    if workers is not None and workers < 1:
        raise ConfigError(f"--workers must be >= 1, got {workers}")
    loaded = rigjax.load_project(job.project)
    clips = [_as_clip(c, out) for c in clips]
    outputs = [c.output for c in clips]
    if len(set(outputs)) != len(outputs):
        twice = sorted({o for o in outputs if outputs.count(o) > 1})
        raise ConfigError(f"two clips would be written to {twice[0]}: give them other names (a list file's output)")
    if ray is None:
        return _stitch_batch(job, loaded, clips, "this machine", run_local, started, progress)
    from . import cluster

    where = cluster.connect(ray)  # first: an address nobody answers at is refused before any work
    try:
        run = functools.partial(
            cluster.run_on_ray, workers=workers, cpus_per_worker=cpus_per_worker, gpus_per_worker=gpus_per_worker
        )
        return _stitch_batch(job, loaded, clips, where, run, started, progress)
    finally:
        cluster.disconnect()


def _stitch_batch(
    job: BatchJob,
    project: rigjax.Project,
    clips: list[Clip],
    where: str,
    run: Callable[[BatchJob, list[ClipPlan], Done, Failed], int],
    started: float,
    progress: bool,
) -> BatchReport:
    """:func:`stitch_batch` once connected: plan every clip, ``run`` their missing chunks, join."""
    from tqdm import tqdm

    results = {c.output: ClipResult(c) for c in clips}
    plans: list[ClipPlan] = []
    for clip in clips:
        result = results[clip.output]
        if Path(clip.output).exists() and not parts_folder(clip.output).exists():
            result.skipped = True
            continue
        try:
            plan = plan_clip(job, clip, project)
        except CLIP_ERRORS as error:  # this clip cannot be stitched; the others go on
            result.error = str(error)
            continue
        result.chunks, result.notes = len(plan.chunks), plan.notes
        plans.append(plan)
    total = sum(c.end - c.start for plan in plans for c in plan.missing)
    bar = tqdm(total=total, unit="frame", desc=f"{len(plans)} clips", disable=not progress)
    records: list[dict] = []

    def done(plan: ClipPlan, chunk: Chunk, record: dict, notes: list[str]) -> None:
        plan.done[chunk.k] = record
        records.append({"clip": plan.clip.output, "chunk": chunk.k, **record})
        result = results[plan.clip.output]
        result.stitched += 1
        result.notes.extend(n for n in notes if n not in result.notes)
        bar.update(chunk.end - chunk.start)

    def failed(plan: ClipPlan, error: str) -> None:
        results[plan.clip.output].error = error

    try:
        rerun = run(job, plans, done, failed)
    finally:
        bar.close()
    for plan in plans:
        result = results[plan.clip.output]
        if result.error is None:
            try:
                finish_clip(plan, result)
            except CLIP_ERRORS as error:
                result.error = str(error)
    frames = sum(r["frames"] for r in records)
    return BatchReport(list(results.values()), time.perf_counter() - started, where, frames, rerun, records)


def read_clip_list(path: str | os.PathLike, out: str | os.PathLike) -> list[Clip]:
    """The clips of a list file (``learnstitch batch --list``): a line each, its file (side by
    side) or files (one per camera, the ``i`` lines' order, relative to the list's folder), then
    optionally ``offsets=K,K,..`` (frames; default from the audio) and ``out=NAME.mp4`` (default
    the first file's stem); blank lines and ``#`` comments skipped. A line it cannot read is a
    :class:`ConfigError` naming the file and the line."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as error:
        raise ConfigError(f"{path}: cannot read the clip list ({error.strerror})") from None
    clips = []
    for number, line in enumerate(text.splitlines(), 1):
        words = line.split("#", 1)[0].split()
        if not words:
            continue
        videos, offsets, name = [], None, None
        for word in words:
            key, _, value = word.partition("=")
            try:
                if key == "offsets" and value:
                    offsets = tuple(int(v) for v in value.split(","))
                elif key == "out" and value:
                    name = value
                elif "=" in word:
                    raise ValueError(f"unknown key {key!r} (offsets=, out=)")
                else:
                    videos.append(os.fspath(path.parent / word))
            except ValueError as error:
                raise ConfigError(f"{path}, line {number}: {word}: {error}") from None
        if not videos:
            raise ConfigError(f"{path}, line {number}: no clip on the line, only {' '.join(words)}")
        output = os.path.join(os.fspath(out), name or Path(videos[0]).stem + ".mp4")
        clips.append(Clip(tuple(videos), output, offsets))
    return clips


def _as_clip(clip, out: str | os.PathLike | None) -> Clip:
    if isinstance(clip, Clip):
        return clip
    videos = (os.fspath(clip),) if isinstance(clip, (str, os.PathLike)) else tuple(os.fspath(v) for v in clip)
    if out is None:
        raise ConfigError("give the folder the clips are written to (-o out/)")
    return Clip(videos, os.path.join(os.fspath(out), Path(videos[0]).stem + ".mp4"))
