"""``rigjax calibrate`` as a function: a :class:`CalibrateJob` in, a :class:`CalibrateOutcome` out.

The command line parses its arguments into a job, calls :func:`calibrate_job` and prints the
outcome's lines; a batch runner calls the same function in a worker process (set up once with
:func:`rigjax.worker.setup_worker`). The job reads the images or the videos' frames, calibrates
them (:func:`rigjax.calibration.pipeline.calibrate_frames`), and writes the project, the frames or
side-by-side halves it names beside it, and the panorama if asked.

Refusal: when the checks find a parameter the matches do not determine
(``Calibration.undetermined``), nothing is written and the status is 3, unless
``keep_undetermined``: then the project is written with a ``#-rigjax undetermined`` comment per
parameter, and the status is still 3. A last solve that did not converge also ends in status 3.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..errors import EXIT_UNRELIABLE, RigjaxError
from ..outputs import check_output
from ..pto.project import load_project
from ..rendering.blend import render
from ..rendering.images import read_image, read_video_frames, write_image
from .motion import MotionConfig
from .pipeline import Calibration, calibrate_frames, frames_of
from .start import start_sizes, with_start
from .template import load_template


class JobError(RigjaxError):
    """A job whose inputs do not go together (images and videos, ``every`` without videos)."""


@dataclass(frozen=True)
class CalibrateJob:
    """What ``rigjax calibrate`` is asked to do; each field is the option of the same name.

    ``images``: one image per camera (or per two side by side), several frames one after another;
    or ``videos``: one per camera, read at ``time`` seconds, and with ``every``, every ``every``-th
    frame from there on, at most ``frames`` of them. ``render``: also write the panorama there,
    ``width`` pixels wide (default the template's), blended by ``blend``. ``motion``: calibrate the
    lenses from the camera's own motion over the frames (the template's ``motion`` section, or
    :class:`~rigjax.calibration.motion.MotionConfig`'s defaults where it has none). ``start``: a
    project of this camera made before (Hugin's form of a side-by-side template included) whose
    lenses, orientations and crops the calibration starts from
    (:func:`~rigjax.calibration.start.with_start`).
    """

    template: str | os.PathLike[str]
    output: str | os.PathLike[str]
    images: tuple[str, ...] = ()
    videos: tuple[str, ...] = ()
    time: float = 0.0
    every: int | None = None
    frames: int = 5
    render: str | None = None
    width: int | None = None
    blend: str = "multiband"
    seed: int = 0
    keep_undetermined: bool = False
    motion: bool = False  # the template's motion section, or its defaults where it has none
    start: str | os.PathLike[str] | None = None  # a project whose cameras the calibration starts from

    def check_outputs(self) -> None:
        """Raise :class:`~rigjax.outputs.OutputError` unless every output path can be written."""
        check_output(self.output)
        if self.render:
            check_output(self.render, image=True, what="--render")


class Line(NamedTuple):
    """A line for the user: on standard output, or on standard error when ``error``."""

    text: str
    error: bool = False


@dataclass(frozen=True, eq=False)
class CalibrateOutcome:
    """What :func:`calibrate_job` did.

    ``calibration``: what the images gave; ``status``: the command's exit status (0, or 3: refused,
    written with undetermined parameters, or a last solve that did not converge); ``refusal``: why
    the project was not written (the undetermined parameters, ``"; "``-joined), None when it was;
    ``written``: the files written, in order; ``lines``: what the command prints, in order.
    """

    calibration: Calibration
    status: int
    refusal: str | None
    written: tuple[str, ...]
    lines: tuple[Line, ...]


def video_frame_names(videos: Sequence[str], time: float, every: int, count: int) -> list[str]:
    """Names of ``count`` frames of each video, frame by frame (the first frame of each video, the
    second ...): ``STEM_Ts.png`` for the frame at ``time`` seconds, ``STEM_Ts+N.png`` for the one
    ``N`` frames later."""
    stems = [os.path.splitext(os.path.basename(v))[0] for v in videos]
    return [
        f"{stem}_{time:g}s+{f * every}.png" if f else f"{stem}_{time:g}s.png" for f in range(count) for stem in stems
    ]


def read_inputs(job: CalibrateJob) -> tuple[list[np.ndarray], list[str]]:
    """The job's images and their names: the image files', or the videos' frames
    (:func:`video_frame_names`), frame by frame."""
    if job.every is not None and not job.videos:
        raise JobError("--every reads frames of --video files; give images as frames one after another")
    if job.videos:
        if job.images:
            raise JobError("give images or --video files, not both")
        every, count = (job.every, job.frames) if job.every else (1, 1)
        clips = [read_video_frames(v, every, count, job.time) for v in job.videos]
        length = min(len(clip) for clip in clips)
        images = [clip[f] for f in range(length) for clip in clips]
        return images, video_frame_names(job.videos, job.time, every, length)
    if job.images:
        return [read_image(p) for p in job.images], [os.path.basename(p) for p in job.images]
    raise JobError("give one image per camera, or --video files")


def calibrate_job(
    job: CalibrateJob,
    *,
    progress: Callable[[str], None] | None = None,
    emit: Callable[[Line], None] | None = None,
) -> CalibrateOutcome:
    """Do what ``rigjax calibrate`` does for ``job`` and say what it did; ``progress`` is called
    with each step's name, ``emit`` with each line for the user as it comes (the summary before
    the files are written). Bad input raises (a :class:`~rigjax.errors.RigjaxError`); a refusal
    is an outcome (``status`` 3, ``refusal``). The geometry wants JAX's float64
    (:func:`rigjax.worker.setup_worker`)."""
    lines: list[Line] = []

    def say(text: str, error: bool = False) -> None:
        lines.append(Line(text, error))
        if emit is not None:
            emit(lines[-1])

    job.check_outputs()
    config = load_template(job.template)
    if job.motion and config.motion is None:
        config = dataclasses.replace(config, motion=MotionConfig())
    start = None if job.start is None else load_project(job.start)  # its errors before the frames are read
    images, names = read_inputs(job)
    frames = frames_of(images, config, names)  # side-by-side images split: calibrated, written, rendered
    images, names = frames[0]
    if start is not None:
        config = with_start(config, start, start_sizes(images, names), source=job.start)
    calibration = calibrate_frames(frames, config, seed=job.seed, progress=progress)
    say(calibration.summary())
    refused = "; ".join(calibration.undetermined)
    if refused and not job.keep_undetermined:
        say(f"rigjax calibrate: {job.output} not written: {refused} (--keep-undetermined writes it)", True)
        return CalibrateOutcome(calibration, EXIT_UNRELIABLE, refused, (), tuple(lines))
    project = calibration.project
    if refused:
        project = project.with_comment_lines([f"#-rigjax undetermined: {line}" for line in calibration.undetermined])
        say(f"warning: written with parameters the matches do not determine: {refused}", True)
    written = []
    if job.videos or config.rig.side_by_side:  # the frames or halves the project names, beside it
        folder = os.path.dirname(os.path.abspath(job.output))
        for name, image in zip(names, images):
            written.append(os.path.join(folder, name))
            write_image(written[-1], image)
    project.save(job.output)
    written.append(os.fspath(job.output))
    say(f"wrote {job.output}")
    if job.render:
        pano, _ = render(project, images, width=job.width, blend=job.blend, names=names)
        write_image(job.render, pano)
        written.append(os.fspath(job.render))
        say(f"wrote {job.render}")
    if not calibration.result.ok:
        last = calibration.result.stages[-1]
        say(
            f"rigjax calibrate: written, but its last solve ({last.name}) stopped without converging: "
            f"{last.status} after {last.steps} steps (optimise.solver.max_steps in the template)",
            True,
        )
    status = 0 if calibration.result.ok and not refused else EXIT_UNRELIABLE
    return CalibrateOutcome(calibration, status, None, tuple(written), tuple(lines))


__all__ = [
    "CalibrateJob",
    "CalibrateOutcome",
    "JobError",
    "Line",
    "calibrate_job",
    "read_inputs",
    "video_frame_names",
]
