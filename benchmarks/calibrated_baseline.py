#!/usr/bin/env python3
"""Benchmark: rigjax-calibrated stitching of learnstitch's samples, against the true cameras.

For test samples of each config: calibrate the three fisheyes with rigjax
(``configs/rig/tri_fisheye.yaml`` with the data's nominal camera centres, as ``learnstitch
evaluate`` does: points tracked through each pair's seam band, RANSAC on the epipolar constraint,
the bundle adjustment with hfov estimated about the data's nominal lens, its tolerance the
prior's standard deviation, pruning), turn the rig as a whole onto the true one
(images cannot tell the rig's orientation in the world), and stitch (unwarp + feather blend).
Printed per config: how often calibration succeeds, the orientation error of the calibrated and
of the nominal rig, and PSNR over the panorama and its seams of three stitches — calibrated,
nominal rig (what calibration starts from), true cameras (the rotation-only reference) — and of
a fourth, the calibrated rig's depth stitch (``calibrated_depth_stitch``: each input resampled
through the calibrated centres at the inverse depth of the control points near each pixel,
infinity away from them). Failed calibrations are stitched with the nominal rig, as
``learnstitch evaluate`` does.

    python benchmarks/calibrated_baseline.py [--samples 16] [--configs paper_d02 paper_d04] [--workers 2]
"""

from __future__ import annotations

import multiprocessing
import statistics
import time
from functools import cache

from _record import recorded, rig_sample_arguments

import rigjax
from learnstitch.baselines import (
    align_rig,
    calibrated_depth_stitch,
    calibrated_stitch,
    orientation_errors_deg,
    psnr,
    rotation_only_stitch,
    stitch_with_cameras,
)
from learnstitch.config import load_config
from learnstitch.data.rig import nominal_cameras
from learnstitch.data.sample import make_sample, nominal_unwarp_grids
from learnstitch.data.store import SPLIT_SEED_BASE
from learnstitch.worker import setup_worker


@cache
def _inputs(name: str):
    """The config's data section and the rig template, read once per worker process."""
    return load_config(f"configs/stitch/{name}.yaml").data, rigjax.load_template("configs/rig/tri_fisheye.yaml")


def _one(job):
    name, index = job
    setup_worker(torch_threads=1)
    config, template = _inputs(name)
    sample = make_sample(config, SPLIT_SEED_BASE["test"] + index)
    truth = sample.rig.cameras
    t = time.perf_counter()
    calibrated = calibrated_stitch(sample.fisheyes, config, template, reference=truth, seed=index)
    seconds = time.perf_counter() - t
    nominal = align_rig(nominal_cameras(config.fisheye_size, config.hfov), truth)
    _, masks, _ = nominal_unwarp_grids(config)
    seams = masks.sum(dim=0) >= 2
    panos = {
        "calibrated": calibrated.pano,
        "depth": calibrated_depth_stitch(sample.fisheyes, calibrated, config),
        "nominal": stitch_with_cameras(sample.fisheyes, nominal, config)[0],
        "true": rotation_only_stitch(sample.fisheyes, sample.rig, config)[0],
    }
    return {
        "ok": calibrated.failure is None,
        "seconds": seconds,
        "error_calibrated": float(orientation_errors_deg(calibrated.cameras, truth).mean()),
        "error_nominal": float(orientation_errors_deg(nominal, truth).mean()),
        **{f"psnr_{k}": float(psnr(p, sample.pano)) for k, p in panos.items()},
        **{f"seams_{k}": float(psnr(p, sample.pano, seams)) for k, p in panos.items()},
    }


def main() -> None:
    args = rig_sample_arguments(__doc__)
    print(
        "| config | calibrated | orientation error, calibrated / nominal (deg) | PSNR calibrated / nominal / true (dB) "
        "| seams: calibrated / nominal / true (dB) | calibrated beats true (PSNR) "
        "| calibrated depth stitch: PSNR / seams (dB), beats true | calibration time (median) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    with multiprocessing.get_context("spawn").Pool(args.workers) as pool:
        for name in args.configs:
            rows = pool.map(_one, [(name, k) for k in range(args.samples)], chunksize=1)
            ok = [r for r in rows if r["ok"]]

            def mean(key, rows=rows):
                return statistics.fmean(r[key] for r in rows)

            print(
                f"| {name} | {len(ok)}/{len(rows)} | {mean('error_calibrated'):.2f} / {mean('error_nominal'):.2f} "
                f"| {mean('psnr_calibrated'):.2f} / {mean('psnr_nominal'):.2f} / {mean('psnr_true'):.2f} "
                f"| {mean('seams_calibrated'):.2f} / {mean('seams_nominal'):.2f} / {mean('seams_true'):.2f} "
                f"| {sum(r['psnr_calibrated'] > r['psnr_true'] for r in rows)}/{len(rows)} "
                f"| {mean('psnr_depth'):.2f} / {mean('seams_depth'):.2f}, "
                f"{sum(r['psnr_depth'] > r['psnr_true'] for r in rows)}/{len(rows)} "
                f"| {statistics.median(r['seconds'] for r in rows):.1f} s |"
            )
            if ok:
                print(
                    f"|   (successful calibrations only) | {len(ok)} | {mean('error_calibrated', ok):.2f} / "
                    f"{mean('error_nominal', ok):.2f} | {mean('psnr_calibrated', ok):.2f} / {mean('psnr_nominal', ok):.2f} / "
                    f"{mean('psnr_true', ok):.2f} | {mean('seams_calibrated', ok):.2f} / {mean('seams_nominal', ok):.2f} / "
                    f"{mean('seams_true', ok):.2f} | | {mean('psnr_depth', ok):.2f} / {mean('seams_depth', ok):.2f} | |"
                )


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main()
