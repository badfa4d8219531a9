"""A network and its ablated variants, scored on the same test samples: shared by the stitching
benchmarks (``stitch_geometry``'s warps off, ``stitch_targets``' fill off); and the rig-aware
checkpoints that ``stitch_pole`` and ``stitch_near`` compare."""

from __future__ import annotations

import statistics
import sys
from collections.abc import Callable

import torch

CLEAN = {"gain_jitter": 0.0, "vignetting": 0.0, "noise_std": 0.0}


def rig_aware_models(checkpoints: list[str]) -> list[tuple[torch.nn.Module, object]]:
    """``(model, config)`` of each checkpoint, in eval mode; a checkpoint that is not a rig-aware
    model (``model.warp: depth``) ends the benchmark with a message naming it."""
    from learnstitch.checkpoint import load_model

    models = [load_model(path) for path in checkpoints]
    for path, (model, config) in zip(checkpoints, models):
        if config.model.warp != "depth":
            sys.exit(f"{path}: not a rig-aware model (model.warp: {config.model.warp})")
        model.eval()
    return models


def mean_psnr(
    config,
    data,
    variants: dict[str, torch.nn.Module],
    samples: int,
    regions: Callable[[object], dict[str, torch.Tensor | None]],
    *,
    gain: bool,
) -> dict[str, dict[str, float]]:
    """``{variant: {region: mean PSNR}}`` over the first ``samples`` seeds of the test split of
    ``data`` (inputs as ``config.model.inputs`` says); ``regions(test)`` gives each region's mask
    (``None``: the whole panorama) of a :class:`learnstitch.evaluation.TestSample`."""
    from learnstitch.baselines import psnr
    from learnstitch.data.sample import nominal_unwarp_grids
    from learnstitch.data.store import SPLIT_SEED_BASE
    from learnstitch.evaluation import prepare_sample

    grids, masks, _ = nominal_unwarp_grids(data)
    scores: dict[str, dict[str, list[float]]] = {name: {} for name in variants}
    for seed in range(SPLIT_SEED_BASE["test"], SPLIT_SEED_BASE["test"] + samples):
        print(f"{', '.join(variants)}: sample {seed}", file=sys.stderr)
        test = prepare_sample(data, seed, grids, masks, config.model.inputs)
        for name, net in variants.items():
            with torch.no_grad():
                pano = net(test.inputs[None], test.masks[None], gain=gain, centres=test.centres()).pano[0]
                pano = pano.clamp(0.0, 1.0)
            for region, mask in regions(test).items():
                scores[name].setdefault(region, []).append(float(psnr(pano, test.sample.pano, mask)))
    return {name: {r: statistics.fmean(v) for r, v in by_region.items()} for name, by_region in scores.items()}
