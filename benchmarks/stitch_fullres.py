"""Full-resolution stitching of rigs of several shapes: the depth at a working size, every input resampled at full size.

    python benchmarks/stitch_fullres.py [--samples 3] [--first-seed 0] [--rigs tri_d02 tri_d04 dual ring4]
        [--workers 2] [--anyrig learnstitch/weights/cpu_tiny_anyrig.pt]

Each rig of `learnstitch.data.rigs.FULLRES_RIGS` (three 185° fisheyes 1024² at 0.2 and 0.4 m, a dual
fisheye of two 190° lenses 1024² 3 cm apart, a ring of four 150° fisheyes 768² 0.1 m out; orientations
±2° and hfov ±1° off the design) is rendered for `--samples` street scenes (seeds `--first-seed`, and on;
seam objects in the rig's own seams) with the lens and sensor of learnstitch's data (gain, vignetting, noise: "as
configured") and photometrically clean, and stitched into 2048×1024 panoramas by `learnstitch.fullres`
(`stitch_rig`, every input resampled at full resolution along its sight line), with the depth from:

- **nominal**: the rig's design, every centre at the origin (a rotation-only stitch);
- **true rotation**: the true cameras, every centre at the origin (no parallax correction);
- **depth oracle**: the truth's depth, and which inputs see each point (ray cast): what a warp can do at best;
- **truth's depth**: the truth's depth alone, as `--inverse-depth` gives it: which inputs see each point
  is the renderer's own test (`learnstitch.fullres.occlusion`, a z-buffer around each camera), and
  "no occlusion test" blends every input that sees the point's direction (`render.occlusion_tolerance: 0`):
  how far the renderer reaches through a perfect depth;
- **given depths, mixed**: the depth the network of any rig's panorama was rendered at
  (`Stitched.rendered_depth`, what `--depth d.npy` writes) given back as a full-size depth ("network's,
  given": through the occlusion test), and the truth's depth where two or more inputs truly see the
  point ("two-view") or where one alone does ("one-view"), the network's elsewhere: where a better
  depth pays;
- **network, three cameras**: the rig-aware network of the three-fisheye rig
  (`learnstitch/weights/cpu_tiny_depth_d04.pt`, trained on 128² triplets) on its 256×128 canvas, the
  inputs read from their full-size images; three-camera rigs only;
- **network, any rig**: the network of any rig (`--anyrig`, `configs/stitch/cpu_tiny_anyrig.yaml`:
  pooled over the inputs, trained on random rigs of 2–6 cameras at 128²), the same way, on every rig;
  "its blend": the inputs weighted by their shares of the network's own blend too (`render.blend: network`);
  "no surface rule": the network's own depth (`model.surface_rule: 0`), what the shipped rule and its
  grown surface (`surface_rule: 2`, `surface_grow: 4`) are measured against; "not refined": its working depth
  brought up as it is (`render.refine_levels: 0`), without the refinement by the full-resolution inputs'
  agreement (`learnstitch.fullres.refine`, on by default);
- **sweep**: the plane sweep at 512×256 (no network), refined the same way, any rig.

PSNR in dB over the whole panorama, the seams (two inputs of the nominal rig see the pixel), the seen
pixels (some input sees the scene point) and the near objects in the seams (seen, in the seams, nearer
than 2 m); "gap" is the share of the true-rotation → oracle gap that a method closes over the clean seen
pixels and over the clean near objects in the seams. Every method corrects colour the same way (each
input's exposure and the lens's vignetting fitted in the working canvas's overlaps), so the tables compare
geometry. Time: `stitch_rig` in a worker process of one thread (tables, depth, photometry, render),
median; `benchmarks/stitch_fullres_speed.py` times the command as a user runs it.
"""

from __future__ import annotations

import argparse
import dataclasses
import multiprocessing
import statistics
import sys
from pathlib import Path

from _record import recorded

ROOT = Path(__file__).resolve().parents[1]
METHODS = (
    "nominal",
    "true rotation",
    "depth oracle",
    "truth's depth",
    "truth's depth, no occlusion test",
    "given: network's",
    "given: truth's two-view, network's elsewhere",
    "given: truth's one-view, network's elsewhere",
    "network, three cameras",
    "network, any rig",
    "network, any rig, not refined",
    "network, any rig, its blend",
    "network, any rig, no surface rule",
    "sweep",
)
REGIONS = ("whole", "seams", "seen", "near")
WIDTH = 2048


def arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=3)
    parser.add_argument("--first-seed", type=int, default=0, help="the first scene's seed (seeds used for no tuning)")
    parser.add_argument("--rigs", nargs="+", default=["tri_d02", "tri_d04", "dual", "ring4"])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--anyrig", default=str(ROOT / "learnstitch" / "weights" / "cpu_tiny_anyrig.pt"))
    return parser.parse_args()


def _init() -> None:
    from learnstitch.worker import setup_worker

    setup_worker(torch_threads=1)


def score(job: tuple[str, int, str]) -> dict:
    """Every method's PSNR per region on one sample of one rig, as configured and clean."""
    import numpy as np
    import torch

    from learnstitch.baselines import psnr
    from learnstitch.checkpoint import load_model
    from learnstitch.data.rig import unwarp_grids
    from learnstitch.data.rigs import FULLRES_RIGS, render_rig
    from learnstitch.data.sample import SynthConfig
    from learnstitch.data.store import to_uint8
    from learnstitch.data.visibility import rig_sight_lines
    from learnstitch.evaluation import NEAR_M
    from learnstitch.fullres.config import RenderConfig
    from learnstitch.fullres.rig import Rig
    from learnstitch.fullres.stitcher import GivenDepth, NetworkDepth, Stitcher, stitch_rig
    from learnstitch.inference import SHIPPED_MODEL

    name, seed, anyrig = job
    shape = FULLRES_RIGS[name]
    n = len(shape.yaws)
    circle = np.full(n, shape.hfov)
    configured = SynthConfig()
    clean = SynthConfig(gain_jitter=0.0, vignetting=0.0, noise_std=0.0)
    out = {"rig": name, "seed": seed, "psnr": {}, "seconds": {}}
    networks = [("network, three cameras", *load_model(SHIPPED_MODEL)), ("network, any rig", *load_model(anyrig))]
    lines = None
    for photometry, label in ((configured, "configured"), (clean, "clean")):
        sample = render_rig(shape, seed, WIDTH, photometry)
        if lines is None:  # the geometry is the same for both
            lines = rig_sight_lines(sample.scene, sample.rig.cameras, sample.rig.centres, sample.depth, shape.hfov)
            _, masks, _ = unwarp_grids(shape.nominal(), (WIDTH, WIDTH // 2), shape.hfov)
            seams = masks.sum(dim=0) >= 2
            regions = {
                "whole": None,
                "seams": seams,
                "seen": lines.seen,
                "near": lines.seen & seams & (sample.depth < NEAR_M),
            }
        images = [to_uint8(f) for f in sample.fisheyes]
        rig = Rig(sample.rig.cameras, np.asarray(sample.rig.centres), images, [], WIDTH, True)
        inverse_depth = torch.where(torch.isfinite(sample.depth), 1.0 / sample.depth, torch.zeros_like(sample.depth))
        fitted = RenderConfig()  # every method with the fitted colour correction
        panos = {}
        panos["nominal"] = stitch_rig(
            rig._replace(cameras=shape.nominal(), centres=np.zeros((n, 3))), WIDTH, fitted, circle_deg=circle
        )
        panos["true rotation"] = stitch_rig(rig._replace(centres=np.zeros((n, 3))), WIDTH, fitted, circle_deg=circle)
        oracle = GivenDepth(full=inverse_depth, visibility=lines.visible)
        panos["depth oracle"] = stitch_rig(rig, WIDTH, fitted, oracle, circle_deg=circle)
        truth = GivenDepth(full=inverse_depth)
        panos["truth's depth"] = stitch_rig(rig, WIDTH, fitted, truth, circle_deg=circle)
        untested = dataclasses.replace(fitted, occlusion_tolerance=0.0)
        panos["truth's depth, no occlusion test"] = stitch_rig(rig, WIDTH, untested, truth, circle_deg=circle)
        for method, model, trained in networks:
            if model.inputs not in (None, n):  # None: a network of any rig
                continue
            working = NetworkDepth(model, trained.data.pano_width)
            stitcher = Stitcher.prepare(rig, WIDTH, trained.render, working, circle_deg=circle)
            stitcher.keep_depth = model.inputs is None
            panos[method] = stitcher.still()
            if model.inputs is None:
                network = panos[method].rendered_depth
                views = lines.visible.sum(dim=0)
                for mixed, where in (
                    ("network's", None),
                    ("truth's two-view", views >= 2),
                    ("truth's one-view", views == 1),
                ):
                    given = network if where is None else torch.where(where, inverse_depth.float(), network)
                    row = f"given: {mixed}" + ("" if where is None else ", network's elsewhere")
                    panos[row] = stitch_rig(rig, WIDTH, trained.render, GivenDepth(full=given), circle_deg=circle)
                blend = dataclasses.replace(trained.render, blend="network")
                panos[f"{method}, its blend"] = stitch_rig(rig, WIDTH, blend, working, circle_deg=circle)
                shipped = model.config
                model.config = dataclasses.replace(shipped, surface_rule=0.0, surface_grow=0)
                panos[f"{method}, no surface rule"] = stitch_rig(rig, WIDTH, trained.render, working, circle_deg=circle)
                model.config = shipped
                coarse = dataclasses.replace(trained.render, refine_levels=0)
                panos[f"{method}, not refined"] = stitch_rig(rig, WIDTH, coarse, working, circle_deg=circle)
        panos["sweep"] = stitch_rig(rig, WIDTH, RenderConfig(), circle_deg=circle)
        for method, stitched in panos.items():
            image = torch.from_numpy(stitched.pano).permute(2, 0, 1).float() / 255.0
            out["psnr"][(label, method)] = {
                region: float(psnr(image, sample.pano, mask)) for region, mask in regions.items()
            }
            out["seconds"][(label, method)] = sum(stitched.seconds.values())
    print(f"{name} sample {seed} done", file=sys.stderr)
    return out


def gap(mean, method: str, region: str) -> float:
    """The share of the true-rotation → oracle gap ``method`` closes over the clean ``region``."""
    base = mean("true rotation", region, "clean")
    return (mean(method, region, "clean") - base) / (mean("depth oracle", region, "clean") - base)


def main(args: argparse.Namespace) -> None:
    import torch  # noqa: F401  (the page's machine line names its version)

    seeds = range(args.first_seed, args.first_seed + args.samples)
    jobs = [(name, seed, args.anyrig) for name in args.rigs for seed in seeds]
    with multiprocessing.get_context("spawn").Pool(args.workers, initializer=_init) as pool:
        results = pool.map(score, jobs, chunksize=1)
    print(
        f"\n{args.samples} samples per rig (seeds {seeds.start}–{seeds.stop - 1}), {WIDTH}×{WIDTH // 2} panoramas; "
        "PSNR (dB), mean over the samples.\n"
    )
    for label in ("configured", "clean"):
        print(f"\n**{'As configured' if label == 'configured' else 'Photometrically clean'}**\n")
        print("| rig | method | whole | seams | seen | near objects in the seams | gap: seen | gap: near | time (s) |")
        print("|---|---|---:|---:|---:|---:|---:|---:|---:|")
        for name in args.rigs:
            mine = [r for r in results if r["rig"] == name]

            def mean(method, region, which=label, mine=mine):
                return statistics.fmean(r["psnr"][(which, method)][region] for r in mine)

            for method in METHODS:
                if (label, method) not in mine[0]["psnr"]:
                    continue
                time = statistics.median(r["seconds"][(label, method)] for r in mine)
                cells = " | ".join(f"{mean(method, region):.2f}" for region in REGIONS)
                shares = " | ".join(
                    ""
                    if method in ("nominal", "true rotation", "depth oracle")
                    else f"{100 * gap(mean, method, region):.0f} %"
                    for region in ("seen", "near")
                )
                print(f"| {name} | {method} | {cells} | {shares} | {time:.2f} |")


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main(arguments())
