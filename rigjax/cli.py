"""The ``rigjax`` command line: a thin layer over the Python API.

    rigjax trafo [-r] PROJECT.pto [IMAGE_NR]    drop-in for Hugin's pano_trafo
    rigjax demo [--out DIR]                     synthetic rig: write a project, print its transforms
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

    demo = sub.add_parser("demo", help="write a synthetic rig project and print its transforms")
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
