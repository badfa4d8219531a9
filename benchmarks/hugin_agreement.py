"""rigjax's transforms against Hugin's pano_trafo on the recorded golden data.

``tests/rigjax/data/golden/`` holds small projects covering every lens type, non-zero ``a, b, c,
d, e``, portrait and landscape images, large and gimbal-locked angles, a linked 6-camera rig,
partial and odd-sized canvases and a lens whose distortion turns back inside the frame, with 40
forward and 40 reverse points per image recorded from Hugin's ``pano_trafo`` (``make golden``).
``tests/rigjax/test_golden_hugin.py`` checks every comparable point to 0.01 px on every test run,
and again live on fresh points when ``pano_trafo`` is installed; this prints how close they are.

    python benchmarks/hugin_agreement.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np
from _record import recorded

import rigjax

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "rigjax"))
from golden import GOLDEN, PROJECTS, comparable, load_golden  # the tests' reader and comparison rule


def main() -> None:
    rows = {"f": [0, 0.0], "r": [0, 0.0]}  # points compared, largest difference (px)
    for name in PROJECTS:
        project = rigjax.load_project(GOLDEN / f"{name}.pto")
        for direction, golden in load_golden(name).items():
            out, valid = rigjax.transform_points(
                project.cameras(), project.canvas(), golden.image, golden.xy_in, reverse=direction == "r"
            )
            sizes = np.array([[project.images[k].width, project.images[k].height] for k in golden.image])
            both = np.asarray(valid) & comparable(sizes, direction, golden.xy_out)
            err = np.abs(np.asarray(out) - golden.xy_out).max(axis=1)
            rows[direction][0] += int(both.sum())
            rows[direction][1] = max(rows[direction][1], float(err[both].max()))
    print(f"{len(PROJECTS)} projects; float64, jax {jax.__version__}\n")
    print("| direction | points both define | largest difference to Hugin |")
    print("|---|---|---|")
    for direction, label in (("f", "image → panorama"), ("r", "panorama → image")):
        print(f"| {label} | {rows[direction][0]} | {rows[direction][1]:.1e} px |")
    print(
        "\nlibpano13 stops its Newton solve of the distortion at 1e-6 of the normalised radius; rigjax "
        "solves it to machine precision. pano_trafo prints six decimals."
    )


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main()
