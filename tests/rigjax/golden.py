"""Reading the pano_trafo golden data recorded by tests/rigjax/data/make_golden.py."""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

GOLDEN = Path(__file__).parent / "data" / "golden"
PROJECTS = sorted(p.stem for p in GOLDEN.glob("*.pto"))


class Golden(NamedTuple):
    image: np.ndarray  # (n,) image number
    xy_in: np.ndarray  # (n, 2)
    xy_out: np.ndarray  # (n, 2) as printed by pano_trafo (may be nan or huge where undefined)


def load_golden(name: str) -> dict[str, Golden]:
    """``{"f": forward (image -> panorama), "r": reverse}`` for one golden project."""
    rows = [line.split() for line in (GOLDEN / f"{name}.txt").read_text().splitlines() if not line.startswith("#")]
    out = {}
    for direction in "fr":
        sel = [r for r in rows if r[0] == direction]
        data = np.array([[float(v) for v in r[1:]] for r in sel])
        out[direction] = Golden(data[:, 0].astype(int), data[:, 1:3], data[:, 3:5])
    return out
