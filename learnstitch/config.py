"""Typed configuration of learnstitch, read from YAML (``configs/stitch/*.yaml``).

A file has one section per part of the pipeline, each a frozen dataclass:

* ``data`` — the synthetic samples (:class:`learnstitch.SynthConfig`);
* ``model`` — the network (:class:`learnstitch.network.model.ModelConfig`);
* ``loss`` — the training loss (:class:`learnstitch.network.losses.LossConfig`);
* ``train`` — the optimiser, data and run-keeping (:class:`TrainConfig`);
* ``evaluate`` — the evaluation job (:class:`EvalConfig`);
* ``render`` — full-resolution stitching of a calibrated rig (:class:`learnstitch.fullres.config.RenderConfig`).

Every section and key is optional (defaults below and in those classes). Unknown sections and
keys, and values of the wrong type or range, are errors that name the file and the key
(:mod:`rigjax.config`, the configuration system both packages share).
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path

from rigjax.config import as_dict, read_yaml, typed_from_dict
from rigjax.errors import ConfigError

from .data.sample import SynthConfig
from .fullres.config import RenderConfig
from .network.losses import LossConfig
from .network.model import ModelConfig


@dataclass(frozen=True)
class TrainConfig:
    """The ``train:`` section of ``configs/stitch/*.yaml``."""

    seed: int = 0
    epochs: int = 10
    batch_size: int = 4
    lr: float = 1e-3
    lr_schedule: str = "cosine"  # "constant", or "cosine": from lr down to 0 over the run (a function of the step)
    samples: int = 256  # training samples (one epoch)
    data_dir: str | None = None  # a `learnstitch synth` folder (filled first if short); null: render on the fly
    synth_workers: int = 2  # processes that fill data_dir
    loader_workers: int = 0  # DataLoader processes (spawn); useful when rendering on the fly
    grad_clip: float = 0.0  # max gradient norm; 0: no clipping
    checkpoint_every: int = 100  # steps
    log_every: int = 10
    image_every: int = 200
    tensorboard: bool = True
    device: str = "auto"  # "auto" (CUDA when available), "cpu", "cuda", "cuda:1" ...
    amp: bool = True  # bfloat16 autocast around the convolutions, on CUDA only
    validate_every: int = 0  # steps between validations (PSNR over seen pixels, gain on and off); 0: none
    validate_samples: int = 8  # validation samples, each rendered as configured and photometrically clean
    # A checkpoint whose weights start this run where their names and shapes match this model's
    # (the rest as train.seed initialises them): a network of another pooling or rig starts from
    # what it shares with a trained one. Null: from scratch.
    init_from: str | None = None

    def __post_init__(self) -> None:
        for name in (
            "epochs",
            "batch_size",
            "samples",
            "synth_workers",
            "checkpoint_every",
            "log_every",
            "image_every",
        ):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name} must be >= 1, got {getattr(self, name)!r}")
        if self.samples < self.batch_size:
            raise ConfigError(f"samples ({self.samples}) must be at least batch_size ({self.batch_size})")
        if self.lr_schedule not in ("constant", "cosine"):
            raise ConfigError(f"lr_schedule must be 'constant' or 'cosine', got {self.lr_schedule!r}")
        if self.validate_every < 0 or self.validate_samples < 1:
            raise ConfigError(
                f"validate_every must be >= 0 and validate_samples >= 1, got {self.validate_every!r}, "
                f"{self.validate_samples!r}"
            )
        if not self.lr > 0.0 or self.grad_clip < 0.0 or self.loader_workers < 0:
            raise ConfigError(
                f"lr must be > 0, grad_clip and loader_workers >= 0; got {self.lr!r}, {self.grad_clip!r}, {self.loader_workers!r}"
            )


@dataclass(frozen=True)
class EvalConfig:
    """The ``evaluate:`` section: the test samples the network and the baselines are judged on."""

    samples: int = 32  # test samples (seeds of the test split: never trained on)
    workers: int = 2  # worker processes, one torch thread each
    examples: int = 4  # samples shown in examples.png
    calibrate_template: str | None = None  # a rigjax rig template: also score rigjax-calibrated stitching

    def __post_init__(self) -> None:
        if self.samples < 1 or self.workers < 1 or self.examples < 0:
            raise ConfigError(f"samples and workers must be >= 1 and examples >= 0; got {self}")


@dataclass(frozen=True)
class StitchConfig:
    data: SynthConfig = field(default_factory=SynthConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    evaluate: EvalConfig = field(default_factory=EvalConfig)
    render: RenderConfig = field(default_factory=RenderConfig)
    name: str = ""

    def __post_init__(self) -> None:
        for key in ("depth_weight", "plane_weight", "class_weight", "surface_weight"):
            if getattr(self.loss, key) > 0 and self.model.warp != "depth":
                raise ConfigError(f"loss.{key} > 0 needs model.warp: depth (the homography warp predicts no depth)")
        if self.loss.surface_weight > 0 and not self.model.first_surface:
            raise ConfigError("loss.surface_weight > 0 needs model.first_surface: true")
        stride = self.model.stride
        if self.data.pano_width % stride or self.data.pano_height % stride:
            raise ConfigError(
                f"data.pano_width {self.data.pano_width} x {self.data.pano_height}: both must be multiples of "
                f"the encoder's stride {stride} (2 ** len(model.widths))"
            )


def config_from_dict(values: dict, where: str = "config") -> StitchConfig:
    """A :class:`StitchConfig` from a parsed YAML document; ``name`` defaults to the file's stem."""
    config = typed_from_dict(StitchConfig, values, where)
    return config if config.name else dataclasses.replace(config, name=Path(where).stem)


def config_as_dict(config: StitchConfig) -> dict:
    """Plain values, as YAML would hold them (with ``name``); ``config_from_dict`` reads it back."""
    return as_dict(config)


def load_config(path: str | PathLike) -> StitchConfig:
    """Read ``configs/stitch/NAME.yaml``; errors name the file and the key."""
    return config_from_dict(read_yaml(os.fspath(path)) or {}, os.fspath(path))
