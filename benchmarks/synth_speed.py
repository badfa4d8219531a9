#!/usr/bin/env python3
"""Benchmark: synthetic triplets per second (learnstitch.data.sample), rendering and writing split.

For each config, the median over a few seeds of: rendering one sample (three fisheyes and the
panorama, ray cast), and writing its folder (PNGs, depth, .pto); then the throughput of one
process (all cores), and of one worker process per core rendering and writing samples as
``learnstitch synth --workers N`` does (each with one torch thread, timed once all have warmed up).

    python benchmarks/synth_speed.py [--samples 4] [--device cpu|cuda]
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import torch
from _record import recorded

from learnstitch.config import load_config
from learnstitch.data.generate import _render_and_write
from learnstitch.data.sample import make_sample
from learnstitch.data.store import write_sample
from learnstitch.worker import setup_worker


def _warm_worker(config, barrier) -> None:
    """Pool initializer: render one sample (JAX compiles the camera maps), then wait for the others."""
    setup_worker(torch_threads=1)
    make_sample(config, 0)
    barrier.wait()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--samples", type=int, default=4)
    parser.add_argument("--configs", nargs="+", default=["cpu_tiny_d02", "paper_d02"])
    parser.add_argument("--device", default="cpu", help="where the rays are cast: cpu or cuda")
    args = parser.parse_args()
    cores = os.cpu_count() or 1
    device = torch.device(args.device)
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else "CPU"
    print(f"{platform.machine()}, {cores} cores, torch {torch.__version__}, rays cast on {name}\n")
    print(
        "| config | fisheyes / panorama | render (median) | write the folder (median) | triplets/s, 1 process | "
        f"triplets/s, {cores} workers |"
    )
    print("|---|---|---|---|---|---|")
    for name in args.configs:
        config = load_config(f"configs/stitch/{name}.yaml").data
        make_sample(config, 0, device)  # warm-up (JAX compiles the camera maps)
        render_times, write_times = [], []
        with tempfile.TemporaryDirectory() as tmp:
            for seed in range(1, args.samples + 1):
                t = time.perf_counter()
                sample = make_sample(config, seed, device)
                if device.type == "cuda":
                    torch.cuda.synchronize(device)
                render_times.append(time.perf_counter() - t)
                t = time.perf_counter()
                write_sample(sample, config, Path(tmp) / str(seed))
                write_times.append(time.perf_counter() - t)
        one = 1.0 / (statistics.median(render_times) + statistics.median(write_times))
        context = multiprocessing.get_context("spawn")
        with context.Manager() as manager:
            barrier = manager.Barrier(cores + 1)
            with tempfile.TemporaryDirectory() as tmp, context.Pool(cores, _warm_worker, (config, barrier)) as pool:
                jobs = [(config, k, 1 + k, tmp) for k in range(args.samples * cores)]
                barrier.wait()  # every worker has warmed up
                t = time.perf_counter()
                pool.map(_render_and_write, jobs, chunksize=1)
                many = len(jobs) / (time.perf_counter() - t)
        print(
            f"| {name} | {config.fisheye_size}² / {config.pano_width}×{config.pano_height} | "
            f"{statistics.median(render_times) * 1e3:.0f} ms | {statistics.median(write_times) * 1e3:.0f} ms | "
            f"{one:.2f} | {many:.2f} |"
        )


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main()
