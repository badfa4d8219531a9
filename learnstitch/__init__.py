"""learnstitch: a supervised PyTorch stitching network for three 185-degree fisheye cameras.

Built on rigjax's camera model. This release provides the training data: procedural street
scenes ray cast into three fisheyes with true parallax and the ground-truth panorama from the
rig's centre (:mod:`learnstitch.synth`), datasets (:mod:`learnstitch.data`), and the classical
rotation-only reference (:mod:`learnstitch.baselines`). The network arrives with its own issue.
"""

from ._config import StitchConfig, config_from_dict, load_config
from ._generate import SynthReport, contact_sheet, synthesise
from .baselines import psnr, rotation_only_stitch, ssim
from .data import FolderDataset, GeneratedDataset, InfiniteGeneratedDataset
from .synth import ConfigError, Sample, SynthConfig, make_sample, nominal_unwarp_grids, unwarp

__version__ = "0.1.0"

__all__ = [
    "ConfigError",
    "FolderDataset",
    "GeneratedDataset",
    "InfiniteGeneratedDataset",
    "Sample",
    "StitchConfig",
    "SynthConfig",
    "SynthReport",
    "config_from_dict",
    "contact_sheet",
    "load_config",
    "make_sample",
    "nominal_unwarp_grids",
    "psnr",
    "rotation_only_stitch",
    "ssim",
    "synthesise",
    "unwarp",
]
