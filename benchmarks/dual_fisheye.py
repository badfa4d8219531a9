#!/usr/bin/env python3
"""Benchmark: calibrating a dual-fisheye 360 camera from its own side-by-side frames, with parallax.

Synthetic frames of a consumer dual-fisheye camera (``learnstitch.data.dual``): learnstitch's street
scenes (buildings 5-40 m, near objects 0.5-3 m from the camera, one in each seam) ray cast into two
circular fisheyes back to back, 1440x1440 each, side by side. Per scene, drawn from its seed: one lens for both (hfov
uniform in 189-191, K2 -0.01 as the template's), each lens's yaw, pitch and roll within 2 degrees
of the design, the lenses' centres 2-3 cm apart along their axis (the template says 2.5), and
Hugin's photometric model applied to the scene's light: camera 1's exposure within 0.5 EV of
camera 0's, its white balance (Er, Eb) within 7 %, one vignetting polynomial for both lenses
(V(r) = 1 + Vb r^2, Vb in -0.5..-0.1), 8-bit with noise. A sequence is five frames of the camera
turning by 72 degrees a frame on the spot (different content in the seam each frame); a single
frame is its first, where the near objects stand in the seams.

Calibrations of each scene:

* ``far``: ``configs/rig/dual_fisheye_far.yaml`` (rotation-only, features in the seam band), frame 1;
* ``1 frame``, ``3 frames``, ``5 frames``: ``configs/rig/dual_fisheye.yaml`` (tracked seam band, bundle
  adjustment with the lenses' nominal centres and a robust loss, prior 1 degree on the hfov, two
  more passes of tracking through the calibrated bands) on the first 1, 3, 5 frames; several
  frames are each calibrated alone too and the pool checked against them
  (``rigjax.calibration.agreement``: "k frame(s) left out" where the pool of every frame was
  contradicted and the agreeing frames pooled instead);
* ``no prior``: that template without the hfov's prior, frame 1 (the kind of calibration that
  ended at a 274-degree lens): it must end refused (``rigjax calibrate`` status 3) or right;
* ``hugin``: Hugin's ``cpfind`` + ``autooptimiser -n`` (yaw, pitch, roll of camera 1 and the
  shared hfov) on frame 1's halves, with the template's lens, where cpfind finds points.

Per calibration: what ``rigjax calibrate`` would end with (``ok``: written, exit 0; ``refused``:
an undetermined parameter, exit 3; ``not converged``: written, exit 3; ``failed``: too few
consistent matches, exit 1), the error of
the lenses' relative orientation (degrees, the angle of the rotation between the calibrated and the
true ``R_0^T R_1``) and camera 1's reported turn standard deviation, the error through the rays
(95th percentile over a 48 x 48 raster of each lens within its field less 2 degrees, the rig's own
turn removed: ``rigjax.calibration.agreement.ray_angles_deg``), the hfov's error and reported standard deviation, the exposure difference's
error (EV) and the white balance's (%), the vignetting (fitted, or held as undetermined), and the
seam ring's disagreement: the median absolute difference of the two lenses' exposure-normalised
luminance (0-255) where both see a 2048x1024 panorama (``rigjax.seam_disagreement``), for the true
cameras, the calibration and the rotation-only template's calibration (its nominal cameras where it
fails). The true cameras disagree too: a near object in the seam is seen from two places, and a
rotation-only panorama cannot draw it once; a calibration's figure is judged by how close it comes
to theirs, not by how low it is (a rotation can trade the far content's alignment for the near
object's).

    python benchmarks/dual_fisheye.py [--scenes 16] [--no-hugin]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import re
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
from learnstitch.data.dual import draw_dual, render_dual_frames
from rigjax.calibration.agreement import ray_angles_deg
from rigjax.calibration.pipeline import frames_of

TEMPLATE = "configs/rig/dual_fisheye.yaml"
FAR_TEMPLATE = "configs/rig/dual_fisheye_far.yaml"
SIZE = 1440
FRAMES = 5
PANORAMA_WIDTH = 2048


def relative_error_deg(cameras: rigjax.Camera, truth: rigjax.Camera) -> float:
    def relative(c):
        r = np.asarray(rigjax.world_from_cam(np.asarray(c.yaw), np.asarray(c.pitch), np.asarray(c.roll)))
        return r[0].T @ r[1]

    m = relative(cameras) @ relative(truth).T
    return math.degrees(math.acos(np.clip((np.trace(m) - 1.0) / 2.0, -1.0, 1.0)))


def calibrate(frames: list[np.ndarray], config: rigjax.CalibrateConfig, names: list[str]):
    """``(calibration or None, what rigjax calibrate would end with)``."""
    try:
        calibration = rigjax.calibrate(frames, config, names=names)
    except rigjax.CalibrationError as error:
        agree = re.search(r"only (\d+) of their (\d+) matches agree", str(error))
        return None, f"failed: {agree[1]} of {agree[2]} matches agree" if agree else f"failed: {str(error)[:60]}"
    left_out = sum(line.startswith("note: left out:") for line in calibration.notes)
    frames = f", {left_out} frame(s) left out" if left_out else ""
    if calibration.undetermined:  # the first line's parameter and why, shortened
        what = calibration.undetermined[0]
        what = what.split(": ", 1)[1] if what.startswith("camera") else what
        return calibration, f"refused: {what.split(' (')[0]}{frames}"
    if not calibration.result.ok:  # written, but status 3
        return calibration, f"not converged: {calibration.result.stages[-1].status}{frames}"
    return calibration, f"ok{frames}"


def hugin(halves: list[np.ndarray], start: rigjax.Project, folder: Path):
    """cpfind + autooptimiser -n on the halves: ``(project or None, control points)``."""
    for k, half in enumerate(halves):
        rigjax.write_image(folder / f"half{k}.png", half)
    images = [im.replace(filename=f"half{k}.png") for k, im in enumerate(start.images)]
    variables = [rigjax.OptVariable(x, 1) for x in "ypr"] + [rigjax.OptVariable("v", 0)]
    rigjax.Project.new(start.panorama, images, None, variables).save(folder / "start.pto")
    found = subprocess.run(
        ["cpfind", "--multirow", "-o", str(folder / "cp.pto"), str(folder / "start.pto")],
        capture_output=True,
        cwd=folder,
    )
    if found.returncode != 0 or not (folder / "cp.pto").exists():
        return None, 0
    points = len(rigjax.load_project(folder / "cp.pto").control_points)
    if points < 3:
        return None, points
    optimised = subprocess.run(
        ["autooptimiser", "-n", "-o", str(folder / "opt.pto"), str(folder / "cp.pto")], capture_output=True, cwd=folder
    )
    if optimised.returncode != 0:
        return None, points
    return rigjax.load_project(folder / "opt.pto"), points


def fmt(value: float, spec: str) -> str:
    return "-" if value is None or not math.isfinite(value) else format(value, spec)


def sd(value: float | None) -> str:
    return f" ({value:.3f})" if value is not None and math.isfinite(value) else ""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=16)
    parser.add_argument("--no-hugin", action="store_true", help="skip Hugin's cpfind + autooptimiser")
    args = parser.parse_args()
    use_hugin = not args.no_hugin and shutil.which("cpfind") is not None and shutil.which("autooptimiser") is not None
    config = rigjax.load_template(TEMPLATE)
    no_prior = dataclasses.replace(
        config,
        optimise=dataclasses.replace(config.optimise, priors=dataclasses.replace(config.optimise.priors, v=None)),
    )
    far = rigjax.load_template(FAR_TEMPLATE)
    runs = {"far": (far, 1), "1 frame": (config, 1), "3 frames": (config, 3), "5 frames": (config, 5)}
    runs["no prior"] = (no_prior, 1)
    print(
        "| scene | calibration | ends | orientation error (sd) deg | rays p95 deg | hfov error (sd) deg | "
        "exposure error EV | white balance error % | vignetting | seam disagreement: calibration / true / far |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for seed in range(args.scenes):
        started = time.perf_counter()
        truth = draw_dual(seed, SIZE)
        frames = render_dual_frames(seed, truth, FRAMES)
        names = [f"s{seed}f{f}.png" for f in range(FRAMES)]
        halves = frames_of(frames[:1], config, names[:1])[0][0]
        results = {}
        for run, (template, count) in runs.items():
            results[run] = calibrate(frames[:count], template, names[:count])
        # each scene compiles programs of its own sizes: let them go, or a long run reaches the kernel's
        # limit on memory mappings (vm.max_map_count) and dies in a compilation
        jax.clear_caches()
        anchor = next((c for c, _ in results.values() if c is not None), None)
        seam = {}
        if anchor is not None:
            true = truth.project(tuple(im.filename for im in anchor.project.images))
            seam["true"] = rigjax.seam_disagreement(true, halves, width=PANORAMA_WIDTH)
        if results["far"][0] is not None:
            seam["far"] = rigjax.seam_disagreement(results["far"][0].project, halves, width=PANORAMA_WIDTH)
        elif anchor is not None:  # the template's nominal cameras: what a user of it is left with
            seam["far"] = rigjax.seam_disagreement(anchor.start, halves, width=PANORAMA_WIDTH)
        if use_hugin:
            with tempfile.TemporaryDirectory() as folder:
                project, points = hugin(
                    halves, results["far"][0].start if results["far"][0] else anchor.start, Path(folder)
                )
            results["hugin"] = (None, f"failed: cpfind found {points} points") if project is None else (project, "ok")
        for run, (calibration, ends) in results.items():
            row = dict(scene=seed, run=run, ends=ends)
            if calibration is not None:
                project = calibration if isinstance(calibration, rigjax.Project) else calibration.project
                cameras = project.cameras(host=True)
                row["orientation"] = relative_error_deg(cameras, truth.cameras)
                row["hfov"] = float(cameras.hfov[0] - truth.cameras.hfov[0])
                true = truth.project(tuple(im.filename for im in project.images))
                row["rays"] = float(np.percentile(np.concatenate(ray_angles_deg(project, true)), 95))
                result = getattr(calibration, "result", None)
                deviations = None if result is None else result.standard_deviations  # None: rotation-only
                row["hfov_sd"] = float(deviations[0, 0]) if deviations is not None else math.nan
                row["turn_sd"] = float(result.orientation_sd_deg[1]) if deviations is not None else math.nan
                row["seam"] = rigjax.seam_disagreement(project, halves, width=PANORAMA_WIDTH).median
                fit = getattr(calibration, "exposure", None)
                if fit is not None:
                    a, b = fit.project.images
                    row["exposure"] = (b.exposure_value - a.exposure_value) - (
                        truth.exposure_value[1] - truth.exposure_value[0]
                    )
                    row["white_balance"] = 100 * max(
                        abs(b.white_balance_red / a.white_balance_red / truth.white_balance[1, 0] - 1),
                        abs(b.white_balance_blue / a.white_balance_blue / truth.white_balance[1, 1] - 1),
                    )
                    held = any("vignetting" in line for line in fit.held)
                    row["vignetting"] = (
                        "held (undetermined)" if held else f"Vb {a.vignetting_b:+.3f} (true {truth.vignetting_b:+.3f})"
                    )
            rows.append(row)
            hfov = fmt(row.get("hfov"), "+.3f") + sd(row.get("hfov_sd"))
            orientation = fmt(row.get("orientation"), ".3f") + sd(row.get("turn_sd"))
            print(
                f"| {seed} | {run} | {ends} | {orientation} | {fmt(row.get('rays'), '.3f')} | {hfov} | "
                f"{fmt(row.get('exposure'), '+.3f')} | {fmt(row.get('white_balance'), '.2f')} | {row.get('vignetting', '-')} | "
                f"{fmt(row.get('seam'), '.2f')} / {fmt(seam['true'].median if 'true' in seam else None, '.2f')} / "
                f"{fmt(seam['far'].median if 'far' in seam else None, '.2f')} |",
                flush=True,
            )
            row["seam_true"] = seam["true"].median if "true" in seam else math.nan
            row["seam_far"] = seam["far"].median if "far" in seam else math.nan
        print(f"scene {seed}: {time.perf_counter() - started:.0f} s", file=sys.stderr, flush=True)
    summarise(rows, args.scenes)


def summarise(rows: list[dict], scenes: int) -> None:
    print()
    print(f"Over {scenes} scenes (share of scenes; an unfinished calibration counts as a miss):")
    print()
    print(
        "| calibration | ends ok / refused / not converged / failed | orientation < 0.2 deg | median orientation error deg | "
        "orientation within 3 sd | rays p95 < 0.15 deg | written > 1 deg off (rays p95) | hfov < 1 deg | "
        "hfov within 3 sd | exposure within 0.05 EV | seam closer to the true cameras' than far's |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for run in dict.fromkeys(r["run"] for r in rows):
        own = [r for r in rows if r["run"] == run]
        ends = [sum(r["ends"].startswith(word) for r in own) for word in ("ok", "refused", "not converged", "failed")]
        done = [r for r in own if r["ends"].startswith("ok")]

        def share(test) -> str:
            return f"{sum(1 for r in done if test(r))}/{len(own)}"

        errors = [r["orientation"] for r in done]
        within = share(lambda r: abs(r["hfov"]) <= 3 * r["hfov_sd"]) if run not in ("far", "hugin") else "-"
        turn_within = share(lambda r: r["orientation"] <= 3 * r["turn_sd"]) if run not in ("far", "hugin") else "-"
        exposure = share(lambda r: abs(r["exposure"]) <= 0.05) if run != "hugin" else "-"
        closer = (
            share(lambda r: abs(r["seam"] - r["seam_true"]) < abs(r["seam_far"] - r["seam_true"]))
            if run not in ("far", "hugin")
            else "-"
        )
        print(
            f"| {run} | {' / '.join(map(str, ends))} | {share(lambda r: r['orientation'] < 0.2)} | "
            f"{fmt(float(np.median(errors)) if errors else math.nan, '.3f')} | {turn_within} | "
            f"{share(lambda r: r['rays'] < 0.15)} | {sum(1 for r in done if r['rays'] > 1.0)} | "
            f"{share(lambda r: abs(r['hfov']) < 1.0)} | "
            f"{within} | {exposure} | {closer} |"
        )


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main()
