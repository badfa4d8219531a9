"""The ``learnstitch`` command line: a thin layer over the Python API.

    learnstitch synth --config configs/stitch/NAME.yaml --out DIR [--split train|test] [--num N]
                      [--workers W] [--preview]
    learnstitch train --config configs/stitch/NAME.yaml [--out DIR] [--resume]
    learnstitch evaluate --config configs/stitch/NAME.yaml --checkpoint FILE [--data KEY=VALUE ...] --out DIR
    learnstitch curves RUN [LABEL=RUN ...] -o curves.png
    learnstitch stitch --rig rig.pto -o pano.jpg [--width W] [--checkpoint FILE | --sweep | --inverse-depth FILE]
                       [--depth depth.npy|depth.png] [--confidence confidence.npy] [--render KEY=VALUE ...]
                       [IMAGE ...]
    learnstitch stitch FISHEYE_0 FISHEYE_1 FISHEYE_2 --checkpoint FILE -o pano.png
    learnstitch demo [--out DIR] [--checkpoint CKPT] [--fullres SIZE | --dual SIZE]

``train`` also runs under ``torchrun --nproc_per_node N -m learnstitch.cli train ...`` (data parallel).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence

from . import __version__


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="learnstitch",
        description="Supervised stitching of fisheye rigs into equirectangular panoramas.",
    )
    parser.add_argument("--version", action="version", version=f"learnstitch {__version__}")
    commands = parser.add_subparsers(dest="command", required=True)
    synth = commands.add_parser("synth", help="render synthetic fisheye triplets and panoramas to a folder (resumable)")
    synth.add_argument("--config", required=True, help="configs/stitch/NAME.yaml (its data section)")
    synth.add_argument("--out", required=True, help="output folder (created; a rerun resumes it)")
    synth.add_argument("--split", default="train", choices=["train", "test"])
    synth.add_argument("--num", type=int, default=100, help="samples in the split (default 100)")
    synth.add_argument("--workers", type=int, default=1, help="parallel worker processes (default 1)")
    synth.add_argument("--preview", action="store_true", help="also write OUT/preview_SPLIT.png, a contact sheet")
    synth.add_argument("--quiet", action="store_true", help="no progress bar")

    train = commands.add_parser(
        "train", help="train the network of a config (checkpoints, resume, JSONL + TensorBoard)"
    )
    train.add_argument("--config", required=True, help="configs/stitch/NAME.yaml")
    train.add_argument("--out", help="run folder (default runs/NAME)")
    train.add_argument("--resume", action="store_true", help="continue the run in --out from its checkpoint")
    train.add_argument("--quiet", action="store_true", help="no progress bar")

    evaluate = commands.add_parser(
        "evaluate", help="PSNR/SSIM of a trained network and the classical references on the test split"
    )
    evaluate.add_argument("--config", required=True, help="configs/stitch/NAME.yaml (data and evaluate sections)")
    evaluate.add_argument("--checkpoint", required=True, help="model.pt or checkpoint.pt of a run of that config")
    evaluate.add_argument("--out", required=True, help="folder for metrics.json, table.md, examples.png")
    evaluate.add_argument("--device", default="cpu", help="torch device (default cpu; workers are used on cpu only)")
    evaluate.add_argument("--samples", type=int, help="test samples (default: the config's evaluate.samples)")
    evaluate.add_argument("--workers", type=int, help="worker processes (default: the config's evaluate.workers)")
    evaluate.add_argument(
        "--data",
        nargs="+",
        metavar="KEY=VALUE",
        help="override keys of the test data, e.g. gain_jitter=0 vignetting=0 noise_std=0 (clean photometry)",
    )
    evaluate.add_argument("--quiet", action="store_true", help="no progress bar")

    curves = commands.add_parser("curves", help="draw the learning curves of training runs on one figure")
    curves.add_argument("runs", nargs="+", metavar="RUN", help="run folders (train --out), or LABEL=RUN")
    curves.add_argument("-o", "--output", required=True, help="PNG to write")

    stitch = commands.add_parser(
        "stitch",
        help="stitch a calibrated rig's images at full resolution (--rig rig.pto), or three fisheyes at a network's size",
    )
    stitch.add_argument(
        "images",
        nargs="*",
        metavar="IMAGE",
        help="with --rig: images in place of those its i lines name (in their order); without: the three "
        "fisheyes of the network's rig (cameras at yaw 0, 120, 240), stitched at the network's size",
    )
    stitch.add_argument(
        "--rig",
        help="the rig's calibration (.pto, as rigjax calibrate or Hugin writes it): any number of cameras, any "
        "lens and image size, centres from its '#-rigjax centre' lines; stitched at full resolution",
    )
    stitch.add_argument("-o", "--output", required=True, help="equirectangular panorama (PNG, JPEG, ...)")
    stitch.add_argument("--width", type=int, help="with --rig: the panorama's width (default the .pto's p line), 2:1")
    depth = stitch.add_mutually_exclusive_group()
    depth.add_argument(
        "--checkpoint",
        help="a rig-aware network's model.pt (with --rig: the depth at its size; default the shipped network of "
        "any rig, learnstitch/weights/cpu_tiny_anyrig.pt)",
    )
    depth.add_argument("--sweep", action="store_true", help="with --rig: the depth from the plane sweep, no network")
    depth.add_argument(
        "--inverse-depth",
        metavar="FILE",
        help="with --rig: the panorama's own inverse depth (.npy, float, the panorama's size, 1 / metres from the "
        "rig's centre, 0 at infinity: a depth sensor's, a scan's, another model's) in place of the network's",
    )
    stitch.add_argument(
        "--depth",
        help="with --rig: also write the depth here: a .npy gets the inverse depth each pixel was rendered at "
        "(float32, the panorama's size, 1 / metres, 0 at infinity: what --inverse-depth reads); an image, the "
        "working inverse depth (refined: half the panorama's width), near bright",
    )
    stitch.add_argument(
        "--confidence",
        metavar="FILE.npy",
        help="with --rig: also write the depth refinement's confidence in each pixel's depth (.npy, float32, the "
        "panorama's size, 0 to 1: 0 where the inputs could not tell)",
    )
    stitch.add_argument(
        "--render",
        nargs="+",
        metavar="KEY=VALUE",
        help="with --rig: render: settings replaced (a still's: the network's config's, or the defaults; a "
        "video's: the defaults, refine_scale 0.25), e.g. refine_levels=0 (the depth not refined: faster)",
    )
    stitch.add_argument(
        "--device", default="cpu", help="where the network runs (default cpu; the render runs on the CPU)"
    )
    _video_arguments(stitch)

    batch = commands.add_parser(
        "batch",
        help="stitch many clips of one rig into 360 videos, chunk by chunk, on this machine or a Ray cluster (resumable)",
    )
    batch.add_argument(
        "clips", nargs="*", metavar="CLIP", help="side-by-side clips, each written as -o's folder/NAME.mp4"
    )
    batch.add_argument("--rig", required=True, help="the rig's calibration (.pto), on a path every worker reads")
    batch.add_argument(
        "--list",
        metavar="FILE",
        help="clips a line each: a side-by-side clip, or one clip per camera in the i lines' order, then "
        "optionally offsets=K,K,.. (default: from the audio) and out=NAME.mp4; # starts a comment",
    )
    batch.add_argument("-o", "--output", required=True, metavar="FOLDER", help="where the 360 videos are written")
    batch.add_argument("--width", type=int, help="the panoramas' width (default the .pto's p line), 2:1")
    batch_depth = batch.add_mutually_exclusive_group()
    batch_depth.add_argument("--checkpoint", help="a rig-aware network's model.pt (default the shipped network)")
    batch_depth.add_argument("--sweep", action="store_true", help="the depth from the plane sweep, no network")
    batch.add_argument("--device", default="cpu", help="where the network runs (default cpu; cuda with GPU workers)")
    footage = batch.add_argument_group("each clip, as stitch --video stitches it")
    _footage_arguments(footage)
    chunks = batch.add_argument_group("chunks and workers")
    chunks.add_argument("--chunk-frames", type=int, help="frames a chunk (default 300: ten seconds at 30 fps)")
    chunks.add_argument(
        "--threads",
        type=int,
        help="threads each chunk's stitch and encoder use (default: this machine's cores; with --ray, 1): pinned, "
        "so a chunk's frames do not depend on where it ran",
    )
    chunks.add_argument(
        "--ray",
        metavar="ADDRESS",
        help="stitch on a Ray cluster: auto (the running one, else a local one) or its head's host:port "
        "(default: this machine, no Ray)",
    )
    chunks.add_argument("--workers", type=int, help="with --ray: actors (default: as many as the CPUs hold)")
    chunks.add_argument("--cpus-per-worker", type=float, help="with --ray: CPUs an actor (default --threads)")
    chunks.add_argument("--gpus-per-worker", type=float, default=0.0, help="with --ray: GPUs an actor (default 0)")
    chunks.add_argument("--quiet", action="store_true", help="no progress bar")

    turns = commands.add_parser(
        "turns", help="the camera's turn in every frame of a rig's clip, as CSV (yaw, pitch, roll from the first frame)"
    )
    turns.add_argument("--rig", required=True, help="the rig's calibration (.pto, as rigjax calibrate writes it)")
    turns.add_argument(
        "--video",
        nargs="+",
        required=True,
        metavar="CLIP",
        help="the clip(s), as learnstitch stitch --video takes them",
    )
    turns.add_argument("-o", "--output", help="CSV to write (default: beside the .pto, CLIP's name + .turns.csv)")
    turns.add_argument("--time", type=float, default=0.0, help="start at the frame on screen at this many seconds")
    turns.add_argument("--duration", type=float, help="seconds to measure (default: to the end)")
    turns.add_argument(
        "--offsets", type=int, nargs="+", help="per clip, its frame that is the rig's first (default: from the audio)"
    )

    demo = commands.add_parser(
        "demo", help="stitch a synthetic test triplet with the small model shipped in the package"
    )
    demo.add_argument(
        "--checkpoint",
        help="a rig-aware checkpoint to stitch it with (default: the shipped network of any rig, "
        "learnstitch/weights/cpu_tiny_anyrig.pt)",
    )
    demo.add_argument("--out", default="build/demo/stitch", help="folder for the panoramas (default build/demo/stitch)")
    demo.add_argument("--seed", type=int, default=0, help="test sample (default 0)")
    demo.add_argument(
        "--fullres",
        type=int,
        metavar="SIZE",
        help="instead: a rig of three SIZE x SIZE fisheyes written as a user's (PNGs, rig.pto) and stitched at "
        "full resolution (learnstitch stitch --rig)",
    )
    demo.add_argument(
        "--dual",
        type=int,
        metavar="SIZE",
        help="instead: three side-by-side frames of a dual-fisheye camera (SIZE x SIZE per lens) and their truth "
        "(truth.pto), for rigjax calibrate --template configs/rig/dual_fisheye.yaml",
    )
    demo.add_argument(
        "--video",
        type=int,
        metavar="SIZE",
        help="instead: a clip of a dual-fisheye camera walking and turning (SIZE x SIZE per lens, with audio) and "
        "its truth, for rigjax calibrate --video and learnstitch stitch --video",
    )
    return parser


def _synth(args) -> int:
    from pathlib import Path

    from .config import load_config
    from .data.generate import synthesise, write_contact_sheet

    config = load_config(args.config)
    report = synthesise(
        config.data,
        args.out,
        split=args.split,
        num=args.num,
        workers=args.workers,
        config_name=config.name,
        progress=not args.quiet,
    )
    print(
        f"{report.folder}: {report.written} written, {report.already_done} already there"
        + (f", {report.partial_removed} half-written removed" if report.partial_removed else "")
    )
    if args.preview:
        path = write_contact_sheet(report.folder, Path(args.out) / f"preview_{args.split}.png")
        print(f"preview: {path}")
    return 0


def _train(args) -> int:
    from .config import load_config
    from .training import train

    config = load_config(args.config)
    report = train(config, args.out or f"runs/{config.name}", resume=args.resume, progress=not args.quiet)
    if int(os.environ.get("RANK", "0")) == 0:
        print(
            f"{report.out}: {report.steps} steps in {report.seconds:.0f} s (step {report.final_step}), "
            f"last loss {report.last_loss:.4f}; weights in {report.out / 'model.pt'}"
        )
    return 0


def _evaluate(args) -> int:
    from .config import load_config
    from .evaluation import evaluate, parse_overrides

    config = load_config(args.config)
    report = evaluate(
        config,
        args.checkpoint,
        out=args.out,
        device=args.device,
        samples=args.samples,
        workers=args.workers,
        data=parse_overrides(args.data),
        progress=not args.quiet,
    )
    print(report.table)
    print(f"written: {report.out / 'metrics.json'}, {report.out / 'table.md'}, {report.out / 'examples.png'}")
    return 0


def _curves(args) -> int:
    from pathlib import Path

    from rigjax.outputs import check_output

    from .curves import plot_learning_curves

    check_output(args.output)
    runs = {}
    for item in args.runs:
        label, sep, run = item.rpartition("=")
        runs[label if sep else Path(run).name] = Path(run)
    print(plot_learning_curves(runs, args.output))
    return 0


def _video_arguments(stitch: argparse.ArgumentParser) -> argparse._ArgumentGroup:
    """``learnstitch stitch --rig rig.pto --video clip.mp4 -o pano.mp4``: a 360 video."""
    video = stitch.add_argument_group("360 video (with --rig and --video)")
    video.add_argument(
        "--video",
        nargs="+",
        metavar="CLIP",
        help="a side-by-side clip (its frame cut into the .pto's images, left to right) or one clip per camera "
        "in the i lines' order; -o names the MP4 to write",
    )
    _footage_arguments(video)
    video.add_argument(
        "--offsets", type=int, nargs="+", help="per clip, its frame that is the rig's first (default: from the audio)"
    )
    video.add_argument(
        "--segment-frames", type=int, help="frames per segment, the unit --resume restarts from (default 300)"
    )
    video.add_argument(
        "--resume", action="store_true", help="continue a run killed midway after its last whole segment"
    )
    video.add_argument(
        "--stabilise",
        nargs="?",
        const=True,
        default=False,
        metavar="TURNS.csv",
        help="horizon level, heading smoothed: from the camera's turn in every frame, measured first or read "
        "from learnstitch turns' CSV",
    )
    video.add_argument(
        "--stabilise-seconds", type=float, default=1.0, metavar="S", help="the heading's smoothing (default 1 s)"
    )
    video.add_argument("--quiet", action="store_true", help="no progress bar")
    return video


def _footage_arguments(video: argparse._ArgumentGroup) -> None:
    """The options ``stitch --video`` and ``batch`` share: the mode, the range, the audio, the encoding."""
    video.add_argument(
        "--mode",
        choices=["depth", "template"],
        default="depth",
        help="depth (default): the depth-aware stitch, filtered over time; template: a fixed remap, no depth (fast)",
    )
    video.add_argument("--time", type=float, default=0.0, help="start at the frame on screen at this many seconds")
    video.add_argument("--duration", type=float, help="seconds to stitch (default: to the end)")
    video.add_argument("--audio", type=int, default=0, help="the clip whose audio is kept (default 0, the first)")
    video.add_argument("--no-audio", action="store_true", help="write no audio")
    video.add_argument("--codec", choices=["h264", "h265"], default="h264", help="default h264 (every player)")
    video.add_argument("--crf", type=int, default=18, help="x264/x265 constant rate factor (default 18; 0 lossless)")
    video.add_argument("--preset", default="veryfast", help="x264/x265 speed preset (default veryfast)")
    video.add_argument("--no-temporal", action="store_true", help="stitch every frame on its own (no filter over time)")
    video.add_argument(
        "--depth-every",
        type=int,
        default=1,
        metavar="K",
        help="estimate the depth and colour correction on every K-th frame, carried through the camera's turn between (default 1)",
    )


def video_defaults() -> dict[str, object]:
    """The options of ``stitch --video`` (``--video`` aside) and their defaults: one given without
    ``--video`` is an error."""
    group = _video_arguments(argparse.ArgumentParser(add_help=False))
    return {action.dest: action.default for action in group._group_actions if action.dest != "video"}


def _enable_compilation_cache() -> None:
    """Keep JAX's compiled programs for later runs (:func:`rigjax.compiled.persist`): the sight
    tables' camera maps of the next stitch of a rig of the same sizes load instead of compiling."""
    from .worker import setup_worker

    setup_worker(compilation_cache=True)


def _stitch_options(args) -> dict[str, object]:
    """:meth:`learnstitch.video.VideoStitch.prepare`'s settings from ``stitch --video``'s or ``batch``'s arguments."""
    return {
        "mode": args.mode,
        "width": args.width,
        "model": "sweep" if args.sweep else args.checkpoint,
        "time_s": args.time,
        "temporal": not args.no_temporal,
        "depth_every": args.depth_every,
        "device": args.device,
    }


def _render_overrides(items: list[str] | None) -> dict[str, object]:
    """``--render KEY=VALUE ...`` as a dict; the evaluation module (heavy) is imported only when given."""
    if not items:
        return {}
    from .evaluation import parse_overrides

    return parse_overrides(items, "--render", "refine_levels=0")


def _stitch_video(args) -> int:
    from rigjax.errors import ConfigError
    from rigjax.outputs import check_output

    from .video import Encoding, stitch_video

    if args.rig is None:
        raise ConfigError("--video needs --rig (the rig's calibration, as rigjax calibrate writes it)")
    if args.images or args.depth is not None or args.inverse_depth is not None or args.confidence is not None:
        raise ConfigError(
            "--video stitches the clips' frames: give no IMAGE, no --depth, no --confidence and no --inverse-depth"
        )
    if not args.stabilise and args.stabilise_seconds != video_defaults()["stabilise_seconds"]:
        raise ConfigError("--stabilise-seconds needs --stabilise (the heading's smoothing)")
    config = None
    if args.render:  # the template mode's start-up imports neither torch nor JAX without it
        from .fullres.config import render_with
        from .video.pipeline import VIDEO_RENDER

        config = render_with(VIDEO_RENDER, _render_overrides(args.render))
    check_output(args.output)
    _enable_compilation_cache()
    report = stitch_video(
        args.rig,
        args.video,
        args.output,
        offsets=args.offsets,
        duration=args.duration,
        encoding=Encoding(args.codec, args.crf, args.preset),
        audio=None if args.no_audio else args.audio,
        resume=args.resume,
        progress=not args.quiet,
        stabilise=args.stabilise,
        stabilise_seconds=args.stabilise_seconds,
        config=config,
        **({"segment_frames": args.segment_frames} if args.segment_frames is not None else {}),
        **_stitch_options(args),
    )
    print(report.summary())
    return 0


def _batch(args) -> int:
    from rigjax.errors import EXIT_BAD_INPUT, ConfigError

    from .video import Encoding
    from .video.batch import read_clip_list, stitch_batch

    clips = list(args.clips)
    if args.list:
        clips += read_clip_list(args.list, args.output)
    if not clips:
        raise ConfigError("give the clips to stitch (CLIP ... or --list FILE)")
    if args.ray is None and (args.workers or args.cpus_per_worker or args.gpus_per_worker):
        raise ConfigError("--workers, --cpus-per-worker and --gpus-per-worker size a Ray pool: they need --ray")
    _enable_compilation_cache()
    threads = args.threads or (1 if args.ray else os.cpu_count() or 1)
    report = stitch_batch(
        args.rig,
        clips,
        args.output,
        ray=args.ray,
        workers=args.workers,
        cpus_per_worker=args.cpus_per_worker,
        gpus_per_worker=args.gpus_per_worker,
        progress=not args.quiet,
        options=_stitch_options(args),
        duration=args.duration,
        encoding=Encoding(args.codec, args.crf, args.preset),
        audio=None if args.no_audio else args.audio,
        threads=threads,
        **({"chunk_frames": args.chunk_frames} if args.chunk_frames is not None else {}),
    )
    print(report.summary())
    for failed in report.failed:
        print(f"learnstitch batch: error: {failed.error}", file=sys.stderr)
    return EXIT_BAD_INPUT if report.failed else 0


def _stitch(args) -> int:
    if args.video is not None:  # before the stills' imports: the template mode needs neither torch nor JAX
        return _stitch_video(args)
    from rigjax.errors import ConfigError
    from rigjax.outputs import check_output

    from .inference import read_fisheyes, stitch_files, stitch_project_to

    for flag, given in video_defaults().items():
        if getattr(args, flag) != given:
            raise ConfigError(f"--{flag.replace('_', '-')} needs --video (a 360 video of a rig's clips)")
    check_output(args.output, image=True)
    if args.rig is None:
        for flag in ("width", "depth", "inverse_depth", "confidence", "render"):
            if getattr(args, flag) is not None:
                raise ConfigError(
                    f"--{flag.replace('_', '-')} needs --rig (the full-resolution stitch of a calibrated rig)"
                )
        if args.checkpoint is None or args.sweep:
            raise ConfigError(
                "without --rig, pass the three fisheyes and --checkpoint (a network stitches them at its size)"
            )
        pano = stitch_files(read_fisheyes(args.images), args.checkpoint, args.output, device=args.device)
        print(f"{args.output}: {pano.shape[-1]} x {pano.shape[-2]} panorama")
        return 0
    if args.depth is not None:
        check_output(args.depth, image=not args.depth.lower().endswith(".npy"))
    if args.confidence is not None:
        if not args.confidence.lower().endswith(".npy"):
            raise ConfigError(f"--confidence {args.confidence}: the confidence is written as a .npy array")
        if args.inverse_depth is not None:
            raise ConfigError("--confidence is the depth refinement's: --inverse-depth is stitched through as given")
        check_output(args.confidence)
    _enable_compilation_cache()
    done = stitch_project_to(
        args.rig,
        args.output,
        args.width,
        "sweep" if args.sweep else args.checkpoint,
        images=args.images or None,
        depth_output=args.depth,
        device=args.device,
        inverse_depth=args.inverse_depth,
        confidence_output=args.confidence,
        render=_render_overrides(args.render),
    )
    print(done.summary(args.output))
    return 0


def _turns(args) -> int:
    from pathlib import Path

    from rigjax.outputs import check_output

    from .video.turns import clip_turns

    output = args.output or Path(args.rig).with_name(f"{Path(args.video[0]).stem}.turns.csv")
    check_output(output)
    report = clip_turns(args.rig, args.video, time_s=args.time, duration=args.duration, offsets=args.offsets)
    report.turns.write(output)
    print(report.summary(output))
    return 0


def _demo(args) -> int:
    from .demo import demo, dual_demo, fullres_demo, video_demo
    from .inference import RIG_MODEL

    if args.video is not None:
        print(video_demo(args.out, size=args.video, seed=args.seed))
    elif args.dual is not None:
        print(dual_demo(args.out, size=args.dual, seed=args.seed))
    elif args.fullres is not None:
        print(fullres_demo(args.out, size=args.fullres, seed=args.seed))
    else:
        print(demo(args.out, seed=args.seed, checkpoint=args.checkpoint or RIG_MODEL))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.command in ("stitch", "batch"):
        from .worker import setup_worker

        # OpenMP threads that spin while they wait slow the command many times over when other work
        # keeps the cores busy (benchmarks/stitch_fullres_speed.py measures it); set before torch
        # loads, so only in a fresh process (the command, not a caller of main), unless the user
        # chose otherwise.
        setup_worker(omp_wait_policy="PASSIVE")
    from rigjax.errors import EXIT_BAD_INPUT, RigjaxError

    try:
        return {
            "synth": _synth,
            "train": _train,
            "evaluate": _evaluate,
            "curves": _curves,
            "stitch": _stitch,
            "batch": _batch,
            "turns": _turns,
            "demo": _demo,
        }[args.command](args)
    except RigjaxError as error:  # every bad input of rigjax and learnstitch (ConfigError included)
        print(f"learnstitch {args.command}: error: {error}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as error:
        training = sys.modules.get("learnstitch.training")  # imported by the commands that train
        if training is None or not isinstance(error, training.TrainingError):
            raise
        print(f"learnstitch {args.command}: training stopped: {error}", file=sys.stderr)
        return 3


if __name__ == "__main__":
    sys.exit(main())
