"""``rigjax demo``: calibrate a synthetic 6-camera fisheye rig and print what it recovered.

The rig: six 1440x1080 full-frame fisheyes (hfov 123, K2 -0.01) a few degrees off a cube, about
950 control points with 0.5 px noise. The start: every camera but the anchor 3-20 degrees off in
yaw, pitch and roll, a nominal hfov 3-8 degrees off and K2 = 0. The default schedule
(``YPR,VBYPR``) solves it; the table compares every camera with the truth. Writes the start and
the optimised projects as Hugin ``.pto`` files, and compares the optimised project's transforms
with Hugin's ``pano_trafo`` when it is installed.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np

from ._camera import img_to_ray
from ._optimise import evaluate, format_report, optimise
from ._project import load_project
from ._trafo import transform_points
from .synthetic import control_points_from_truth, cube_rig, perturb


def _centre_ray_error_arcmin(a, b, k: int) -> float:
    image = a.images[k]
    centre = np.array([image.width / 2 - 0.5, image.height / 2 - 0.5])
    ra, _ = img_to_ray(a.cameras().take(k), centre)
    rb, _ = img_to_ray(b.cameras().take(k), centre)
    return float(np.degrees(np.arccos(np.clip(np.dot(np.asarray(ra), np.asarray(rb)), -1, 1))) * 60)


def run_demo(out: str | Path) -> None:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    truth = control_points_from_truth(cube_rig(orientation_jitter_deg=3.0, seed=1), 1500, noise_px=0.5, seed=2)
    start = perturb(truth, angle_deg=(3.0, 20.0), hfov_offset_deg=(3.0, 8.0), b=0.0, seed=3)
    start.save(out / "cube_rig_start.pto")
    image = truth.images[0]
    print(f"synthetic rig: {len(truth.images)} full-frame fisheyes {image.width}x{image.height}, hfov {image.hfov:g}, "
          f"K2 {image.b:g}; {len(truth.control_points)} control points with 0.5 px noise")  # fmt: skip
    print(f"start: orientations 3-20 deg off, nominal hfov {start.images[0].hfov:.2f}, K2 0  -> {out / 'cube_rig_start.pto'}\n")

    result = optimise(load_project(out / "cube_rig_start.pto"), "YPR,VBYPR")
    print(format_report(result))
    print(f"\nfinal rms {result.rms:.4f} px; at the true parameters {evaluate(truth).rms:.4f} px (the noise floor)\n")
    header = f"{'cam':>3} {'hfov err':>9} {'K2 err':>9} {'yaw err':>9} {'pitch err':>9} {'roll err':>9} {'axis err arcmin':>15}"
    print(header)
    print("-" * len(header))
    for k, (got, want) in enumerate(zip(result.project.images, truth.images)):
        d = {letter: got.value(letter) - want.value(letter) for letter in "vbypr"}
        d["y"], d["r"] = ((d[x] + 180) % 360 - 180 for x in "yr")
        print(f"{k:>3} {d['v']:>9.4f} {d['b']:>9.5f} {d['y']:>9.4f} {d['p']:>9.4f} {d['r']:>9.4f} "
              f"{_centre_ray_error_arcmin(result.project, truth, k):>15.3f}")  # fmt: skip
    print("(looking straight up or down, yaw and roll turn about nearly the same axis and trade off;\n"
          " the optical-axis error is the measure that counts there)")
    path = out / "cube_rig_optimised.pto"
    result.project.save(path)
    print(f"\nwrote {path} (open it in Hugin)")

    if shutil.which("pano_trafo"):
        project = load_project(path)
        rng = np.random.default_rng(0)
        idx = rng.integers(0, len(project.images), 2000)
        size = np.array([[im.width, im.height] for im in project.images])[idx]
        pts = rng.uniform(0, 1, (len(idx), 2)) * size - 0.5
        ours, ok = transform_points(project.cameras(), project.canvas(), idx, pts, reverse=False)
        text = "".join(f"{k} {x:.6f} {y:.6f}\n" for k, (x, y) in zip(idx, pts))
        lines = subprocess.run(["pano_trafo", str(path)], input=text, capture_output=True, text=True, check=True).stdout
        hugin = np.array([[float(v) for v in line.split()] for line in lines.splitlines()[: len(idx)]])
        print(f"Hugin's pano_trafo on 2000 random pixels of it: largest difference {np.abs(ours - hugin)[ok].max():.2e} px")
    print(f"try:  echo '0 719.5 539.5' | rigjax trafo {path}")
