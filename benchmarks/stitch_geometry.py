"""The stitching networks against the classical references and the depth oracle: PSNR and SSIM over
the whole panorama, its seams and the pixels some input sees, as configured and photometrically clean.

    python benchmarks/stitch_geometry.py [--runs build/stitch/runs] [--samples 32] [--workers 2]

Trains (or reuses a finished run, or resumes an interrupted one) in ``RUNS/NAME``: the paper's
network (``model.warp: homography``) at d = 0.2 and 0.4 m (``cpu_tiny_d02``, ``cpu_tiny_d04``:
nominal inputs, 384 samples), the same network on calibrated inputs with 2048 samples and the
rig-aware run's schedule (``cpu_tiny_calibrated_d04``), and the rig-aware network
(``model.warp: depth``, ``cpu_tiny_depth_d04``). The rig-aware network takes the camera centres
at run time, so its d = 0.4 weights also stitch the d = 0.2 rig. Every network is evaluated on
the same test samples (the first ``--samples`` seeds of the test split), as configured and with
``gain_jitter=0 vignetting=0 noise_std=0``, each with its colour correction on and off; the
rig-aware network trained at 128-pixel fisheyes is also run at 256 pixels
(``cpu_small_depth_d04``). The references: the nominal rig, the true-rotation stitch and the depth
oracle (every input resampled through the true depth; the best a warp can do). What the warps
themselves add: each d = 0.4 network again with its warps switched off (homographies at the
identity and no displacement; the rig-aware network's depth at infinity), its blend weights kept.
The runs' learning curves are drawn to ``docs/results/stitch_learning_curves.png``.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import sys
import time
from pathlib import Path

import torch
from _ablation import CLEAN, mean_psnr
from _record import recorded

ROOT = Path(__file__).resolve().parents[1]
REFERENCES = ("nominal", "rotation_only", "depth_oracle")


def _train(name: str, runs: Path):
    from learnstitch import load_config
    from learnstitch.training import train

    config = load_config(ROOT / "configs" / "stitch" / f"{name}.yaml")
    run = runs / name
    started = time.perf_counter()
    report = train(config, run, resume=True, progress=True)
    print(f"{name}: {report.steps} new steps in {time.perf_counter() - started:.0f} s", file=sys.stderr)
    log = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    minutes = sum(r["seconds_per_step"] for r in log) * config.train.log_every / 60
    return config, run / "model.pt", report.final_step, minutes


def _at_distance(config, distance: float):
    data = dataclasses.replace(config.data, distance=distance)
    return dataclasses.replace(config, data=data, name=f"{config.name} at d = {distance:g}")


def main() -> None:
    from learnstitch import load_config
    from learnstitch.evaluation import METHOD_NAMES, REGIONS, evaluate

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", default=str(ROOT / "build" / "stitch" / "runs"))
    parser.add_argument("--samples", type=int, default=32)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    runs = Path(args.runs)

    paper = {0.2: _train("cpu_tiny_d02", runs), 0.4: _train("cpu_tiny_d04", runs)}
    calibrated = _train("cpu_tiny_calibrated_d04", runs)
    depth_config, depth_model, depth_steps, depth_minutes = _train("cpu_tiny_depth_d04", runs)
    small = load_config(ROOT / "configs" / "stitch" / "cpu_small_depth_d04.yaml")
    cases = []  # (size, d, networks: {label: (config, checkpoint)})
    for distance in (0.2, 0.4):
        cases.append(
            (
                "cpu_tiny",
                distance,
                {
                    "paper network": (paper[distance][0], paper[distance][1]),
                    **({"paper network, calibrated inputs": calibrated[:2]} if distance == 0.4 else {}),
                    "rig-aware network": (_at_distance(depth_config, distance), depth_model),
                },
            )
        )
    cases.append(("cpu_small (trained at cpu_tiny)", 0.4, {"rig-aware network": (small, depth_model)}))

    rows, gaps = [], []
    for size, distance, networks in cases:
        for photometry, overrides in (("as configured", None), ("clean", CLEAN)):
            references = None
            for label, (config, checkpoint) in networks.items():
                tag = f"{size.split()[0]}_d{distance:g}_{'clean' if overrides else 'configured'}"
                print(f"evaluate {label} {tag}", file=sys.stderr)
                report = evaluate(
                    config,
                    checkpoint,
                    out=Path(checkpoint).parent / f"eval_{tag}",
                    samples=args.samples,
                    workers=args.workers,
                    data=overrides,
                    progress=False,
                )
                if references is None:
                    references = {m: report.means[m] for m in REFERENCES}
                    for method, means in references.items():
                        rows.append((size, distance, photometry, METHOD_NAMES[method], means, report.blind_spot))
                for method in ("network", "network_gain_off"):
                    if method in report.means:
                        name = label + (", colour correction off" if method.endswith("off") else "")
                        rows.append((size, distance, photometry, name, report.means[method], report.blind_spot))
                        if label == "rig-aware network":
                            gaps.append((size, distance, photometry, name, report.means[method], references))

    print(
        f"\nMean PSNR (dB) and SSIM over {args.samples} test samples (seeds of the test split). Regions: whole "
        "panorama; seams (two or more unwarped inputs overlap); seen (the scene point some input sees from its own "
        "centre). Blind spot: the share of the panorama no input sees.\n"
    )
    psnrs = " | ".join(f"PSNR {r}" for r in REGIONS)
    print(f"| fisheyes | d (m) | photometry | method | {psnrs} | SSIM seen | blind spot |")
    print("|---|---:|---|---|" + "---:|" * (len(REGIONS) + 2))
    for size, distance, photometry, name, m, blind in rows:
        values = " | ".join(f"{m[f'psnr_{r}']:.2f}" for r in REGIONS)
        print(f"| {size} | {distance:g} | {photometry} | {name} | {values} | {m['ssim_seen']:.3f} | {blind:.1%} |")

    print("\nThe rig-aware network against the references (PSNR, dB):\n")
    print(
        "| fisheyes | d (m) | photometry | network | seen: over true-rotation "
        "| seen: share of the gap to the oracle closed | whole: over true-rotation |"
    )
    print("|---|---:|---|---|---:|---:|---:|")
    for size, distance, photometry, name, means, ref in gaps:
        seen = means["psnr_seen"] - ref["rotation_only"]["psnr_seen"]
        gap = ref["depth_oracle"]["psnr_seen"] - ref["rotation_only"]["psnr_seen"]
        whole = means["psnr_whole"] - ref["rotation_only"]["psnr_whole"]
        print(f"| {size} | {distance:g} | {photometry} | {name} | {seen:+.2f} | {seen / gap:.0%} | {whole:+.2f} |")
    networks = {"paper network": paper[0.4][:2], "paper network, calibrated inputs": calibrated[:2]}
    _warps_off_table(networks | {"rig-aware network": (depth_config, depth_model)}, args.samples)
    print(
        f"\nTraining on this machine: cpu_tiny_depth_d04 {depth_steps} steps in {depth_minutes:.0f} min; "
        f"cpu_tiny_calibrated_d04 {calibrated[2]} steps in {calibrated[3]:.0f} min; "
        + "; ".join(f"cpu_tiny_d0{int(d * 10)} {paper[d][2]} steps in {paper[d][3]:.0f} min" for d in paper)
        + " (sums of the logged seconds per step)."
    )
    from learnstitch.curves import plot_learning_curves

    curves = {label: Path(checkpoint).parent for label, (_, checkpoint) in networks.items()}
    curves["rig-aware network"] = Path(depth_model).parent
    plot_learning_curves(curves, ROOT / "docs" / "results" / "stitch_learning_curves.png")
    print(
        "\nLearning curves (validation PSNR over seen pixels against steps, colour correction on and off; the "
        "paper network on nominal inputs has no validation log): [stitch_learning_curves.png](stitch_learning_curves.png)"
    )


class _WarpsOff(torch.nn.Module):
    """A trained network with its warps switched off and its blend weights and colour kept: the
    homographies at the identity and no displacement, or the rig-aware depth at infinity."""

    def __init__(self, model: torch.nn.Module):
        super().__init__()
        self.model = model
        if model.config.warp == "homography":
            model.config = dataclasses.replace(model.config, max_corner_offset=0.0, max_displacement=0.0)

    def forward(self, inputs, masks, *, gain=True):
        if self.model.config.warp == "homography":
            return self.model(inputs, masks, gain=gain)
        return self.model(inputs, masks, gain=gain, inverse_depth=inputs.new_zeros(inputs.shape[0], *inputs.shape[-2:]))


def _warps_off_table(networks: dict, samples: int) -> None:
    """Seen-pixel PSNR of each network with its warps on and off, clean data, colour correction off."""
    from learnstitch import load_model
    from learnstitch.evaluation import data_with

    print(
        "\nWhat the warps add (d = 0.4, clean data, seen pixels, colour correction off; PSNR dB): each network as "
        "trained, and with its warps switched off and its blend weights kept.\n"
    )
    print("| network | warps on | warps off | the warps add |")
    print("|---|---:|---:|---:|")
    for label, (config, checkpoint) in networks.items():
        print(f"warps off: {label}", file=sys.stderr)
        model, _ = load_model(checkpoint, config)
        variants = {"on": model, "off": _WarpsOff(copy.deepcopy(model))}
        seen = lambda test: {"seen": test.regions["seen"]}  # noqa: E731
        scores = mean_psnr(config, data_with(config.data, CLEAN), variants, samples, seen, gain=False)
        on, off = scores["on"]["seen"], scores["off"]["seen"]
        print(f"| {label} | {on:.2f} | {off:.2f} | {on - off:+.2f} |")


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main()
