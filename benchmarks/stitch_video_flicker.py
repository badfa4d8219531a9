"""Temporal flicker of the video stitch (`learnstitch stitch --video`): filtered over time, every frame alone, the depth oracle.

    python benchmarks/stitch_video_flicker.py [--sequences 4] [--frames 60] [--dual-size 720]
        [--three-size 512] [--width 1024] [--network] [--depth-every K] [--not-refined]

Each rig kind of `learnstitch.data.sequence` (`dual`: two 190° fisheyes back to back, one side-by-side
clip; `three`: three 185° fisheyes 0.4 m out, one clip per camera) is walked and turned through the
street scenes of seeds 0 … `--sequences` − 1 (`Motion()`: 1.4 m/s, 15°/s, a hand's wobble; 30 fps) for
`--frames` frames, rendered at `--dual-size`² / `--three-size`² per camera with the truth panorama,
inverse depth and visibility `--width` wide. The clips are written losslessly (`libx264rgb`, crf 0,
RGB: decoded bit for bit) and every frame stitched through the sequence's fixed project
(`sequence_project`) into a `--width` × `--width`/2 panorama, three ways:

- **oracle**: a prepared `Stitcher` (the plane sweep's settings) given each frame's true inverse depth
  and visibility (`GivenDepth(full=..., visibility=...)`), colour fitted frame by frame;
- **stills**: `stitch_video(mode="depth", model="sweep", temporal=False)`: every frame stitched alone;
- **video**: `stitch_video(mode="depth", model="sweep", temporal=True)`: the working depth filtered over
  time through the camera's turn (`TemporalDepth`) and the fitted colour smoothed (`TemporalPhotometry`);
- with `--network`, the same two with the shipped network's depth (`model=None`);
- with `--depth-every K` (and `--network`), the network's video with key frames (`depth_every=K`): the
  depth and colour correction estimated on every K-th frame only, carried through the turn between them;
- with `--not-refined` (and `--network`), the network's stills and video with its working depth brought up
  as it is (`render.refine_levels: 0`), not refined by the inputs' agreement (`learnstitch.fullres.refine`,
  on in every other row).

All are encoded the same way (H.264 4:2:0, crf 0, one segment: the temporal filter runs unbroken over
the clip) and decoded again. Luminance is the decoded Y plane, `(Y − 16) / 219`, in the matrix its stream
is tagged with (BT.709: the panoramas of an RGB source), against the truth panorama's luminance by the same
matrix; each method's luminance is first scaled by
one least-squares gain per sequence over its seen pixels (the dual camera's images are darker than the
truth: camera 0 is exposed +0.5 EV, and the fitted colour correction keeps camera 0's exposure), the same
fit for every method.

- **F** (the issue's flicker, in 8-bit levels, 255 × luminance): for each pair of consecutive frames, the
  mean of `|(P_t − P_{t−1}) − (G_t − G_{t−1})|` over the pixels some camera sees in both frames (truth
  visibility), P the decoded stitch and G the truth, averaged over the pairs;
  `ratio = (F_video − F_oracle) / (F_stills − F_oracle)`, target ≤ 0.5;
- **PSNR** (dB, luminance): per frame over the near objects in the seams (seen, inside two or more image
  circles, nearer than 2 m: `learnstitch.evaluation.NEAR_M`, as `benchmarks/stitch_fullres.py` scores
  them), averaged over the frames; target video ≥ stills − 0.1 dB.

The rendered sequences are cached in `build/bench/video_flicker/KIND-SEED-SIZE-FRAMES/` (clips, truth
`.npz`; each written under a temporary name and renamed; remove the folder when the renderer changes),
and each method's stitched clip beside them, kept while learnstitch/ is unchanged: a rerun resumes. Run
on one core (`OMP_NUM_THREADS=1`, torch and OpenCV one thread each).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import shutil
import statistics
import sys
import time
from fractions import Fraction
from pathlib import Path

from _record import recorded

ROOT = Path(__file__).resolve().parents[1]
CACHE = ROOT / "build" / "bench" / "video_flicker"
KINDS = ("dual", "three")
LEVELS = 255.0  # F in 8-bit levels
RATIO_TARGET, PSNR_TOLERANCE_DB = 0.5, 0.1


def stem(method: str) -> str:
    """A method's file name: ``network video, depth every 3`` -> ``network-video-depth-every-3``."""
    return method.replace(",", "").replace(" ", "-")


def arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences", type=int, default=4, help="seeds 0 .. N-1 per rig kind")
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--dual-size", type=int, default=720, help="each fisheye of the dual rig, pixels square")
    parser.add_argument("--three-size", type=int, default=512, help="each fisheye of the three-camera rig")
    parser.add_argument("--width", type=int, default=1024, help="the panorama's (and the truth's) width")
    parser.add_argument("--kinds", nargs="+", default=list(KINDS), choices=KINDS)
    parser.add_argument("--network", action="store_true", help="also the shipped network's depth (model=None)")
    parser.add_argument("--depth-every", type=int, default=1, help="with --network: also its video with key frames")
    parser.add_argument(
        "--not-refined", action="store_true", help="with --network: also its stills and video, depth not refined"
    )
    return parser.parse_args()


# --- the rendered sequences, cached ----------------------------------------------------------------


def _replace(partial: Path, final: Path) -> None:
    with open(partial, "rb") as f:
        os.fsync(f.fileno())
    os.replace(partial, final)


class ClipWriter:
    """A lossless clip (``libx264rgb``, crf 0, RGB), written under ``.partial`` and renamed by :meth:`close`."""

    def __init__(self, path: Path, width: int, height: int, rate: Fraction):
        import av

        self.path, self.partial = path, path.with_name(path.name + ".partial")
        self.container = av.open(str(self.partial), "w", format="mp4")
        self.stream = self.container.add_stream("libx264rgb", rate=rate, options={"crf": "0", "preset": "ultrafast"})
        self.stream.width, self.stream.height, self.stream.pix_fmt = width, height, "rgb24"

    def write(self, image) -> None:
        import av

        self.container.mux(self.stream.encode(av.VideoFrame.from_ndarray(image, format="rgb24")))

    def close(self) -> None:
        self.container.mux(self.stream.encode(None))
        self.container.close()
        _replace(self.partial, self.path)


def clip_names(kind: str) -> list[str]:
    return ["dual.mp4"] if kind == "dual" else [f"cam{k}.mp4" for k in range(3)]


def rendered(kind: str, seed: int, size: int, frames: int, width: int) -> tuple[Path, float | None, bool]:
    """The folder of sequence ``kind``/``seed`` (clips and ``truth-WIDTH.npz``), rendering it unless
    cached; the seconds the render took when it was rendered (None: not recorded); whether it was cached."""
    import numpy as np

    from learnstitch.data.sequence import Motion, render_sequence

    folder = CACHE / f"{kind}-{seed}-{size}-{frames}"
    truth = folder / f"truth-{width}.npz"
    clips = [folder / name for name in clip_names(kind)]
    timing = folder / f"render-{width}.json"
    if truth.exists() and all(c.exists() for c in clips):
        return folder, json.loads(timing.read_text())["seconds"] if timing.exists() else None, True
    folder.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    rate = Fraction(Motion().fps).limit_denominator(1000)
    writers = None
    panos, inverse, visible, poses = [], [], [], []
    for frame in render_sequence(kind, seed, frames, size, pano_width=width):
        images = [frame.side_by_side] if kind == "dual" else frame.images
        if writers is None:
            writers = [ClipWriter(c, im.shape[1], im.shape[0], rate) for c, im in zip(clips, images)]
        for writer, image in zip(writers, images):
            writer.write(image)
        panos.append(frame.pano)
        inverse.append(frame.inverse_depth.astype(np.float32))
        visible.append(np.packbits(frame.visibility, axis=-1))
        poses.append(frame.pose.world_from_rig)
        print(f"  rendered {kind} seed {seed} frame {frame.index + 1}/{frames}", file=sys.stderr, flush=True)
    for writer in writers:
        writer.close()
    partial = truth.with_name(truth.name + ".partial")
    with open(partial, "wb") as f:
        np.savez_compressed(
            f,
            pano=np.stack(panos),
            inverse_depth=np.stack(inverse),
            visibility=np.stack(visible),  # packed along the width
            world_from_rig=np.stack(poses),
        )
    _replace(partial, truth)
    seconds = time.perf_counter() - started
    timing.write_text(json.dumps({"seconds": seconds}))
    return folder, seconds, False


class Truth:
    """A cached sequence's truth: ``pano`` (T, H, W, 3) uint8, ``inverse_depth`` (T, H, W), ``visibility``
    (T, N, H, W) bool, ``world_from_rig`` (T, 3, 3)."""

    def __init__(self, path: Path, width: int):
        import numpy as np

        with np.load(path) as data:
            self.pano = data["pano"]
            self.inverse_depth = data["inverse_depth"]
            self.visibility = np.unpackbits(data["visibility"], axis=-1, count=width).astype(bool)
            self.world_from_rig = data["world_from_rig"]

    def luma(self, weights: tuple[float, float, float]):
        """(T, H, W) float32 luminance in [0, 1] by a matrix's ``weights`` of R, G and B."""
        import numpy as np

        return (self.pano.astype(np.float32) @ np.array(weights, np.float32)) / 255.0


# --- the stitches -----------------------------------------------------------------------------------


def _git(*words: str) -> str:
    import subprocess

    return subprocess.run(["git", *words], cwd=ROOT, capture_output=True, text=True).stdout.strip()


def source_state() -> str:
    """The commit the library runs from, and whether learnstitch/ has uncommitted changes."""
    dirty = _git("status", "--porcelain", "--", "learnstitch")
    return f"learnstitch at commit {_git('rev-parse', '--short', 'HEAD')}" + (
        " with uncommitted changes" if dirty else ""
    )


def source_key() -> str:
    """What the stitched clips depend on: learnstitch/'s tree at HEAD and its uncommitted changes; a
    cached clip stitched by other code is stitched again."""
    import hashlib

    diff = _git("diff", "HEAD", "--", "learnstitch") + _git("status", "--porcelain", "--", "learnstitch")
    return (
        "v2:"
        + _git("rev-parse", "HEAD:learnstitch")
        + ("+" + hashlib.sha256(diff.encode()).hexdigest()[:12] if diff else "")
    )


@contextlib.contextmanager
def observed():
    """``VideoStitch.prepare`` wrapped, for the stitch that ``stitch_video`` makes to be seen: its
    temporal depth (the turns it found), each frame's working depth as rendered (the stitcher's depth
    source wrapped by one that keeps it) and fitted and applied exposures (its ``photometry_filter``
    wrapped by one that records; the identity where there was none). What is stitched does not change."""
    from learnstitch.video.pipeline import VideoStitch

    original = VideoStitch.__dict__["prepare"]
    seen: dict = {"exposures": [], "depths": []}

    def prepare(*args, **kwargs):
        stitch = original.__func__(VideoStitch, *args, **kwargs)
        seen["stitch"] = stitch
        stitcher = stitch.stitcher
        inner, source = stitcher.photometry_filter, stitcher.depth

        def record(fitted):
            applied = fitted if inner is None else inner(fitted)
            seen["exposures"].append((fitted.exposure.tolist(), applied.exposure.tolist()))
            return applied

        def depth(frame, config):
            found = source(frame, config)
            seen["depths"].append(found.working.clone())
            return found

        stitcher.photometry_filter, stitcher.depth = record, depth
        return stitch

    VideoStitch.prepare = prepare
    try:
        yield seen
    finally:
        VideoStitch.prepare = original


def stitched(
    folder: Path, kind: str, seed: int, size: int, frames: int, width: int, method: str, truth: Truth, source: str
) -> dict:
    """Stitch the cached sequence in ``folder`` by ``method`` into ``METHOD-WIDTH.mp4`` beside it (unless
    cached by the same ``source``: :func:`source_key`) and return what the stitch recorded
    (``METHOD-WIDTH.json``): seconds, turns, exposures."""
    import numpy as np

    from learnstitch.data.sequence import sequence_project
    from learnstitch.fullres.config import RenderConfig
    from learnstitch.video import Encoding, stitch_video

    output = folder / f"{stem(method)}-{width}.mp4"
    record = output.with_suffix(".json")
    if output.exists() and record.exists():
        info = json.loads(record.read_text())
        if info.get("source") == source:
            return info
    project = sequence_project(kind, seed, size, width)
    clips = [str(folder / name) for name in clip_names(kind)]
    encoding = Encoding(crf=0)
    info: dict = {"method": method, "source": source}
    if method == "oracle":
        info.update(oracle(project, clips, output, truth, width, encoding))
    else:
        shutil.rmtree(output.with_name(output.name + ".parts"), ignore_errors=True)
        model = "sweep" if "network" not in method else None
        temporal = "video" in method
        depth_every = int(method.rsplit(" ", 1)[1]) if "every" in method else 1
        config = RenderConfig(refine_levels=0) if "not refined" in method else None
        with observed() as seen:
            report = stitch_video(
                project,
                clips,
                output,
                encoding=encoding,
                audio=None,
                segment_frames=frames,
                offsets=[0] * len(clips),
                mode="depth",
                width=width,
                model=model,
                temporal=temporal,
                depth_every=depth_every,
                config=config,
            )
        if report.frames != frames:
            raise RuntimeError(f"{output}: {report.frames} frames written, {frames} expected")
        info["seconds"] = report.seconds
        info["notes"] = report.notes
        info["exposures"] = seen["exposures"]
        info["depth_steps"] = depth_steps(seen["depths"], truth.world_from_rig)
        depth = seen["stitch"].temporal
        if depth is not None:
            info["turns"] = [None if t is None else np.asarray(t).tolist() for t in depth.turns]
    partial = record.with_name(record.name + ".partial")
    partial.write_text(json.dumps(info))
    _replace(partial, record)
    return info


def oracle(project, clips: list[str], output: Path, truth: Truth, width: int, encoding) -> dict:
    """The depth oracle: each frame stitched through the truth's inverse depth and visibility, encoded
    as ``stitch_video`` encodes (one :class:`SegmentWriter` segment)."""
    import torch

    from learnstitch.fullres.stitcher import GivenDepth
    from learnstitch.inference import prepare_project
    from learnstitch.video.colour import colour_of, panorama_colour
    from learnstitch.video.sink import SegmentWriter
    from learnstitch.video.source import Footage, layout, rgb_images

    started = time.perf_counter()
    sizes = [(int(i.width), int(i.height)) for i in project.images]
    found = layout(clips, sizes, [0] * len(clips), "the project")
    frames = len(truth.pano)
    writer, stitcher, exposures = None, None, []
    try:
        for t, decoded in Footage(found, 0, frames):
            images = rgb_images(decoded, found)
            if stitcher is None:
                stitcher = prepare_project(project, width, "sweep", images=images).stitcher
                colour = panorama_colour(colour_of(decoded[0]))  # as stitch_video's
                segment = output.with_name(output.name + ".segment")
                writer = SegmentWriter(segment, 0, width, width // 2, found.rate, encoding, colour)
            depth = GivenDepth(
                full=torch.from_numpy(truth.inverse_depth[t]), visibility=torch.from_numpy(truth.visibility[t])
            )
            result = stitcher(images, depth=depth)
            exposures.append((result.exposure.tolist(), result.exposure.tolist()))
            writer.write(result.pano)
        writer.close()
    except BaseException:
        if writer is not None:
            writer.abandon()
        raise
    if writer is None or writer.frames != frames:
        raise RuntimeError(f"{output}: {writer.frames} frames stitched, {frames} expected")
    os.replace(writer.path, output)
    return {"seconds": time.perf_counter() - started, "exposures": exposures}


# --- the measures -----------------------------------------------------------------------------------


def depth_steps(depths, world_from_rig) -> list[float]:
    """Per pair of consecutive frames, the mean |q_t - q_{t-1} carried through the true turn| of the
    working inverse depths ``depths`` (1/m, every working pixel): how much the depth changes."""
    from learnstitch.video.temporal import carry

    steps = []
    for t in range(1, len(depths)):
        turn = world_from_rig[t - 1].T @ world_from_rig[t]  # prev_from_cur
        steps.append(float((depths[t] - carry(depths[t - 1][None], turn)[0]).abs().mean()))
    return steps


def truth_depth_steps(truth: Truth, working_width: int) -> list[float]:
    """:func:`depth_steps` of the truth's inverse depth reduced to the working width as the oracle's
    is (each working pixel's nearest surface): the change the walk itself makes."""
    import torch

    from learnstitch.fullres.stitcher import reduce_depth

    depths = [reduce_depth(torch.from_numpy(q), working_width) for q in truth.inverse_depth]
    return depth_steps(depths, truth.world_from_rig)


LUMA_WEIGHTS = {1: (0.2126, 0.7152, 0.0722), 5: (0.299, 0.587, 0.114), 6: (0.299, 0.587, 0.114)}  # by matrix


def decoded_luma(path: Path):
    """(T, H, W) float32: the Y plane of every frame of ``path``, ``(Y - 16) / 219``, and the weights
    of R, G and B that make luma in the matrix the stream is tagged with (BT.709 or BT.601)."""
    import av
    import numpy as np

    frames, matrices = [], set()
    with av.open(str(path)) as container:
        for frame in container.decode(video=0):
            matrices.add(int(frame.colorspace))
            if frame.format.name != "yuv420p" or len(matrices) > 1 or not matrices <= set(LUMA_WEIGHTS):
                raise RuntimeError(
                    f"{path}: {frame.format.name} frames tagged {sorted(matrices)}; yuv420p expected, "
                    "tagged BT.709 or BT.601"
                )
            plane = frame.planes[0]
            y = np.frombuffer(plane, np.uint8).reshape(plane.height, plane.line_size)[:, : plane.width]
            frames.append((y.astype(np.float32) - 16.0) / 219.0)
    return np.stack(frames), LUMA_WEIGHTS[matrices.pop()]


def seam_mask(kind: str, seed: int, size: int, width: int):
    """(H, W) bool: inside two or more image circles of the project's cameras (the rig frame)."""
    from learnstitch.data.rig import unwarp_grids
    from learnstitch.data.sequence import draw_sequence

    truth = draw_sequence(kind, seed, size)
    _, masks, _ = unwarp_grids(truth.cameras, (width, width // 2), truth.circle_deg)
    return masks.numpy().sum(0) >= 2


def measure(luma, truth_luma, seen, near, seams) -> dict:
    """F (levels) over the pixels seen in both frames of each pair, and split into the seams and the
    rest, the pairs' mean signed difference (a whole-image shift), PSNR per frame near seam objects
    and over the seen pixels; after one least-squares gain of ``luma`` to the truth over the seen pixels."""
    import numpy as np

    gain = float((luma * truth_luma * seen).sum() / max((luma**2 * seen).sum(), 1e-12))
    p = gain * luma
    flicker, in_seams, outside, near_seams, shift = [], [], [], [], []
    for t in range(1, len(p)):
        both = seen[t] & seen[t - 1]
        d = (p[t] - p[t - 1]) - (truth_luma[t] - truth_luma[t - 1])
        flicker.append(np.abs(d[both]).mean())
        in_seams.append(np.abs(d[both & seams]).mean())
        outside.append(np.abs(d[both & ~seams]).mean())
        if (both & near[t]).any():
            near_seams.append(np.abs(d[both & near[t]]).mean())
        shift.append(abs(d[both].mean()))

    def psnr(mask) -> float:
        values = []
        for t in range(len(p)):
            if mask[t].any():
                mse = float(((p[t] - truth_luma[t])[mask[t]] ** 2).mean())
                values.append(10.0 * math.log10(1.0 / max(mse, 1e-12)))
        return statistics.fmean(values) if values else math.nan

    return {
        "gain": gain,
        "F": LEVELS * statistics.fmean(flicker),
        "F_seams": LEVELS * statistics.fmean(in_seams),
        "F_rest": LEVELS * statistics.fmean(outside),
        "F_near": LEVELS * statistics.fmean(near_seams) if near_seams else math.nan,
        "F_worst": LEVELS * max(flicker),
        "shift": LEVELS * statistics.fmean(shift),
        "F_pairs": [LEVELS * f for f in flicker],
        "psnr_near": psnr(near),
        "psnr_seen": psnr(seen),
    }


def rotation_deg(rotation) -> float:
    import numpy as np

    return math.degrees(math.acos(float(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0))))


def turn_errors(info: dict, truth: Truth) -> dict | None:
    """How the temporal filter's turns (``prev_from_cur``) compare with the truth's ``W_{t-1}^T W_t``:
    frames with none found, the median angle between found and true, the median true turn."""
    import numpy as np

    turns = info.get("turns")
    if turns is None:
        return None
    errors, shares, true_angles, missing = [], [], [], 0
    for t in range(1, len(turns)):
        true = truth.world_from_rig[t - 1].T @ truth.world_from_rig[t]
        true_angles.append(rotation_deg(true))
        if turns[t] is None:
            missing += 1
        else:
            errors.append(rotation_deg(np.asarray(turns[t]).T @ true))
            shares.append(rotation_deg(np.asarray(turns[t])) / max(true_angles[-1], 1e-9))
    return {
        "missing": missing,
        "pairs": len(turns) - 1,
        "error_deg": statistics.median(errors) if errors else math.nan,
        "worst_deg": max(errors) if errors else math.nan,
        "true_deg": statistics.median(true_angles),
        "share": statistics.median(shares) if shares else math.nan,
    }


def exposure_steps(info: dict) -> tuple[float, float]:
    """Mean |change| of the fitted and of the applied exposures from frame to frame (log2 units, max over cameras)."""
    import numpy as np

    fitted = np.array([f for f, _ in info["exposures"]])
    applied = np.array([a for _, a in info["exposures"]])
    if len(fitted) < 2:
        return math.nan, math.nan
    return (
        float(np.abs(np.diff(fitted, axis=0)).max(-1).mean()),
        float(np.abs(np.diff(applied, axis=0)).max(-1).mean()),
    )


# --- the run ----------------------------------------------------------------------------------------


def run_sequence(kind: str, seed: int, size: int, args: argparse.Namespace, methods: list[str], source: str) -> dict:
    import numpy as np

    from learnstitch.evaluation import NEAR_M

    folder, render_seconds, cached = rendered(kind, seed, size, args.frames, args.width)
    truth = Truth(folder / f"truth-{args.width}.npz", args.width)
    seen = truth.visibility.any(axis=1)
    seams = seam_mask(kind, seed, size, args.width)
    with np.errstate(divide="ignore"):
        distance = np.where(truth.inverse_depth > 0, 1.0 / truth.inverse_depth, np.inf)
    near = seen & seams & (distance < NEAR_M)
    out = {"kind": kind, "seed": seed, "render_seconds": render_seconds, "cached": cached}
    out["truth_depth_step"] = statistics.fmean(truth_depth_steps(truth, 512))
    for method in methods:
        print(f"  {kind} seed {seed}: {method}", file=sys.stderr, flush=True)
        info = stitched(folder, kind, seed, size, args.frames, args.width, method, truth, source)
        luma, weights = decoded_luma(folder / f"{stem(method)}-{args.width}.mp4")
        truth_luma = truth.luma(weights)
        if luma.shape != truth_luma.shape:
            raise RuntimeError(f"{kind} seed {seed} {method}: decoded {luma.shape}, truth {truth_luma.shape}")
        result = measure(luma, truth_luma, seen, near, seams)
        result["seconds"] = info["seconds"]
        result["turns"] = turn_errors(info, truth)
        result["exposure_steps"] = exposure_steps(info)
        result["depth_step"] = statistics.fmean(info["depth_steps"]) if "depth_steps" in info else math.nan
        out[method] = result
    return out


def ratio(oracle: float, stills: float, video: float) -> float:
    return (video - oracle) / (stills - oracle) if stills != oracle else math.nan


def table(kind: str, results: list[dict], stills: str, video: str, args: argparse.Namespace) -> None:
    """The per-sequence table of one rig and one depth source, and the mean."""
    print(f"\n**{kind}: {stills} / {video}**\n")
    print(
        "| sequence | F oracle | F stills | F video | ratio (≤ 0.5) | flicker met | PSNR stills (dB) | "
        "PSNR video (dB) | video − stills (≥ −0.1 dB) | PSNR met |"
    )
    print("|---|---:|---:|---:|---:|:---:|---:|---:|---:|:---:|")
    rows = [
        (
            f"seed {r['seed']}",
            r["oracle"]["F"],
            r[stills]["F"],
            r[video]["F"],
            r[stills]["psnr_near"],
            r[video]["psnr_near"],
        )
        for r in results
    ]
    if len(rows) > 1:
        mean = ["mean", *(statistics.fmean(row[k] for row in rows) for k in range(1, 6))]
        rows.append(tuple(mean))
    for name, f_oracle, f_stills, f_video, p_stills, p_video in rows:
        q = ratio(f_oracle, f_stills, f_video)
        delta = p_video - p_stills
        print(
            f"| {name} | {f_oracle:.3f} | {f_stills:.3f} | {f_video:.3f} | {q:.2f} | {'yes' if q <= RATIO_TARGET else 'no'} | "
            f"{p_stills:.2f} | {p_video:.2f} | {delta:+.2f} | {'yes' if delta >= -PSNR_TOLERANCE_DB else 'no'} |"
        )


def diagnostics(kind: str, results: list[dict], methods: list[str]) -> None:
    """Where the flicker is, per method, mean over the sequences."""
    print(f"\n*{kind}: where the flicker is (means over the sequences)*\n")
    print(
        "| method | F | F in the seams | F outside the seams | F near seam objects | F, worst pair | "
        "whole-image shift | PSNR seen (dB) | gain | exposure step fitted / applied (log2) | "
        "working depth step (1/m) | stitch (s / frame) |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for method in methods:
        rs = [r[method] for r in results]

        def mean(key, rs=rs):
            return statistics.fmean(r[key] for r in rs)

        fitted = statistics.fmean(r["exposure_steps"][0] for r in rs)
        applied = statistics.fmean(r["exposure_steps"][1] for r in rs)
        per_frame = statistics.fmean(r["seconds"] / (len(r["F_pairs"]) + 1) for r in rs)
        print(
            f"| {method} | {mean('F'):.3f} | {mean('F_seams'):.3f} | {mean('F_rest'):.3f} | {mean('F_near'):.3f} | "
            f"{mean('F_worst'):.3f} | {mean('shift'):.3f} | "
            f"{mean('psnr_seen'):.2f} | {mean('gain'):.3f} | {fitted:.4f} / {applied:.4f} | "
            f"{'—' if math.isnan(mean('depth_step')) else format(mean('depth_step'), '.4f')} | {per_frame:.2f} |"
        )
    truth_step = statistics.fmean(r["truth_depth_step"] for r in results)
    print(f"| truth (at the working size) | | | | | | | | | | {truth_step:.4f} | |")
    print(f"\n*{kind}: the turns `TemporalDepth` found between consecutive frames, against the truth's*\n")
    print(
        "| sequence | methods | pairs with no turn found | median error (°) | worst error (°) | found / true angle, "
        "median | true turn, median (°) |"
    )
    print("|---|---|---:|---:|---:|---:|---:|")
    for r in results:
        rows: dict[str, list[str]] = {}  # methods whose turns agree share a row
        for method in methods:
            t = r[method]["turns"]
            if t is not None:
                cells = (
                    f"{t['missing']} / {t['pairs']} | {t['error_deg']:.3f} | {t['worst_deg']:.3f} | "
                    f"{t['share']:.2f} | {t['true_deg']:.3f}"
                )
                rows.setdefault(cells, []).append(method)
        for cells, names in rows.items():
            print(f"| seed {r['seed']} | {', '.join(names)} | {cells} |")


def main(args: argparse.Namespace) -> None:
    from learnstitch.worker import setup_worker

    state, source = source_state(), source_key()  # before the library is imported

    setup_worker(torch_threads=1, opencv_threads=1)
    methods = ["oracle", "stills", "video"] + (["network stills", "network video"] if args.network else [])
    keyed = f"network video, depth every {args.depth_every}"
    if args.network and args.depth_every > 1:
        methods.append(keyed)
    if args.network and args.not_refined:
        methods += ["network stills, not refined", "network video, not refined"]
    sizes = {"dual": args.dual_size, "three": args.three_size}
    results: dict[str, list[dict]] = {}
    for kind in args.kinds:
        for seed in range(args.sequences):
            started = time.perf_counter()
            result = run_sequence(kind, seed, sizes[kind], args, methods, source)
            result["wall"] = time.perf_counter() - started
            results.setdefault(kind, []).append(result)
            print(
                f"{kind} seed {seed}: "
                + ", ".join(f"{m} F {result[m]['F']:.3f} PSNR {result[m]['psnr_near']:.2f}" for m in methods)
                + f" ({result['wall']:.0f} s)",
                file=sys.stderr,
                flush=True,
            )
    print(
        f"\n{args.sequences} sequences × {args.frames} frames per rig (30 fps, `Motion()`); fisheyes "
        f"{args.dual_size}² (dual, side by side {2 * args.dual_size} × {args.dual_size}) and {args.three_size}² "
        f"(three); panoramas and truth {args.width} × {args.width // 2}; plane-sweep depth at 512 × 256. "
        "F in 8-bit levels of luminance (lower is better), PSNR of luminance over the near objects in the seams; "
        f"each method's luminance scaled by its own least-squares gain per sequence first. {state}."
    )
    for kind, rs in results.items():
        table(kind, rs, "stills", "video", args)
        if args.network:
            table(kind, rs, "network stills", "network video", args)
        if keyed in methods:
            table(kind, rs, "network stills", keyed, args)
        if "network video, not refined" in methods:
            table(kind, rs, "network stills, not refined", "network video, not refined", args)
    print(
        "\nF in the seams / outside / near seam objects: the same F over the seen pixels inside two or more image "
        "circles / one / the near objects in the seams (of frame t); F, worst pair: the largest pair's; "
        "whole-image shift: the mean over the pairs of |mean of (P_t − P_{t−1}) − (G_t − G_{t−1})| (a frame "
        "brightening or darkening as a whole); exposure step: the mean over the pairs of the largest change of a "
        "camera's log2 exposure, as fitted and as applied (the video's smoothed); gain: the least-squares gain "
        "of the stitch's luminance to the truth's; working depth step: the mean over the pairs of the mean "
        "|q_t − q_{t−1}| of the working inverse depth as rendered (the video's filtered), q_{t−1} carried through "
        "the true turn (the truth's row: its inverse depth reduced to the working size, the change the walk "
        "itself makes); the oracle's is the truth's."
    )
    for kind, rs in results.items():
        diagnostics(kind, rs, methods)
    print("\n*Time per sequence (s; one core)*\n")
    print("| rig | sequence | render | " + " | ".join(methods) + " | render and stitches | this run |")
    print("|---|---|---:|" + "---:|" * len(methods) + "---:|---:|")
    for kind, rs in results.items():
        for r in rs:
            render = "—" if r["render_seconds"] is None else f"{r['render_seconds']:.0f}"
            render += " (cached)" if r["cached"] else ""
            cells = " | ".join(f"{r[m]['seconds']:.0f}" for m in methods)
            total = (r["render_seconds"] or math.nan) + sum(r[m]["seconds"] for m in methods)
            print(f"| {kind} | seed {r['seed']} | {render} | {cells} | {total:.0f} | {r['wall']:.0f} |")
    print(
        "\nTimes as recorded when each sequence was rendered and each clip stitched (`stitch_video`'s wall time, "
        "preparation and join included; the oracle's loop); \"cached\": read from an earlier run's cache. This "
        "run: this command's time for the sequence, the measures included (decoding, F, PSNR, the truth's depth "
        "steps); what was cached is only read."
    )


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main(arguments())
