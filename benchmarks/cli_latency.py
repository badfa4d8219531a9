"""Whole-process time of the command lines, against Hugin's tools on the same projects.

    python benchmarks/cli_latency.py [--repeats 5]

Each row is one command run as a user runs it, start-up, imports, tracing, compilation and I/O
included: the median of ``--repeats`` runs. rigjax runs twice over: each run of the *empty cache*
column with a fresh, empty compilation cache (``RIGJAX_CACHE_DIR``), as a user's first run; the
*warm cache* column after one run has filled it, as every later run. Hugin's ``pano_trafo`` and
``autooptimiser`` (``apt-get install hugin-tools``) run on the same project and input. The
projects are the test suite's: ``cube_rig_linked.pto`` (six cameras) for ``trafo`` with one
point, ``linked_vabc.start.pto`` (six cameras, 977 control points) for ``optimise``, with the
defaults (``YPR,VBYPR``, pruning) and with ``configs/rig/hugin.yaml`` (the project's ``v`` lines
on Hugin's objective, as ``autooptimiser -n``).
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
DATA = ROOT / "tests" / "rigjax" / "data"
BIN = Path(sys.executable).parent


def _cases(out: Path) -> list[tuple[str, list[str], list[str] | None, str]]:
    """``(what, rigjax command, Hugin command or None, standard input)``."""
    trafo = str(DATA / "golden" / "cube_rig_linked.pto")
    start = str(DATA / "golden_optimiser" / "linked_vabc.start.pto")
    hugin_config = str(ROOT / "configs" / "rig" / "hugin.yaml")
    return [
        ("rigjax --help", [str(BIN / "rigjax"), "--help"], None, ""),
        ("learnstitch --help", [str(BIN / "learnstitch"), "--help"], None, ""),
        ("trafo, one point", [str(BIN / "rigjax"), "trafo", trafo, "0"], ["pano_trafo", trafo, "0"], "100 200\n"),
        (
            "optimise, defaults (YPR,VBYPR, pruning)",
            [str(BIN / "rigjax"), "optimise", start, "-o", str(out / "rigjax.pto")],
            ["autooptimiser", "-n", "-o", str(out / "hugin.pto"), start],
            "",
        ),
        (
            "optimise, configs/rig/hugin.yaml (v lines)",
            [str(BIN / "rigjax"), "optimise", start, "-o", str(out / "rigjax.pto"), "--config", hugin_config],
            ["autooptimiser", "-n", "-o", str(out / "hugin.pto"), start],
            "",
        ),
    ]


def _seconds(command: list[str], stdin: str, cache: Path | None) -> float:
    env = dict(os.environ)
    if cache is not None:
        env["RIGJAX_CACHE_DIR"] = str(cache)
    started = time.perf_counter()
    done = subprocess.run(command, input=stdin, capture_output=True, text=True, env=env)
    seconds = time.perf_counter() - started
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(command)} exited {done.returncode}:\n{done.stderr}")
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    hugin = shutil.which("pano_trafo") is not None and shutil.which("autooptimiser") is not None
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for case, (what, command, hugin_command, stdin) in enumerate(_cases(tmp)):
            print(what, file=sys.stderr)
            # One folder per case and run: no run finds programs that another case compiled.
            cold = [_seconds(command, stdin, tmp / f"cold_{case}_{k}") for k in range(args.repeats)]
            warm_cache = tmp / f"warm_{case}"
            _seconds(command, stdin, warm_cache)
            warm = [_seconds(command, stdin, warm_cache) for _ in range(args.repeats)]
            theirs = (
                statistics.median(_seconds(hugin_command, stdin, None) for _ in range(args.repeats))
                if hugin and hugin_command
                else None
            )
            rows.append((what, statistics.median(cold), statistics.median(warm), hugin_command, theirs))
    print(f"\nMedian seconds of {args.repeats} whole-process runs each.\n")
    print("| command | rigjax, empty cache | rigjax, warm cache | Hugin | Hugin's time | rigjax warm / Hugin |")
    print("|---|---:|---:|---|---:|---:|")
    for what, cold, warm, hugin_command, theirs in rows:
        name = f"`{hugin_command[0]}`" if hugin_command else "-"
        if theirs is None:
            their_cell, ratio = ("not installed" if hugin_command else "-"), "-"
        else:
            their_cell, ratio = f"{theirs:.3f}", f"{warm / theirs:.0f}x"
        print(f"| {what} | {cold:.2f} | {warm:.2f} | {name} | {their_cell} | {ratio} |")


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main()
