"""The ``learnstitch`` command line: a thin layer over the Python API.

    learnstitch synth --config configs/stitch/NAME.yaml --out DIR [--split train|test] [--num N]
                      [--workers W] [--preview]
"""

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
    commands = parser.add_subparsers(dest="command", required=True)
    synth = commands.add_parser("synth", help="render synthetic fisheye triplets and panoramas to a folder (resumable)")
    synth.add_argument("--config", required=True, help="configs/stitch/NAME.yaml (its data section)")
    synth.add_argument("--out", required=True, help="output folder (created; a rerun resumes it)")
    synth.add_argument("--split", default="train", choices=["train", "test"])
    synth.add_argument("--num", type=int, default=100, help="samples in the split (default 100)")
    synth.add_argument("--workers", type=int, default=1, help="parallel worker processes (default 1)")
    synth.add_argument("--preview", action="store_true", help="also write OUT/preview_SPLIT.png, a contact sheet")
    synth.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def _synth(args) -> int:
    from pathlib import Path

    from ._config import load_config
    from ._generate import synthesise, write_contact_sheet

    config = load_config(args.config)
    report = synthesise(config.data, args.out, split=args.split, num=args.num, workers=args.workers,
                        config_name=config.name, progress=not args.quiet)  # fmt: skip
    print(f"{report.folder}: {report.written} written, {report.already_done} already there"
          + (f", {report.partial_removed} half-written removed" if report.partial_removed else ""))  # fmt: skip
    if args.preview:
        path = write_contact_sheet(report.folder, Path(args.out) / f"preview_{args.split}.png")
        print(f"preview: {path}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from .synth import ConfigError

    try:
        return {"synth": _synth}[args.command](args)
    except ConfigError as error:
        print(f"learnstitch: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
