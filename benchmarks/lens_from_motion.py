#!/usr/bin/env python3
"""Benchmark: a dual-fisheye camera's lenses calibrated from its own motion (``rigjax calibrate --motion``).

Synthetic clips of a hand-held dual-fisheye camera turning on the spot (``learnstitch.data.sequence``,
``Motion(speed=0)``): learnstitch's street scenes (buildings 5-40 m, a near object 0.5-3 m from the
camera in each seam) ray cast into two circular fisheyes back to back, 1440x1440 each, side by side,
the lenses' centres 2-3 cm apart along their axis. Per clip, drawn from its seed: each lens its own
hfov (uniform 188-196 degrees; the image circle 190 degrees across), Hugin's ``a``, ``b``, ``c`` about
those of a real consumer camera's lenses (-0.28, 0.52, -0.14, each within ±0.04), its optical centre
0-30 px off the image centre (``d``, ``e``), each lens's mounting within 2 degrees of back to back, the
vignetting ``1 + Vb r^2`` with ``Vb`` in -1.0..-0.3 (about -1 stop at the rim at -1.0), camera 1's
exposure within 0.5 EV of camera 0's; 8-bit with noise. Five frames one second apart of a camera
turning 8 degrees a second, wobbling up to 3 degrees in pitch and roll: at least 30 degrees of turn.

Calibrations of each clip:

* ``motion 5``, ``motion 3``: ``configs/rig/dual_fisheye.yaml`` with ``--motion`` (each lens's hfov, a,
  b, c, d, e from the frames: ``rigjax.calibration.motion``) on the first 5 or 3 frames; the spread is
  how far lens 1's mounting, as each frame's own matches pull it, strays from its mean
  (``motion.max_spread_deg`` refuses above 0.1 degrees);
* ``ring 5``: the same template without ``--motion`` on the 5 frames (the ring's matches pooled: the
  template's nominal lens, centred, its hfov with a prior of 1 degree);
* ``hugin``: Hugin's recipe for these cameras on the same 5 frames' 10 halves: ``cpfind --multirow``,
  ``autooptimiser -p`` (positions), then ``autooptimiser -n`` of every image's yaw, pitch and roll and
  each lens's v, a, b, c, d, e (images of one lens linked), from the template's lens.

Each is judged through its rays, not its parameters (``rigjax.synthetic.ray_angles_deg``): a 48 x 48
grid of each lens's pixels whose true ray lies within the lens's field (190 degrees) less 2 degrees;
the angle between the calibrated and the true ray after the one rotation of both lenses together that
fits them best. ``ends``: what ``rigjax calibrate`` would end with (``ok``: written, exit 0;
``refused``: exit 3, nothing written; ``failed``: exit 1). The last table: the share of clips whose
rays are within 0.15 degrees (p95; about one pixel at 1440 px), and the written calibrations more
than 1 degree off.

The motion calibrations fit the photometry over every frame's images (the template's
``photometry``; each lens's vignetting linked across the frames): ``V(r) error``, each lens's largest
``|V(r) - V_true(r)|`` over its pixels within 95 % of the frame's half width (``held`` where the fit
could not tell it); ``exposure error``, the largest error of any frame's image's exposure relative to
frame 0's lens 0 (EV). The last table counts the clips within 0.02 (both lenses) and 0.05 EV.

    python benchmarks/lens_from_motion.py [--clips 16] [--no-hugin] [--no-ring] [--only "motion 5"]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np
from _record import recorded

import rigjax
from learnstitch.data.sequence import Motion, draw_sequence
from rigjax.calibration.motion import MotionConfig, frames_project
from rigjax.camera.photometry import vignetting

TEMPLATE = "configs/rig/dual_fisheye.yaml"
SIZE = 1440
FRAMES = 5
CIRCLE_DEG = 190.0
MOTION = Motion(speed=0.0, yaw_rate=8.0, wobble_deg=3.0, fps=1.0, duration=FRAMES - 1.0)
REAL_ABC = (-0.28, 0.52, -0.14)  # a Hugin calibration of a consumer dual-fisheye camera's lens


def draw_clip(seed: int):
    """The clip of ``seed``: its truth (a :class:`~learnstitch.data.sequence.SequenceTruth` whose
    lenses are drawn as the module docstring says) and its side-by-side frames."""
    truth = draw_sequence("dual", seed, SIZE, MOTION)
    rng = np.random.default_rng([seed, 0x4E5])
    radius, angle = 30.0 * np.sqrt(rng.uniform(0.0, 1.0, 2)), rng.uniform(0.0, 2.0 * math.pi, 2)
    lens = dict(
        hfov=rng.uniform(188.0, 196.0, 2),
        a=REAL_ABC[0] + rng.uniform(-0.04, 0.04, 2),
        b=REAL_ABC[1] + rng.uniform(-0.04, 0.04, 2),
        c=REAL_ABC[2] + rng.uniform(-0.04, 0.04, 2),
        d=radius * np.cos(angle),
        e=radius * np.sin(angle),
    )
    sensor = dataclasses.replace(
        truth.sensor, cameras=truth.sensor.cameras._replace(**lens), vignetting_b=float(rng.uniform(-1.0, -0.3))
    )
    truth = dataclasses.replace(truth, sensor=sensor, cameras=truth.cameras._replace(**lens), circle_deg=CIRCLE_DEG)
    frames = [frame.side_by_side for frame in truth.frames(FRAMES, pano_width=16)]
    return truth, frames


def calibrate(frames, config, names):
    """``(project or None, what rigjax calibrate would end with, seconds, lens 1's mounting spread,
    the photometric fit or None)``."""
    started = time.perf_counter()
    try:
        calibration = rigjax.calibrate(frames, config, names=names)
    except rigjax.CalibrationError as error:
        return None, f"failed: {str(error)[:70]}", time.perf_counter() - started, math.nan, None
    seconds = time.perf_counter() - started
    spread = math.nan if calibration.mounting_spread_deg is None else float(calibration.mounting_spread_deg[1])
    ends = "ok" if calibration.result.ok else "not converged"
    if calibration.undetermined:
        ends = f"refused: {calibration.undetermined[0][:70]}"
    return calibration.project, ends, seconds, spread, calibration.exposure


def photometry_errors(fit, truth) -> tuple[list[float], float]:
    """Each lens's largest ``|V(r) - V_true(r)|`` over the pixels within 95 % of the frame's half width
    (inside the image circle), NaN where the fit held it; and the largest error of any frame's image's
    exposure relative to frame 0's lens 0, EV."""
    y, x = np.mgrid[0:SIZE:24, 0:SIZE:24].astype(float)
    inside = np.hypot(x - (SIZE - 1) / 2, y - (SIZE - 1) / 2) < 0.95 * SIZE / 2
    xy = np.stack([x[inside], y[inside]], -1)
    lens = truth.sensor
    errors = []
    for k in range(2):
        image = fit.project.images[k]
        true_v = vignetting(image.replace(vignetting_b=lens.vignetting_b, vignetting_c=0.0, vignetting_d=0.0), xy)
        held = math.isnan(fit.vignetting_sd[k])
        errors.append(math.nan if held else float(np.abs(vignetting(image, xy) - true_v).max()))
    fitted = np.array([image.exposure_value for image in fit.project.images])
    true = np.array([lens.exposure_value[k % 2] for k in range(len(fitted))])
    return errors, float(np.abs((fitted - fitted[0]) - (true - true[0])).max())


def hugin(halves, nominal: rigjax.Project, folder: Path):
    """Hugin's recipe (module docstring) on the frames' halves: ``(project or None, what it ended with)``."""
    frames = len(halves) // 2
    names = [[f"f{f}-{k}.png" for k in range(2)] for f in range(frames)]
    for f in range(frames):
        for k in range(2):
            rigjax.write_image(folder / names[f][k], halves[2 * f + k])
    project = frames_project(nominal, np.tile(np.eye(3), (frames, 1, 1)), names)
    project.save(folder / "start.pto")
    run = dict(capture_output=True, cwd=folder)
    found = subprocess.run(["cpfind", "--multirow", "-o", "cp.pto", "start.pto"], **run)
    if found.returncode != 0 or not (folder / "cp.pto").exists():
        return None, "failed: cpfind"
    points = rigjax.load_project(folder / "cp.pto").control_points
    between = int(np.sum(points.image_a % 2 != points.image_b % 2))
    if between < 3:
        return None, f"failed: cpfind found {between} points between the lenses ({len(points)} in all)"
    if subprocess.run(["autooptimiser", "-p", "-o", "positions.pto", "cp.pto"], **run).returncode != 0:
        return None, "failed: autooptimiser -p"
    positions = rigjax.load_project(folder / "positions.pto")
    variables = [rigjax.OptVariable(x, k) for k in range(1, len(positions.images)) for x in "ypr"]
    variables += [rigjax.OptVariable(x, k) for k in range(2) for x in "vabcde"]
    positions.replace(variables=tuple(variables)).save(folder / "lens.pto")
    if subprocess.run(["autooptimiser", "-n", "-o", "opt.pto", "lens.pto"], **run).returncode != 0:
        return None, "failed: autooptimiser -n"
    solved = rigjax.load_project(folder / "opt.pto")
    rig = rigjax.Project.new(solved.panorama, solved.images[:2])
    return rig, f"ok ({len(points)} points, {between} between the lenses)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clips", type=int, default=16)
    parser.add_argument("--no-hugin", action="store_true", help="skip Hugin's cpfind + autooptimiser")
    parser.add_argument("--no-ring", action="store_true", help="skip the ring-only calibration")
    parser.add_argument("--only", nargs="+", choices=["motion 5", "motion 3"], help="only these motion calibrations")
    args = parser.parse_args()
    use_hugin = not args.no_hugin and shutil.which("cpfind") is not None and shutil.which("autooptimiser") is not None
    ring = rigjax.load_template(TEMPLATE)
    motion = dataclasses.replace(ring, motion=MotionConfig())  # the template's photometry: fitted over the frames
    ring = dataclasses.replace(ring, photometry=dataclasses.replace(ring.photometry, fit=False))
    runs = {"motion 5": (motion, 5), "motion 3": (motion, 3)}
    if args.only:
        runs = {run: runs[run] for run in args.only}
    if not args.no_ring:
        runs["ring 5"] = (ring, 5)
    print(
        "| clip | calibration | ends | ray error p95 / max deg | hfov error deg (lens 0, 1) | "
        "centre error px (lens 0, 1) | lens 1's mounting spread deg | V(r) error (lens 0, 1) | "
        "exposure error EV | seconds |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for seed in range(args.clips):
        truth, frames = draw_clip(seed)
        names = [f"c{seed}f{f}.png" for f in range(FRAMES)]
        results = {}
        for run, (config, count) in runs.items():
            print(f"clip {seed}: {run}", file=sys.stderr, flush=True)
            results[run] = calibrate(frames[:count], config, names[:count])
        # each clip compiles programs of its own sizes: let them go, or a long run reaches the kernel's
        # limit on memory mappings (vm.max_map_count) and dies in a compilation
        jax.clear_caches()
        if use_hugin:
            print(f"clip {seed}: hugin", file=sys.stderr, flush=True)
            halves = [half for frame, _ in rigjax.frames_of(frames, ring, names) for half in frame]
            nominal = rigjax.Project.new(
                rigjax.PanoramaLine(4096, 2048),
                [
                    rigjax.Image(width=SIZE, height=SIZE, projection=2, hfov=190.0, yaw=yaw, filename=f"{k}.png")
                    for k, yaw in enumerate((0.0, 180.0))
                ],
            )
            started = time.perf_counter()
            with tempfile.TemporaryDirectory() as folder:
                project, ends = hugin(halves, nominal, Path(folder))
            results["hugin"] = (project, ends, time.perf_counter() - started, math.nan, None)
        true_project = truth.project(("left.png", "right.png"))
        for run, (project, ends, seconds, spread, fit) in results.items():
            row = dict(clip=seed, run=run, ends=ends, written=ends.startswith(("ok", "not converged")))
            cells = ["-", "-", "-"]
            if project is not None:
                angles = np.concatenate(rigjax.synthetic.ray_angles_deg(project, true_project, field_deg=CIRCLE_DEG))
                row["p95"], row["max"] = float(np.percentile(angles, 95)), float(angles.max())
                hfov = [g.hfov - w.hfov for g, w in zip(project.images, true_project.images)]
                centre = [math.hypot(g.d - w.d, g.e - w.e) for g, w in zip(project.images, true_project.images)]
                cells = [
                    f"{row['p95']:.3f} / {row['max']:.3f}",
                    f"{hfov[0]:+.2f}, {hfov[1]:+.2f}",
                    f"{centre[0]:.1f}, {centre[1]:.1f}",
                ]
            cells += ["-" if math.isnan(spread) else f"{spread:.3f}", "-", "-"]
            if fit is not None:
                row["vignetting"], row["exposure"] = photometry_errors(fit, truth)
                cells[-2] = ", ".join("held" if math.isnan(v) else f"{v:.3f}" for v in row["vignetting"])
                cells[-1] = f"{row['exposure']:.3f}"
            print(f"| {seed} | {run} | {ends} | {' | '.join(cells)} | {seconds:.0f} |", flush=True)
            rows.append(row)
    print()
    print(
        "| calibration | clips | written | rays within 0.15 deg (p95) | written and more than 1 deg off (p95) | "
        "V(r) within 0.02 (both lenses) | every image's exposure within 0.05 EV |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|")
    for run in list(runs) + (["hugin"] if use_hugin else []):
        mine = [r for r in rows if r["run"] == run]
        written = [r for r in mine if r["written"]]
        within = [r for r in written if r.get("p95", math.inf) < 0.15]
        off = [r for r in written if r.get("p95", math.inf) > 1.0]
        fitted = [r for r in mine if "exposure" in r]
        vig = sum(all(v <= 0.02 for v in r["vignetting"]) for r in fitted)  # a held lens (NaN) is not within
        ev = sum(r["exposure"] <= 0.05 for r in fitted)
        photometry = f"{vig} of {len(fitted)} | {ev} of {len(fitted)}" if fitted else "- | -"
        print(
            f"| {run} | {len(mine)} | {len(written)} | {len(within)} ({100 * len(within) / len(mine):.0f} %) | "
            f"{len(off)} | {photometry} |"
        )


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main()
