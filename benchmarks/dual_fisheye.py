#!/usr/bin/env python3
"""Benchmark: dual-fisheye calibration, matching in the seam band against matching in the images.

Synthetic dual-fisheye images: two 1440x1440 circular fisheyes back to back (orientations jittered
by 2 degrees), K2 -0.01, rendered from the procedural environment side by side. Two lenses: hfov
191 (overlap 5.5 degrees either side of the seam) and 186 (3 degrees); the template
(``configs/rig/dual_fisheye.yaml``) says 190 or 185, one degree narrower. For each lens, both
matchings (``seam_band_deg: 8`` and none) and both schedules (``YPR,VYPR``: K2 held at its nominal
value, which here is the truth; ``YPR,VBYPR``: K2 free too):

* matches, and how many are correct by the truth (the true rig maps them within 8 arcmin, about
  one pixel at the seam), RANSAC inliers;
* the largest ray error against the truth over a 24x24 raster of each image (the whole lens) and
  over a 240x240 raster restricted to the overlap ring (what stitching needs), arcmin;
* the recovered hfov and K2.

    python benchmarks/dual_fisheye.py
"""

from __future__ import annotations

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np
import yaml
from _record import recorded

import rigjax
from rigjax import synthetic

TEMPLATE = "configs/rig/dual_fisheye.yaml"


def correct(truth: rigjax.Project, pair: rigjax.PairMatches, limit_arcmin: float = 8.0) -> int:
    cameras = truth.cameras()
    ray_a, _ = rigjax.img_to_ray(cameras.take(pair.a), pair.xy_a)
    ray_b, _ = rigjax.img_to_ray(cameras.take(pair.b), pair.xy_b)
    angle = np.degrees(np.arccos(np.clip(np.sum(np.asarray(ray_a) * np.asarray(ray_b), -1), -1.0, 1.0))) * 60
    return int((angle < limit_arcmin).sum())


def main() -> None:
    with open(TEMPLATE, encoding="utf-8") as f:
        template = yaml.safe_load(f)
    environment = synthetic.procedural_environment(4096, seed=0)
    print(
        "| true hfov | matching | schedule | matches (correct) | inliers | max ray error, whole lens | "
        "in the overlap | hfov | K2 |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for hfov in (191.0, 186.0):
        truth = synthetic.rig_from_orientations(
            [(0, 0, 0), (180, 0, 0)],
            width=1440,
            height=1440,
            projection=2,
            hfov=hfov,
            b=-0.01,
            orientation_jitter_deg=2.0,
            seed=3,
        )
        image = np.concatenate(synthetic.render_images(truth, environment, noise_std=2.0, seed=0), axis=1)
        overlap = hfov / 2 - 90
        for band in (8.0, None):
            for schedule in ("YPR,VYPR", "YPR,VBYPR"):
                data = {
                    **template,
                    "rig": {**template["rig"], "hfov": hfov - 1.0},
                    "features": {**template["features"], "seam_band_deg": band},
                    "optimise": {**template["optimise"], "schedule": schedule},
                }
                config = rigjax.template_from_dict(data, TEMPLATE)
                halves, _ = rigjax.split_side_by_side([image], config)
                pair = rigjax.match_images(halves, config)[0]
                calibration = rigjax.calibrate_matches([pair], [(1440, 1440)] * 2, config)
                whole = synthetic.ray_errors_arcmin(calibration.project, truth).max()
                ring = synthetic.ray_errors_arcmin(
                    calibration.project, truth, grid=240, off_axis_deg=(90 - overlap, 90 + overlap)
                ).max()
                lens = calibration.project.images[0]
                print(
                    f"| {hfov:g} | {'seam band' if band else 'images'} | {schedule} | {len(pair.xy_a)} "
                    f"({correct(truth, pair)}) | {calibration.pairs[0].inliers} | {whole:.2f}' | {ring:.2f}' | "
                    f"{lens.hfov:.3f} | {lens.b:.4f} |",
                    flush=True,
                )


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main()
