"""The ``rigjax`` command line: a thin layer over the Python API.

    rigjax trafo [-r] PROJECT.pto [IMAGE_NR]    drop-in for Hugin's pano_trafo
    rigjax optimise IN.pto -o OUT.pto [...]     staged Levenberg-Marquardt on control points
    rigjax demo [--out DIR]                     synthetic rig: optimise it, print what it recovered
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import TextIO

from ._errors import RigjaxError


def _enable_float64() -> None:
    import jax

    jax.config.update("jax_enable_x64", True)


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
    import numpy as np

    from ._project import load_project
    from ._trafo import transform_points

    project = load_project(args.project)
    cameras, canvas = project.cameras(), project.canvas()
    if args.image is not None and not 0 <= args.image < len(project.images):
        raise InputError(f"image {args.image} does not exist (the project has {len(project.images)} images)")
    images, xy = read_points(sys.stdin, len(project.images), args.image)
    if len(images) == 0:
        return 0
    out, valid = transform_points(cameras, canvas, images, xy, reverse=args.reverse)
    out = np.where(valid[:, None], out, np.nan)
    sys.stdout.write("".join(f"{x:.6f} {y:.6f}\n" for x, y in out))
    if not valid.all():
        print(f"rigjax trafo: {int((~valid).sum())} point(s) have no "
              f"{'image' if args.reverse else 'panorama'} position and are printed as 'nan nan'",
              file=sys.stderr)  # fmt: skip
    return 0


def _optimise(args: argparse.Namespace) -> int:
    _enable_float64()
    _enable_compilation_cache()
    import dataclasses

    from ._config import OptimiseConfig, RobustConfig, load_config
    from ._optimise import format_report, optimise
    from ._project import load_project

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
    project = load_project(args.project)
    result = optimise(project, config.schedule, pto_vars=config.pto_vars, objective=config.objective,
                      robust=config.robust.loss, robust_scale=config.robust.scale, anchor=config.anchor,
                      solver=config.solver)  # fmt: skip
    print(format_report(result))
    for line in result.not_optimised:
        print(f"not optimised: {line}")
    result.project.save(args.output)
    print(f"final rms {result.rms:.4f} px (transfer), {result.sphere_rms:.4f} px (sphere); wrote {args.output}")
    return 0 if result.ok else 3


def _enable_compilation_cache() -> None:
    """Persist compiled solves, so that a second run of the same rig shape compiles less."""
    import os

    import jax

    cache = os.environ.get("RIGJAX_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME", os.path.expanduser("~/.cache")), "rigjax", "jax"
    )
    jax.config.update("jax_compilation_cache_dir", cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)


def _demo(args: argparse.Namespace) -> int:
    _enable_float64()
    from .demo import run_demo

    run_demo(args.out)
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
        "Command-line options override the config file. Exit status 3 when a stage did not converge.",
    )
    opt.add_argument("project", help="Hugin .pto project with control points")
    opt.add_argument("-o", "--output", required=True, help="where to write the optimised project")
    opt.add_argument("--config", help="YAML config (see configs/rig/)")
    opt.add_argument("--schedule", help="stages, e.g. YPR,VBYPR (default) or YPR,YPR_VB")
    opt.add_argument("--pto-vars", action="store_true", help="optimise exactly the project's v lines")
    opt.add_argument("--objective", choices=["transfer", "sphere", "hugin"])
    opt.add_argument("--robust", choices=["huber", "cauchy"], help="robust loss")
    opt.add_argument("--robust-scale", type=float, help="robust loss scale in pixels (default 2)")
    opt.add_argument("--anchor", type=int, help="image whose orientation stays fixed (default 0)")
    opt.add_argument("--max-steps", type=int, help="LM steps per stage")
    opt.set_defaults(run=_optimise)

    demo = sub.add_parser("demo", help="calibrate a synthetic 6-camera rig and print what it recovered")
    demo.add_argument("--out", default="build/demo", help="output folder (default build/demo)")
    demo.set_defaults(run=_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.run(args)
    except RigjaxError as exc:
        print(f"rigjax {args.command}: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
