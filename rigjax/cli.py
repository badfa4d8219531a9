"""The ``rigjax`` command line: a thin layer over the Python API.

rigjax trafo [-r] PROJECT.pto [IMAGE_NR]    drop-in for Hugin's pano_trafo
rigjax optimise IN.pto -o OUT.pto [...]     staged Levenberg-Marquardt on control points, with pruning
rigjax calibrate IMAGE... --template T.yaml -o OUT.pto [--render PANO]   from images to a calibrated rig
rigjax render PROJECT.pto [IMAGE...] -o PANO.png [--width W]            equirectangular panorama
rigjax demo [--out DIR]                     synthetic rig: optimise it, print what it recovered
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import TextIO

from .errors import EXIT_BAD_INPUT, RigjaxError
from .outputs import check_output


def _enable_float64() -> None:
    """The commands' geometry in float64 (rigjax.worker)."""
    from .worker import setup_worker

    setup_worker(float64=True)


class InputError(RigjaxError):
    """Bad text on standard input; the message names the line."""


def read_points(stream: TextIO, n_images: int, image: int | None, name: str = "<stdin>"):
    """Parse ``pano_trafo`` input: ``x y`` per line with an image number, else ``image x y``.

    Blank lines are skipped. Returns ``(images, xy)`` as numpy arrays.
    """
    import math

    import numpy as np

    images, points = [], []
    expected = "x y" if image is not None else "image x y"
    for number, line in enumerate(stream, start=1):
        fields = line.split()
        if not fields:
            continue
        if len(fields) != len(expected.split()):
            raise InputError(f"{name}:{number}: expected '{expected}', got {line.strip()!r}")
        if image is None:
            try:
                k = int(fields[0])
            except ValueError:
                raise InputError(f"{name}:{number}: image number {fields[0]!r} is not an integer") from None
            fields = fields[1:]
        else:
            k = image
        if not 0 <= k < n_images:
            raise InputError(f"{name}:{number}: image {k} does not exist (the project has {n_images} images)")
        xy = []
        for field in fields:
            try:
                value = float(field)
            except ValueError:
                raise InputError(f"{name}:{number}: coordinate {field!r} is not a number") from None
            if not math.isfinite(value):
                raise InputError(f"{name}:{number}: coordinate {field!r} is not a finite number")
            xy.append(value)
        images.append(k)
        points.append(xy)
    return np.asarray(images, dtype=np.int32), np.asarray(points, dtype=np.float64).reshape(-1, 2)


def _trafo(args: argparse.Namespace) -> int:
    _enable_float64()
    _enable_compilation_cache()
    import numpy as np

    from .camera.trafo import transform_points
    from .pto.project import load_project

    project = load_project(args.project)
    # Host (NumPy) arrays: the compiled transform takes them as they are, where device arrays built
    # op by op would each compile a small program first.
    cameras, canvas = project.cameras(host=True), project.canvas(host=True)
    if args.image is not None and not 0 <= args.image < len(project.images):
        raise InputError(f"image {args.image} does not exist (the project has {len(project.images)} images)")
    images, xy = read_points(sys.stdin, len(project.images), args.image)
    if len(images) == 0:
        return 0
    out, valid = transform_points(cameras, canvas, images, xy, reverse=args.reverse)
    out = np.where(valid[:, None], out, np.nan)
    sys.stdout.write("".join(f"{x:.6f} {y:.6f}\n" for x, y in out))
    if not valid.all():
        print(
            f"rigjax trafo: {int((~valid).sum())} point(s) have no "
            f"{'image' if args.reverse else 'panorama'} position and are printed as 'nan nan'",
            file=sys.stderr,
        )
    return 0


def _optimise(args: argparse.Namespace) -> int:
    check_output(args.output)
    _enable_float64()
    _enable_compilation_cache()
    from .optimiser.job import OptimiseJob, optimise_job

    outcome = optimise_job(OptimiseJob(args.project, args.output, _optimise_config(args)))
    print(*outcome.lines, sep="\n")
    return outcome.status


def _optimise_config(args: argparse.Namespace):
    """The settings ``rigjax optimise``'s options ask for: the config file's (or the defaults),
    each option given replacing its key."""
    import dataclasses

    from .optimiser.config import OptimiseConfig, PruneConfig, RobustConfig, load_config

    config = load_config(args.config) if args.config else OptimiseConfig()
    if args.schedule:
        config = config.replace(schedule=args.schedule, pto_vars=False)
    if args.pto_vars:
        config = config.replace(pto_vars=True)
    if args.objective:
        config = config.replace(objective=args.objective)
    if args.robust:
        config = config.replace(robust=RobustConfig(args.robust, args.robust_scale or config.robust.scale))
    if args.anchor is not None:
        config = config.replace(anchor=args.anchor)
    if args.max_steps:
        config = config.replace(solver=dataclasses.replace(config.solver, max_steps=args.max_steps))
    if args.prune is False or (args.prune is None and args.objective == "hugin"):
        # Hugin's optimiser does not prune: its optimum needs every point (a config file with objective
        # hugin and no prune key says the same, see rigjax.optimiser.config).
        config = config.replace(prune=None)
    elif args.prune and config.prune is None:
        config = config.replace(prune=PruneConfig())
    return config


def _calibrate(args: argparse.Namespace) -> int:
    from .calibration.job import CalibrateJob, Line, calibrate_job

    job = CalibrateJob(
        template=args.template,
        output=args.output,
        images=tuple(args.images or ()),
        videos=tuple(args.video or ()),
        time=args.time,
        every=args.every,
        frames=args.frames,
        render=args.render,
        width=args.width,
        blend=args.blend,
        seed=args.seed,
        keep_undetermined=args.keep_undetermined,
        motion=args.motion,
        start=args.start,
    )
    job.check_outputs()  # before the work starts
    _enable_float64()
    _enable_compilation_cache()
    with _ProgressBar("calibrate", quiet=args.quiet) as progress:

        def emit(line: Line) -> None:
            progress.close()  # the bar goes before the first line
            print(line.text, file=sys.stderr if line.error else sys.stdout)

        return calibrate_job(job, progress=progress, emit=emit).status


class _ProgressBar:
    """A progress callback that shows each step's name on a bar; the bar opens at the first step
    (so that an error before it prints alone) and is cleared by :meth:`close` or at the end."""

    def __init__(self, desc: str, *, quiet: bool):
        self.desc, self.quiet, self.bar = desc, quiet, None

    def __call__(self, text: str) -> None:
        if self.bar is None:
            from tqdm import tqdm

            self.bar = tqdm(desc=self.desc, unit="step", disable=self.quiet, leave=False)
        self.bar.set_postfix_str(text)
        self.bar.update()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()

    def __enter__(self) -> _ProgressBar:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _render(args: argparse.Namespace) -> int:
    check_output(args.output, image=True)
    _enable_float64()
    from .rendering.job import RenderJob, render_job

    job = RenderJob(
        args.project, args.output, tuple(args.images), width=args.width, blend=args.blend, exposure=args.exposure
    )
    for line in render_job(job).lines:
        print(line)
    return 0


def _enable_compilation_cache() -> None:
    """Keep compiled programs for later runs (rigjax.compiled): a second run on data of the same
    structure loads its solves instead of tracing and compiling them, and the machine code of the
    transform behind ``trafo``."""
    from .worker import setup_worker

    setup_worker(float64=False, compilation_cache=True)


def _demo(args: argparse.Namespace) -> int:
    _enable_float64()
    from .demo import run_demo

    run_demo(args.out, args.template)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="rigjax", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)

    trafo = sub.add_parser(
        "trafo",
        help="transform coordinates between images and the panorama (drop-in for Hugin's pano_trafo)",
        description="Reads coordinates from standard input and prints the transformed ones, as Hugin's "
        "pano_trafo does: 'x y' per line when IMAGE_NR is given, 'image x y' otherwise. Points without "
        "a position (behind a lens, beyond the distortion's invertible range) print as 'nan nan'.",
    )
    trafo.add_argument("-r", "--reverse", action="store_true", help="panorama -> image (default image -> panorama)")
    trafo.add_argument("project", help="Hugin .pto project")
    trafo.add_argument("image", nargs="?", type=int, help="image number (then stdin holds 'x y' pairs)")
    trafo.set_defaults(run=_trafo)

    opt = sub.add_parser(
        "optimise",
        help="optimise a project's cameras on its control points (staged Levenberg-Marquardt)",
        description="Optimises yaw/pitch/roll and lens parameters stage by stage, prints a table per stage "
        "and writes the project (control points and every line it does not interpret are kept). "
        "Command-line options override the config file. Exit status 3 when a stage did not converge and no later "
        "stage optimised all its parameters to convergence.",
    )
    opt.add_argument("project", help="Hugin .pto project with control points")
    opt.add_argument("-o", "--output", required=True, help="where to write the optimised project")
    opt.add_argument("--config", help="YAML config (see configs/rig/)")
    opt.add_argument("--schedule", help="stages, e.g. YPR,VBYPR (default) or YPR,YPR_VB")
    opt.add_argument("--pto-vars", action="store_true", help="optimise exactly the project's v lines")
    opt.add_argument(
        "--objective",
        choices=["transfer", "sphere", "hugin", "reprojection"],
        help="point residual (default transfer); reprojection: cameras with centres (the config's or the "
        "project's '#-rigjax centre' lines) and control points as scene points",
    )
    opt.add_argument("--robust", choices=["huber", "cauchy"], help="robust loss")
    opt.add_argument("--robust-scale", type=float, help="robust loss scale in pixels (default 2)")
    opt.add_argument(
        "--anchor",
        type=int,
        help="image whose orientation stays fixed (default 0); reprojection: whose centre stays fixed with X, "
        "and whose orientation is estimated too where the centres tell the rig's",
    )
    opt.add_argument("--max-steps", type=int, help="LM steps per stage")
    opt.add_argument(
        "--prune",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="remove badly matched points between LM rounds (default on; off for --objective hugin)",
    )
    opt.set_defaults(run=_optimise)

    cal = sub.add_parser(
        "calibrate",
        help="calibrate a rig from one image (or video) per camera, or per two cameras side by side",
        description="Features, matches, RANSAC, initial values (template or closed form), Lévy-flight starts, "
        "staged LM and pruning; prints matches per pair, per-stage RMS, pruning and the final geometry, and "
        "writes a Hugin project. Exit status 3 when the solve did not converge, as for optimise, and when the "
        "matches do not determine a parameter or it ends outside the template's plausible lens (the template's "
        "checks): then nothing is written, unless --keep-undetermined.",
    )
    cal.add_argument(
        "images",
        nargs="*",
        help="one image per camera (or per two side by side), in the template's order; several frames of "
        "the rig one after another, their matches pooled",
    )
    cal.add_argument("--template", required=True, help="rig template (see configs/rig/ring6.yaml)")
    cal.add_argument("-o", "--output", required=True, help="where to write the calibrated project")
    cal.add_argument("--video", nargs="+", help="one video per camera instead of images")
    cal.add_argument("--time", type=float, default=0.0, help="seconds into the videos (default 0)")
    cal.add_argument(
        "--every", type=int, help="with --video: every N-th frame from --time on, each a frame of the rig (pooled)"
    )
    cal.add_argument("--frames", type=int, default=5, help="with --every: at most this many frames (default 5)")
    cal.add_argument(
        "--motion",
        action="store_true",
        help="several frames of a turning camera: calibrate each lens (hfov, a, b, c, d, e; with the template's "
        "photometry, its vignetting) from the camera's own motion (the template's motion section, or its defaults)",
    )
    cal.add_argument(
        "--start",
        metavar="PTO",
        help="a project of this camera made before (Hugin's, an earlier calibration's; a dual-fisheye template "
        "whose i lines state the whole frame with crops included): start from its lenses (v, a, b, c, d, e), "
        "orientations and crops, the template's priors about them",
    )
    cal.add_argument("--render", help="also render the panorama to this file")
    cal.add_argument("--width", type=int, help="panorama width (default the template's)")
    cal.add_argument("--blend", choices=["multiband", "feather", "none"], default="multiband")
    cal.add_argument("--seed", type=int, default=0, help="seed of RANSAC, subsampling and the Lévy search")
    cal.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    cal.add_argument(
        "--keep-undetermined",
        action="store_true",
        help="write the project even when the checks find a parameter the matches do not determine "
        "(still exit status 3; the project says which in '#-rigjax undetermined' comments)",
    )
    cal.set_defaults(run=_calibrate)

    ren = sub.add_parser("render", help="render a project's images into an equirectangular panorama")
    ren.add_argument("project", help="Hugin .pto project (equirectangular p line)")
    ren.add_argument("images", nargs="*", help="the images, in the project's order (default: the files it names)")
    ren.add_argument("-o", "--output", required=True, help="panorama file (.png, .jpg, .tif)")
    ren.add_argument("--width", type=int, help="width in pixels (default the p line's)")
    ren.add_argument("--blend", choices=["multiband", "feather", "none"], default="multiband")
    ren.add_argument("--exposure", action="store_true", help="equalise the images' gains first")
    ren.set_defaults(run=_render)

    demo = sub.add_parser("demo", help="calibrate a synthetic 6-camera rig from its images, render the panorama")
    demo.add_argument("--out", default="build/demo", help="output folder (default build/demo)")
    demo.add_argument("--template", default="configs/rig/ring6.yaml", help="rig template (default ring6)")
    demo.set_defaults(run=_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.run(args)
    except RigjaxError as exc:
        print(f"rigjax {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
