"""Speed and peak memory of full-resolution stitching (`learnstitch stitch --rig`), quiet and beside other work.

    python benchmarks/stitch_fullres_speed.py [--runs 3] [--sizes 1024 2048]

Three 185° fisheyes 0.4 m out (`learnstitch.data.rigs.FULLRES_RIGS["tri_d04"]`, scene of seed 0) rendered
at S² pixels (S from `--sizes`), written as PNGs with their `rig.pto`, and stitched into a panorama
2S × S (1024² → 2048×1024, 2048² → 4096×2048 and, with `--width`, 8192×4096) with the depth from the
shipped network of any rig (`learnstitch/weights/cpu_tiny_anyrig.pt`, the default of `stitch --rig`):

- **in process**: `learnstitch.stitch_project(rig.pto, width)` after one warm-up in the same process
  (median of `--runs`): reading the images, the sight tables, the network's depth, the photometry, the render;
- **command**: `learnstitch stitch --rig rig.pto -o pano.jpg --width W` in a fresh process, start-up,
  imports, reading and writing included (median of `--runs`, after one run that fills the compile cache),
  and its peak resident memory (`ru_maxrss` of the child); "depth not refined": the same with
  `--render refine_levels=0` (the working depth not refined by the inputs' agreement, `learnstitch.fullres.refine`);
- **busy**: the same command while two other processes keep both cores busy (pure-Python loops);
- references: `grid_sample` of the three inputs into the panorama (bilinear, one call each: the resampling
  alone), and Hugin's `nona` + `verdandi` on the same `.pto` where they are installed (a rotation-only stitch).
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _record import recorded

ROOT = Path(__file__).resolve().parents[1]
LEARNSTITCH = [sys.executable, "-m", "learnstitch.cli"]


def arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--sizes", nargs="+", type=int, default=[1024, 2048])
    parser.add_argument("--width", type=int, default=8192, help="the panorama's width for the largest size")
    # internal: one step in a process of its own (a child's peak RSS starts at its parent's, which
    # must stay small): write a rig, or time stitch_project in process
    parser.add_argument("--write", nargs=2, metavar=("FOLDER", "SIZE"), help=argparse.SUPPRESS)
    parser.add_argument("--in-process", nargs=2, metavar=("PTO", "WIDTH"), help=argparse.SUPPRESS)
    return parser.parse_args()


def write_rig(folder: Path, size: int) -> Path:
    import dataclasses

    import rigjax
    from learnstitch.data.rigs import FULLRES_RIGS, render_rig
    from learnstitch.data.sample import SynthConfig
    from learnstitch.data.store import to_uint8

    shape = dataclasses.replace(FULLRES_RIGS["tri_d04"], size=size)
    sample = render_rig(shape, 0, 2 * size, SynthConfig())
    names = tuple(f"cam{k}.png" for k in range(len(shape.yaws)))
    for name, fisheye in zip(names, sample.fisheyes):
        rigjax.write_image(folder / name, to_uint8(fisheye))
    path = folder / "rig.pto"
    sample.rig.project((2 * size, size), names).save(path)
    return path


def run_child(command: list[str], cwd: Path, env: dict) -> tuple[float, float]:
    """Wall seconds and peak RSS (MB) of one child process."""
    start = time.perf_counter()
    child = subprocess.Popen(command, cwd=cwd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(child.pid, 0)
    seconds = time.perf_counter() - start
    if status != 0:
        sys.exit(f"{' '.join(command)} failed: {child.stderr.read().decode()}")
    return seconds, usage.ru_maxrss / 1024


def child(*args: str) -> str:
    """The last line a step of this script prints, run in a process of its own."""
    done = subprocess.run([sys.executable, __file__, *args], capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"{' '.join(args)} failed:\n{done.stderr}")
    return done.stdout.strip().splitlines()[-1]


def busy() -> list[subprocess.Popen]:
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]


def in_process(pto: Path, width: int, runs: int) -> float:
    """The median seconds of ``stitch_project`` after a warm-up (``runs`` 0: :func:`resampling`)."""
    if runs == 0:
        return resampling(pto, width)
    from learnstitch.inference import stitch_project

    stitch_project(pto, width)
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        stitch_project(pto, width)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def resampling(pto: Path, width: int) -> float:
    """Seconds to bilinearly resample every input into the panorama with ``grid_sample`` (grids given)."""
    import torch

    import rigjax

    images = [
        torch.from_numpy(rigjax.read_image(pto.parent / f"cam{k}.png")).permute(2, 0, 1).float()[None] for k in range(3)
    ]
    grid = torch.rand(1, width // 2, width, 2) * 2 - 1
    start = time.perf_counter()
    for image in images:
        torch.nn.functional.grid_sample(image, grid, mode="bilinear", align_corners=False)
    return time.perf_counter() - start


def hugin(pto: Path, width: int, env: dict) -> float | None:
    if not (shutil.which("nona") and shutil.which("verdandi")):
        return None
    start = time.perf_counter()
    folder = pto.parent
    subprocess.run(
        ["nona", "-o", "remapped", "-m", "TIFF_m", str(pto)], cwd=folder, env=env, check=True, capture_output=True
    )
    tifs = sorted(str(p) for p in folder.glob("remapped*.tif"))
    subprocess.run(["verdandi", "-o", "hugin.tif", *tifs], cwd=folder, env=env, check=True, capture_output=True)
    return time.perf_counter() - start


def main(args: argparse.Namespace) -> None:
    if args.write:
        print(write_rig(Path(args.write[0]), int(args.write[1])))
        return
    if args.in_process:
        print(in_process(Path(args.in_process[0]), int(args.in_process[1]), args.runs))
        return
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, RIGJAX_CACHE_DIR=str(Path(tmp) / "cache"))
        for size in args.sizes:
            folder = Path(tmp) / f"rig{size}"
            folder.mkdir()
            pto = Path(child("--write", str(folder), str(size)))
            width = 2 * size if size != max(args.sizes) else max(2 * size, args.width)
            print(f"rig of {size}² fisheyes written", file=sys.stderr)
            command = [*LEARNSTITCH, "stitch", "--rig", str(pto), "-o", "pano.jpg", "--width", str(width)]
            first, _ = run_child(command, folder, env)
            quiet = [run_child(command, folder, env) for _ in range(args.runs)]
            coarse = [run_child([*command, "--render", "refine_levels=0"], folder, env)[0] for _ in range(args.runs)]
            load = busy()
            try:
                loaded = [run_child(command, folder, env)[0] for _ in range(args.runs)]
            finally:
                for process in load:
                    process.kill()
                    process.wait()
            rows.append(
                {
                    "size": size,
                    "width": width,
                    "in_process": float(child("--in-process", str(pto), str(width), "--runs", str(args.runs))),
                    "first": first,
                    "command": statistics.median(t for t, _ in quiet),
                    "not_refined": statistics.median(coarse),
                    "peak": max(m for _, m in quiet),
                    "busy": statistics.median(loaded),
                    "resampling": float(child("--in-process", str(pto), str(width), "--runs", "0")),
                    "hugin": hugin(pto, width, env) if width == 2 * size else None,
                }
            )
    print(f"\nMedian of {args.runs} runs; the command's first run fills the compile cache (`$RIGJAX_CACHE_DIR`).")
    installed = shutil.which("nona") and shutil.which("verdandi")
    print(
        f"Hugin's nona + verdandi: {'at the .pto size' if installed else 'not installed here (apt-get install hugin-tools)'}.\n"
    )
    print(
        "| fisheyes → panorama | in process (s) | command (s) | command, depth not refined (s) | command, first run (s) | "
        "peak RSS (MB) | command beside two busy processes (s) | grid_sample alone (s) | nona + verdandi (s) |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        nona = "—" if r["hugin"] is None else f"{r['hugin']:.2f}"
        print(
            f"| 3 × {r['size']}² → {r['width']}×{r['width'] // 2} | {r['in_process']:.2f} | {r['command']:.2f} | "
            f"{r['not_refined']:.2f} | {r['first']:.2f} | "
            f"{r['peak']:.0f} | {r['busy']:.2f} | {r['resampling']:.2f} | {nona} |"
        )
    import torch  # after the measurements: this process stays small, and its children's peak RSS with it

    print(f"\ntorch threads: {torch.get_num_threads()}; the command sets `OMP_WAIT_POLICY=PASSIVE` unless it is set.")
    print("Peak RSS: the command's `ru_maxrss`, which on Linux starts at its parent's, this small process.")


if __name__ == "__main__":
    args = arguments()
    if args.write or args.in_process:  # a step of a run: its output is not the page
        main(args)
    else:
        with recorded(__file__, __doc__):
            main(args)
