"""Inference speed, size and peak memory of the stitching network, per config.

    python benchmarks/stitch_speed.py [--configs cpu_tiny_d02 cpu_tiny_depth_d04 ...] [--device cpu] [--runs 5]

For each config: parameters, milliseconds per triplet (median of ``--runs`` after one warm-up) for
the unwarping of the three fisheyes and for the network, and peak memory: on CPU the process's
peak resident set (``ru_maxrss``, each config measured in its own process, so it includes the
interpreter and libraries: the "idle" column is the same process before the first inference);
on CUDA ``torch.cuda.max_memory_allocated``. Weights are random: speed does not depend on them.
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

from _record import recorded

ROOT = Path(__file__).resolve().parents[1]


def measure(config_name: str, device: str, runs: int) -> dict:
    import torch

    from learnstitch import load_config
    from learnstitch.data.rig import nominal_centres
    from learnstitch.data.sample import nominal_unwarp_grids, unwarp
    from learnstitch.network import build_model
    from learnstitch.network.model import parameter_count

    config = load_config(ROOT / "configs" / "stitch" / f"{config_name}.yaml")
    torch.manual_seed(0)
    model = build_model(config.model, config.data).to(device).eval()
    grids, masks, _ = nominal_unwarp_grids(config.data)
    grids, masks = grids.to(device), masks.float().to(device)
    fisheyes = torch.rand(3, 3, config.data.fisheye_size, config.data.fisheye_size, device=device)
    centres = torch.as_tensor(nominal_centres(config.data.distance), dtype=torch.float32, device=device)[None]
    sync = torch.cuda.synchronize if device.startswith("cuda") else (lambda: None)
    idle_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    unwarp_ms, net_ms = [], []
    with torch.no_grad(), torch.autocast(device.split(":")[0], dtype=torch.bfloat16, enabled=device.startswith("cuda")):
        for _ in range(runs + 1):
            sync()
            t0 = time.perf_counter()
            inputs = unwarp(fisheyes, grids)[None]
            sync()
            t1 = time.perf_counter()
            model(inputs, masks[None], centres=centres)
            sync()
            t2 = time.perf_counter()
            unwarp_ms.append(1e3 * (t1 - t0))
            net_ms.append(1e3 * (t2 - t1))
    peak = (
        (torch.cuda.max_memory_allocated() / 2**20)
        if device.startswith("cuda")
        else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    )
    return {
        "config": config_name,
        "size": f"{config.data.fisheye_size}² → {config.data.pano_width}×{config.data.pano_height}",
        "parameters": parameter_count(model),
        "unwarp_ms": statistics.median(unwarp_ms[1:]),
        "network_ms": statistics.median(net_ms[1:]),
        "idle_mb": idle_mb,
        "peak_mb": peak,
        "threads": torch.get_num_threads(),
        "device": device,
    }


def arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--configs",
        nargs="+",
        default=["cpu_tiny_d02", "cpu_tiny_depth_d04", "cpu_small_depth_d04", "paper_l1_ssim_d02"],
    )
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--one", help=argparse.SUPPRESS)  # internal: measure one config in this process
    return parser.parse_args()


def main(args: argparse.Namespace) -> None:
    if args.one:
        print(json.dumps(measure(args.one, args.device, args.runs)))
        return
    rows = []
    for name in args.configs:
        child = subprocess.run(
            [sys.executable, __file__, "--one", name, "--device", args.device, "--runs", str(args.runs)],
            capture_output=True,
            text=True,
        )
        if child.returncode != 0:
            sys.exit(f"measuring {name} failed:\n{child.stderr}")
        rows.append(json.loads(child.stdout.strip().splitlines()[-1]))
    memory = "peak CUDA memory (MB)" if args.device.startswith("cuda") else "peak RSS (MB; idle)"
    print(f"\nStitching network inference, device {args.device}, median of {args.runs} runs, batch 1\n")
    print(f"| config | fisheyes → panorama | parameters | unwarp (ms) | network (ms) | {memory} |")
    print("|---|---|---:|---:|---:|---:|")
    for r in rows:
        mem = f"{r['peak_mb']:.0f}" + ("" if args.device.startswith("cuda") else f" ({r['idle_mb']:.0f})")
        print(
            f"| {r['config']} | {r['size']} | {r['parameters'] / 1e6:.2f} M | {r['unwarp_ms']:.1f} | {r['network_ms']:.0f} | {mem} |"
        )
    print(f"\n{rows[0]['threads']} torch threads.")


if __name__ == "__main__":
    args = arguments()
    if args.one:  # a child measuring one config: its JSON line is not the page
        main(args)
    else:
        device = args.device.split(":")[0]
        with recorded(__file__, __doc__, page=None if device == "cpu" else f"stitch_speed_{device}"):
            main(args)
