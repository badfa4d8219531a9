"""``rigjax optimise`` as a function: an :class:`OptimiseJob` in, an :class:`OptimiseOutcome` out.

The command line turns its options into an :class:`~rigjax.optimiser.config.OptimiseConfig`, calls
:func:`optimise_job` and prints the outcome's lines; a batch runner calls the same function in a
worker process (set up once with :func:`rigjax.worker.setup_worker`). With ``config.prune`` the
points are pruned (:func:`~rigjax.optimiser.prune.optimise_pruned`), else every point is used
(:func:`~rigjax.optimiser.staged.optimise`). A solve that did not converge is still written, with
status 3.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

from ..errors import EXIT_UNRELIABLE
from ..outputs import check_output
from ..pto.project import load_project
from .config import OptimiseConfig
from .prune import format_pruning, optimise_pruned
from .result import OptimiseResult
from .staged import optimise


@dataclass(frozen=True)
class OptimiseJob:
    """What ``rigjax optimise`` is asked to do: ``project`` (a ``.pto`` file with control points)
    optimised as ``config`` says and written to ``output``."""

    project: str | os.PathLike[str]
    output: str | os.PathLike[str]
    config: OptimiseConfig = field(default_factory=OptimiseConfig)

    def check_outputs(self) -> None:
        """Raise :class:`~rigjax.outputs.OutputError` unless the project can be written."""
        check_output(self.output)


@dataclass(frozen=True, eq=False)
class OptimiseOutcome:
    """What :func:`optimise_job` did: the final ``result``, the exit ``status`` (0, or 3: a solve
    that did not converge), the files ``written`` and the ``lines`` the command prints."""

    result: OptimiseResult
    status: int
    written: tuple[str, ...]
    lines: tuple[str, ...]


def optimise_job(job: OptimiseJob) -> OptimiseOutcome:
    """Do what ``rigjax optimise`` does for ``job`` and say what it did; bad input raises (a
    :class:`~rigjax.errors.RigjaxError`)."""
    job.check_outputs()
    project = load_project(job.project)
    if job.config.prune is None:
        result = stages = optimise(project, job.config)
        written, lines = result.project, [stages.format_stages()]
    else:
        pruned = optimise_pruned(project, job.config)
        result, stages, written = pruned.result, pruned.first, pruned.project
        lines = [stages.format_stages()]  # every stage of the schedule: the first, robust solve's
    lines += [f"not optimised: {line}" for line in stages.not_optimised]
    if job.config.prune is not None:
        lines.append(format_pruning(pruned, project))
    if deviations := result.format_deviations():  # the bundle adjustment's (objective reprojection)
        lines.append(deviations)
    written.save(job.output)
    lines.append(f"final rms {result.format_rms()}; wrote {job.output}")
    status = 0 if stages.ok and result.ok else EXIT_UNRELIABLE
    return OptimiseOutcome(result, status, (os.fspath(job.output),), tuple(lines))
