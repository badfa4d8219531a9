#!/usr/bin/env python3
"""Record Hugin's optimum: ``autooptimiser -n`` on seeded synthetic rigs (``make golden``).

For each case below, writes ``golden_optimiser/NAME.start.pto`` (the start: synthetic control
points, perturbed cameras and the ``v`` lines to optimise) and ``golden_optimiser/NAME.hugin.pto``
(what ``autooptimiser -n`` wrote). ``tests/rigjax/test_hugin_objective.py`` checks that
``rigjax.optimise(start, rigjax.OptimiseConfig(pto_vars=True, objective="hugin"))`` lands on the recorded optimum, and
re-runs ``autooptimiser`` when it is installed. Needs rigjax (the project's virtual environment)
and Hugin's command-line tools (``apt-get install hugin-tools``).
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import rigjax
from rigjax import synthetic

HERE = Path(__file__).parent / "golden_optimiser"


def _rig(
    seed: int, hfov_start: float, links: bool = False, b_start: float = 0.0, lines: bool = False
) -> rigjax.Project:
    """The issue's 6-camera rig (1440x1080 full-frame fisheyes, hfov 123, K2 -0.01, 0.5 px noise),
    started 1-4 degrees off with every hfov at ``hfov_start`` and K2 at ``b_start``; ``lines``
    adds four straight vertical lines (t3-t6) and two of t1 vertical-line points."""
    truth = synthetic.cube_rig(hfov=123.0, b=-0.01, orientation_jitter_deg=3.0, seed=seed)
    truth = synthetic.control_points_from_truth(truth, 1500, noise_px=0.5, seed=seed + 100)
    if lines:
        truth = synthetic.vertical_lines_from_truth(truth, 4, 6, noise_px=0.5, seed=seed + 300)
        truth = synthetic.vertical_lines_from_truth(truth, 2, 4, kind=1, noise_px=0.5, seed=seed + 400)
    start = synthetic.perturb(truth, angle_deg=(1.0, 4.0), hfov_offset_deg=(0.0, 0.0), b=b_start, seed=seed + 200)
    images = tuple(
        image.replace(hfov=hfov_start, links={k: 0 for k in "vabc"} if (links and i) else {})
        for i, image in enumerate(start.images)
    )
    return start.replace(images=images)


def _variables(project: rigjax.Project, lens: str, per_image: bool) -> tuple[rigjax.OptVariable, ...]:
    n = len(project.images)
    orientation = [rigjax.OptVariable(letter, k) for k in range(1, n) for letter in "ypr"]
    lens_images = range(n) if per_image else [0]
    return tuple(orientation + [rigjax.OptVariable(letter, k) for k in lens_images for letter in lens])


def cases() -> dict[str, rigjax.Project]:
    # Every lens its own v and b, started wide of the truth: the mean hfov shrinks towards the
    # optimum, so libpano13's FOV stabilisation is active.
    per_lens = _rig(31, hfov_start=127.0)
    # One lens linked across the rig (v, a, b, c listed on image 0), started narrow.
    linked = _rig(32, hfov_start=120.0, links=True)
    # Straight vertical lines (t3, t4, ...) and t1 vertical-line points level the rig (the true
    # lens, orientations only): the anchor's pitch and roll are free and start 2 degrees off.
    lines = _rig(33, hfov_start=123.0, b_start=-0.01, lines=True)
    anchor = lines.images[0].replace(pitch=lines.images[0].pitch + 2.0, roll=lines.images[0].roll - 2.0)
    levelled = (rigjax.OptVariable("p", 0), rigjax.OptVariable("r", 0)) + _variables(lines, "", per_image=True)
    return {
        "per_lens_vb": per_lens.replace(variables=_variables(per_lens, "vb", per_image=True)),
        "linked_vabc": linked.replace(variables=_variables(linked, "vabc", per_image=False)),
        "lines_t1_t3": lines.replace(images=(anchor,) + lines.images[1:], variables=levelled),
    }


def main() -> None:
    HERE.mkdir(exist_ok=True)
    for name, project in cases().items():
        start, out = HERE / f"{name}.start.pto", HERE / f"{name}.hugin.pto"
        project.save(start)
        subprocess.run(["autooptimiser", "-n", "-o", str(out), str(start)], check=True, capture_output=True)
        print(f"wrote {start.name} and {out.name}")


if __name__ == "__main__":
    main()
