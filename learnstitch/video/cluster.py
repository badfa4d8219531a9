"""A batch's chunks (:mod:`learnstitch.video.chunks`) stitched by a pool of Ray actors: each actor
holds a clip's set-up (the rig's tables, the depth network or the template's maps) once and
stitches that clip's chunks as they come, on whichever node of the cluster it runs.

Where an actor is lost (its node gone, its process killed), the chunk it was stitching goes back
to the queue and runs on another actor: its segment was being written under a name of its own and
is renamed into place only when complete, so nothing is lost, and a chunk run twice (an actor lost
to the driver but still writing) is still one segment in the output. Ray is an
optional extra (``pip install -e ".[ray]"``); this module is imported only when ``--ray`` is given.

Every Ray process of a cluster this module starts binds 127.0.0.1 and sends no usage statistics.
"""

from __future__ import annotations

import logging
import os
import socket
import time
from collections import deque
from urllib.parse import urlsplit

from rigjax.errors import ConfigError

from .chunks import CLIP_ERRORS, BatchJob, Chunk, ClipPlan, Done, Failed, prepare_clip, stitch_chunk

LOCAL_ENVIRONMENT = {"RAY_USAGE_STATS_ENABLED": "0", "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0"}
LOST_ACTORS = 3  # a chunk whose actor was lost more often than this fails its clip
PLACED_S = 300  # seconds to wait for a first actor to start while none is stitching


def run_on_ray(
    job: BatchJob,
    plans: list[ClipPlan],
    done: Done,
    failed: Failed,
    workers: int | None,
    cpus_per_worker: float | None,
    gpus_per_worker: float,
) -> int:
    """The missing chunks of ``plans`` stitched on the cluster :func:`connect` joined by
    ``workers`` actors (None: as many as the cluster's CPUs hold) of ``cpus_per_worker`` CPUs
    (None: the job's threads) and ``gpus_per_worker`` GPUs. Returns the chunks run again after
    their actor was lost."""
    import ray

    cpus = float(cpus_per_worker or job.threads)
    queue = [(plan, chunk) for plan in plans for chunk in plan.missing]
    if workers is None:  # as many as the cluster holds, by CPUs and by GPUs
        total = ray.cluster_resources()
        workers = int(total.get("CPU", 0) // cpus)
        if gpus_per_worker:
            workers = min(workers, int(total.get("GPU", 0) // gpus_per_worker))
        workers = max(1, workers)
    workers = min(workers, len(queue))  # no actor without a chunk to take
    if not workers:
        return 0
    pool = _Pool(job, {"num_cpus": cpus, "num_gpus": gpus_per_worker}, workers)
    pool.run(queue, done, failed)
    return pool.lost


def connect(address: str) -> str:
    """Join the Ray cluster at ``address`` (``host:port`` or ``ray://host:port``), or with
    ``"auto"`` the running one (``RAY_ADDRESS``, ``ray start``) or a local one started here (every
    process on 127.0.0.1, no usage statistics). Returns where it runs, in words. An address nobody
    answers at is a :class:`ConfigError` before anything starts; end with :func:`disconnect`."""
    if address != "auto":
        _answers(address)
        if _loopback(address):  # before Ray is imported: it reads them then
            for key, value in LOCAL_ENVIRONMENT.items():
                os.environ.setdefault(key, value)
    try:
        import ray
    except ImportError:
        raise ConfigError('--ray needs Ray, an extra of this project: pip install -e ".[ray]"') from None

    quiet = {"logging_level": logging.WARNING, "configure_logging": True}
    running = address if address != "auto" else os.environ.get("RAY_ADDRESS") or _started_here()
    try:
        if running is None:
            os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # read when the cluster starts
            ray.init(include_dashboard=False, _node_ip_address="127.0.0.1", **quiet)
            return "a local Ray cluster"
        if running != address:  # RAY_ADDRESS's: checked as a given one is
            _answers(running)
        ray.init(address=running, **quiet)
    except (ConnectionError, RuntimeError, ValueError) as error:  # not Ray there, another version, ...
        raise ConfigError(f"--ray {address}: Ray could not join {running or 'a local cluster'}: {error}") from None
    return f"the Ray cluster at {ray.get_runtime_context().gcs_address}"


def disconnect() -> None:
    import ray

    ray.shutdown()


def _started_here() -> str | None:
    """The address of the cluster ``ray start`` left on this machine, if one is running."""
    from ray._private.utils import read_ray_address

    found = read_ray_address()
    return found if found and _unreachable(found) is None else None


def _host_port(address: str) -> tuple[str, int]:
    parts = urlsplit(address if "://" in address else f"tcp://{address}")
    if parts.hostname is None or parts.port is None:
        raise ConfigError(f"--ray {address}: give the cluster's head as host:port (or auto)")
    return parts.hostname, parts.port


def _loopback(address: str) -> bool:
    host, _ = _host_port(address)
    return host in ("localhost", "127.0.0.1", "::1")


def _unreachable(address: str, timeout: float = 5.0) -> str | None:
    """Why nothing answers at ``address`` (None: something does)."""
    try:
        with socket.create_connection(_host_port(address), timeout=timeout):
            return None
    except OSError as error:
        return error.strerror or type(error).__name__


def _answers(address: str) -> None:
    if (reason := _unreachable(address)) is not None:
        host, port = _host_port(address)
        raise ConfigError(
            f"--ray {address}: no Ray cluster answers at {host}:{port} ({reason}); start one (ray start --head), or "
            "leave --ray out to stitch on this machine"
        )


class _Pool:
    """Ray actors that stitch chunks, each holding the set-up of the clip it stitched last. An
    actor takes chunks once it has started (the cluster placed it); one lost mid-chunk puts the
    chunk back and is replaced (placed wherever the cluster then has room, or never)."""

    def __init__(self, job: BatchJob, resources: dict, size: int):
        import ray

        self.ray, self.job, self.resources = ray, job, resources
        self.worker = ray.remote(max_restarts=0, max_task_retries=0, **resources)(ChunkWorker)
        self.starting = {}  # an actor's ready() -> the actor
        for _ in range(size):
            self.start()
        self.lost = 0  # chunks run again after their actor was lost

    def start(self) -> None:
        actor = self.worker.remote(self.job)
        self.starting[actor.ready.remote()] = actor

    def run(self, queue: list[tuple[ClipPlan, Chunk]], done: Done, failed: Failed) -> None:
        ray, exceptions = self.ray, self.ray.exceptions
        pending, idle, running = deque(queue), [], {}
        holds: dict = {}  # actor -> the clip whose set-up it holds
        losses: dict[tuple[str, int], int] = {}  # a chunk's lost actors
        broken: set[str] = set()  # clips that cannot be stitched: their other chunks are dropped

        def give_up(plan: ClipPlan, error: str) -> None:
            nonlocal pending
            broken.add(plan.clip.output)
            pending = deque(item for item in pending if item[0].clip.output != plan.clip.output)
            failed(plan, error)

        while pending or running:
            while idle and pending:  # an actor takes a chunk of the clip it holds where there is one
                actor = idle.pop()
                held = next((i for i, (plan, _) in enumerate(pending) if plan.clip.output == holds.get(actor)), 0)
                plan, chunk = pending[held]
                del pending[held]
                holds[actor] = plan.clip.output
                running[actor.stitch.remote(chunk)] = (actor, plan, chunk, time.perf_counter())
            if not pending and not running:
                break
            waiting = [*running, *self.starting]
            if not waiting:
                raise ConfigError("every Ray actor died as it started: the Ray logs say why (ray logs, or /tmp/ray)")
            ready, _ = ray.wait(waiting, num_returns=1, timeout=None if running else PLACED_S)
            if not ready:
                raise ConfigError(
                    f"no Ray actor of {self.resources['num_cpus']:g} CPUs and {self.resources['num_gpus']:g} GPUs "
                    f"started in {PLACED_S} s (the cluster has {_free(ray)}): ask for less (--cpus-per-worker, "
                    "--gpus-per-worker) or add nodes"
                )
            (ref,) = ready
            if ref in self.starting:
                actor = self.starting.pop(ref)
                try:
                    ray.get(ref)
                    idle.append(actor)
                except exceptions.RayActorError:  # it died starting: the chunks go to the others
                    pass
                continue
            actor, plan, chunk, submitted = running.pop(ref)
            try:
                record, notes = ray.get(ref)
            except exceptions.RayActorError:  # its node or process is gone: the chunk runs again elsewhere
                key = (plan.clip.output, chunk.k)
                losses[key] = losses.get(key, 0) + 1
                self.lost += 1
                if losses[key] > LOST_ACTORS:
                    lost = f"{losses[key]} times"
                    give_up(
                        plan, f"chunk {chunk.k} (frames {chunk.start}-{chunk.end - 1}): its Ray actor was lost {lost}"
                    )
                elif plan.clip.output not in broken:
                    pending.appendleft((plan, chunk))
                self.start()  # a replacement, wherever the cluster has room
                continue
            except exceptions.RayTaskError as error:
                if not isinstance(error.cause, CLIP_ERRORS):
                    raise
                if plan.clip.output not in broken:  # the clip's first error is its error
                    give_up(plan, str(error.cause))
                idle.append(actor)
                continue
            record["round_trip"] = round(time.perf_counter() - submitted, 3)
            done(plan, chunk, record, notes)
            idle.append(actor)


def _free(ray) -> str:
    free = ray.available_resources()
    return f"{free.get('CPU', 0):g} CPUs and {free.get('GPU', 0):g} GPUs free"


class ChunkWorker:
    """A Ray actor's state: the batch's settings and the set-up of the clip it stitched last."""

    def __init__(self, job: BatchJob):
        from ..worker import setup_worker

        # compiled programs kept on the node for its next actors; OpenMP threads that sleep while they wait
        setup_worker(compilation_cache=True, omp_wait_policy="PASSIVE")
        self.job, self.output, self.prepared = job, None, None

    def ready(self) -> bool:
        """Answers once the actor has started: it takes chunks from then on."""
        return True

    def stitch(self, chunk: Chunk) -> tuple[dict, list[str]]:
        """``chunk`` stitched (:func:`~learnstitch.video.chunks.stitch_chunk`): its record, with
        the set-up's seconds where this call made it and the worker's process, and the set-up's notes."""
        seconds = 0.0
        if self.output != chunk.clip.output:
            started = time.perf_counter()
            self.prepared, self.output = prepare_clip(self.job, chunk.clip), chunk.clip.output
            seconds = time.perf_counter() - started
        record = stitch_chunk(self.job, chunk, self.prepared)
        return {**record, "prepare": round(seconds, 3), "pid": os.getpid()}, list(self.prepared.notes)


__all__ = ["connect", "disconnect", "run_on_ray"]
