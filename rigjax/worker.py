"""What a process sets up once before it runs rigjax's work: the command line, a batch runner's
worker, a benchmark's pool.

:func:`setup_worker` is the one place: JAX's 64-bit floats, the persistent compilation cache
(:func:`rigjax.compiled.persist`), OpenCV's thread count and the default of ``OMP_WAIT_POLICY``.
It touches only what its arguments ask for, so that a caller states what differs: the commands
that compile solves keep them (``compilation_cache=True``), a pool of one-thread workers says
``opencv_threads=1``. ``learnstitch.worker.setup_worker`` adds torch's thread count.

Convention: call it before the work, once per process. Float width and the cache apply to JAX
programs traced after the call; ``OMP_WAIT_POLICY`` is read by an OpenMP runtime when it loads
(torch's, say), so it only counts before that.
"""

from __future__ import annotations

import os
from pathlib import Path

from .errors import RigjaxError


def setup_worker(
    *,
    float64: bool = True,
    compilation_cache: bool | str | os.PathLike[str] = False,
    opencv_threads: int | None = None,
    omp_wait_policy: str | None = None,
) -> Path | None:
    """Set up this process for rigjax's work.

    Args:
        float64: turn on JAX's 64-bit floats (rigjax's geometry is exact to Hugin's in float64);
            False leaves JAX's setting as it is.
        compilation_cache: keep compiled programs for later processes (:func:`rigjax.compiled.persist`):
            True in its default folder (``$RIGJAX_CACHE_DIR``, else the user's cache), or in the
            folder given; False: none.
        opencv_threads: OpenCV's thread count (feature detection, remapping, blending); None leaves it.
        omp_wait_policy: the default of ``OMP_WAIT_POLICY`` (``"PASSIVE"``: OpenMP threads sleep
            while they wait instead of spinning); a value the environment already has is kept.

    Returns the compilation cache's folder, or None without one.
    """
    if omp_wait_policy is not None:
        os.environ.setdefault("OMP_WAIT_POLICY", omp_wait_policy)
    if float64:
        import jax

        jax.config.update("jax_enable_x64", True)
    if opencv_threads is not None:
        if opencv_threads < 1:
            raise RigjaxError(f"opencv_threads: expected a count of 1 or more, got {opencv_threads!r}")
        import cv2

        cv2.setNumThreads(opencv_threads)
    if compilation_cache is False:
        return None
    from .compiled import persist

    return persist(None if compilation_cache is True else compilation_cache)


__all__ = ["setup_worker"]
