"""The demo's seam pole: what the matching cost says there, and what the networks draw

    python benchmarks/stitch_pole.py [--checkpoint CKPT ...] [--samples 32]

`make demo` stitches test sample 0 of the shipped rig-aware config; a pole about 1 m from the
rig's centre stands in one of its seams. The pole's pixels are those of that sample that some input
sees, in the seams, above the horizon and nearer than 2 m (the truth's depth); the band is the
same rows 20 columns either side of it, where a stitch at the wrong depth puts the pole's ghosts.

1. The evidence: where two inputs see the point at the truth's depth plane, the matching cost
   (:func:`learnstitch.network.sweep.matching_cost`, through the inputs unwarped at the sample's
   own cameras) at that plane against its least at the two farthest planes, for boxes of 5, 3 and 1
   pixels, on the data as configured and photometrically clean.
2. The stitches at the pole, on the data as configured (the demo's): PSNR over the pole's pixels and
   over the band, and the share of the pole's pixels whose inverse depth is within 0.2 1/m of the
   truth's, for the true-rotation stitch, the depth oracle and each ``--checkpoint`` (rig-aware
   models; by default the one shipped for `make demo`).
3. The ghost cue (:func:`learnstitch.network.sweep.ghost_cost`) as evidence, over the first
   ``--samples`` test samples: at the seam pixels where the relative cost has a minimum below 0.5
   both among the planes 6 and nearer and at the two farthest planes (a near and a far answer), the
   share whose truth lies within a plane of the near minimum, against ``log(1 + g)`` at that plane.
Nothing is trained.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from _ablation import rig_aware_models
from _record import recorded

ROOT = Path(__file__).resolve().parents[1]
WEIGHTS = ROOT / "learnstitch" / "weights" / "cpu_tiny_depth_d04.pt"
NEAR_PLANE = 6  # the near answers: planes this far from infinity and nearer
GHOST_BINS = (0.0, 1.0, 2.0, 3.0, float("inf"))


def swept(model, test):
    """The sample's inputs (colour, mask) swept over ``model``'s planes at their own cameras:
    ``(1, N, 4, P, H, W)``."""
    import torch

    x = torch.cat([test.inputs, test.masks.to(test.inputs.dtype)[:, None]], dim=1)[None]  # (1, N, 4, H, W)
    return model.sweep(x, model.sweep_grid(*x.shape[-2:]))


def pole_of(test):
    """The pole's pixels ``(H, W)`` (seen, in the seams, above the horizon, nearer than 2 m), the band
    20 columns either side of them over the same rows, and the pole's columns."""
    import torch

    pole = test.near_seams(above_horizon=True)
    columns = torch.nonzero(pole.any(dim=0))[:, 0]
    rows = torch.nonzero(pole.any(dim=1))[:, 0]
    band = torch.zeros_like(pole)
    band[int(rows.min()) : int(rows.max()) + 1, max(int(columns.min()) - 20, 0) : int(columns.max()) + 21] = True
    return pole, band, columns


def main() -> None:
    import numpy as np
    import torch

    from learnstitch.baselines import depth_oracle_stitch, psnr, rotation_only_stitch
    from learnstitch.data.sample import nominal_unwarp_grids
    from learnstitch.data.store import SPLIT_SEED_BASE
    from learnstitch.evaluation import CLEAN_PHOTOMETRY, data_with, prepare_sample
    from learnstitch.network.sweep import matching_cost

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", action="append", help="a rig-aware checkpoint (repeatable)")
    parser.add_argument("--samples", type=int, default=32)
    args = parser.parse_args()
    checkpoints = args.checkpoint or [str(WEIGHTS)]
    models = rig_aware_models(checkpoints)
    model, config = models[0]
    planes = model.planes
    spacing = float(planes[1] - planes[0])
    grids, masks, _ = nominal_unwarp_grids(config.data)
    seed = SPLIT_SEED_BASE["test"]
    top = float(planes[-1])

    # 1. The evidence at the pole.
    print("**The matching cost at the pole** (test sample 0, the inputs at their own cameras):\n")
    print(
        "| data | box | pole pixels | two inputs see the truth's plane | cost there, median | "
        "least cost of the two farthest planes, median | truth's plane cheaper |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|")
    demo = {}  # the demo sample, as configured and clean
    for name, data in (("as configured", config.data), ("clean", data_with(config.data, CLEAN_PHOTOMETRY))):
        test = demo[name] = prepare_sample(data, seed, grids, masks, config.model.inputs)
        pole, _, _ = pole_of(test)
        sweep = swept(model, test)
        true_plane = (test.inverse_depth(top) / spacing).round().long()[None, None]
        for window in (5, 3, 1):
            cost, overlap = matching_cost(sweep[:, :, :3], sweep[:, :, 3], window)
            seen_twice = pole & (overlap.gather(1, true_plane)[0, 0] > 0)
            at_truth = cost.gather(1, true_plane)[0, 0][seen_twice]
            far = torch.where(overlap[0, :2] > 0, cost[0, :2], torch.inf).min(dim=0).values[seen_twice]
            print(
                f"| {name} | {window} | {int(pole.sum())} | {int(seen_twice.sum())} | {float(at_truth.median()):.4f} "
                f"| {float(far.median()):.4f} | {float((at_truth < far).float().mean()):.0%} |"
            )

    # 2. The stitches at the pole.
    test = demo["as configured"]
    pole, band, columns = pole_of(test)
    q = test.inverse_depth(top)
    truth = test.sample.pano
    rotation_only, _ = rotation_only_stitch(test.sample.fisheyes, test.sample.rig, config.data)
    rows = [
        ("true-rotation stitch", rotation_only, ""),
        (
            "depth oracle",
            depth_oracle_stitch(test.sample.fisheyes, test.lines, config.data, rotation_only),
            "the truth",
        ),
    ]
    for path, (net, _) in zip(checkpoints, models):
        with torch.no_grad():
            out = net(test.inputs[None], test.masks[None], centres=test.centres())
        shown = Path(path).resolve()
        shown = shown.relative_to(ROOT) if shown.is_relative_to(ROOT) else shown
        placed = ((out.inverse_depth[0] - q).abs() < 0.2)[pole].float().mean()
        rows.append((f"`{shown}`", out.pano[0].clamp(0.0, 1.0), f"{float(placed):.0%}"))
    print(
        f"\n**The stitches at the pole** (test sample 0 as configured: {int(pole.sum())} pole pixels in columns "
        f"{int(columns.min())}-{int(columns.max())} of {pole.shape[1]}, true inverse depth "
        f"{float(q[pole].min()):.2f}-{float(q[pole].max()):.2f} 1/m):\n"
    )
    print("| stitch | PSNR, pole's pixels (dB) | PSNR, band (dB) | pole's pixels at the truth's depth |")
    print("|---|---:|---:|---:|")
    for name, pano, placed in rows:
        print(f"| {name} | {float(psnr(pano, truth, pole)):.2f} | {float(psnr(pano, truth, band)):.2f} | {placed} |")

    # 3. The ghost cue as evidence, where the cost has a near and a far answer.
    counts = np.zeros((len(GHOST_BINS) - 1, 4))  # pixels, truth near, truth far, network near
    index = torch.arange(len(planes))[:, None, None]
    for k in range(args.samples):
        print(f"ghost cue: sample {k + 1}/{args.samples}", file=sys.stderr)
        test = prepare_sample(config.data, seed + k, grids, masks, config.model.inputs)
        q = test.inverse_depth(top)
        with torch.no_grad():
            out = model(test.inputs[None], test.masks[None], planes=True, colours=False, centres=test.centres())
            sweep = swept(model, test)
            cost, overlap = matching_cost(sweep[:, :, :3], sweep[:, :, 3], config.model.cost_window)
            cue = model.ghosts(cost, overlap, sweep[:, :, 3])[0]
        relative, seen_twice = out.plane_cost[0], out.plane_overlap[0] > 0
        near_cost = torch.where(seen_twice & (index >= NEAR_PLANE), relative, torch.inf)
        near_plane = near_cost.argmin(dim=0)
        far_cost = torch.where(seen_twice[:2], relative[:2], torch.inf).min(dim=0).values
        both = (near_cost.min(dim=0).values < 0.5) & (far_cost < 0.5)
        at_near = cue.gather(0, near_plane[None])[0]
        true_plane = (q / spacing).round().long()
        truth_near = (true_plane - near_plane).abs() <= 1
        network_near = (out.inverse_depth[0] - planes[near_plane]).abs() <= 1.5 * spacing
        for b in range(len(GHOST_BINS) - 1):
            m = both & (at_near >= GHOST_BINS[b]) & (at_near < GHOST_BINS[b + 1])
            counts[b] += [
                float(m.sum()),
                float((m & truth_near).sum()),
                float((m & (true_plane <= 2)).sum()),
                float((m & network_near).sum()),
            ]
    print(
        f"\n**The ghost cue as evidence** ({args.samples} test samples as configured; pixels where the relative "
        f"cost is below 0.5 at one of the two farthest planes and at a plane {NEAR_PLANE} or nearer; the near "
        f"answer is that plane of least cost; `{Path(checkpoints[0]).name}`'s depth read as near within 1.5 "
        "planes of it):\n"
    )
    print(
        "| log(1 + g) at the near answer | pixels | truth at the near answer | truth at the three farthest planes | network near |"
    )
    print("|---|---:|---:|---:|---:|")
    for b, (pixels, near, far, network) in enumerate(counts):
        if pixels:
            low, high = GHOST_BINS[b], GHOST_BINS[b + 1]
            print(
                f"| {low:g}-{high:g} | {int(pixels)} | {near / pixels:.0%} | {far / pixels:.0%} | {network / pixels:.0%} |"
            )


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main()
