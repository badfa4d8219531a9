#!/usr/bin/env python3
"""Benchmark: how much parallax the synthetic data carries.

The rotation-only stitch (true orientations and lenses, camera offsets ignored; feather blend) of
the same seeds at camera distances 0, 0.2 and 0.4 m, against the ground-truth panorama: PSNR and
SSIM over the covered panorama, mean over the seeds, with the configs' photometric variation
(gain, vignetting, noise) and without it (geometry only).

    python benchmarks/parallax_table.py [--config cpu_tiny_d02] [--seeds 20]
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
from _record import recorded

from learnstitch.baselines import psnr, rotation_only_stitch, ssim
from learnstitch.config import load_config
from learnstitch.data.sample import make_sample


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default="cpu_tiny_d02")
    parser.add_argument("--seeds", type=int, default=20)
    args = parser.parse_args()
    base = load_config(f"configs/stitch/{args.config}.yaml").data
    geometry = dict(gain_jitter=0.0, vignetting=0.0, noise_std=0.0)
    print(
        f"{args.config}: {base.fisheye_size}² fisheyes, {base.pano_width}×{base.pano_height} panorama, "
        f"seeds 0-{args.seeds - 1}\n"
    )
    print("| distance d | PSNR dB (data) | SSIM (data) | PSNR dB (geometry only) | SSIM (geometry only) |")
    print("|---|---|---|---|---|")
    for distance in (0.0, 0.2, 0.4):
        row = []
        for extra in ({}, geometry):
            config = dataclasses.replace(base, distance=distance, **extra)
            p, s = [], []
            for seed in range(args.seeds):
                sample = make_sample(config, seed)
                pano, covered = rotation_only_stitch(sample.fisheyes, sample.rig, config)
                p.append(float(psnr(pano, sample.pano, covered)))
                s.append(float(ssim(pano, sample.pano, covered)))
            row += [f"{np.mean(p):.2f} ± {np.std(p):.2f}", f"{np.mean(s):.3f}"]
        print(f"| {distance} | " + " | ".join(row) + " |")


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main()
