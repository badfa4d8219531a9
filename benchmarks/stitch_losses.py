"""Train and evaluate the stitching network per loss and camera distance; print the comparison table.

    python benchmarks/stitch_losses.py [--configs cpu_tiny_l1_d02 cpu_tiny_d02 ...] [--runs build/stitch/runs]
                                            [--samples 32] [--workers 2]

Each config trains into ``RUNS/NAME`` (a finished run is reused, an interrupted one resumed) and is
evaluated on the same test samples (the first ``--samples`` seeds of the test split) with the
rotation-only baseline beside it. Configs whose loss needs files this machine lacks (the VGG-16
weights of the perceptual loss) are listed as not run, with the reason.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from _record import recorded

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = [
    "cpu_tiny_l1_d02",
    "cpu_tiny_d02",
    "cpu_tiny_pl1_ssim_d02",
    "cpu_tiny_l1_d04",
    "cpu_tiny_d04",
    "cpu_tiny_pl1_ssim_d04",
]
LOSS_NAMES = {
    ("l1", 1.0): "L1",
    ("l1", 0.4): "0.4 L1 + 0.6 (1 − SSIM)",
    ("perceptual", 0.4): "0.4 VGG-16 L1 + 0.6 (1 − SSIM)",
}


def main() -> None:
    from learnstitch import ConfigError, load_config
    from learnstitch.checkpoint import load_checkpoint
    from learnstitch.evaluation import evaluate
    from learnstitch.training import train

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--configs", nargs="+", default=DEFAULT)
    parser.add_argument("--runs", default=str(ROOT / "build" / "stitch" / "runs"))
    parser.add_argument("--samples", type=int, default=32)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()

    rows, skipped, baseline = [], [], {}
    for name in args.configs:
        config = load_config(ROOT / "configs" / "stitch" / f"{name}.yaml")
        run = Path(args.runs) / name
        try:
            started = time.perf_counter()
            report = train(config, run, resume=True, progress=True)
        except ConfigError as error:
            skipped.append((name, str(error).split(":")[0] + ": " + str(error).split(": ", 1)[-1][:120]))
            continue
        seconds = (
            sum(json.loads(line)["seconds_per_step"] for line in (run / "metrics.jsonl").read_text().splitlines())
            * config.train.log_every
        )
        result = evaluate(config, run / "model.pt", out=run / "eval", samples=args.samples, workers=args.workers)
        loss = LOSS_NAMES.get((config.loss.pixel, config.loss.beta), f"{config.loss.pixel}, beta {config.loss.beta}")
        rows.append(
            (
                loss,
                config.data.distance,
                result.means["network"],
                load_checkpoint(run / "model.pt")["step"],
                seconds,
                name,
            )
        )
        baseline[config.data.distance] = result.means["rotation_only"]
        print(f"{name}: {report.steps} new steps in {time.perf_counter() - started:.0f} s", file=sys.stderr)

    print(f"\nMean PSNR (dB) / SSIM over {args.samples} test samples; training time from the run's log.\n")
    print("| loss | d (m) | PSNR whole | SSIM whole | PSNR seams | SSIM seams | steps | training time | config |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---|")
    for distance, m in sorted(baseline.items()):
        print(
            f"| rotation-only baseline (true orientations) | {distance:g} | {m['psnr_whole']:.2f} | {m['ssim_whole']:.3f} "
            f"| {m['psnr_seams']:.2f} | {m['ssim_seams']:.3f} | | | |"
        )
    for loss, distance, m, steps, seconds, name in sorted(rows, key=lambda r: (r[1], r[0])):
        print(
            f"| {loss} | {distance:g} | {m['psnr_whole']:.2f} | {m['ssim_whole']:.3f} | {m['psnr_seams']:.2f} | {m['ssim_seams']:.3f} "
            f"| {steps} | {seconds / 60:.1f} min | {name} |"
        )
    for name, reason in skipped:
        print(f"\nnot run: {name}: {reason}")


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main()
