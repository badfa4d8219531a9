#!/usr/bin/env python3
"""Benchmark: how far tracks through the seam bands lie from the truth, and how much of that a
region's tracks share.

For validation samples of each config (learnstitch's rigs: three 185-degree fisheyes d metres
from the rig's middle), every pair's grid is tracked through its seam band as ``rigjax calibrate``
tracks it (``configs/rig/tri_fisheye.yaml``). Each track's first end is cast into the sample's
scene from its camera's centre (the true cameras), and the scene point found there projected
into the second camera: the track's true second end. A track's error *across* its epipolar line
(the line that the point's depth moves it along) is what the calibration must explain by turning
the cameras; along the line it is the depth's to explain. Per config: the median and 90th
percentile of the errors across, the share above 1 px, and their part that each 32-pixel cell
of a pair's tracks (the bundle adjustment's clusters) has in common: the spread of the cells'
mean errors less what their tracks' own scatter puts there (the square root of the mean of
``mean_c^2 - s_c^2 / n_c`` over the cells of 3 or more tracks, tracks within 2 px: those pruning keeps). That shared
part is what ``features.track_bias_px`` lets the standard deviations allow for.

    python benchmarks/track_errors.py [--samples 16] [--configs paper_d02 paper_d04] [--workers 2]
"""

from __future__ import annotations

import multiprocessing
from functools import cache

import numpy as np
import torch
from _record import recorded, rig_sample_arguments

import rigjax
from learnstitch.baselines import rig_template, to_uint8
from learnstitch.config import load_config
from learnstitch.data.sample import make_sample
from learnstitch.data.scene import render, sample_scene
from learnstitch.data.store import SPLIT_SEED_BASE
from learnstitch.worker import setup_worker
from rigjax.camera.model import img_to_ray, map_points, ray_to_img

CELL_PX = 32.0
KEPT_PX = 2.0


@cache
def _inputs(name: str):
    config = load_config(f"configs/stitch/{name}.yaml").data
    return config, rig_template(rigjax.load_template("configs/rig/tri_fisheye.yaml"), config)


def _one(job) -> np.ndarray:
    """``(n, 6)``: each track's sample, pair ``(a, b)``, first end ``(x, y)`` and error across its
    epipolar line (px, NaN for tracks into the sky, which have no epipolar line)."""
    name, index = job
    setup_worker(torch_threads=1)
    config, template = _inputs(name)
    sample = make_sample(config, SPLIT_SEED_BASE["validation"] + index)
    truth, centres = sample.rig.cameras, sample.rig.centres
    scene = sample_scene(sample.seed)
    images = [to_uint8(f) for f in sample.fisheyes]
    rows = []
    for pair in rigjax.match_images(images, template):
        camera_a, camera_b = truth.take(pair.a), truth.take(pair.b)
        ray = np.asarray(map_points(img_to_ray, camera_a, pair.xy_a)[0])
        origin = torch.as_tensor(centres[pair.a], dtype=torch.float32)
        depth = render(scene, origin, torch.tensor(ray, dtype=torch.float32))[1].double().numpy()
        near = np.isfinite(depth)
        towards = centres[pair.a] + np.where(near, depth, 0.0)[:, None] * ray - centres[pair.b]
        towards = np.where(near[:, None], towards, ray)
        true_b = np.asarray(map_points(ray_to_img, camera_b, towards / np.linalg.norm(towards, axis=1)[:, None])[0])
        at_infinity = np.asarray(map_points(ray_to_img, camera_b, ray)[0])
        along = at_infinity - true_b  # the epipolar line's direction: the point moved out to infinity
        length = np.linalg.norm(along, axis=1)
        along /= np.where(length > 1e-6, length, 1.0)[:, None]
        error = pair.xy_b - true_b
        across = np.where(near & (length > 1e-6), error[:, 0] * along[:, 1] - error[:, 1] * along[:, 0], np.nan)
        which = np.tile([index, pair.a, pair.b], (len(across), 1))
        rows.append(np.column_stack([which, pair.xy_a, across]))
    return np.concatenate(rows)


def shared_bias(tracks: np.ndarray, cell_px: float, kept_px: float) -> tuple[float, float, int]:
    """The standard deviation of the error that each ``cell_px`` cell of a pair's tracks shares,
    the tracks' own scatter about their cell's mean, and the number of cells (3 or more tracks
    within ``kept_px``)."""
    across = tracks[:, 5]
    use = np.isfinite(across) & (np.abs(across) < kept_px)
    keys = np.column_stack([tracks[:, :3], np.floor(tracks[:, 3:5] / cell_px)])[use]
    cell = np.unique(keys, axis=0, return_inverse=True)[1].reshape(-1)
    x = across[use]
    n, total, squares = np.bincount(cell), np.bincount(cell, x), np.bincount(cell, x * x)
    many = n >= 3
    mean = total[many] / n[many]
    scatter = (squares[many] - n[many] * mean**2) / (n[many] - 1)
    shared = np.mean(mean**2) - np.mean(scatter / n[many])
    return float(np.sqrt(max(shared, 0.0))), float(np.sqrt(np.mean(scatter))), int(many.sum())


def main() -> None:
    args = rig_sample_arguments(__doc__)
    print(
        f"{args.samples} validation samples per config, every track of every pair (the template's grid). "
        f"Errors across the epipolar line, px. Shared per cell: the standard deviation of what the tracks "
        f"of one {CELL_PX:.0f}-pixel cell of a pair have in common (tracks within {KEPT_PX:g} px); scatter: "
        "about their cell's mean.\n"
    )
    print("| config | tracks | median abs error | 90th percentile | above 1 px | shared per cell | scatter | cells |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    with multiprocessing.get_context("spawn").Pool(args.workers) as pool:
        for name in args.configs:
            tracks = np.concatenate(pool.map(_one, [(name, k) for k in range(args.samples)], chunksize=1))
            across = np.abs(tracks[:, 5][np.isfinite(tracks[:, 5])])
            shared, scatter, cells = shared_bias(tracks, CELL_PX, KEPT_PX)
            print(
                f"| {name} | {len(across)} | {np.median(across):.3f} | {np.percentile(across, 90):.2f} "
                f"| {np.mean(across > 1.0):.1%} | {shared:.3f} | {scatter:.3f} | {cells} |"
            )


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main()
