"""Reading .pto projects of 1 KB to 10 MB: time per MB for four shapes of file.

    python benchmarks/pto_parse_speed.py [--largest-mb 10] [--repeats 3]

`rigjax.parse_project` on generated text (no disk): many images (one `i` line each), long lines
(an `i` line with thousands of unknown tokens, kept verbatim), a long link chain (every image's
`v` linked to the one before), and many control points (100,000 `c` lines make 4.6 MB). The time
is the median of `--repeats` reads; a reader linear in the file's size keeps the seconds per MB
flat down each column.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

from _record import recorded

import rigjax

HEAD = "p f2 w4000 h2000 v360\n"
IMAGE = 'i w4000 h3000 f3 v165.25 Ra0 Rb0 Rc0 Rd0 Re0 Eev0 Er1 Eb1 r0.5 p-1.25 y{y} TrX0 TrY0 TrZ0 Tpy0 Tpp0 j0 a0 b-0.02 c0 d0 e0 g0 t0 n"img{k}.jpg"\n'


def _filled(size: int, head: str, line) -> str:
    """``head`` and ``line(1)``, ``line(2)`` ... up to ``size`` characters (lines grow with their number)."""
    parts, total, k = [head], len(head), 1
    while total < size or k == 1:
        parts.append(line(k))
        total += len(parts[-1])
        k += 1
    return "".join(parts)


def many_images(size: int) -> str:
    return _filled(size, HEAD, lambda k: IMAGE.format(y=k % 360, k=k))


def long_lines(size: int) -> str:
    lines = max(1, size // 100_000)
    tokens = " ".join(f"Xq{k}" for k in range(max(1, (size // lines) // 8)))
    return HEAD + "".join(IMAGE.format(y=k, k=k).replace(' n"', f' {tokens} n"') for k in range(lines))


def link_chain(size: int) -> str:
    return _filled(size, HEAD + IMAGE.format(y=0, k=0), lambda k: f"i w4000 h3000 f3 v={k - 1} y{k % 360}\n")


def control_points(size: int) -> str:
    line = "c n0 N1 x1234.5 y567.25 X2345.75 Y678.5 t0\n"
    return HEAD + IMAGE.format(y=0, k=0) + IMAGE.format(y=90, k=1) + line * max(1, size // len(line))


SHAPES = {
    "many images": many_images,
    "long lines": long_lines,
    "link chain": link_chain,
    "control points": control_points,
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--largest-mb", type=float, default=10.0)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    sizes = [s for s in (1_000, 10_000, 100_000, 1_000_000, 10_000_000) if s <= args.largest_mb * 1e6]
    rows = []
    for size in sizes:
        row = []
        for name, make in SHAPES.items():
            text = make(size)
            times = []
            for _ in range(args.repeats):
                started = time.perf_counter()
                rigjax.parse_project(text)
                times.append(time.perf_counter() - started)
            seconds = statistics.median(times)
            print(f"{name} {len(text):,} bytes: {seconds:.4f} s", file=sys.stderr)
            row.append((len(text), seconds))
        rows.append((size, row))
    print("\nMedian read time, and seconds per MB of the file (in brackets):\n")
    print("| size | " + " | ".join(SHAPES) + " |")
    print("|---|" + "---:|" * len(SHAPES))
    for size, row in rows:
        cells = " | ".join(f"{s * 1e3:.1f} ms ({s / (n / 1e6):.2f} s/MB)" for n, s in row)
        print(f"| {size / 1e6:g} MB | {cells} |")
    one_mb = [s for size, row in rows if size == 1_000_000 for _, s in row]
    if one_mb:
        print(f"\nThe slowest 1 MB file: {max(one_mb):.2f} s.")


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main()
