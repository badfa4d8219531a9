"""360 video throughput: `learnstitch stitch --video` against FFmpeg's `v360` filter, one clip, one run.

    python benchmarks/stitch_video.py [--frames 300] [--depth-frames 150] [--long 600] [--real CLIP --real-rig PTO]

The clip: a synthetic dual-fisheye camera (`learnstitch.data.sequence`, two 190° lenses 1920² side by
side, walking and turning through the street of seed 0), `--distinct` frames rendered and played
forward and back, encoded as a consumer camera records: 3840×1920 HEVC at 29.97 fps with
an AAC track (cached in `build/bench/stitch_video/`). Every row is a fresh process on the same clip
→ 2048×1024 H.264 (`veryfast`, crf 18), decode and encode included, timed whole (start-up, imports,
preparation, join) and in process (`stitch_video`'s own wall time: preparation, stitch and join, the
imports and the interpreter's start left out); peak resident memory is the child's `VmHWM`:

- **FFmpeg v360**: PyAV's decode → `v360=input=dfisheye:output=equirect:ih_fov=190:iv_fov=190` →
  libx264, the plain anchor (fov only: no lens calibration, no parallax, no blend), with the same
  FFmpeg libraries as learnstitch. Each frame's picture type is cleared before the encoder, as the
  `ffmpeg` command does (`fftools`' `frame_encode`, `do_video_out` in 5.1: none unless a key frame is
  forced): a frame out
  of a filter keeps the type the camera's encoder gave it, which libx264 takes as a forced frame type
  and which saves it its own decisions, about a seventh of its time here;
- **ffmpeg command**: the same filter by a system `ffmpeg` (where one is installed; its own
  FFmpeg and x264 builds), as a user types it, `-c:a copy` as learnstitch copies the audio;
- **template**: `learnstitch stitch --video --mode template` (the fixed remap through the `.pto`), on
  a rig's first clip (its maps made: an empty template cache; JAX's compilation cache as a user's
  earlier runs leave it) and on the next clip of the rig (its maps from the cache, which the first
  run wrote); v360, the command and the two template runs take turns `--repeats` times, the
  medians reported;
- **depth**: the depth-aware stitch (the shipped network of any rig, filtered over time), every
  frame a key frame, and with `--depth-every 3`;
- length: template and depth (every frame a key frame) at `--short` and `--long` / `--long-depth`
  frames, for their peak memory, and v360 at `--long` frames beside them (the start-up counts less
  on a longer clip).

With `--real CLIP --real-rig RIG.pto` (a real dual-fisheye clip, never committed, and its
calibration by `rigjax calibrate --video`), the clip is scaled to 2:1 if it is not (the Gear 360
clips of `acalcutt/Gear360_html5_viewer` are 16:9) and stitched at its own size in both modes.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from fractions import Fraction
from pathlib import Path

import numpy as np
from _record import recorded

ROOT = Path(__file__).resolve().parents[1]
CACHE = ROOT / "build" / "bench" / "stitch_video"
WIDTH = 2048


def arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=300, help="frames of the throughput runs (v360, template)")
    parser.add_argument("--depth-frames", type=int, default=150, help="frames of the depth-aware throughput runs")
    parser.add_argument("--short", type=int, default=60, help="frames of the memory check's short runs")
    parser.add_argument("--long", type=int, default=600, help="frames of the memory check's long template run")
    parser.add_argument("--long-depth", type=int, default=600, help="frames of its long depth-aware run")
    parser.add_argument("--distinct", type=int, default=16, help="frames rendered (played forward and back)")
    parser.add_argument(
        "--repeats", type=int, default=3, help="turns of v360, the command and the template runs (medians)"
    )
    parser.add_argument("--real", help="a real dual-fisheye clip (side by side) to stitch as a user would")
    parser.add_argument("--real-rig", help="its calibration (rigjax calibrate --video on it)")
    # internal: one row in a process of its own
    parser.add_argument("--v360", nargs=2, metavar=("CLIP", "OUT"), help=argparse.SUPPRESS)
    return parser.parse_args()


def make_clip(frames: int, distinct: int, size: int = 1920) -> Path:
    """The synthetic camera's clip of ``frames`` frames, two ``size``-pixel lenses side by side,
    and its project ``dual{size}.pto`` beside it (cached)."""
    import av
    import numpy as np

    from learnstitch.data.sequence import render_sequence, sequence_project

    CACHE.mkdir(parents=True, exist_ok=True)
    clip, rig = CACHE / f"dual{size}-{frames}.mp4", CACHE / f"dual{size}.pto"
    if clip.exists() and rig.exists():
        return clip
    stills = CACHE / f"dual{size}-{distinct}.npz"
    if not stills.exists():
        rendered = [f.side_by_side for f in render_sequence("dual", 0, distinct, size=size, pano_width=64)]
        partial = stills.with_suffix(".partial.npz")
        np.savez(partial, *rendered)
        os.replace(partial, stills)
    with np.load(stills) as loaded:
        rendered = [loaded[k] for k in loaded.files]
    sequence_project("dual", 0, size=size, pano_width=WIDTH, names=["left.png", "right.png"]).save(rig)
    order = [*range(len(rendered)), *range(len(rendered) - 2, 0, -1)]  # forward and back
    rate = 30000 / 1001  # NTSC's 29.97, as consumer cameras record
    partial = clip.with_suffix(".partial.mp4")
    with av.open(str(partial), "w", format="mp4") as out:
        options = {"crf": "22", "preset": "fast", "x265-params": "log-level=error"}
        video = out.add_stream("libx265", rate=Fraction(30000, 1001), options=options)
        video.width, video.height, video.pix_fmt = 2 * size, size, "yuv420p"
        sound = out.add_stream("aac", rate=48000, layout="stereo")
        tone = np.random.default_rng(0).normal(0, 0.05, (2, int(48000 * frames / rate) + 1024)).astype(np.float32)
        for i in range(frames):
            frame = av.VideoFrame.from_ndarray(rendered[order[i % len(order)]], format="rgb24")
            frame.pts = i
            out.mux(video.encode(frame))
        out.mux(video.encode(None))
        for start in range(0, tone.shape[1] - 1024, 1024):
            chunk = av.AudioFrame.from_ndarray(
                np.ascontiguousarray(tone[:, start : start + 1024]), format="fltp", layout="stereo"
            )
            chunk.sample_rate, chunk.pts = 48000, start
            out.mux(sound.encode(chunk))
        out.mux(sound.encode(None))
    os.replace(partial, clip)
    return clip


def v360(clip: str, output: str) -> None:
    """The FFmpeg anchor, in this process: decode, v360, encode; prints its frames."""
    import av

    frames = 0
    with av.open(clip) as source, av.open(output, "w") as out:
        stream = source.streams.video[0]
        stream.thread_type = "AUTO"
        video = out.add_stream("libx264", rate=stream.average_rate, options={"crf": "18", "preset": "veryfast"})
        video.width, video.height, video.pix_fmt = WIDTH, WIDTH // 2, "yuv420p"
        video.codec_context.thread_type = "AUTO"  # libx264 on frame threads, as `ffmpeg` runs it
        video.time_base = tick = 1 / stream.average_rate  # frame k at k ticks, whatever the clip's own timestamps
        graph = av.filter.Graph()
        chain = [
            graph.add_buffer(template=stream),
            graph.add("v360", f"input=dfisheye:output=equirect:ih_fov=190:iv_fov=190:w={WIDTH}:h={WIDTH // 2}"),
            graph.add("buffersink"),
        ]
        chain[0].link_to(chain[1])
        chain[1].link_to(chain[2])
        graph.configure()
        for frame in source.decode(stream):
            graph.push(frame)
            while True:
                try:
                    panorama = graph.pull()
                except (av.BlockingIOError, av.EOFError):
                    break
                panorama.pts, panorama.time_base = frames, tick
                panorama.pict_type = av.video.frame.PictureType.NONE  # as `ffmpeg` does (module docstring)
                frames += 1
                out.mux(video.encode(panorama))
        out.mux(video.encode(None))
    print(json.dumps({"frames": frames}))


def ffmpeg_command(clip: Path, output: Path) -> dict | None:
    """The system ``ffmpeg``'s v360 as a user types it (None where there is none): wall time, frames."""
    ffmpeg = shutil.which("ffmpeg")
    if ffmpeg is None:
        return None
    command = [ffmpeg, "-hide_banner", "-loglevel", "error", "-y", "-i", str(clip), "-vf"]
    command += [f"v360=input=dfisheye:output=equirect:ih_fov=190:iv_fov=190:w={WIDTH}:h={WIDTH // 2}"]
    command += ["-c:v", "libx264", "-preset", "veryfast", "-crf", "18", "-c:a", "copy", str(output)]
    started = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True)
    seconds = time.perf_counter() - started
    if done.returncode:
        raise RuntimeError(f"{' '.join(command)}: {done.stderr[-2000:]}")
    import av

    with av.open(str(output)) as container:
        stream = container.streams.video[0]
        frames = stream.frames or sum(1 for packet in container.demux(stream) if packet.size)
    return {"seconds": seconds, "frames": frames, "peak_mb": None}


def ffmpeg_version() -> str:
    done = subprocess.run([shutil.which("ffmpeg"), "-version"], capture_output=True, text=True, check=True)
    return done.stdout.split()[2]


# The template cache of the benchmark's runs: a folder of its own, emptied for a rig's first clip.
TEMPLATES = Path(tempfile.gettempdir()) / "stitch_video_bench_cache"


def run(command: list[str]) -> dict:
    """A fresh process: its wall time, its peak resident memory (``VmHWM``: this process's own, where a
    forked child's ``ru_maxrss`` starts from its parent's) and its standard output."""
    wrapper = (
        "import runpy, sys; sys.argv = sys.argv[1:]; code = 0\n"
        "try:\n"
        "    if sys.argv[0].endswith('.py'):\n"
        "        sys.path.insert(0, sys.argv[0].rsplit('/', 1)[0]); runpy.run_path(sys.argv[0], run_name='__main__')\n"
        "    else: runpy.run_module(sys.argv[0], run_name='__main__')\n"
        "except SystemExit as e:\n    code = e.code or 0\n"
        "peak = [l.split()[1] for l in open('/proc/self/status') if l.startswith('VmHWM')][0]\n"
        "print('MAXRSS', peak, file=sys.stderr)\n"
        "sys.exit(code)\n"
    )
    env = {**os.environ, "OMP_WAIT_POLICY": "PASSIVE", "LEARNSTITCH_CACHE_DIR": str(TEMPLATES)}
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", wrapper, *command], capture_output=True, text=True, env=env, cwd=ROOT)
    seconds = time.perf_counter() - started
    if done.returncode:
        raise RuntimeError(f"{command}: {done.stderr[-2000:]}")
    peak = int(done.stderr.rsplit("MAXRSS", 1)[1].split()[0]) / 1024
    return {"seconds": seconds, "peak_mb": peak, "stdout": done.stdout}


def stitch_row(clip: Path, out: Path, *extra: str) -> dict:
    command = ["learnstitch.cli", "stitch", "--rig", str(CACHE / "dual1920.pto"), "--video", str(clip)]
    command += ["-o", str(out), "--width", str(WIDTH), "--preset", "veryfast", "--crf", "18", "--quiet", *extra]
    done = run(command)
    last = done["stdout"].strip().splitlines()[-1]  # "...: N frames ...; stitched N frames in S s (F fps)"
    done["frames"] = int(last.split(": ", 1)[1].split(" frames")[0])
    done["loop_fps"] = float(last.rsplit("(", 1)[1].split(" fps")[0])
    return done


def two_to_one(clip: Path) -> Path:
    """``clip`` scaled to a 2:1 frame (its width kept), as a user would before stitching it (cached)."""
    import av

    with av.open(str(clip)) as source:
        stream = source.streams.video[0]
        width, height, rate = stream.width, stream.height, stream.average_rate
    if width == 2 * height:
        return clip
    scaled = CACHE / f"{clip.stem}-2to1.mp4"
    if not scaled.exists():
        partial = scaled.with_suffix(".partial.mp4")
        with av.open(str(clip)) as source, av.open(str(partial), "w", format="mp4") as out:
            video = out.add_stream("libx264", rate=rate, options={"crf": "14", "preset": "veryfast"})
            video.width, video.height, video.pix_fmt = width, width // 2, "yuv420p"
            for k, frame in enumerate(source.decode(video=0)):
                picture = frame.reformat(width=width, height=width // 2, format="yuv420p", interpolation="LANCZOS")
                picture.pts, picture.time_base = k, 1 / rate
                out.mux(video.encode(picture))
            out.mux(video.encode(None))
        os.replace(partial, scaled)
    return scaled


def real_rows(clip: Path, rig: Path, out: Path) -> None:
    """The real clip in both modes, at its own width (the template's whole clip, the depth's first 5 s)."""
    import av

    scaled = two_to_one(clip)
    with av.open(str(scaled)) as source:
        width = source.streams.video[0].width
    print(f"\nReal footage: {clip.name} ({scaled.name}, {width}×{width // 2}), calibrated as {rig.name}.\n")
    print("| run | frames | wall s | fps (whole) | fps (in process) |")
    print("|---|---:|---:|---:|---:|")
    crops = []
    for label, extra in (("template", ["--mode", "template"]), ("depth", ["--duration", "5"])):
        command = ["learnstitch.cli", "stitch", "--rig", str(rig), "--video", str(scaled), "-o", str(out / "real.mp4")]
        row = run([*command, "--width", str(width), "--quiet", *extra])
        last = row["stdout"].strip().splitlines()[-1]
        frames = int(last.split(": ", 1)[1].split(" frames")[0])
        loop = float(last.rsplit("(", 1)[1].split(" fps")[0])
        print(f"| {label} | {frames} | {row['seconds']:.1f} | {frames / row['seconds']:.2f} | {loop:.2f} |")
        crops.append(seam_crops(out / "real.mp4", SEAM_FRAME))
    picture = ROOT / "docs" / "results" / "stitch_video_real_seams.jpg"
    write_jpeg(picture, np.vstack(crops))
    print(
        f"\n![Frame {SEAM_FRAME} of the real clip, around its two seams (longitudes -90 and +90 degrees, the "
        f"lenses' overlap), template above, depth-aware below]({picture.name})\n\n"
        "Each row is two crops side by side, one per seam: a seam runs down the middle of each crop, and "
        "the edge where the two crops meet is not a seam.\n"
    )


SEAM_FRAME = 48  # 2 s into the real clip (24 fps)


def seam_crops(video: Path, index: int) -> np.ndarray:
    """Frame ``index`` of a dual-fisheye panorama video around its two seams, side by side: the
    columns within a twelfth of the width of longitudes -90 and +90 degrees, the middle two thirds
    of the rows."""
    import av

    from learnstitch.video.colour import to_rgb

    with av.open(str(video)) as container:
        for k, frame in enumerate(container.decode(video=0)):
            if k == index:
                rgb = to_rgb(frame)  # as players read it
                break
        else:
            raise RuntimeError(f"{video}: {k + 1} frames, no frame {index} to show the seams of")
    height, width = rgb.shape[:2]
    rows, half = slice(height // 6, height - height // 6), width // 12
    return np.hstack([rgb[rows, c - half : c + half] for c in (width // 4, 3 * width // 4)])


def write_jpeg(path: Path, rgb: np.ndarray) -> None:
    import cv2

    cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 88])


def seconds_of(frames: int) -> str:
    """``--duration`` for ``frames`` frames of the clip (29.97 fps), a little under the next frame."""
    return f"{(frames - 0.5) * 1001 / 30000:.4f}"


def main() -> None:
    args = arguments()
    if args.v360:
        v360(*args.v360)
        return
    sys.stderr.write("making the clip ...\n")
    clip = make_clip(max(args.frames, args.long), args.distinct)
    out = CACHE / "out"
    out.mkdir(exist_ok=True)
    short = CACHE / f"dual1920-{args.frames}.mp4"  # the anchor decodes a whole file: its own, as long
    if not short.exists():
        make_clip(args.frames, args.distinct)
    turns: dict[str, list[dict]] = {"v360": [], "command": [], "first": [], "next": []}
    template = ["--mode", "template", "--duration", seconds_of(args.frames)]
    for turn in range(args.repeats):  # taking turns: the machine's drift falls on them all alike
        sys.stderr.write(f"v360 and template, turn {turn + 1} of {args.repeats} ...\n")
        anchor = run([str(Path(__file__).resolve()), "--v360", str(short), str(out / "v360.mp4")])
        anchor["frames"] = json.loads(anchor["stdout"].strip().splitlines()[-1])["frames"]
        turns["v360"].append(anchor)
        command = ffmpeg_command(short, out / "ffmpeg.mp4")
        if command is not None:
            turns["command"].append(command)
        shutil.rmtree(TEMPLATES, ignore_errors=True)  # the rig's first clip: its maps made
        turns["first"].append(stitch_row(short, out / "pano.mp4", *template))
        turns["next"].append(stitch_row(short, out / "pano.mp4", *template))  # its maps from the cache

    def median(runs: list[dict]) -> tuple[int, float, float | None, float]:
        loops = [r["loop_fps"] for r in runs if "loop_fps" in r]
        return (
            runs[0]["frames"],
            statistics.median(r["seconds"] for r in runs),
            statistics.median(loops) if loops else None,
            None if runs[0]["peak_mb"] is None else max(r["peak_mb"] for r in runs),
        )

    rows = [
        ("FFmpeg v360 (dfisheye, fov only), learnstitch's FFmpeg", *median(turns["v360"])),
        ("learnstitch --mode template, a rig's first clip (maps made)", *median(turns["first"])),
        ("learnstitch --mode template, its next clip (maps from the cache)", *median(turns["next"])),
    ]
    anchors = [(rows[0][0], "v360 with learnstitch's FFmpeg")]
    if turns["command"]:
        rows.append((f"`ffmpeg` {ffmpeg_version()} command, v360", *median(turns["command"])))
        anchors.append((rows[-1][0], "the `ffmpeg` command"))
    for label, extra, count in (
        ("learnstitch, depth (every frame)", [], args.depth_frames),
        ("learnstitch, depth --depth-every 3", ["--depth-every", "3"], args.depth_frames),
    ):
        sys.stderr.write(f"{label} ...\n")
        row = stitch_row(short, out / "pano.mp4", *extra, "--duration", seconds_of(count))
        rows.append((label, row["frames"], row["seconds"], row["loop_fps"], row["peak_mb"]))
    print(f"Clip: 3840×1920 HEVC 29.97 fps with AAC → {WIDTH}×{WIDTH // 2} H.264 `veryfast` crf 18, audio copied.\n")
    print(f"v360, the command and the template runs: medians of {args.repeats} turns; the depth runs: one each.\n")
    print("| run | frames | wall s (whole process) | fps (whole) | fps (in process) | peak MB |")
    print("|---|---:|---:|---:|---:|---:|")
    for label, n, seconds, loop, peak in rows:
        loop_text = "" if loop is None else f"{loop:.2f}"
        peak_text = "" if peak is None else f"{peak:.0f}"
        print(f"| {label} | {n} | {seconds:.1f} | {n / seconds:.2f} | {loop_text} | {peak_text} |")
    fps = {label: n / seconds for label, n, seconds, *_ in rows}
    first, following = fps[rows[1][0]], fps[rows[2][0]]
    for label, name in anchors:
        print(
            f"\nTemplate over {name} (whole process, same clip, size and preset, medians): "
            f"{first / fps[label]:.2f}× on a rig's first clip, {following / fps[label]:.2f}× on its next clips."
        )
    print()
    if args.real:
        real_rows(Path(args.real), Path(args.real_rig), out)
    sys.stderr.write("memory against length ...\n")
    print("Peak memory against the clip's length (one process each):\n")
    print("| run | frames | peak MB | fps (whole) |")
    print("|---|---:|---:|---:|")
    long_anchor = run([str(Path(__file__).resolve()), "--v360", str(clip), str(out / "v360.mp4")])
    long_frames = json.loads(long_anchor["stdout"].strip().splitlines()[-1])["frames"]
    print(
        f"| FFmpeg v360 | {long_frames} | {long_anchor['peak_mb']:.0f} | {long_frames / long_anchor['seconds']:.2f} |"
    )
    for label, extra, counts in (
        ("template", ["--mode", "template"], (args.short, args.long)),
        ("depth (every frame)", [], (args.short, args.long_depth)),
    ):
        for count in counts:
            row = stitch_row(clip, out / "pano.mp4", *extra, "--duration", seconds_of(count))
            print(f"| {label} | {row['frames']} | {row['peak_mb']:.0f} | {row['frames'] / row['seconds']:.2f} |")


if __name__ == "__main__":
    if "--v360" in sys.argv:
        main()
    else:
        with recorded(__file__, __doc__):
            main()
