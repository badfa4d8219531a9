"""The .pto reader and writer under a hundred thousand seeded mutations of the golden projects.

    python benchmarks/pto_fuzz.py [--inputs 100000]

Each input is one of the golden projects (`tests/rigjax/data/golden*/`) with one to three random
edits (`rigjax.pto.fuzz.mutate`: extreme numbers, tokens and lines deleted, duplicated or moved,
links pointed anywhere, stray characters, the file cut short). Every input must load or be
refused with a PtoError naming the file; a loaded one must save and reload to the same values,
and save unedited to its own text (`rigjax.pto.fuzz.check`). The suite runs the first 2,000.
"""

from __future__ import annotations

import argparse
import collections
import re
import sys
from pathlib import Path

from _record import recorded

from rigjax.pto import fuzz

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--inputs", type=int, default=100_000)
    args = parser.parse_args()
    texts = [p.read_bytes().decode() for p in sorted((ROOT / "tests" / "rigjax" / "data").glob("golden*/*.pto"))]
    outcomes, failures, reasons = collections.Counter(), collections.Counter(), collections.Counter()
    example: dict[str, int] = {}
    slowest = (0.0, 0, 0)  # seconds per KB, seed, bytes
    for seed in range(args.inputs):
        if seed % 10_000 == 0:
            print(f"{seed} / {args.inputs}", file=sys.stderr)
        text = fuzz.mutate(texts[seed % len(texts)], seed)
        try:
            outcome = fuzz.check(text)
        except fuzz.FuzzFailure as failure:
            failures[str(failure)[:100]] += 1
            example.setdefault(str(failure)[:100], seed)
            continue
        outcomes[outcome.status] += 1
        per_kb = outcome.seconds / max(len(text) / 1024, 1.0)
        slowest = max(slowest, (per_kb, seed, len(text)))
        if outcome.status == "refused":  # the kind of refusal, without file, line and token
            reasons[re.sub(r"'[^']*'|\d+", "_", outcome.message.split(": ", 2)[-1])[:60]] += 1

    print(f"\n{args.inputs:,} mutated projects from {len(texts)} golden ones:\n")
    print("| outcome | inputs |")
    print("|---|---:|")
    for status in ("loaded", "refused"):
        print(f"| {status} (properties held) | {outcomes[status]:,} |")
    print(f"| a property broke | {sum(failures.values()):,} |")
    for reason, count in failures.most_common():
        print(f"\n- {count} × {reason} (first at seed {example[reason]})")
    print(
        f"\nSlowest read: {slowest[0] * 1e3:.2f} ms per KB (seed {slowest[1]}, {slowest[2]:,} bytes; inputs under "
        "1 KB counted as 1 KB).\n"
    )
    print("The most common refusals (numbers and quoted tokens shown as _):\n")
    print("| refusal | inputs |")
    print("|---|---:|")
    for reason, count in reasons.most_common(10):
        print(f"| {reason} | {count:,} |")


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main()
