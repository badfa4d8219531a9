"""Evaluation: ``learnstitch evaluate --config ... --checkpoint ... [--data KEY=VALUE ...] --out DIR``.

The network and the classical references (:mod:`learnstitch.baselines`) stitch the same test
samples (seeds of the test split, never trained on), rendered on the fly from the config's
``data`` section, with ``--data`` overrides (``gain_jitter=0 vignetting=0 noise_std=0``: a
photometrically clean test set, on which only geometry counts). The methods:

* ``nominal``: the inputs feather-blended as unwarped, at the rig's design;
* ``rotation_only``: the true cameras' orientations and lenses, no parallax correction;
* ``depth_oracle``: every input resampled along its sight line to the truth's scene point (the
  true depth and cameras), blended over the inputs that see it; the true-rotation stitch in the
  blind spot. What a warp could do at best;
* ``network`` and ``network_gain_off`` (its colour correction switched off: no gain maps, no
  fitted exposures and vignetting), when the model corrects colour;
* ``calibrated`` with ``evaluate.calibrate_template`` (a rigjax rig template): orientations and
  hfov calibrated from the three fisheyes, the rig then turned as a whole onto the true one,
  which images cannot tell;
* ``calibrated_depth``, with a template that gives the rig's centres (the bundle adjustment): the
  calibrated cameras' inputs resampled through the depths of their control points, spread over
  the panorama (:func:`learnstitch.baselines.calibrated_depth_stitch`); without points (a failed
  calibration) it is the calibrated stitch.

All are judged against the ground-truth panorama by PSNR and SSIM over three regions:

* ``whole``: every panorama pixel;
* ``seams``: the pixels at least two of the unwarped inputs see (where the blend decides);
* ``seen``: the pixels whose scene point some input sees from its own centre
  (:mod:`learnstitch.data.visibility`); the rest, the blind spot, no warp can recover. Its share
  is reported as ``blind_spot``.

Written to ``DIR``: ``metrics.json`` (per-sample values and means), ``table.md`` (the means, one
row per method) and ``examples.png`` (per example: truth, network, references, and each one's
absolute error times 4). Samples are spread over worker processes (``spawn``, one torch thread
each); the result does not depend on the number of workers.
"""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
import statistics
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch
from tqdm import tqdm

import rigjax
from rigjax.config import typed_from_dict
from rigjax.errors import ConfigError

from .baselines import (
    calibrated_depth_stitch,
    calibrated_stitch,
    depth_oracle_stitch,
    nominal_stitch,
    orientation_errors_deg,
    psnr,
    rotation_only_stitch,
    ssim,
)
from .checkpoint import load_model
from .config import StitchConfig
from .data.rig import unwarp_grids
from .data.sample import SynthConfig, make_sample, nominal_unwarp_grids, unwarp
from .data.store import SPLIT_SEED_BASE, write_png
from .data.visibility import sight_lines
from .network.model import corrects_colour
from .worker import setup_worker

CLEAN_PHOTOMETRY = {"gain_jitter": 0.0, "vignetting": 0.0, "noise_std": 0.0}  # --data overrides: geometry alone
METHODS = ("nominal", "rotation_only", "depth_oracle", "network", "network_gain_off", "calibrated", "calibrated_depth")
REGIONS = ("whole", "seams", "seen")
NEAR_M = 2.0  # a near object: its surface nearer than this to the panorama's centre, metres


class EvalReport(NamedTuple):
    means: dict[str, dict[str, float]]  # method -> "psnr_whole", "ssim_whole", ... per region
    # (calibrated: also "failed", the share of samples the nominal rig stood in for, and
    # "orientation_error_deg", the mean angle from the true orientations after alignment)
    samples: list[dict]  # per sample: index, seed, blind_spot and each method's metrics
    blind_spot: float  # mean share of the panorama no input sees
    table: str
    out: Path | None


def parse_overrides(items: list[str] | None, flag: str = "--data", example: str = "gain_jitter=0") -> dict[str, Any]:
    """``["gain_jitter=0", ...]`` to ``{"gain_jitter": 0, ...}`` (values read as YAML scalars); a
    malformed item is refused naming ``flag`` and an ``example``."""
    import yaml

    overrides = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"{flag} {item!r}: expected KEY=VALUE, e.g. {example}")
        overrides[key.strip()] = yaml.safe_load(value)
    return overrides


def data_with(data: SynthConfig, overrides: dict[str, Any] | None, where: str = "--data") -> SynthConfig:
    """``data`` with some keys replaced, checked as the config's own keys are."""
    if not overrides:
        return data
    return typed_from_dict(SynthConfig, {**dataclasses.asdict(data), **overrides}, where)


class TestSample(NamedTuple):
    """A rendered sample with what every method and region needs."""

    sample: Any  # learnstitch.data.sample.Sample
    inputs: torch.Tensor  # (3, 3, H, W) unwarped at the nominal rig
    masks: torch.Tensor  # (3, H, W) float
    regions: dict[str, torch.Tensor | None]  # REGIONS -> (H, W) bool (None: every pixel)
    lines: Any  # learnstitch.data.visibility.SightLines

    def centres(self) -> torch.Tensor:
        """The sample's camera centres as a batch of one ``(1, N, 3)``, world metres: what a network
        stitches it through (``model(inputs, masks, centres=test.centres())``)."""
        return torch.as_tensor(self.sample.rig.centres, dtype=torch.float32)[None]

    def distance(self) -> torch.Tensor:
        """The truth's distance from the panorama's centre per pixel ``(H, W)``, metres (inf: sky)."""
        return self.sample.depth.reshape(self.inputs.shape[-2:])

    def inverse_depth(self, top: float) -> torch.Tensor:
        """The truth's inverse depth per pixel ``(H, W)``, 1/m, 0 at infinity, clipped to ``[0, top]``
        (a rig-aware model's ``max_inverse_depth``)."""
        return (1.0 / self.distance().clamp_min(1e-6)).clamp(0.0, top)

    def near_seams(self, above_horizon: bool = False) -> torch.Tensor:
        """``(H, W)`` bool: the near objects in the seams — seen, inside two or more image circles,
        nearer than :data:`NEAR_M`; ``above_horizon``: those in the panorama's upper half only (the
        objects rather than the ground beside them: test sample 0's pole)."""
        near = self.regions["seen"] & self.regions["seams"] & (self.distance() < NEAR_M)
        if above_horizon:
            near = near & (torch.arange(near.shape[0]) < near.shape[0] // 2)[:, None]
        return near


def prepare_sample(
    data: SynthConfig, seed: int, grids: torch.Tensor, masks: torch.Tensor, inputs: str = "nominal"
) -> TestSample:
    """Render sample ``seed`` of ``data`` and its inputs (``grids``, ``masks``: :func:`nominal_unwarp_grids`;
    ``inputs="calibrated"``: unwarped at the sample's own cameras instead). The seams are the
    nominal masks' overlaps either way."""
    sample = make_sample(data, seed)
    lines = sight_lines(sample, data)
    regions = {"whole": None, "seams": masks.sum(dim=0) >= 2, "seen": lines.seen}
    if inputs == "calibrated":
        grids, masks, _ = unwarp_grids(sample.rig.cameras, (data.pano_width, data.pano_height), data.circle_deg)
    return TestSample(sample, unwarp(sample.fisheyes, grids), masks.float(), regions, lines)


def network_panos(model: torch.nn.Module, test: TestSample, device: str | torch.device) -> dict[str, torch.Tensor]:
    """The network's panorama, and the one with its colour correction (gain maps or fitted
    photometry) off when it has one."""
    args = test.inputs[None].to(device), test.masks[None].to(device)
    gains = (True, False) if corrects_colour(model) else (True,)
    centres = test.centres().to(device)
    panos = {}
    with torch.no_grad():
        for gain in gains:
            pano = model(*args, gain=gain, centres=centres).pano[0].clamp(0.0, 1.0).cpu()
            panos["network" if gain else "network_gain_off"] = pano
    return panos


def region_metrics(image: torch.Tensor, truth: torch.Tensor, regions: dict[str, torch.Tensor | None]) -> dict:
    """PSNR (dB) and SSIM of ``image`` over each region."""
    metrics = {}
    for name, mask in regions.items():
        metrics[f"psnr_{name}"] = float(psnr(image, truth, mask))
        metrics[f"ssim_{name}"] = float(ssim(image, truth, mask))
    return metrics


class _Job(NamedTuple):
    config: StitchConfig
    data: SynthConfig  # the test samples' (config.data with the --data overrides)
    checkpoint: str
    device: str
    template: rigjax.CalibrateConfig | None  # evaluate.calibrate_template, read once


_WORKER: dict = {}


def _init_worker(job: _Job, threads: int) -> None:
    setup_worker(torch_threads=threads)
    model, _ = load_model(job.checkpoint, job.config, job.device)
    grids, masks, _ = nominal_unwarp_grids(job.config.data)
    _WORKER.update(job=job, model=model, grids=grids, masks=masks)


def _evaluate_one(index: int) -> tuple[dict, torch.Tensor | None]:
    job, model = _WORKER["job"], _WORKER["model"]
    seed = SPLIT_SEED_BASE["test"] + index
    test = prepare_sample(job.data, seed, _WORKER["grids"], _WORKER["masks"], job.config.model.inputs)
    sample = test.sample
    rotation_only = rotation_only_stitch(sample.fisheyes, sample.rig, job.data)[0]
    stitched = {
        "nominal": nominal_stitch(sample.fisheyes, job.data)[0],
        "rotation_only": rotation_only,
        "depth_oracle": depth_oracle_stitch(sample.fisheyes, test.lines, job.data, rotation_only),
        **network_panos(model, test, job.device),
    }
    if job.template is not None:
        calibrated = calibrated_stitch(sample.fisheyes, job.data, job.template, reference=sample.rig.cameras, seed=seed)
        stitched["calibrated"] = calibrated.pano
        stitched["calibrated_depth"] = calibrated_depth_stitch(sample.fisheyes, calibrated, job.data)
    record = {
        "index": index,
        "seed": seed,
        "blind_spot": 1.0 - float(test.regions["seen"].float().mean()),
        **{m: region_metrics(image, sample.pano, test.regions) for m, image in stitched.items()},
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
        shown = [stitched[m] for m in ("network", "rotation_only", "depth_oracle", "calibrated") if m in stitched]
        error = [((p - sample.pano).abs() * 4.0).clamp(0.0, 1.0) for p in shown]
        row = torch.cat([sample.pano, *shown, *error], dim=2)
    return record, row


def evaluate(
    config: StitchConfig,
    checkpoint: str | Path,
    *,
    out: str | Path | None = None,
    device: str = "cpu",
    samples: int | None = None,
    workers: int | None = None,
    data: dict[str, Any] | None = None,
    progress: bool = True,
) -> EvalReport:
    """Evaluate ``checkpoint`` (trained with ``config``'s model and data) on the test split.

    ``samples`` and ``workers`` override ``config.evaluate``; ``data`` overrides keys of the test
    samples' ``data`` section (``{"gain_jitter": 0, "vignetting": 0, "noise_std": 0}``: clean
    photometry). A checkpoint of another model or data config raises
    :class:`learnstitch.ConfigError` naming the keys that differ. A config of random rigs
    (``data.rig: random``) is judged on the three-fisheye rig its other data keys describe, one of
    its cases (other rigs: ``benchmarks/stitch_fullres.py``).
    """
    samples = config.evaluate.samples if samples is None else samples
    workers = config.evaluate.workers if workers is None else workers
    if samples < 1 or workers < 1:
        raise ConfigError(
            f"evaluate needs at least one sample and one worker, got samples={samples}, workers={workers}"
        )
    test_data = data_with(config.data, {"rig": "tri", **(data or {})})
    path = config.evaluate.calibrate_template
    template = None if path is None else rigjax.load_template(path)  # a bad template fails here, naming the file
    job = _Job(config, test_data, str(checkpoint), device, template)
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
    blind_spot = statistics.fmean(r["blind_spot"] for r in records)
    overrides = ", ".join(f"{k}={v}" for k, v in (data or {}).items())
    table = results_table({config.data.distance: means}, len(records), blind_spot={config.data.distance: blind_spot})
    if overrides:
        table += f"Test data as configured but {overrides}.\n"
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "metrics.json").write_text(
            json.dumps(
                {
                    "config": config.name,
                    "checkpoint": str(checkpoint),
                    "distance": config.data.distance,
                    "data_overrides": data or {},
                    "blind_spot": blind_spot,
                    "means": means,
                    "samples": records,
                },
                indent=1,
            )
        )
        (out / "table.md").write_text(table)
        if rows:
            write_png(out / "examples.png", torch.cat([rows[i] for i in sorted(rows)], dim=1))
    return EvalReport(means, records, blind_spot, table, out)


METHOD_NAMES = {
    "nominal": "nominal rig (design orientations)",
    "rotation_only": "true-rotation stitch",
    "depth_oracle": "depth oracle (true depth)",
    "network": "learnstitch network",
    "network_gain_off": "learnstitch network, colour correction off",
    "calibrated": "rigjax-calibrated (from the images)",
    "calibrated_depth": "rigjax-calibrated, through its points' depths",
}


def results_table(
    by_distance: dict[float, dict[str, dict[str, float]]],
    samples: int,
    *,
    blind_spot: dict[float, float] | None = None,
    names: dict[str, str] | None = None,
) -> str:
    """A markdown table of mean PSNR (dB) and SSIM per method, region and camera distance.

    ``names``: row labels for methods (default :data:`METHOD_NAMES`)."""
    names = {**METHOD_NAMES, **(names or {})}
    header = " | ".join(f"PSNR {r}" for r in REGIONS) + " | " + " | ".join(f"SSIM {r}" for r in REGIONS)
    lines = [f"| method | d (m) | {header} |", "|---|---:|" + "---:|" * 2 * len(REGIONS)]
    notes = []
    for distance, means in sorted(by_distance.items()):
        for method, m in means.items():
            psnrs = " | ".join(f"{m[f'psnr_{r}']:.2f}" for r in REGIONS)
            ssims = " | ".join(f"{m[f'ssim_{r}']:.3f}" for r in REGIONS)
            lines.append(f"| {names.get(method, method)} | {distance:g} | {psnrs} | {ssims} |")
            if method == "calibrated":
                notes.append(
                    f"At d = {distance:g} m calibration failed on {m['failed']:.0%} of the samples (the nominal rig "
                    f"stood in); orientation error {m['orientation_error_deg']:.2f} degrees on average, after "
                    "turning the rig as a whole onto the true one."
                )
        if blind_spot and distance in blind_spot:
            notes.append(
                f"At d = {distance:g} m the blind spot (seen by no input from its centre) is "
                f"{blind_spot[distance]:.1%} of the panorama."
            )
    return (
        "\n".join(lines)
        + f"\n\nMeans over {samples} test samples (seeds of the test split). Regions: whole panorama; seams "
        "(two or more inputs overlap); seen (the scene point some input sees from its own centre).\n"
        + "".join(f"{note}\n" for note in notes)
    )
