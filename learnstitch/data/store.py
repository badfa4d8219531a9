"""Samples on disk: one folder per sample, written atomically, and the dataset's manifest.

Layout of an output folder::

    OUT/manifest.json            the data config and each split's seed base
    OUT/train/000017/            fisheye_0.png .. fisheye_{N-1}.png (three, or a random rig's N)
                                 pano.png depth.npy (float16 metres, inf for the sky) rig.pto
                                 sample.json (seed, centres, cameras' angles, image circle)

A sample is written into a hidden temporary folder and renamed into place: a folder with a
sample's name is complete, and an interrupted run leaves only ``.partial-*`` folders, which the
next run removes. Sample ``k`` of a split always has seed ``seed_base + k``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np
import torch

from rigjax.errors import ConfigError
from rigjax.rendering.images import write_image

from .sample import Sample, SynthConfig

MANIFEST = "manifest.json"
FORMAT = 2  # 2: gain jitter and vignetting strengths drawn per sample
SPLIT_SEED_BASE = {"train": 0, "test": 1_000_000_000, "validation": 2_000_000_000}  # disjoint: never trained on
FILES = ("fisheye_0.png", "fisheye_1.png", "pano.png", "depth.npy", "rig.pto", "sample.json")  # and more fisheyes


def sample_name(index: int) -> str:
    return f"{index:06d}"


def to_uint8(image: torch.Tensor) -> np.ndarray:
    """(3, H, W) float in [0, 1] -> (H, W, 3) uint8, channels as given (RGB)."""
    return (image.permute(1, 2, 0).cpu().numpy() * 255.0).round().clip(0, 255).astype(np.uint8)


def to_bgr_uint8(image: torch.Tensor) -> np.ndarray:
    """(3, H, W) float in [0, 1] -> (H, W, 3) uint8 BGR for OpenCV."""
    return np.ascontiguousarray(to_uint8(image)[..., ::-1])


def write_sample(sample: Sample, config: SynthConfig, folder: Path) -> None:
    """Write ``sample`` as ``folder`` atomically (a temporary sibling folder, then a rename)."""
    folder = Path(folder)
    tmp = Path(tempfile.mkdtemp(prefix=f".partial-{folder.name}-", dir=folder.parent))
    try:
        names = tuple(f"fisheye_{k}.png" for k in range(len(sample.fisheyes)))
        for name, fisheye in zip(names, sample.fisheyes):
            write_png(tmp / name, fisheye)
        write_png(tmp / "pano.png", sample.pano)
        np.save(tmp / "depth.npy", sample.depth.cpu().numpy().astype(np.float16))
        sample.rig.project((config.pano_width, config.pano_height), names).save(tmp / "rig.pto")
        cams = sample.rig.cameras
        meta = {
            "seed": sample.seed,
            "centres_m": np.asarray(sample.rig.centres).tolist(),
            "cameras": {f: np.asarray(getattr(cams, f)).tolist() for f in ("hfov", "yaw", "pitch", "roll")},
            "circle_deg": sample.circle_deg,
        }
        (tmp / "sample.json").write_text(json.dumps(meta, indent=1))
        os.chmod(tmp, 0o755)
        os.rename(tmp, folder)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def read_images(folder: Path) -> tuple[torch.Tensor, torch.Tensor]:
    """A sample folder's fisheyes ``(N, 3, S, S)`` and panorama ``(3, H, W)``, float in [0, 1]."""

    def load(name):
        image = cv2.imread(str(folder / name), cv2.IMREAD_COLOR)
        if image is None:
            raise ConfigError(f"{folder / name}: missing or not an image")
        return torch.from_numpy(image[..., ::-1].copy()).permute(2, 0, 1).float() / 255.0

    count = len(list(folder.glob("fisheye_*.png")))
    return torch.stack([load(f"fisheye_{k}.png") for k in range(count)]), load("pano.png")


def ensure_manifest(out: Path, config: SynthConfig, config_name: str) -> dict:
    """Create ``out/manifest.json``, or check that the one there is for the same data config.

    Raises :class:`ConfigError` naming the keys that differ: samples of another config are never
    mixed in nor overwritten.
    """
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{out}: is a file; --out names the folder the samples go to")
    out.mkdir(parents=True, exist_ok=True)
    path = out / MANIFEST
    tmp = path.with_suffix(".json.partial")  # a run killed before its rename leaves this: written again
    wanted = {
        "format": FORMAT,
        "config_name": config_name,
        "data": dataclasses.asdict(config),
        "seed_base": SPLIT_SEED_BASE,
        "seeds": "sample k of a split (folder k) has seed seed_base[split] + k",
    }
    if path.exists():
        try:
            found = json.loads(path.read_text())
        except json.JSONDecodeError as error:
            raise ConfigError(f"{path}: not a learnstitch manifest ({error}); choose another --out") from None
        # As JSON holds them (lists for tuples); a key newer than the manifest at its default.
        found_data = {**json.loads(json.dumps(dataclasses.asdict(SynthConfig()))), **found.get("data", {})}
        wanted["data"] = json.loads(json.dumps(wanted["data"]))
        differ = sorted(k for k in set(found_data) | set(wanted["data"]) if found_data.get(k) != wanted["data"].get(k))
        if found.get("format") != FORMAT or differ:
            detail = ", ".join(f"{k}: {found_data.get(k)!r} there, {wanted['data'].get(k)!r} now" for k in differ)
            if found.get("format") != FORMAT:
                detail = f"data format {found.get('format')!r} there, {FORMAT} now" + (f", {detail}" if detail else "")
            raise ConfigError(
                f"{out} holds samples of another data config ({found.get('config_name')!r}; {detail}); "
                "nothing was written: choose another --out"
            )
        return found
    elif any(entry != tmp for entry in out.iterdir()):
        raise ConfigError(
            f"{out} is not empty and has no {MANIFEST}; nothing was written: choose an empty or new --out"
        )
    tmp.write_text(json.dumps(wanted, indent=1))
    os.rename(tmp, path)
    return wanted


def remove_partials(split_dir: Path) -> int:
    """Remove what an interrupted run left (``.partial-*`` folders); returns how many."""
    stale = list(split_dir.glob(".partial-*"))
    for folder in stale:
        shutil.rmtree(folder, ignore_errors=True)
    return len(stale)


def done(split_dir: Path, index: int) -> bool:
    folder = split_dir / sample_name(index)
    return all((folder / name).is_file() for name in FILES)


def write_png(path: Path, image: torch.Tensor) -> None:
    """Write ``(3, H, W)`` RGB in [0, 1] as a PNG (or the format of the suffix); an image that
    cannot be written is an error naming it, never a silent success."""
    write_image(path, to_uint8(image))


def write_depth(path: str | Path, inverse_depth: torch.Tensor, max_inverse_depth: float | None = None) -> None:
    """An inverse depth map ``(h, w)`` as a grey image, near bright: ``q / max_inverse_depth``
    (default the map's own maximum) of full white."""
    top = float(inverse_depth.max()) if max_inverse_depth is None else max_inverse_depth
    grey = (inverse_depth / max(top, 1e-6)).clamp(0.0, 1.0)
    write_image(path, (grey * 255.0 + 0.5).to(torch.uint8)[..., None].expand(-1, -1, 3).numpy())
