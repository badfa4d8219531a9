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


def comparable(sizes: np.ndarray, direction: str, hugin_out: np.ndarray) -> np.ndarray:
    """Where Hugin's answer can be compared: ``pano_trafo`` printed a point (not nan, not its
    ``-1 -1``), and, panorama -> image, the point lies within ten frame sizes of the image: rays
    grazing a rectilinear lens's 90 degrees land ~1e9 px away, where tan(theta) makes any absolute
    tolerance meaningless. ``sizes`` is ``(n, 2)``, each point's image width and height."""
    defined = np.all(np.isfinite(hugin_out), axis=1) & ~np.all(hugin_out == -1.0, axis=1)
    if direction == "r":
        defined &= np.all(np.abs(np.nan_to_num(hugin_out) - sizes / 2) <= 10 * sizes, axis=1)
    return defined
