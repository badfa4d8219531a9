"""``rigjax demo``: a synthetic 6-camera fisheye rig, written as a Hugin project and transformed.

Prints, per camera, where its image centre and corners land in the panorama, and the largest
image -> panorama -> image round-trip error over a grid of pixels; compares with Hugin's
``pano_trafo`` when it is installed.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np

from ._project import load_project
from ._trafo import transform_points
from .synthetic import control_points_from_truth, cube_rig


def run_demo(out: str | Path) -> None:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rig = control_points_from_truth(cube_rig(orientation_jitter_deg=3.0, seed=1), n_directions=400, seed=2)
    path = out / "cube_rig.pto"
    rig.save(path)
    project = load_project(path)
    print(f"wrote {path}: {len(project.images)} full-frame fisheyes {project.images[0].width}x"
          f"{project.images[0].height}, hfov {project.images[0].hfov:g}, {len(project.control_points)} control points")  # fmt: skip

    cameras, canvas = project.cameras(), project.canvas()
    print(f"\npanorama {project.panorama.width}x{project.panorama.height}, hfov {project.panorama.hfov:g} (equirectangular)\n")
    header = f"{'cam':>3} {'yaw':>8} {'pitch':>8} {'roll':>8}   {'centre -> panorama':>22}   {'round trip max px':>17}"
    print(header)
    print("-" * len(header))
    for k, image in enumerate(project.images):
        w, h = image.width, image.height
        gx, gy = np.meshgrid(np.linspace(-0.5, w - 0.5, 97), np.linspace(-0.5, h - 0.5, 73))
        grid = np.stack([gx.ravel(), gy.ravel()], -1)
        idx = np.full(len(grid), k)
        pano, ok = transform_points(cameras, canvas, idx, grid, reverse=False)
        back, ok_back = transform_points(cameras, canvas, idx, pano, reverse=True)
        both = ok & ok_back
        err = np.abs(back - grid)[both].max()
        centre, _ = transform_points(cameras, canvas, np.array([k]), np.array([[w / 2 - 0.5, h / 2 - 0.5]]), reverse=False)
        print(f"{k:>3} {image.yaw:>8.3f} {image.pitch:>8.3f} {image.roll:>8.3f}   "
              f"({centre[0, 0]:>9.3f}, {centre[0, 1]:>8.3f})   {err:>17.2e}")  # fmt: skip

    if shutil.which("pano_trafo"):
        rng = np.random.default_rng(0)
        idx = rng.integers(0, len(project.images), 2000)
        size = np.array([[im.width, im.height] for im in project.images])[idx]
        pts = rng.uniform(0, 1, (len(idx), 2)) * size - 0.5
        ours, ok = transform_points(cameras, canvas, idx, pts, reverse=False)
        text = "".join(f"{k} {x:.6f} {y:.6f}\n" for k, (x, y) in zip(idx, pts))
        lines = subprocess.run(["pano_trafo", str(path)], input=text, capture_output=True, text=True, check=True).stdout
        hugin = np.array([[float(v) for v in line.split()] for line in lines.splitlines()[: len(idx)]])
        print(f"\nHugin's pano_trafo on 2000 random pixels: largest difference {np.abs(ours - hugin)[ok].max():.2e} px")
    else:
        print("\n(install hugin-tools to compare with Hugin's pano_trafo)")
    print(f"\ntry:  echo '0 719.5 539.5' | rigjax trafo {path}")
