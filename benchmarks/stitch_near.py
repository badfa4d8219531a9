"""Near objects in the seams: what the rig-aware models draw there, against the true-rotation stitch and the depth oracle

    python benchmarks/stitch_near.py [--samples 32] [--checkpoint CKPT ...]

Each ``--checkpoint`` (a rig-aware model; by default the shipped one for any rig,
`learnstitch/weights/cpu_tiny_anyrig.pt`) on the first ``--samples`` seeds of the three-fisheye
test split (128² fisheyes, 256×128 panoramas) at d = 0.2 and 0.4 m, as configured and
photometrically clean. PSNR pooled over two regions: the **near objects in the seams** (the truth's
depth under 2 m, seen by some input from its own centre, inside two or more image circles) and all
**seen** pixels; beside the true-rotation stitch and the depth oracle, and the share of the gap
between those two that each model closes. The depth column is the share of the near seam pixels
whose predicted inverse depth lies within one plane of the truth's. Then the demo's pole (test
sample 0 as configured at d = 0.4 m, the sample `learnstitch demo` stitches; its pixels are those
seen, in the seams, above the horizon and nearer than 2 m): PSNR over them and the same depth share.
Each checkpoint runs without ``model.surface_rule``, with it at ``--surface-rule`` planes (2 by
default; 0: as its config says): its depth replaced by the first surface wherever that is so many
planes nearer, and with that surface grown ``--surface-grow`` pixels (``model.surface_grow``, 4 by
default; 0: not) into where one input's ray ends. The near seam objects are also split by how many
inputs see each point (ray cast): one alone, or two or more. Last, what placing them would be worth:
the last model with the truth's depth put in at the near seam points two or more inputs see (what
matching between views can reach), at those one input alone sees, and at all. Nothing is trained.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import math
import sys
from pathlib import Path

from _ablation import rig_aware_models
from _record import RESULTS, recorded

ROOT = Path(__file__).resolve().parents[1]
WEIGHTS = ROOT / "learnstitch" / "weights" / "cpu_tiny_anyrig.pt"
FIGURE = "stitch_near_pole.png"
SETTINGS = ((0.2, "as configured"), (0.2, "clean"), (0.4, "as configured"), (0.4, "clean"))
# The last model's depth with the truth's at these near seam points (near, one input alone sees them).
CEILINGS = {
    "the truth's depth where two or more inputs see": lambda near, alone: near & ~alone,
    "the truth's depth where one input sees": lambda near, alone: near & alone,
    "the truth's depth at every near seam point": lambda near, alone: near,
}


def shown(path: str) -> str:
    resolved = Path(path).resolve()
    return str(resolved.relative_to(ROOT) if resolved.is_relative_to(ROOT) else resolved)


def main() -> None:
    import torch

    from learnstitch.baselines import depth_oracle_stitch, rotation_only_stitch
    from learnstitch.data.sample import nominal_unwarp_grids
    from learnstitch.data.store import SPLIT_SEED_BASE, write_png
    from learnstitch.evaluation import CLEAN_PHOTOMETRY, data_with, prepare_sample

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", action="append", help="a rig-aware checkpoint (repeatable)")
    parser.add_argument("--samples", type=int, default=32)
    parser.add_argument(
        "--surface-rule",
        type=float,
        default=2.0,
        help="also each checkpoint with model.surface_rule at this many planes (0: not)",
    )
    parser.add_argument(
        "--surface-grow",
        type=int,
        default=4,
        help="also each checkpoint with the rule's surface grown this many pixels (0: not)",
    )
    args = parser.parse_args()
    checkpoints = args.checkpoint or [str(WEIGHTS)]
    models = dict(zip(map(shown, checkpoints), rig_aware_models(checkpoints)))
    if args.surface_rule > 0:  # each checkpoint without the rule (whatever its config says) and with it
        for name, (model, config) in list(models.items()):
            del models[name]
            variants = [
                (0.0, 0, "no first-surface rule"),
                (args.surface_rule, 0, f"first-surface rule ({args.surface_rule:g} planes)"),
            ]
            if args.surface_grow > 0:
                label = f"first-surface rule ({args.surface_rule:g} planes), grown {args.surface_grow} px"
                variants.append((args.surface_rule, args.surface_grow, label))
            for rule, grow, label in variants:
                variant = copy.deepcopy(model)
                variant.config = dataclasses.replace(model.config, surface_rule=rule, surface_grow=grow)
                models[f"{name}, {label}"] = (variant, config)
    reference = next(iter(models.values()))[1].data
    last = list(models)[-1]  # the one whose depth the truth's is put into (CEILINGS)
    torch.set_grad_enabled(False)

    sums: dict[tuple, list[float]] = {}  # (d, photometry, method, region) -> [squared error, pixels]

    def add(key: tuple, image: torch.Tensor, truth: torch.Tensor, where: torch.Tensor) -> None:
        error = ((image.clamp(0.0, 1.0) - truth) ** 2).mean(dim=0)[where]
        total = sums.setdefault(key, [0.0, 0.0])
        total[0] += float(error.sum())
        total[1] += float(where.sum())

    pole_rows = []
    for distance, photometry in SETTINGS:
        overrides = {"rig": "tri", "distance": distance, **(CLEAN_PHOTOMETRY if photometry == "clean" else {})}
        data = data_with(reference, overrides)
        grids, masks, _ = nominal_unwarp_grids(data)
        for index in range(args.samples):
            print(f"d = {distance:g}, {photometry}: sample {index + 1}/{args.samples}", file=sys.stderr)
            test = prepare_sample(data, SPLIT_SEED_BASE["test"] + index, grids, masks, "calibrated")
            sample, seen, near = test.sample, test.regions["seen"], test.near_seams()
            alone = test.lines.visible.sum(dim=0) == 1  # one input sees the point (ray cast), the others not
            pole = test.near_seams(above_horizon=True) if index == 0 else None
            rotation_only = rotation_only_stitch(sample.fisheyes, sample.rig, data)[0]
            panos = {
                "true-rotation stitch": (rotation_only, None),
                "depth oracle": (depth_oracle_stitch(sample.fisheyes, test.lines, data, rotation_only), None),
            }
            for name, (model, config) in models.items():
                own = data_with(config.data, overrides)  # the same sample, rendered again only for other data keys
                inputs = test if own == data else prepare_sample(own, sample.seed, grids, masks, config.model.inputs)
                centres = test.centres()
                out = model(inputs.inputs[None], inputs.masks[None], centres=centres)
                panos[name] = (out.pano[0], out.inverse_depth[0])
                if name != last:
                    continue
                # Its depth with the truth's put in at some near seam points: what placing them
                # would be worth, by how many inputs see them.
                truth = test.inverse_depth(float(model.planes[-1]))
                for label, where in CEILINGS.items():
                    given = torch.where(where(near, alone), truth, out.inverse_depth[0])
                    placed = model(inputs.inputs[None], inputs.masks[None], inverse_depth=given[None], centres=centres)
                    add((distance, photometry, f"{name}, {label}", "near"), placed.pano[0], sample.pano, near)
            demo = index == 0 and distance == 0.4 and photometry == "as configured"
            for method, (pano, inverse_depth) in panos.items():
                add((distance, photometry, method, "near"), pano, sample.pano, near)
                add((distance, photometry, method, "seen"), pano, sample.pano, seen)
                add((distance, photometry, method, "near, one view"), pano, sample.pano, near & alone)
                add((distance, photometry, method, "near, two views"), pano, sample.pano, near & ~alone)
                within = None
                if inverse_depth is not None:
                    model = models[method][0]
                    spacing = float(model.planes[1] - model.planes[0])
                    within = (inverse_depth - test.inverse_depth(float(model.planes[-1]))).abs() <= spacing
                    total = sums.setdefault((distance, photometry, method, "within"), [0.0, 0.0])
                    total[0] += float(within[near].sum())
                    total[1] += float(near.sum())
                if demo:
                    pole_rows.append((method, pano, within, pole, sample.pano))

    def psnr(key: tuple) -> float:
        error, count = sums[key]
        return 10.0 * math.log10(count / max(error, 1e-12))

    print(
        f"{args.samples} test samples of the three-fisheye rig per row, inputs at each sample's own cameras. "
        "PSNR (dB) pooled over each region's pixels; gap closed: (model − true-rotation) / (oracle − "
        "true-rotation) in dB; depth: the near seam pixels whose inverse depth is within one plane of the truth's.\n"
    )
    print(
        "| d (m) | data | stitch | near seam pixels | PSNR near seam objects | gap closed | PSNR seen | "
        "gap closed | depth within one plane |"
    )
    print("|---:|---|---|---:|---:|---:|---:|---:|---:|")
    for distance, photometry in SETTINGS:
        base = {region: psnr((distance, photometry, "true-rotation stitch", region)) for region in ("near", "seen")}
        best = {region: psnr((distance, photometry, "depth oracle", region)) for region in ("near", "seen")}
        for method in ("true-rotation stitch", "depth oracle", *models):
            cells = []
            for region in ("near", "seen"):
                value = psnr((distance, photometry, method, region))
                gap = (value - base[region]) / (best[region] - base[region])
                cells += [f"{value:.2f}", f"{gap:.0%}" if method in models else ""]
            within = sums.get((distance, photometry, method, "within"))
            depth = f"{within[0] / within[1]:.0%}" if within else ""
            pixels = int(sums[distance, photometry, method, "near"][1])
            name = f"`{method}`" if method in models else method
            print(f"| {distance:g} | {photometry} | {name} | {pixels} | {' | '.join(cells)} | {depth} |")
    print(
        "\n**Near seam objects by how many inputs see them** (ray cast: inside the image circle, not occluded). "
        "A point near the rig in a seam often lies in one camera's circle only, though its direction from the "
        "centre is in two; no match between views can place it. PSNR (dB) and the share of the gap closed:\n"
    )
    print("| d (m) | data | stitch | one view: pixels | PSNR | gap closed | two or more: pixels | PSNR | gap closed |")
    print("|---:|---|---|---:|---:|---:|---:|---:|---:|")
    for distance, photometry in SETTINGS:
        for method in models:
            cells = []
            for region in ("near, one view", "near, two views"):
                base, best = (psnr((distance, photometry, m, region)) for m in ("true-rotation stitch", "depth oracle"))
                value = psnr((distance, photometry, method, region))
                pixels = int(sums[distance, photometry, method, region][1])
                cells += [str(pixels), f"{value:.2f}", f"{(value - base) / (best - base):.0%}"]
            print(f"| {distance:g} | {photometry} | `{method}` | {' | '.join(cells)} |")
    print(
        f"\n**What placing them would be worth**: `{last}` with the truth's depth put in at the near seam "
        "points that two or more inputs see (where matching between views can place them), at those one "
        "input alone sees (where only cues from one view can), and at all of them; its own blend. PSNR (dB) "
        "over all near seam objects and the share of the gap closed:\n"
    )
    print("| d (m) | data | " + " | ".join(["its own depth", *CEILINGS]) + " |")
    print("|---:|---|" + "---:|" * (1 + len(CEILINGS)))
    for distance, photometry in SETTINGS:
        base, best = (psnr((distance, photometry, m, "near")) for m in ("true-rotation stitch", "depth oracle"))
        cells = []
        for method in [last, *(f"{last}, {label}" for label in CEILINGS)]:
            value = psnr((distance, photometry, method, "near"))
            cells.append(f"{value:.2f} ({(value - base) / (best - base):.0%})")
        print(f"| {distance:g} | {photometry} | {' | '.join(cells)} |")
    if pole_rows:
        pixels = int(pole_rows[0][3].sum())
        print(
            f"\n**The demo's pole** (test sample 0 as configured, d = 0.4 m; {pixels} pixels seen, in the seams, "
            "above the horizon and nearer than 2 m):\n"
        )
        print("| stitch | PSNR over the pole (dB) | pole pixels within one plane of the truth |")
        print("|---|---:|---:|")
        for method, pano, within, pole, truth in pole_rows:
            error = float(((pano.clamp(0.0, 1.0) - truth) ** 2).mean(dim=0)[pole].mean())
            depth = f"{float(within[pole].float().mean()):.0%}" if within is not None else ""
            name = f"`{method}`" if method in models else method
            print(f"| {name} | {10.0 * math.log10(1.0 / max(error, 1e-12)):.2f} | {depth} |")
        figure = pole_figure([pole_rows[0][4]] + [row[1] for row in pole_rows], pole_rows[0][3])
        write_png(RESULTS / FIGURE, figure)
        names = ", ".join(["the truth", *(row[0] for row in pole_rows)])
        print(f"\n![The demo's pole]({FIGURE}) *Around the pole, three times its size, left to right: {names}.*")


def pole_figure(images: list, pole):
    """The pole's rows and 25 columns either side of it from each image, side by side, three times
    their size."""
    import torch

    rows = torch.nonzero(pole.any(dim=1))[:, 0]
    columns = torch.nonzero(pole.any(dim=0))[:, 0]
    top, bottom = max(int(rows.min()) - 8, 0), int(rows.max()) + 9
    left, right = max(int(columns.min()) - 25, 0), int(columns.max()) + 26
    gap = torch.ones(3, bottom - top, 2)
    crops = [torch.cat([image.clamp(0.0, 1.0)[:, top:bottom, left:right], gap], dim=2) for image in images]
    return torch.cat(crops, dim=2).repeat_interleave(3, dim=1).repeat_interleave(3, dim=2)


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main()
