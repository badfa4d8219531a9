#!/usr/bin/env python3
"""Benchmark: control-point projects with 15 % and 30 % wrong matches, rigjax's pruning against
Hugin's ``cpclean`` + ``autooptimiser``.

Each seeded problem is the 6-camera cube rig (1440x1080 full-frame fisheyes, hfov 123, K2 -0.01,
orientations jittered by 3 degrees) with control points from 4000 random directions (~2600 points)
at 0.3 px noise, of which a fraction gets its second end moved to a random pixel (wrong matches);
the start is 1-3 degrees off with every hfov 2-3 degrees wide and K2 at 0; the ``v`` lines free
y/p/r of images 1-5 and v, b of every image. Rows, in one run:

* ``rigjax.optimise_pruned(start, "YPR,VBYPR")``: what ``rigjax optimise IN.pto -o OUT.pto`` does
  by default (staged LM with a Cauchy loss, then least-squares pruning rounds);
* the noise floor: ``rigjax.optimise`` on the good points only (an oracle that knows which are wrong);
* ``cpclean`` (Hugin's statistical cleaning: pairwise, then whole-panorama, mean + 2 sigma) followed
  by ``autooptimiser -n``, wall time of both processes;
* ``autooptimiser -n`` alone, for reference: what the wrong matches do unremoved.

Columns: wrong matches removed, good ones removed (share of each), the largest ray error of any
camera against the truth (24x24 raster per image, arcmin; the success criterion is 1 arcmin), and
the time.

    python benchmarks/prune_compare.py [--problems 5]

Without Hugin's tools (``apt-get install hugin-tools``) only rigjax's rows are printed.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np
from _record import recorded

import rigjax
from rigjax import synthetic


def problem(fraction: float, seed: int) -> tuple[rigjax.Project, rigjax.Project, np.ndarray]:
    """(truth with the wrong matches, start, which control points are wrong)."""
    rig = synthetic.cube_rig(orientation_jitter_deg=3.0, seed=seed)
    truth = synthetic.control_points_from_truth(rig, 4000, noise_px=0.3, outlier_fraction=fraction, seed=seed + 100)
    clean = synthetic.control_points_from_truth(rig, 4000, noise_px=0.3, seed=seed + 100)
    wrong = np.any(truth.control_points.xy_b != clean.control_points.xy_b, axis=1)
    start = synthetic.perturb(truth, angle_deg=(1.0, 3.0), hfov_offset_deg=(2.0, 3.0), b=0.0, seed=seed + 200)
    variables = [rigjax.OptVariable(letter, k) for k in range(1, 6) for letter in "ypr"]
    variables += [rigjax.OptVariable(letter, k) for k in range(6) for letter in "vb"]
    return truth, start.replace(variables=tuple(variables)), wrong


def kept_by_coordinates(start: rigjax.Project, cleaned: rigjax.Project) -> np.ndarray:
    """Which of ``start``'s control points a cleaned project still has (matched by their pixels as
    written to the file)."""

    def keys(cps):
        return [
            (int(a), int(b), *np.round([*xa, *xb], 3))
            for a, b, xa, xb in zip(cps.image_a, cps.image_b, cps.xy_a, cps.xy_b)
        ]

    left = set(keys(cleaned.control_points))
    return np.array([key in left for key in keys(start.control_points)])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--problems", type=int, default=5)
    args = parser.parse_args()
    hugin = shutil.which("cpclean") is not None and shutil.which("autooptimiser") is not None
    fractions = (0.15, 0.30)
    results: dict[tuple[float, str], list[tuple[float, float, float, float]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for fraction in fractions:
            for seed in range(args.problems):
                truth, start, wrong = problem(fraction, seed)
                tic = time.perf_counter()
                pruned = rigjax.optimise_pruned(start, "YPR,VBYPR")
                seconds = time.perf_counter() - tic
                error = float(synthetic.ray_errors_arcmin(pruned.project, truth).max())
                results.setdefault((fraction, "rigjax"), []).append(
                    (1 - pruned.kept[wrong].mean(), 1 - pruned.kept[~wrong].mean(), error, seconds)
                )
                tic = time.perf_counter()
                oracle = rigjax.optimise(start, "YPR,VBYPR", weights=(~wrong).astype(float))
                seconds = time.perf_counter() - tic
                error = float(synthetic.ray_errors_arcmin(oracle.project, truth).max())
                results.setdefault((fraction, "oracle"), []).append((1.0, 0.0, error, seconds))
                if not hugin:
                    continue
                start_path, clean_path, out_path = (Path(tmp) / name for name in ("start.pto", "clean.pto", "out.pto"))
                start.save(start_path)
                tic = time.perf_counter()
                subprocess.run(["cpclean", "-o", str(clean_path), str(start_path)], check=True, capture_output=True)
                subprocess.run(
                    ["autooptimiser", "-n", "-o", str(out_path), str(clean_path)], check=True, capture_output=True
                )
                seconds = time.perf_counter() - tic
                kept = kept_by_coordinates(start, rigjax.load_project(clean_path))
                error = float(synthetic.ray_errors_arcmin(rigjax.load_project(out_path), truth).max())
                results.setdefault((fraction, "cpclean"), []).append(
                    (1 - kept[wrong].mean(), 1 - kept[~wrong].mean(), error, seconds)
                )
                tic = time.perf_counter()
                subprocess.run(
                    ["autooptimiser", "-n", "-o", str(out_path), str(start_path)], check=True, capture_output=True
                )
                seconds = time.perf_counter() - tic
                error = float(synthetic.ray_errors_arcmin(rigjax.load_project(out_path), truth).max())
                results.setdefault((fraction, "hugin"), []).append((0.0, 0.0, error, seconds))
                print(
                    f"fraction {fraction:.2f} seed {seed}: "
                    + ", ".join(
                        f"{name} {results[(fraction, name)][-1][2]:.2f}'"
                        for name in ("rigjax", "oracle", "cpclean", "hugin")
                    ),
                    file=sys.stderr,
                    flush=True,
                )

    labels = {
        "rigjax": "rigjax optimise (YPR,VBYPR + pruning)",
        "oracle": "noise floor: rigjax on the good points only",
        "cpclean": "cpclean + autooptimiser -n",
        "hugin": "autooptimiser -n, no cleaning",
    }
    n_points = len(problem(0.15, 0)[1].control_points)
    print(
        f"\n{args.problems} problems per fraction: cube rig, ~{n_points} control points at 0.3 px; "
        f"jax {jax.__version__}, {jax.devices()[0].platform}\n"
    )
    print(
        "| wrong matches | method | wrong removed | good removed | max ray error (median, worst) | "
        "all rays < 1' | median time |"
    )
    print("|---|---|---|---|---|---|---|")
    for (fraction, name), values in results.items():
        errors = [v[2] for v in values]
        print(
            f"| {100 * fraction:.0f} % | {labels[name]} | {100 * statistics.mean(v[0] for v in values):.1f} % | "
            f"{100 * statistics.mean(v[1] for v in values):.1f} % | {statistics.median(errors):.2f}', "
            f"{max(errors):.2f}' | {sum(e < 1.0 for e in errors)}/{len(errors)} | "
            f"{statistics.median(v[3] for v in values):.2f} s |"
        )
    print("(rigjax times include the first call's compilation of each padded problem size; medians hide it)")


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main()
