#!/usr/bin/env python3
"""Benchmark: how far off may ``rigjax calibrate``'s start be? Plain LM against LM from Lévy-flight starts.

The rig of ``rigjax demo`` and of the calibration tests (six 1440x1080 full-frame fisheyes 60 degrees
apart, hfov 123, K2 -0.01, orientations jittered by 2 degrees) is rendered once from the procedural
environment and matched once with the template ``configs/rig/ring6.yaml``. Then, for each of N seeded
draws, every camera's nominal yaw/pitch/roll in the template is moved by an independent offset, uniform
in +-45 degrees of yaw and +-20 degrees of pitch and roll, and the matches are calibrated twice from it:

* ``plain LM``: the template with ``levy: false`` (staged LM from the start, then pruning);
* ``Lévy``: the template as shipped (the Lévy-flight search, its best starts in one ``optimise_batch``
  call, the best result pruned).

A calibration succeeds when every ray of every camera (a 24x24 raster, corners included) lies within
1 arcmin of the truth after the one global rotation that the anchor leaves free. The table gives the
success rate, the median and worst largest ray error, after LM (the best start, before pruning) and
after pruning, and the median wall time per calibration (matching excluded: it does not depend on
the start, and its time is printed apart; the first calibration of each kind compiles and is left
out of the median).

    python benchmarks/calibrate_montecarlo.py [--draws 100] [--seed 0]
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np
from _record import recorded

import rigjax
from rigjax import synthetic

TEMPLATE = "configs/rig/ring6.yaml"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--draws", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--yaw", type=float, default=45.0, help="half-width of the yaw offsets (degrees)")
    parser.add_argument("--tilt", type=float, default=20.0, help="half-width of the pitch/roll offsets (degrees)")
    args = parser.parse_args()

    truth = synthetic.ring_rig(orientation_jitter_deg=2.0, seed=1)
    images = synthetic.render_images(truth, synthetic.procedural_environment(4096, seed=0), noise_std=2.0, seed=0)
    template = rigjax.load_template(TEMPLATE)
    tic = time.perf_counter()
    matches = rigjax.match_images(images, template)
    match_s = time.perf_counter() - tic
    sizes = [(im.shape[1], im.shape[0]) for im in images]
    nominal = np.array(template.rig.orientations, float)
    rng = np.random.default_rng(args.seed)
    half = np.array([args.yaw, args.tilt, args.tilt])
    methods = {"plain LM": dataclasses.replace(template, levy=None), "Lévy": template}
    rows = {name: ([], [], []) for name in methods}  # error after LM, after pruning, seconds
    print(
        f"matching {len(images)} images: {match_s:.1f} s; {args.draws} draws, offsets +-{args.yaw:g} yaw, "
        f"+-{args.tilt:g} pitch/roll (degrees)"
    )
    for draw in range(args.draws):
        start = nominal + rng.uniform(-half, half, nominal.shape)
        line = [f"draw {draw:>3}"]
        for name, config in methods.items():
            config = dataclasses.replace(
                config, rig=dataclasses.replace(config.rig, orientations=tuple(map(tuple, start)))
            )
            tic = time.perf_counter()
            calibration = rigjax.calibrate_matches(matches, sizes, config, seed=draw)
            seconds = time.perf_counter() - tic
            lm = float(synthetic.ray_errors_arcmin(calibration.search[0].project, truth).max())
            error = float(synthetic.ray_errors_arcmin(calibration.project, truth).max())
            for values, value in zip(rows[name], (lm, error, seconds)):
                values.append(value)
            line.append(f"{name} {lm:9.3f}' -> {error:9.3f}' {seconds:5.1f} s")
        print("  ".join(line), file=sys.stderr, flush=True)

    print(
        "\n| start offsets (uniform) | method | success (all rays < 1') | max error after LM: median, worst | "
        "after pruning: median, worst | median time per calibration |"
    )
    print("|---|---|---|---|---|---|")
    for name, (lm, errors, seconds) in rows.items():
        ok = sum(e < 1.0 for e in errors)
        print(
            f"| +-{args.yaw:g} yaw, +-{args.tilt:g} p/r | {name} | {ok}/{len(errors)} ({100 * ok / len(errors):.0f} %) | "
            f"{statistics.median(lm):.3f}', {max(lm):.3f}' | {statistics.median(errors):.3f}', {max(errors):.3f}' | "
            f"{statistics.median(seconds[1:] or seconds):.1f} s |"
        )


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main()
