"""Datasets of rigs' fisheyes for training and evaluation, from disk or generated on the fly.

Every item is a dict of tensors, float32 in [0, 1]:

* ``inputs`` ``(N, 3, H, W)``: the N fisheyes (three, or a random rig's) unwarped onto the full
  panorama canvas at the rig's *nominal* orientations (the literature's unwarp-then-pad; zeros
  outside each lens; the three-fisheye rig only), or, with ``inputs="calibrated"``, at the
  sample's own cameras (what a calibrated rig gives);
* ``masks`` ``(N, H, W)``: where each unwarped input is valid (inside its image circle);
* ``centres`` ``(N, 3)``: the cameras' centres, world metres;
* ``pano`` ``(3, H, W)``: the ground truth from the rig's centre;
* ``inverse_depth`` ``(H, W)``: 1 / the truth's depth (metres from the centre; 0 for the sky);
* ``seed``: the sample's seed.

The nominal unwarping grids are computed once per dataset (:func:`learnstitch.data.sample.nominal_unwarp_grids`),
calibrated ones per item. Items of rigs of different N batch with :func:`collate_rigs`.
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
from rigjax.errors import ConfigError

from .rig import cameras_with, unwarp_grids
from .sample import SynthConfig, make_sample, nominal_unwarp_grids, unwarp
from .store import MANIFEST, SPLIT_SEED_BASE, read_images

__all__ = ["FolderDataset", "GeneratedDataset", "InfiniteGeneratedDataset", "collate_rigs"]


def collate_rigs(items: list[dict]) -> dict:
    """A batch of items of rigs of any camera counts: ``inputs``, ``masks`` and ``centres`` padded
    to the batch's largest N with absent cameras (zero images, masks and centres; a pooled network
    leaves them out, :class:`learnstitch.network.depth.DepthStitchNet`), the rest stacked."""
    count = max(len(item["inputs"]) for item in items)

    def padded(key: str) -> torch.Tensor:
        tensors = [item[key] for item in items]
        return torch.stack([torch.cat([t, t.new_zeros(count - len(t), *t.shape[1:])]) for t in tensors])

    batch = {key: padded(key) for key in ("inputs", "masks", "centres")}
    for key in items[0]:
        if key not in batch:
            values = [item[key] for item in items]
            batch[key] = torch.stack(values) if isinstance(values[0], torch.Tensor) else torch.tensor(values)
    return batch


class _Unwarper:
    def __init__(self, config: SynthConfig, inputs: str = "nominal"):
        if inputs not in ("nominal", "calibrated"):
            raise ConfigError(f"inputs must be 'nominal' or 'calibrated', got {inputs!r}")
        self.config, self.calibrated = config, inputs == "calibrated"
        self.grids, self.masks, _ = nominal_unwarp_grids(config)

    def item(
        self,
        fisheyes: torch.Tensor,
        pano: torch.Tensor,
        depth: torch.Tensor,
        seed: int,
        cameras: Camera,
        centres: np.ndarray,
        circle_deg: float,
    ) -> dict:
        grids, masks = self.grids, self.masks
        if self.calibrated:  # unwarped at the sample's own cameras (a perfect calibration)
            grids, masks, _ = unwarp_grids(cameras, (self.config.pano_width, self.config.pano_height), circle_deg)
        elif len(fisheyes) != len(grids):
            raise ConfigError(
                f"sample {seed}: a rig of {len(fisheyes)} cameras has no nominal unwarp (model.inputs: nominal is "
                "the three-fisheye rig's); use model.inputs: calibrated"
            )
        inputs = unwarp(fisheyes, grids)  # zeros outside each mask (the grids point off the image)
        return {
            "inputs": inputs,
            "masks": masks.to(torch.float32),
            "centres": torch.as_tensor(np.asarray(centres), dtype=torch.float32),
            "pano": pano,
            "inverse_depth": 1.0 / depth.to(torch.float32),
            "seed": seed,
        }

    def sample_item(self, sample) -> dict:
        """The item of a :class:`learnstitch.data.sample.Sample`."""
        rig = sample.rig
        return self.item(
            sample.fisheyes, sample.pano, sample.depth, sample.seed, rig.cameras, rig.centres, sample.circle_deg
        )


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
        meta = json.loads((folder / "sample.json").read_text())
        cameras = cameras_with(self.config.fisheye_size, meta["cameras"])
        seed = self.seed_base + int(self.names[index])
        circle = meta.get("circle_deg", self.config.circle_deg)
        return self._unwarp.item(fisheyes, pano, depth, seed, cameras, meta["centres_m"], circle)


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
        return self._unwarp.sample_item(make_sample(self.config, self.seed_base + index))


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
            yield self._unwarp.sample_item(make_sample(self.config, self.seed_base + index))
            index += workers
