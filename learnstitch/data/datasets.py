"""Datasets of fisheye triplets for training and evaluation, from disk or generated on the fly.

Every item is a dict of tensors, float32 in [0, 1]:

* ``inputs`` ``(3, 3, H, W)``: the three fisheyes unwarped onto the full panorama canvas at the
  rig's *nominal* orientations (the literature's unwarp-then-pad; zeros outside each lens), or,
  with ``inputs="calibrated"``, at the sample's own cameras (what a calibrated rig gives);
* ``masks`` ``(3, H, W)``: where each unwarped input is valid (inside its image circle);
* ``pano`` ``(3, H, W)``: the ground truth from the rig's centre;
* ``inverse_depth`` ``(H, W)``: 1 / the truth's depth (metres from the centre; 0 for the sky);
* ``seed``: the sample's seed.

The nominal unwarping grids are computed once per dataset (:func:`learnstitch.data.sample.nominal_unwarp_grids`),
calibrated ones per item.
learnstitch imports JAX (rigjax's camera maps; the generated datasets call it in ``__getitem__``),
and JAX must not be forked: give a ``DataLoader`` with workers ``multiprocessing_context="spawn"``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset, IterableDataset, get_worker_info

from rigjax import Camera

from .rig import cameras_with, unwarp_grids
from .sample import ConfigError, SynthConfig, make_sample, nominal_unwarp_grids, unwarp
from .store import MANIFEST, SPLIT_SEED_BASE, read_images

__all__ = ["FolderDataset", "GeneratedDataset", "InfiniteGeneratedDataset"]


class _Unwarper:
    def __init__(self, config: SynthConfig, inputs: str = "nominal"):
        if inputs not in ("nominal", "calibrated"):
            raise ConfigError(f"inputs must be 'nominal' or 'calibrated', got {inputs!r}")
        self.config, self.calibrated = config, inputs == "calibrated"
        self.grids, self.masks, _ = nominal_unwarp_grids(config)

    def item(self, fisheyes: torch.Tensor, pano: torch.Tensor, depth: torch.Tensor, seed: int, cameras: Camera) -> dict:
        grids, masks = self.grids, self.masks
        if self.calibrated:  # unwarped at the sample's own cameras (a perfect calibration)
            grids, masks, _ = unwarp_grids(
                cameras, (self.config.pano_width, self.config.pano_height), self.config.circle_deg
            )
        inputs = unwarp(fisheyes, grids)  # zeros outside each mask (the grids point off the image)
        return {
            "inputs": inputs,
            "masks": masks.to(torch.float32),
            "pano": pano,
            "inverse_depth": 1.0 / depth.to(torch.float32),
            "seed": seed,
        }


class FolderDataset(Dataset):
    """The samples of one split written by ``learnstitch synth`` (complete samples only)."""

    def __init__(self, root: str | Path, split: str = "train", inputs: str = "nominal"):
        root = Path(root)
        try:
            manifest = json.loads((root / MANIFEST).read_text())
        except (OSError, json.JSONDecodeError) as error:
            raise ConfigError(f"{root / MANIFEST}: cannot read a learnstitch manifest ({error})") from None
        self.config = SynthConfig.from_dict(manifest["data"], f"{root / MANIFEST}: data")
        self.folder = root / split
        self.seed_base = int(manifest["seed_base"][split])
        names = (
            sorted(p.name for p in self.folder.iterdir() if p.is_dir() and not p.name.startswith("."))
            if self.folder.is_dir()
            else []
        )
        if not names:
            raise ConfigError(f"{self.folder}: no samples (run `learnstitch synth --split {split}` first)")
        self.names = names
        self._unwarp = _Unwarper(self.config, inputs)

    def __len__(self) -> int:
        return len(self.names)

    def __getitem__(self, index: int) -> dict:
        folder = self.folder / self.names[index]
        fisheyes, pano = read_images(folder)
        depth = torch.from_numpy(np.load(folder / "depth.npy").astype(np.float32))
        cameras = None
        if self._unwarp.calibrated:
            angles = json.loads((folder / "sample.json").read_text())["cameras"]
            cameras = cameras_with(self.config.fisheye_size, self.config.hfov, angles)
        return self._unwarp.item(fisheyes, pano, depth, self.seed_base + int(self.names[index]), cameras)


class GeneratedDataset(Dataset):
    """``length`` samples of a split rendered on demand: item ``k`` is sample ``k`` of the split,
    the same as ``learnstitch synth`` writes (before PNG quantisation)."""

    def __init__(self, config: SynthConfig, split: str = "train", length: int = 1000, inputs: str = "nominal"):
        if split not in SPLIT_SEED_BASE:
            raise ConfigError(f"split must be one of {sorted(SPLIT_SEED_BASE)}, got {split!r}")
        self.config, self.length, self.seed_base = config, int(length), SPLIT_SEED_BASE[split]
        self._unwarp = _Unwarper(config, inputs)

    def __len__(self) -> int:
        return self.length

    def __getitem__(self, index: int) -> dict:
        if not 0 <= index < self.length:
            raise IndexError(f"sample {index} of a dataset of {self.length}")
        sample = make_sample(self.config, self.seed_base + index)
        return self._unwarp.item(sample.fisheyes, sample.pano, sample.depth, sample.seed, sample.rig.cameras)


class InfiniteGeneratedDataset(IterableDataset):
    """An endless, seeded stream of training samples: worker ``w`` of ``n`` renders samples
    ``start + w, start + w + n, ...`` of the split, so the stream is the same for any number of
    workers, up to order."""

    def __init__(self, config: SynthConfig, split: str = "train", start: int = 0, inputs: str = "nominal"):
        self.config, self.start, self.seed_base = config, int(start), SPLIT_SEED_BASE[split]
        self._unwarp = _Unwarper(config, inputs)

    def __iter__(self):
        info = get_worker_info()
        worker, workers = (info.id, info.num_workers) if info else (0, 1)
        index = self.start + worker
        while True:
            sample = make_sample(self.config, self.seed_base + index)
            yield self._unwarp.item(sample.fisheyes, sample.pano, sample.depth, sample.seed, sample.rig.cameras)
            index += workers
