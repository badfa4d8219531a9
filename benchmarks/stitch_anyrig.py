"""One network for any rig against the three-fisheye network on the three-fisheye test split.

    python benchmarks/stitch_anyrig.py [--samples 32] [--workers 2]
        [--anyrig learnstitch/weights/cpu_tiny_anyrig.pt] [--tri learnstitch/weights/cpu_tiny_depth_d04.pt]

The network of any rig (`configs/stitch/cpu_tiny_anyrig.yaml`: features pooled over the inputs,
trained on random rigs of 2 to 6 cameras, a quarter of them the three-fisheye rig) and the network
trained for the three-fisheye rig alone (`configs/stitch/cpu_tiny_depth_d04.yaml`, the shipped
`cpu_tiny_depth_d04.pt`) on the same first `--samples` seeds of the three-fisheye test split (128²
fisheyes, 256×128 panoramas) at d = 0.2 and 0.4 m, as configured and photometrically clean
(`learnstitch evaluate`'s samples and regions): PSNR over the pixels some input sees, beside the
true-rotation stitch and the depth oracle. What generality costs: the difference of the two
networks' seen-pixel PSNR at d = 0.4 m (the split the three-fisheye network was trained for),
which should be above -0.3 dB.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from _ablation import CLEAN
from _record import recorded

ROOT = Path(__file__).resolve().parents[1]
WEIGHTS = ROOT / "learnstitch" / "weights"


def arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=32)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--anyrig", default=str(WEIGHTS / "cpu_tiny_anyrig.pt"))
    parser.add_argument("--tri", default=str(WEIGHTS / "cpu_tiny_depth_d04.pt"))
    parser.add_argument("--out", default=str(ROOT / "build" / "stitch" / "anyrig"), help="evaluation folders")
    return parser.parse_args()


def main(args: argparse.Namespace) -> None:
    from learnstitch.checkpoint import load_model
    from learnstitch.evaluation import evaluate

    # Each checkpoint with the config it was trained with.
    models = {
        "any rig": (load_model(args.anyrig)[1], args.anyrig),
        "three cameras": (load_model(args.tri)[1], args.tri),
    }
    seen: dict[tuple, float] = {}
    for distance in (0.2, 0.4):
        for photometry, overrides in (("as configured", None), ("clean", CLEAN)):
            for name, (config, checkpoint) in models.items():
                print(f"evaluate {name}, d = {distance:g}, {photometry}", file=sys.stderr)
                at = dataclasses.replace(config, data=dataclasses.replace(config.data, distance=distance))
                tag = f"{name.replace(' ', '_')}_d{distance:g}_{'clean' if overrides else 'configured'}"
                report = evaluate(
                    at,
                    checkpoint,
                    out=Path(args.out) / tag,
                    samples=args.samples,
                    workers=args.workers,
                    data=overrides,
                    progress=False,
                )
                for method in ("rotation_only", "depth_oracle", "network"):
                    key = name if method == "network" else method
                    seen[distance, photometry, key] = report.means[method]["psnr_seen"]
    print(
        f"\nMean PSNR (dB) over the seen pixels of {args.samples} samples of the three-fisheye test split "
        f"(seeds of the test split); networks `{Path(args.anyrig).name}` (any rig) and `{Path(args.tri).name}` "
        "(three cameras).\n"
    )
    print(
        "| d (m) | photometry | true-rotation stitch | depth oracle | three-camera network | any-rig network | any rig − three cameras |"
    )
    print("|---:|---|---:|---:|---:|---:|---:|")
    for distance in (0.2, 0.4):
        for photometry in ("as configured", "clean"):
            row = [seen[distance, photometry, k] for k in ("rotation_only", "depth_oracle", "three cameras", "any rig")]
            cells = " | ".join(f"{v:.2f}" for v in row)
            print(f"| {distance:g} | {photometry} | {cells} | {row[3] - row[2]:+.2f} |")
    worst = min(seen[0.4, p, "any rig"] - seen[0.4, p, "three cameras"] for p in ("as configured", "clean"))
    verdict = "met" if worst >= -0.3 else "not met"
    print(
        f"\nTarget (any rig within 0.3 dB of the three-camera network at d = 0.4 m, or above): {verdict} ({worst:+.2f} dB)."
    )


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main(arguments())
