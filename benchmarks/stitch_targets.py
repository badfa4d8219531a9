"""A rig-aware stitching model against the references and the issue's targets, without training.

    python benchmarks/stitch_targets.py [--config cpu_tiny_depth_d04]
        [--checkpoint learnstitch/weights/cpu_tiny_depth_d04.pt] [--samples 32] [--workers 2]
        [--small cpu_small_depth_d04]

A checkpoint of a rig-aware config (``model.warp: depth``; by default the model shipped for
`make demo`) on the first ``--samples`` seeds of the test split at d = 0.2 and 0.4 m, as
configured and photometrically clean (``gain_jitter=0 vignetting=0 noise_std=0``), with its
colour correction on and off: PSNR over the whole panorama, its seams and the pixels some input
sees, beside the true-rotation stitch and the depth oracle (every input resampled through the
true depth), and the two targets at d = 0.4 m; then the same weights at the ``--small`` config's
size (256-pixel fisheyes: the geometry is in angles). For a model with a fill (``model.fill: true``),
what the fill adds where no input sees: the same weights with the fill head removed. Nothing is
trained; ``benchmarks/stitch_geometry.py`` trains and compares every network.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import sys
from pathlib import Path

from _ablation import CLEAN, mean_psnr
from _record import recorded

ROOT = Path(__file__).resolve().parents[1]
WEIGHTS = ROOT / "learnstitch" / "weights" / "cpu_tiny_depth_d04.pt"


def main() -> None:
    from learnstitch import load_config
    from learnstitch.evaluation import METHOD_NAMES, REGIONS, evaluate

    names = {
        "rotation_only": METHOD_NAMES["rotation_only"],
        "depth_oracle": METHOD_NAMES["depth_oracle"],
        "network": "network",
        "network_gain_off": "network, colour correction off",
    }

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="cpu_tiny_depth_d04", help="configs/stitch/NAME.yaml")
    parser.add_argument("--checkpoint", default=str(WEIGHTS))
    parser.add_argument("--samples", type=int, default=32)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default=str(ROOT / "build" / "stitch" / "targets"), help="evaluation folders")
    parser.add_argument(
        "--small", default="cpu_small_depth_d04", help="also run the weights with this config's data ('': no)"
    )
    args = parser.parse_args()
    config = load_config(ROOT / "configs" / "stitch" / f"{args.config}.yaml")

    rows, means = [], {}
    for distance in (0.2, 0.4):
        at = dataclasses.replace(config, data=dataclasses.replace(config.data, distance=distance))
        for photometry, overrides in (("as configured", None), ("clean", CLEAN)):
            print(f"evaluate d = {distance:g}, {photometry}", file=sys.stderr)
            tag = f"d{distance:g}_{'clean' if overrides else 'configured'}"
            report = evaluate(
                at,
                args.checkpoint,
                out=Path(args.out) / tag,
                samples=args.samples,
                workers=args.workers,
                data=overrides,
                progress=False,
            )
            means[distance, photometry] = report.means
            for method, name in names.items():
                rows.append((distance, photometry, name, report.means[method], report.blind_spot))

    print(
        f"\nMean PSNR (dB) and SSIM over {args.samples} test samples (seeds of the test split) of `{args.checkpoint}`. "
        "Regions: whole panorama; seams (two or more unwarped inputs overlap); seen (the scene point some input "
        "sees from its own centre). Blind spot: the share of the panorama no input sees.\n"
    )
    print("| d (m) | photometry | method | " + " | ".join(f"PSNR {r}" for r in REGIONS) + " | SSIM seen | blind spot |")
    print("|---:|---|---|" + "---:|" * (len(REGIONS) + 2))
    for distance, photometry, name, m, blind in rows:
        print(f"| {distance:g} | {photometry} | {name} | {_cells(m)} | {blind:.1%} |")

    clean, configured = means[0.4, "clean"], means[0.4, "as configured"]
    seen = clean["network"]["psnr_seen"] - clean["rotation_only"]["psnr_seen"]
    gap = clean["depth_oracle"]["psnr_seen"] - clean["rotation_only"]["psnr_seen"]
    whole = configured["network"]["psnr_whole"] - configured["rotation_only"]["psnr_whole"]
    print("\nThe targets at d = 0.4 m (PSNR, dB):\n")
    print("| target | network |")
    print("|---|---:|")
    print(
        f"| clean data, seen pixels: share of the gap from the true-rotation stitch to the oracle closed (>= 60 %) "
        f"| {seen / gap:.0%} ({seen:+.2f} of {gap:+.2f}) |"
    )
    print(f"| data as configured, whole panorama: over the true-rotation stitch (>= +3 dB) | {whole:+.2f} |")
    if args.small:
        _small_table(load_config(ROOT / "configs" / "stitch" / f"{args.small}.yaml"), args, names)
    _fill_table(config, args.checkpoint, args.samples)


def _cells(means: dict[str, float]) -> str:
    """A method's table cells: PSNR per region, then SSIM over the seen pixels."""
    from learnstitch.evaluation import REGIONS

    return " | ".join([f"{means[f'psnr_{r}']:.2f}" for r in REGIONS] + [f"{means['ssim_seen']:.3f}"])


def _small_table(config, args, names: dict[str, str]) -> None:
    """The same weights on fisheyes of another size (their geometry is in angles), d = 0.4 m."""
    from learnstitch.evaluation import REGIONS, evaluate

    print(
        f"\nThe same weights at {config.data.fisheye_size}-pixel fisheyes and a {config.data.pano_width} x "
        f"{config.data.pano_height} panorama (`{config.name}`), d = {config.data.distance:g} m, {args.samples} "
        "test samples:\n"
    )
    print("| photometry | method | " + " | ".join(f"PSNR {r}" for r in REGIONS) + " | SSIM seen |")
    print("|---|---|" + "---:|" * (len(REGIONS) + 1))
    for photometry, overrides in (("as configured", None), ("clean", CLEAN)):
        print(f"evaluate {config.name}, {photometry}", file=sys.stderr)
        report = evaluate(
            config, args.checkpoint, samples=args.samples, workers=args.workers, data=overrides, progress=False
        )
        for method, name in names.items():
            print(f"| {photometry} | {name} | {_cells(report.means[method])} |")


def _fill_table(config, checkpoint: str, samples: int) -> None:
    """Whole-panorama and blind-spot PSNR at d = 0.4 m as configured, with the fill and without."""
    from learnstitch import load_model

    model, _ = load_model(checkpoint, config)
    if getattr(model, "fill_head", None) is None:
        print("\nThe model has no fill (model.fill: false).")
        return
    unfilled = copy.deepcopy(model)
    unfilled.fill_head = None
    scores = mean_psnr(
        config,
        config.data,
        {"on": model, "off": unfilled},
        samples,
        lambda test: {"whole": None, "blind": ~test.regions["seen"]},
        gain=True,
    )
    print(
        f"\nWhat the fill adds (d = 0.4 m, data as configured, colour correction on, {samples} samples; PSNR dB): "
        "the model, and the same weights with the fill head removed.\n"
    )
    print("| region | fill on | fill off | the fill adds |")
    print("|---|---:|---:|---:|")
    for region, label in (("whole", "whole panorama"), ("blind", "blind spot (no input sees)")):
        on, off = scores["on"][region], scores["off"][region]
        print(f"| {label} | {on:.2f} | {off:.2f} | {on - off:+.2f} |")


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main()
