"""Stitching users' images with a trained network, and the demo with the model shipped in the package.

``learnstitch stitch F0 F1 F2 --checkpoint model.pt -o pano.png``: three square circular-fisheye
images of the rig the checkpoint was trained for (cameras at yaw 0, 120 and 240 degrees, the
size of its ``data.fisheye_size``), unwarped at the rig's nominal orientations and stitched.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import torch

import rigjax
from rigjax.errors import ConfigError

from .baselines import psnr, rotation_only_stitch
from .checkpoint import load_model
from .data.sample import SynthConfig, make_sample, nominal_unwarp_grids, unwarp
from .data.store import SPLIT_SEED_BASE, write_png
from .network.model import N_INPUTS, StitchNet

SHIPPED_MODEL = Path(__file__).parent / "weights" / "cpu_tiny_d02.pt"


def read_fisheyes(paths: Sequence[str | Path]) -> tuple[torch.Tensor, list[Path]]:
    """``(3, 3, S, S)`` RGB in [0, 1] from three image files of one size."""
    paths = [Path(p) for p in paths]
    if len(paths) != N_INPUTS:
        raise ConfigError(
            f"expected {N_INPUTS} fisheye images (cameras at yaw 0, 120, 240), got {len(paths)}: {[str(p) for p in paths]}"
        )
    images = []
    for path in paths:
        image = rigjax.read_image(path)  # RGB; names the file it cannot read
        if images and image.shape[:2] != tuple(images[0].shape[-2:]):
            raise ConfigError(
                f"{path}: {image.shape[1]} x {image.shape[0]} pixels, but {paths[0]} is "
                f"{images[0].shape[-1]} x {images[0].shape[-2]}: the three fisheyes must have one size"
            )
        images.append(torch.from_numpy(image).permute(2, 0, 1).float() / 255.0)
    return torch.stack(images), paths


def stitch(model: StitchNet, fisheyes: torch.Tensor, data: SynthConfig, source: str = "the fisheyes") -> torch.Tensor:
    """The network's panorama ``(3, H, W)`` of fisheyes ``(3, 3, S, S)`` from the rig ``data``
    describes; ``source`` names the images in the error for a wrong size."""
    size = data.fisheye_size
    if fisheyes.shape[-2:] != (size, size):
        raise ConfigError(
            f"{source}: {fisheyes.shape[-1]} x {fisheyes.shape[-2]} pixels; the model was trained on "
            f"{size} x {size} fisheyes (resize them, or train a config with that data.fisheye_size)"
        )
    grids, masks, _ = nominal_unwarp_grids(data)
    device = next(model.parameters()).device
    with torch.no_grad():
        out = model(unwarp(fisheyes, grids)[None].to(device), masks.float()[None].to(device))
    return out.pano[0].clamp(0.0, 1.0).cpu()


def stitch_files(
    read: tuple[torch.Tensor, list[Path]], checkpoint: str | Path, output: str | Path, device: str = "cpu"
) -> torch.Tensor:
    fisheyes, paths = read
    model, config = load_model(checkpoint, device=device)
    pano = stitch(model, fisheyes, config.data, source=f"{paths[0]} (and the others)")
    write_png(Path(output), pano)
    return pano


def demo(out: str | Path, seed: int = 0, checkpoint: str | Path = SHIPPED_MODEL) -> str:
    """Stitch test sample ``seed`` with the shipped ``cpu_tiny`` model; write the panoramas to
    ``out`` and return a summary with PSNR against the truth (and the rotation-only baseline's)."""
    model, config = load_model(checkpoint)
    sample = make_sample(config.data, SPLIT_SEED_BASE["test"] + seed)
    pano = stitch(model, sample.fisheyes, config.data)
    baseline, _ = rotation_only_stitch(sample.fisheyes, sample.rig, config.data)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for name, image in (("network", pano), ("rotation_only", baseline), ("truth", sample.pano)):
        write_png(out / f"{name}.png", image)
    return (
        f"stitched test sample {seed} of {config.name} (d = {config.data.distance} m) with {Path(checkpoint).name}:\n"
        f"  network        PSNR {float(psnr(pano, sample.pano)):.2f} dB\n"
        f"  rotation-only  PSNR {float(psnr(baseline, sample.pano)):.2f} dB (true orientations, no parallax correction)\n"
        f"  panoramas in {out}/network.png, rotation_only.png, truth.png"
    )
