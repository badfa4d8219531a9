"""Evaluation: ``learnstitch evaluate --config ... --checkpoint ... [--device cpu] --out DIR``.

The network and the rotation-only baseline (:func:`learnstitch.rotation_only_stitch`: the true
camera orientations, no parallax correction) stitch the same test samples (seeds of the test
split, never trained on), rendered on the fly from the config's ``data`` section; with
``evaluate.calibrate_template`` (a rigjax rig template, ``configs/rig/tri_fisheye.yaml``), so does
rigjax-calibrated stitching (:func:`learnstitch.calibrated_stitch`: orientations and hfov
calibrated from the three fisheyes, the rig then turned as a whole onto the true one, which
images cannot tell). All are judged against the ground-truth panorama by PSNR and SSIM over

* ``full``: every panorama pixel;
* ``seams``: the pixels at least two of the unwarped inputs see (the overlaps, where parallax
  shows and where the blend decides).

Written to ``DIR``: ``metrics.json`` (per-sample values and means), ``table.md`` (the means, one
row per method, in the literature's layout) and ``examples.png`` (per example: truth, network,
baselines, and each one's absolute error times 4). Samples are spread over worker processes
(``spawn``, one torch thread each); the result does not depend on the number of workers.
"""

from __future__ import annotations

import json
import multiprocessing
import statistics
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
from tqdm import tqdm

import rigjax
from rigjax.errors import ConfigError

from .baselines import calibrated_stitch, orientation_errors_deg, psnr, rotation_only_stitch, ssim
from .checkpoint import load_model
from .config import StitchConfig
from .data.sample import make_sample, nominal_unwarp_grids, unwarp
from .data.store import SPLIT_SEED_BASE, write_png

METHODS = ("network", "rotation_only", "calibrated")  # "calibrated" with evaluate.calibrate_template


class EvalReport(NamedTuple):
    means: dict[str, dict[str, float]]  # method -> "psnr_full", "ssim_full", "psnr_seams", "ssim_seams"
    # (calibrated: also "failed", the share of samples the nominal rig stood in for, and
    # "orientation_error_deg", the mean angle from the true orientations after alignment)
    samples: list[dict]
    table: str
    out: Path | None


class _Job(NamedTuple):
    config: StitchConfig
    checkpoint: str
    device: str
    template: rigjax.CalibrateConfig | None  # evaluate.calibrate_template, read once


_WORKER: dict = {}


def _init_worker(job: _Job, threads: int) -> None:
    torch.set_num_threads(threads)
    model, _ = load_model(job.checkpoint, job.config, job.device)
    grids, masks, _ = nominal_unwarp_grids(job.config.data)
    _WORKER.update(job=job, model=model, grids=grids, masks=masks.float(), seams=masks.sum(dim=0) >= 2)


def _metrics(image: torch.Tensor, truth: torch.Tensor, seams: torch.Tensor) -> dict[str, float]:
    return {
        "psnr_full": float(psnr(image, truth)),
        "ssim_full": float(ssim(image, truth)),
        "psnr_seams": float(psnr(image, truth, seams)),
        "ssim_seams": float(ssim(image, truth, seams)),
    }


def _evaluate_one(index: int) -> tuple[dict, torch.Tensor | None]:
    job, model = _WORKER["job"], _WORKER["model"]
    device = torch.device(job.device)
    seed = SPLIT_SEED_BASE["test"] + index
    sample = make_sample(job.config.data, seed)
    inputs = unwarp(sample.fisheyes, _WORKER["grids"])
    with torch.no_grad():
        pano = model(inputs[None].to(device), _WORKER["masks"][None].to(device)).pano[0].clamp(0.0, 1.0).cpu()
    stitched = {"network": pano, "rotation_only": rotation_only_stitch(sample.fisheyes, sample.rig, job.config.data)[0]}
    if job.template is not None:
        calibrated = calibrated_stitch(
            sample.fisheyes, job.config.data, job.template, reference=sample.rig.cameras, seed=seed
        )
        stitched["calibrated"] = calibrated.pano
    record = {
        "index": index,
        "seed": seed,
        **{m: _metrics(image, sample.pano, _WORKER["seams"]) for m, image in stitched.items()},
    }
    if "calibrated" in stitched:
        errors = orientation_errors_deg(calibrated.cameras, sample.rig.cameras)
        record["calibrated"].update(
            failed=float(calibrated.failure is not None), orientation_error_deg=float(errors.mean())
        )
        record["calibration"] = {
            "failure": calibrated.failure,
            "orientation_error_deg": errors.tolist(),
            "hfov_error_deg": (np.asarray(calibrated.cameras.hfov) - sample.rig.cameras.hfov).tolist(),
        }
    row = None
    if index < job.config.evaluate.examples:
        images = list(stitched.values())
        error = [((p - sample.pano).abs() * 4.0).clamp(0.0, 1.0) for p in images]
        row = torch.cat([sample.pano, *images, *error], dim=2)
    return record, row


def evaluate(
    config: StitchConfig,
    checkpoint: str | Path,
    *,
    out: str | Path | None = None,
    device: str = "cpu",
    samples: int | None = None,
    workers: int | None = None,
    progress: bool = True,
) -> EvalReport:
    """Evaluate ``checkpoint`` (trained with ``config``'s model and data) on the test split.

    ``samples`` and ``workers`` override ``config.evaluate``. A checkpoint of another model or
    data config raises :class:`learnstitch.ConfigError` naming the keys that differ.
    """
    samples = config.evaluate.samples if samples is None else samples
    workers = config.evaluate.workers if workers is None else workers
    if samples < 1 or workers < 1:
        raise ConfigError(
            f"evaluate needs at least one sample and one worker, got samples={samples}, workers={workers}"
        )
    path = config.evaluate.calibrate_template
    template = None if path is None else rigjax.load_template(path)  # a bad template fails here, naming the file
    job = _Job(config, str(checkpoint), device, template)
    records, rows = [], {}

    def collect(result: tuple[dict, torch.Tensor | None]) -> None:
        record, row = result
        records.append(record)
        if row is not None:
            rows[record["index"]] = row
        bar.update()

    bar = tqdm(total=samples, desc=f"evaluate {config.name}", unit="sample", disable=not progress)
    try:
        if workers <= 1 or device != "cpu":
            _init_worker(job, torch.get_num_threads())
            for index in range(samples):
                collect(_evaluate_one(index))
        else:
            load_model(checkpoint, config)  # a mismatch fails here, before any worker starts
            with multiprocessing.get_context("spawn").Pool(workers, _init_worker, (job, 1)) as pool:
                for result in pool.imap_unordered(_evaluate_one, range(samples)):
                    collect(result)
    finally:
        bar.close()
        _WORKER.clear()
    records.sort(key=lambda r: r["index"])
    means = {
        m: {k: statistics.fmean(r[m][k] for r in records) for k in records[0][m]} for m in METHODS if m in records[0]
    }
    table = results_table({config.data.distance: means}, len(records))
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "metrics.json").write_text(
            json.dumps(
                {
                    "config": config.name,
                    "checkpoint": str(checkpoint),
                    "distance": config.data.distance,
                    "means": means,
                    "samples": records,
                },
                indent=1,
            )
        )
        (out / "table.md").write_text(table)
        if rows:
            write_png(out / "examples.png", torch.cat([rows[i] for i in sorted(rows)], dim=1))
    return EvalReport(means, records, table, out)


def results_table(by_distance: dict[float, dict[str, dict[str, float]]], samples: int) -> str:
    """A markdown table of mean PSNR (dB) and SSIM per method and camera distance."""
    names = {
        "network": "learnstitch network",
        "rotation_only": "rotation-only (true orientations)",
        "calibrated": "rigjax-calibrated (from the images)",
    }
    lines = ["| method | d (m) | PSNR full | SSIM full | PSNR seams | SSIM seams |", "|---|---:|---:|---:|---:|---:|"]
    notes = []
    for distance, means in sorted(by_distance.items()):
        for method, m in means.items():
            lines.append(
                f"| {names.get(method, method)} | {distance:g} | {m['psnr_full']:.2f} | {m['ssim_full']:.3f} "
                f"| {m['psnr_seams']:.2f} | {m['ssim_seams']:.3f} |"
            )
            if method == "calibrated":
                notes.append(
                    f"At d = {distance:g} m calibration failed on {m['failed']:.0%} of the samples (the nominal rig "
                    f"stood in); orientation error {m['orientation_error_deg']:.2f} degrees on average, after "
                    "turning the rig as a whole onto the true one."
                )
    return (
        "\n".join(lines)
        + f"\n\nMeans over {samples} test samples (seeds of the test split).\n"
        + "".join(f"{note}\n" for note in notes)
    )
