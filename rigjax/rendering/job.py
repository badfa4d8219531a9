"""``rigjax render`` as a function: a :class:`RenderJob` in, a :class:`RenderOutcome` out.

The command line parses its arguments into a job, calls :func:`render_job` and prints the
outcome's lines; a batch runner calls the same function in a worker process (set up once with
:func:`rigjax.worker.setup_worker`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
from jaxtyping import Bool, UInt8

from ..outputs import check_output
from ..pto.project import load_project
from .blend import render
from .images import read_image, write_image


@dataclass(frozen=True)
class RenderJob:
    """What ``rigjax render`` is asked to do: ``project`` (a ``.pto`` file, equirectangular ``p``
    line) rendered from ``images`` (in the project's order; empty: the files it names) to the
    panorama file ``output``, ``width`` pixels wide (default the ``p`` line's), blended by
    ``blend``, the images' gains equalised first with ``exposure``."""

    project: str | os.PathLike[str]
    output: str | os.PathLike[str]
    images: tuple[str, ...] = ()
    width: int | None = None
    blend: str = "multiband"
    exposure: bool = False

    def check_outputs(self) -> None:
        """Raise :class:`~rigjax.outputs.OutputError` unless the panorama can be written."""
        check_output(self.output, image=True)


@dataclass(frozen=True, eq=False)
class RenderOutcome:
    """What :func:`render_job` did: the ``pano`` (RGB) and where an image sees it (``covered``),
    the files ``written`` and the ``lines`` the command prints; ``status`` is the exit status."""

    pano: UInt8[np.ndarray, "h w 3"]
    covered: Bool[np.ndarray, "h w"]
    written: tuple[str, ...]
    lines: tuple[str, ...]
    status: int = 0


def render_job(job: RenderJob) -> RenderOutcome:
    """Do what ``rigjax render`` does for ``job`` and say what it did; bad input raises (a
    :class:`~rigjax.errors.RigjaxError`)."""
    job.check_outputs()
    project = load_project(job.project)
    images = [read_image(p) for p in job.images] if job.images else None
    pano, covered = render(
        project, images, width=job.width, blend=job.blend, exposure=job.exposure, names=list(job.images) or None
    )
    write_image(job.output, pano)
    line = f"wrote {job.output} ({pano.shape[1]}x{pano.shape[0]}, {100 * covered.mean():.1f}% covered)"
    return RenderOutcome(pano, covered, (os.fspath(job.output),), (line,))


__all__ = ["RenderJob", "RenderOutcome", "render_job"]
