"""Footage at scale: `learnstitch batch` on this machine and on a local two-node Ray cluster, and Ray's cost per chunk.

    python benchmarks/stitch_batch.py [--clips 2] [--frames 120] [--chunk 40] [--size 960] [--width 2048]

The clips: the synthetic dual-fisheye camera of `benchmarks/stitch_video.py` (two `--size`-pixel
190° lenses side by side, walking and turning through the street of seed 0, HEVC at 29.97 fps with
AAC, cached in `build/bench/stitch_video/`), `--frames` frames, under `--clips` names. Each row is a
fresh process stitching all of them (`learnstitch.stitch_batch`, as `learnstitch batch` calls it) depth-aware (the shipped network of any
rig, filtered over time) into `--width` H.264 (`veryfast`, crf 18), decode and encode included, in
chunks of `--chunk` frames, timed whole (start-up, set-up, Ray's start, join):

- **this machine**: no Ray, the chunks one after the other in the command's process, `--threads 2`;
- **local Ray, one node**: `--ray auto` (a local cluster started by the command), two actors of one
  thread each;
- **Ray, two nodes**: Ray's own multi-node test cluster on this machine (a head and a worker node
  of one CPU each, started by the benchmark, not timed), `--ray ADDRESS`, an actor on each node.

Ray's cost per chunk, from the chunks' records of the two-node run (medians):
- *set-up*: an actor's first chunk of a clip loads the network and makes the lens tables;
- *warm-up and seek*: a chunk after a clip's first decodes from the key frame before it and runs
  four frames through the temporal filter before its first frame's stitch begins; measured as that
  time (each chunk's record) less a first chunk's (which opens the same decoders, with neither);
- *scheduling and transfer*: the driver's time from submitting a chunk to its result, less the
  actor's own.
Each is given as a share of a chunk's stitch time at the default chunk size (300 frames), from the
per-frame time of the first chunks.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

from _record import recorded
from stitch_video import CACHE, make_clip

from learnstitch.video.chunks import CHUNK_FRAMES as DEFAULT_CHUNK
from learnstitch.video.cluster import LOCAL_ENVIRONMENT

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "build" / "bench" / "stitch_batch"


def arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clips", type=int, default=2, help="clips in the batch (one clip under as many names)")
    parser.add_argument("--frames", type=int, default=120, help="frames of each clip")
    parser.add_argument("--chunk", type=int, default=40, help="frames a chunk")
    parser.add_argument("--size", type=int, default=960, help="each lens's image, pixels square")
    parser.add_argument("--width", type=int, default=2048, help="the panoramas' width")
    parser.add_argument("--distinct", type=int, default=8, help="frames rendered (played forward and back)")
    return parser.parse_args()


CHILD = """
import json, sys
from learnstitch.worker import setup_worker

setup_worker(compilation_cache=True, omp_wait_policy="PASSIVE")  # as the command sets itself up
import learnstitch

rig, clips, out, settings = json.loads(sys.argv[1])
report = learnstitch.stitch_batch(rig, clips, out, **settings)
assert not report.failed, report.summary()
print("REPORT " + json.dumps({"records": report.records, "frames": report.frames, "where": report.where}))
"""


def batch(args, clips: list[Path], out: Path, label: str, **settings) -> tuple[float, dict]:
    """One process stitching the batch (``learnstitch.stitch_batch``, as ``learnstitch batch``
    calls it): its wall time and its report, the chunks' records included."""
    shutil.rmtree(out, ignore_errors=True)
    rig = CACHE / f"dual{args.size}.pto"
    settings |= {"options": {"width": args.width}, "chunk_frames": args.chunk}
    request = json.dumps([str(rig), [str(c) for c in clips], str(out), settings])
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", CHILD, request], capture_output=True, text=True)
    seconds = time.perf_counter() - started
    if done.returncode != 0:
        sys.exit(f"{label} failed:\n{done.stderr[-3000:]}")
    line = next(line for line in done.stdout.splitlines() if line.startswith("REPORT "))
    print(f"  {label}: {seconds:.1f} s", file=sys.stderr)
    return seconds, json.loads(line[len("REPORT ") :])


def main() -> None:
    args = arguments()
    clip = make_clip(args.frames, args.distinct, args.size)
    OUT.mkdir(parents=True, exist_ok=True)
    clips = []
    for k in range(args.clips):
        named = OUT / f"clip{k}.mp4"
        named.unlink(missing_ok=True)
        os.link(clip, named)
        clips.append(named)
    total = args.clips * args.frames
    rows = []
    seconds, _ = batch(args, clips, OUT / "local", "no Ray", threads=2)
    rows.append(("this machine, no Ray (threads 2)", 1, seconds))
    seconds, _ = batch(args, clips, OUT / "ray_local", "local Ray", ray="auto", threads=1, workers=2)
    rows.append(("local Ray cluster, one node (2 actors × 1 thread)", 2, seconds))

    os.environ.update(LOCAL_ENVIRONMENT)
    from ray.cluster_utils import Cluster

    cluster = Cluster(
        initialize_head=True,
        head_node_args={"num_cpus": 1, "node_ip_address": "127.0.0.1", "include_dashboard": False},
    )
    cluster.add_node(num_cpus=1, node_ip_address="127.0.0.1")
    try:
        seconds, report = batch(args, clips, OUT / "ray_two", "two nodes", ray=cluster.address, threads=1)
    finally:
        cluster.shutdown()
    rows.append(("Ray, two nodes of 1 CPU (an actor each × 1 thread)", 2, seconds))

    print(
        f"{args.clips} clips × {args.frames} frames ({2 * args.size}×{args.size} HEVC 29.97 fps with AAC) → "
        f"{args.width}×{args.width // 2} H.264 `veryfast` crf 18, depth-aware, chunks of {args.chunk} frames; "
        "one run each, whole process.\n"
    )
    print("| run | actors | frames | wall s | fps |")
    print("|---|---:|---:|---:|---:|")
    for name, actors, seconds in rows:
        print(f"| {name} | {actors} | {total} | {seconds:.1f} | {total / seconds:.2f} |")
    alone = rows[0][2]
    print(
        f"\nAgainst the single process: local Ray {alone / rows[1][2]:.2f}×, two nodes {alone / rows[2][2]:.2f}×. "
        "Both clusters run on this machine's two cores, so this is no scale-out figure: what it shows is that "
        "two single-threaded stitches side by side kept the two cores busier than one process with two threads "
        "(and each process's set-up ran beside the other's stitch).\n"
    )

    records = report["records"]
    firsts = [r for r in records if r["chunk"] == 0]
    laters = [r for r in records if r["chunk"] > 0]
    per_frame = statistics.median(r["seconds"] / r["frames"] for r in firsts)
    warm = statistics.median(r["warmup"] for r in laters) - statistics.median(r["warmup"] for r in firsts)
    setups = [r["prepare"] for r in records if r["prepare"] > 0]
    setup = statistics.median(setups)
    schedule = statistics.median(r["round_trip"] - r["seconds"] - r["prepare"] for r in records)
    chunk_time = DEFAULT_CHUNK * per_frame
    print(f"Ray's cost per chunk, two-node run ({len(records)} chunks; {len(setups)} set-ups), medians:\n")
    print(f"| cost | seconds | share of a {DEFAULT_CHUNK}-frame chunk ({chunk_time:.0f} s) |")
    print("|---|---:|---:|")
    print(f"| stitch of a frame (first chunks) | {per_frame:.3f} | |")
    print(
        f"| set-up: network and lens tables, an actor's first chunk of a clip | {setup:.2f} | {setup / chunk_time:.1%} |"
    )
    print(f"| warm-up and seek, a later chunk | {warm:.2f} | {warm / chunk_time:.1%} |")
    print(f"| scheduling and transfer | {schedule:.3f} | {schedule / chunk_time:.2%} |")
    steady = (warm + schedule) / chunk_time
    print(
        f"\nAt the default chunk size, a chunk after an actor's first of a clip costs {steady:.1%} more than the "
        f"same frames in one run; an actor's first chunk of a clip also pays the set-up ({setup / chunk_time:.1%})."
    )
    print(
        f"\nOn paper, N nodes of this machine's speed each running one such actor: about "
        f"{1 / per_frame:.2f} × N frames a second, less {steady:.1%}, as long as there are at least N chunks "
        f"in flight (a clip of {DEFAULT_CHUNK * 10} frames keeps ten nodes busy). The driver only plans, "
        "schedules and joins (the join copies packets: seconds per clip)."
    )


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main()
