"""The ``learnstitch`` command line (its subcommands arrive with the data and network work)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from . import __version__


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="learnstitch",
        description="Supervised stitching of three fisheye images into an equirectangular panorama.",
    )
    parser.add_argument("--version", action="version", version=f"learnstitch {__version__}")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    build_parser().parse_args(argv)
    print("learnstitch: no subcommands yet; see `learnstitch --help` and the README's roadmap.", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
