"""Bundle adjustment (the reprojection objective) against the rotation-only transfer objective:
accuracy where there is no parallax, accuracy where there is, and warm solve time.

    python benchmarks/bundle_adjustment.py [--draws 20]

*Accuracy without parallax*: rigs whose cameras share one centre (the 6-camera ring of the test
suite, 123-degree rectilinear cameras; three 185-degree fisheyes 120 degrees apart), control points
of random directions with 0.5 px Gaussian noise, started from orientations 0.5-2 degrees and an
hfov 1-2 degrees off (``rigjax.synthetic.perturb``), schedule ``YPR,VBYPR``. Each draw has its
own points, noise and start. Both objectives solve every draw; the reprojection objective is given
centres at the origin. The ray error is ``rigjax.synthetic.ray_errors_arcmin`` (the largest angle
over a raster of each image, after the best rotation of the whole rig), averaged over the images.

*Accuracy with parallax*: the fisheye rig with its cameras 0.4 m out along their axes (learnstitch's
``d = 0.4``), scene points 1-50 m from the centre (log-uniform), 0.5 px noise; the reprojection
objective is given the true centres. Schedules ``YPR,VYPR`` (hfov estimated) and ``YPR,VBYPR``
(hfov and K2).

*Time*: the parallax rig, ``YPR,VBYPR``, with about 1k, 4k and 16k control points: the second of
two runs of ``bundle_adjust`` and of ``optimise`` on the same project in one process (compilation
excluded), median of 3.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import jax
import numpy as np
from _record import recorded

jax.config.update("jax_enable_x64", True)

from rigjax import bundle_adjust, optimise, synthetic  # noqa: E402


def fisheye_rig(distance: float):
    truth = synthetic.ring_rig(3, width=512, height=512, projection=3, hfov=185.0, b=0.0)
    return truth, synthetic.centres_on_axes(truth, distance)


def _errors(project, truth) -> float:
    return float(np.mean(synthetic.ray_errors_arcmin(project, truth)))


def accuracy(name: str, truth, centres, make_points, draws: int, schedule: str = "YPR,VBYPR") -> list[str]:
    errors = {"transfer": [], "reprojection": []}
    failed = {"transfer": 0, "reprojection": 0}
    points = []
    for draw in range(draws):
        project = make_points(draw)
        points.append(len(project.control_points))
        start = synthetic.perturb(project, angle_deg=(0.5, 2.0), hfov_offset_deg=(1.0, 2.0), b=0.0, seed=1000 + draw)
        results = {
            "transfer": optimise(start, schedule),
            "reprojection": bundle_adjust(start, centres, schedule),
        }
        for objective, result in results.items():
            errors[objective].append(_errors(result.project, truth))
            failed[objective] += not result.ok
        print(f"{name} draw {draw}: " + ", ".join(f"{k} {v[-1]:.3f}'" for k, v in errors.items()), file=sys.stderr)
    t, r = np.mean(errors["transfer"]), np.mean(errors["reprojection"])
    return [
        f"| {name} | `{schedule}` | {draws} | {int(np.median(points))} | {t:.3f} | {r:.3f} | {r / t:.2f} | "
        f"{failed['transfer']} / {failed['reprojection']} |"
    ]


def timing(targets: tuple[int, ...], repeats: int) -> list[str]:
    truth, centres = fisheye_rig(0.4)
    rows = []
    trial, _ = synthetic.control_points_from_scene(truth, centres, synthetic.scene_points(2000, seed=0))
    per_point = len(trial.control_points) / 2000  # control points per scene point on this rig
    for target in targets:
        points = synthetic.scene_points(round(target / per_point), seed=target)
        project, _ = synthetic.control_points_from_scene(truth, centres, points, noise_px=0.5, seed=target)
        start = synthetic.perturb(project, angle_deg=(0.5, 2.0), hfov_offset_deg=(1.0, 2.0), b=0.0, seed=target)
        seconds, steps = {}, {}
        for objective, run in (
            ("transfer", lambda: optimise(start, "YPR,VBYPR")),
            ("reprojection", lambda: bundle_adjust(start, centres, "YPR,VBYPR")),
        ):
            run()  # compiles
            times = []
            for _ in range(repeats):
                begin = time.perf_counter()
                result = run()
                times.append(time.perf_counter() - begin)
            seconds[objective] = statistics.median(times)
            steps[objective] = sum(stage.steps for stage in result.stages)
            print(f"{len(project.control_points)} points, {objective}: {seconds[objective]:.3f} s", file=sys.stderr)
        n = len(project.control_points)
        rows.append(
            f"| {n} | {seconds['transfer']:.3f} ({steps['transfer']}) | {seconds['reprojection']:.3f} "
            f"({steps['reprojection']}) | {seconds['reprojection'] / seconds['transfer']:.2f} | "
            f"{1e6 * seconds['reprojection'] / steps['reprojection'] / n:.2f} |"
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--draws", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()

    ring = synthetic.ring_rig(6, b=-0.01)
    fisheye, _ = fisheye_rig(0.0)
    parallax, centres = fisheye_rig(0.4)

    def rotation_only(truth, directions):
        return lambda draw: synthetic.control_points_from_truth(truth, directions, noise_px=0.5, seed=draw)

    def with_parallax(draw):
        points = synthetic.scene_points(600, seed=draw)
        return synthetic.control_points_from_scene(parallax, centres, points, noise_px=0.5, seed=draw)[0]

    rows = [
        "Ray error (arcmin; mean over draws of the mean over images of the largest error over each image's raster).",
        "",
        "| rig | schedule | draws | control points (median) | transfer | reprojection | ratio | not converged (transfer / reprojection) |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    rows += accuracy("6-camera ring, one centre", ring, np.zeros((6, 3)), rotation_only(ring, 600), args.draws)
    rows += accuracy(
        "3 x 185° fisheyes, one centre", fisheye, np.zeros((3, 3)), rotation_only(fisheye, 600), args.draws
    )
    for schedule in ("YPR,VYPR", "YPR,VBYPR"):
        rows += accuracy("3 x 185° fisheyes, centres 0.4 m out", parallax, centres, with_parallax, args.draws, schedule)
    rows += [
        "",
        "Warm time of a whole `YPR,VBYPR` run (s, median of "
        f"{args.repeats}; LM steps of both stages in brackets) on the parallax rig, and the reprojection "
        "objective's time per step and control point (µs).",
        "",
        "| control points | transfer | reprojection | ratio | µs per step and point |",
        "|---:|---:|---:|---:|---:|",
    ]
    rows += timing((1000, 4000, 16000), args.repeats)
    print("\n".join(rows))


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main()
