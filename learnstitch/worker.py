"""What a process sets up once before it runs learnstitch's work: rigjax's set-up
(:func:`rigjax.worker.setup_worker`) and torch's thread count.

Convention: call it before the work, once per process (a pool's initialiser, a command's start).
``omp_wait_policy`` counts only before torch loads its OpenMP runtime: in a process that has
imported torch already (a caller of ``learnstitch.cli.main``, a test) it is left alone, and so is
the environment that process's children inherit.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from rigjax.worker import setup_worker as setup_rigjax_worker


def setup_worker(
    *,
    torch_threads: int | None = None,
    opencv_threads: int | None = None,
    float64: bool = False,
    compilation_cache: bool | str | os.PathLike[str] = False,
    omp_wait_policy: str | None = None,
) -> Path | None:
    """Set up this process for learnstitch's work.

    Args:
        torch_threads: torch's intra-op thread count (``torch.set_num_threads``); None leaves it. A
            pool of workers on shared cores says 1.
        opencv_threads: OpenCV's (:func:`rigjax.worker.setup_worker`); None leaves it.
        float64: JAX's 64-bit floats (:func:`rigjax.worker.setup_worker`); learnstitch's own camera
            maps run in float32, so False (leave JAX as it is) by default.
        compilation_cache: keep JAX's compiled programs for later processes, as rigjax's.
        omp_wait_policy: the default of ``OMP_WAIT_POLICY`` (``"PASSIVE"``: OpenMP threads sleep
            while they wait; spinning ones slow a run many times over when other work keeps the
            cores busy), set only while torch is not imported yet.

    Returns the compilation cache's folder, or None without one.
    """
    fresh = "torch" not in sys.modules  # OpenMP reads OMP_WAIT_POLICY when torch loads
    folder = setup_rigjax_worker(
        float64=float64,
        compilation_cache=compilation_cache,
        opencv_threads=opencv_threads,
        omp_wait_policy=omp_wait_policy if fresh else None,
    )
    if torch_threads is not None:
        import torch

        torch.set_num_threads(torch_threads)
    return folder


__all__ = ["setup_worker"]
