"""``learnstitch synth``: render a split of samples to disk, in parallel, resumable; and a contact sheet.

Workers are separate processes (``spawn``: JAX, which the camera maps use, must not be forked),
each rendering with one torch thread and with JAX on the CPU unless ``JAX_PLATFORMS`` says
otherwise: the camera maps are small, and on a machine whose JAX has a GPU every worker would
otherwise claim most of its memory at its first map. Every sample is written atomically
(:mod:`learnstitch.data.store`), so a run that is killed resumes where it stopped: complete samples
are kept, half-written ones are removed and rendered again.
"""

from __future__ import annotations

import multiprocessing
import os
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np
import torch
from tqdm import tqdm

from rigjax.errors import ConfigError
from rigjax.rendering.images import write_image

from .sample import SynthConfig, make_sample
from .store import (
    SPLIT_SEED_BASE,
    done,
    ensure_manifest,
    read_images,
    remove_partials,
    sample_name,
    to_bgr_uint8,
    write_sample,
)


class SynthReport(NamedTuple):
    written: int
    already_done: int
    partial_removed: int
    folder: Path


def _worker_init() -> None:
    """A rendering worker: one torch thread, and JAX on the CPU unless ``JAX_PLATFORMS`` is set."""
    torch.set_num_threads(1)
    if not os.environ.get("JAX_PLATFORMS"):
        import jax

        jax.config.update("jax_platforms", "cpu")


def _render_and_write(job: tuple[SynthConfig, int, int, str]) -> int:
    config, index, seed, split_dir = job
    write_sample(make_sample(config, seed), config, Path(split_dir) / sample_name(index))
    return index


def synthesise(
    config: SynthConfig,
    out: str | Path,
    *,
    split: str = "train",
    num: int = 100,
    workers: int = 1,
    config_name: str = "",
    progress: bool = True,
) -> SynthReport:
    """Render samples ``0 .. num-1`` of ``split`` into ``out/split`` (skipping those already there)."""
    if split not in SPLIT_SEED_BASE:
        raise ConfigError(f"split must be one of {sorted(SPLIT_SEED_BASE)}, got {split!r}")
    if num < 0 or workers < 1:
        raise ConfigError(f"num must be >= 0 and workers >= 1, got num={num}, workers={workers}")
    out = Path(out)
    manifest = ensure_manifest(out, config, config_name)
    split_dir = out / split
    split_dir.mkdir(exist_ok=True)
    removed = remove_partials(split_dir)
    base = int(manifest["seed_base"][split])
    todo = [k for k in range(num) if not done(split_dir, k)]
    jobs = [(config, k, base + k, str(split_dir)) for k in todo]
    bar = tqdm(total=num, initial=num - len(todo), desc=f"synth {split}", unit="sample", disable=not progress)
    try:
        if workers == 1 or len(jobs) <= 1:
            for job in jobs:
                _render_and_write(job)
                bar.update()
        else:
            # Rendering in this process leaves the caller's thread count and JAX platform alone (a
            # trainer that renders its own data trains as it resumes).
            context = multiprocessing.get_context("spawn")
            with context.Pool(workers, initializer=_worker_init) as pool:
                for _ in pool.imap_unordered(_render_and_write, jobs):
                    bar.update()
    finally:
        bar.close()
    return SynthReport(len(todo), num - len(todo), removed, split_dir)


def contact_sheet(split_dir: str | Path, count: int = 4, width: int = 1024) -> np.ndarray:
    """A BGR image: one row per sample (its fisheyes, then the panorama), ``width`` wide."""
    folders = sorted(p for p in Path(split_dir).iterdir() if p.is_dir() and not p.name.startswith("."))[:count]
    if not folders:
        raise ConfigError(f"{split_dir}: no samples to preview")
    rows = []
    for folder in folders:
        fisheyes, pano = read_images(folder)
        h = pano.shape[-2]
        tiles = [torch.nn.functional.interpolate(f[None], size=(h, h), mode="area")[0] for f in fisheyes]
        rows.append(np.concatenate([to_bgr_uint8(t) for t in tiles] + [to_bgr_uint8(pano)], axis=1))
    widest = max(row.shape[1] for row in rows)  # rigs of fewer cameras: black to the right
    sheet = np.concatenate([np.pad(row, ((0, 0), (0, widest - row.shape[1]), (0, 0))) for row in rows], axis=0)
    scale = width / sheet.shape[1]
    return cv2.resize(sheet, (width, round(sheet.shape[0] * scale)), interpolation=cv2.INTER_AREA)


def write_contact_sheet(split_dir: str | Path, path: str | Path, count: int = 4) -> Path:
    path = Path(path)
    write_image(path, contact_sheet(split_dir, count)[..., ::-1])
    return path
