"""learnstitch: a supervised PyTorch stitching network for three 185-degree fisheye cameras.

Built on rigjax's camera model: procedural street scenes ray cast into three fisheyes with true
parallax and the ground-truth panorama from the rig's centre (:mod:`learnstitch.synth`), datasets
(:mod:`learnstitch.data`), the network (:mod:`learnstitch.model`: multi-homography warps, a
displacement map, weight maps), its losses (:mod:`learnstitch.losses`), training
(:mod:`learnstitch.train`), evaluation against the rotation-only and rigjax-calibrated
references (:mod:`learnstitch.evaluate`, :mod:`learnstitch.baselines`) and stitching of users' images
(:mod:`learnstitch.stitch`).
"""

from ._config import EvalConfig, StitchConfig, TrainConfig, config_as_dict, config_from_dict, load_config
from ._generate import SynthReport, contact_sheet, synthesise
from .baselines import (CalibratedStitch, align_rig, calibrated_stitch, orientation_errors_deg, psnr,
                        rotation_only_stitch, ssim, stitch_with_cameras)
from .data import FolderDataset, GeneratedDataset, InfiniteGeneratedDataset
from .evaluate import EvalReport, evaluate
from .losses import LossConfig, StitchLoss, VGG16Features, load_vgg16
from .model import ModelConfig, StitchNet, StitchOutput
from .stitch import read_fisheyes, stitch
from .synth import ConfigError, Sample, SynthConfig, make_sample, nominal_unwarp_grids, unwarp
from .train import TrainingError, TrainReport, load_checkpoint, load_model, train

__version__ = "0.1.0"

__all__ = [
    "CalibratedStitch",
    "ConfigError",
    "EvalConfig",
    "EvalReport",
    "FolderDataset",
    "GeneratedDataset",
    "InfiniteGeneratedDataset",
    "LossConfig",
    "ModelConfig",
    "Sample",
    "StitchConfig",
    "StitchLoss",
    "StitchNet",
    "StitchOutput",
    "SynthConfig",
    "SynthReport",
    "TrainConfig",
    "TrainReport",
    "TrainingError",
    "VGG16Features",
    "align_rig",
    "calibrated_stitch",
    "config_as_dict",
    "config_from_dict",
    "contact_sheet",
    "evaluate",
    "load_checkpoint",
    "load_config",
    "load_model",
    "load_vgg16",
    "make_sample",
    "nominal_unwarp_grids",
    "orientation_errors_deg",
    "psnr",
    "read_fisheyes",
    "rotation_only_stitch",
    "ssim",
    "stitch",
    "stitch_with_cameras",
    "synthesise",
    "train",
    "unwarp",
]
