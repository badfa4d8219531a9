#!/usr/bin/env python3
"""Benchmark: matches in the seam bands of learnstitch's rigs, features against tracking.

For test samples of each config (three 185-degree fisheyes whose centres sit d metres from the
rig's middle: real parallax), each pair of cameras is matched in its seam band 30 degrees either
side of the seam (``configs/rig/tri_fisheye.yaml``): SIFT features and matches
(``features.track_step_px: null``), and a grid tracked through the band (``track_step_px: 4``,
the template's: pyramidal Lucas-Kanade with a forward-backward check). Per rig: the matches (all
pairs; and the weakest pair), their spread (the share more than 15 degrees from the seam), their epipolar error under
the true cameras and centres (the angle between a match's second ray and the plane of its first
ray and the baseline; a wrong match, or a bias, shows there), and the bundle adjustment's
calibration from them (``optimise.objective: reprojection``, nominal centres held, schedule
``YPR,VYPR``: hfov estimated, with the data's lens tolerance, 1 degree, as its prior's standard
deviation): how many rigs calibrate, the mean orientation error after turning
the rig onto the truth, how many rigs end below 0.3 degrees, and whether the reported standard
deviations of the orientations cover the errors (the angle against the deviations' rms, and the
error's turn against its reported covariance). The tracked matches once more with the centres
estimated too (``YPR,VYPRX``, each coordinate's prior 2 cm about the nominal centre, which the
data's rigs have exactly), and how far the centres end from it.

    python benchmarks/seam_matches.py [--samples 16] [--configs paper_d02 paper_d04] [--workers 2]
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import statistics
from functools import cache

import numpy as np
from _record import recorded, rig_sample_arguments

import rigjax
from learnstitch.baselines import align_rig, orientation_errors_deg, orientation_turns_deg, rig_template, to_uint8
from learnstitch.config import load_config
from learnstitch.data.sample import make_sample
from learnstitch.data.store import SPLIT_SEED_BASE
from learnstitch.worker import setup_worker
from rigjax.calibration.seam import band_from_world
from rigjax.camera.model import img_to_ray, map_points

MATCHERS = ("features", "tracking", "tracking, centres estimated")
CENTRE_SD_M = 0.02


@cache
def _inputs(name: str):
    config = load_config(f"configs/stitch/{name}.yaml").data
    template = rig_template(rigjax.load_template("configs/rig/tri_fisheye.yaml"), config)

    def matching(step):
        return dataclasses.replace(template, features=dataclasses.replace(template.features, track_step_px=step))

    tracking = matching(4)
    optimise = tracking.optimise
    centres = dataclasses.replace(
        tracking,
        optimise=optimise.replace(
            schedule=optimise.schedule + "X", priors=dataclasses.replace(optimise.priors, x=CENTRE_SD_M)
        ),
    )
    return config, {"features": matching(None), "tracking": tracking, "tracking, centres estimated": centres}


def _pair_statistics(pair, cameras, centres) -> tuple[np.ndarray, np.ndarray]:
    """Each match's epipolar error and angle from the seam (degrees), under the true rig."""
    ray_a = np.asarray(map_points(img_to_ray, cameras.take(pair.a), pair.xy_a)[0])
    ray_b = np.asarray(map_points(img_to_ray, cameras.take(pair.b), pair.xy_b)[0])
    normal = np.cross(ray_a, centres[pair.b] - centres[pair.a])
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    epipolar = np.degrees(np.abs(np.arcsin(np.clip(np.sum(normal * ray_b, -1), -1.0, 1.0))))
    axes = np.asarray(cameras.world_from_cam)[..., :, 2]
    pole = band_from_world(axes[pair.a], axes[pair.b])[1]
    off_seam = np.degrees(np.abs(np.arcsin(np.clip(ray_a @ pole, -1.0, 1.0))))
    return epipolar, off_seam


def _one(job):
    name, index = job
    setup_worker(torch_threads=1)
    config, templates = _inputs(name)
    sample = make_sample(config, SPLIT_SEED_BASE["test"] + index)
    truth, centres = sample.rig.cameras, sample.rig.centres
    images = [to_uint8(f) for f in sample.fisheyes]
    names = [f"fisheye_{k}.png" for k in range(3)]
    sizes = [(image.shape[1], image.shape[0]) for image in images]
    out, matched = {}, {}
    for matcher, template in templates.items():
        if template.features not in matched:
            matched[template.features] = rigjax.match_images(images, template, names=names)
        pairs = matched[template.features]
        stats = [_pair_statistics(pair, truth, centres) for pair in pairs if len(pair.xy_a)]
        epipolar = np.concatenate([s[0] for s in stats]) if stats else np.zeros(0)
        off_seam = np.concatenate([s[1] for s in stats]) if stats else np.zeros(0)
        try:
            calibration = rigjax.calibrate_matches(pairs, sizes, template, names=names, seed=index)
            cameras = calibration.project.cameras()
            cameras = cameras._replace(**{f: np.asarray(getattr(cameras, f)) for f in cameras._fields})
            errors = orientation_errors_deg(align_rig(cameras, truth), truth)
            error = float(errors.mean())
            hfov = float(np.abs(np.asarray(cameras.hfov) - np.asarray(truth.hfov)).mean())
            sd = np.sqrt(np.mean(np.asarray(calibration.project.deviations)[:, 6:9] ** 2, axis=1))
            honest = int(np.sum(errors <= 3.0 * sd))
            turns = orientation_turns_deg(align_rig(cameras, truth), truth)
            inverse = np.linalg.inv(calibration.result.turn_covariance)
            mahalanobis = int(np.sum(np.einsum("ni,nij,nj->n", turns, inverse, turns) <= 9.0))
            moved = np.linalg.norm(np.asarray(calibration.project.centres) - centres, axis=1)[1:]  # the anchor's held
        except rigjax.CalibrationError:
            error = hfov = moved = None
            honest = mahalanobis = 0
        out[matcher] = {
            "matches": len(epipolar),
            "weakest": min(len(pair.xy_a) for pair in pairs),
            "off_seam": float(np.mean(off_seam > 15.0)) if len(off_seam) else 0.0,
            "epipolar": float(np.median(epipolar)) if len(epipolar) else float("nan"),
            "wrong": float(np.mean(epipolar > 0.5)) if len(epipolar) else float("nan"),
            "error": error,
            "hfov": hfov,
            "honest": honest,
            "mahalanobis": mahalanobis,
            "centres": moved,
        }
    return out


def main() -> None:
    args = rig_sample_arguments(__doc__)
    print(
        f"Means over {args.samples} test samples per config. Epipolar error: median per rig, then the mean; "
        "'> 0.5 deg': the share of matches further than that from their epipolar plane. Calibration: "
        "orientation error after alignment, the mean over the rigs that calibrate. Within 3 SD: the "
        "cameras whose orientation error (the angle) is at most 3 times the rms of their reported yaw, "
        "pitch and roll standard deviations (97 % of them for isotropic Gaussian errors), of all cameras "
        "of the rigs that calibrate; and those whose error, as a turn about the world's axes, lies within "
        "3 of the reported covariance's Mahalanobis distance (also 97 % for Gaussian errors, whatever "
        "the covariance's shape).\n"
    )
    print(
        "| config | matcher | matches per rig (median; weakest pair, min) | more than 15 deg from the seam "
        "| epipolar error (deg) | > 0.5 deg | calibrated | orientation error (deg) | below 0.3 deg | hfov error (deg) "
        "| within 3 SD (angle / rms; Mahalanobis) | centre error (mm, mean; max) |"
    )
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    with multiprocessing.get_context("spawn").Pool(args.workers) as pool:
        for name in args.configs:
            rows = pool.map(_one, [(name, k) for k in range(args.samples)], chunksize=1)
            for matcher in MATCHERS:
                r = [row[matcher] for row in rows]
                ok = [x for x in r if x["error"] is not None]
                error = statistics.fmean(x["error"] for x in ok) if ok else float("nan")
                hfov = statistics.fmean(x["hfov"] for x in ok) if ok else float("nan")
                moved = np.concatenate([x["centres"] for x in ok]) * 1000 if ok else np.zeros(0)
                centres = f"{moved.mean():.1f}; {moved.max():.1f}" if "centres" in matcher and len(moved) else "held"
                print(
                    f"| {name} | {matcher} | {statistics.median(x['matches'] for x in r):.0f} "
                    f"({min(x['weakest'] for x in r)}) | {statistics.fmean(x['off_seam'] for x in r):.0%} "
                    f"| {statistics.fmean(x['epipolar'] for x in r):.3f} | {statistics.fmean(x['wrong'] for x in r):.0%} "
                    f"| {len(ok)}/{len(r)} | {error:.2f} | {sum(x['error'] < 0.3 for x in ok)}/{len(r)} | {hfov:.2f} "
                    f"| {sum(x['honest'] for x in ok)}/{3 * len(ok)}; {sum(x['mahalanobis'] for x in ok)}/{3 * len(ok)} "
                    f"| {centres} |"
                )


if __name__ == "__main__":
    with recorded(__file__, __doc__):
        main()
