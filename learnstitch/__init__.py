"""learnstitch: supervised PyTorch stitching networks for three 185-degree fisheye cameras.

Built on rigjax's camera model: procedural street scenes ray cast into three fisheyes with true
parallax and the ground-truth panorama from the rig's centre (:mod:`learnstitch.data.sample`),
datasets (:mod:`learnstitch.data.datasets`), the networks (:mod:`learnstitch.network.model`:
multi-homography warps, a displacement map, weight maps; :mod:`learnstitch.network.depth`: the
rig-aware warp, one inverse-depth map from a spherical sweep), their losses
(:mod:`learnstitch.network.losses`), training (:mod:`learnstitch.training`), evaluation against the
classical references and the depth oracle over the whole panorama, its seams and the pixels the
inputs see (:mod:`learnstitch.evaluation`, :mod:`learnstitch.baselines`,
:mod:`learnstitch.data.visibility`) and stitching of users' images (:mod:`learnstitch.inference`).
"""

from rigjax.errors import ConfigError

from .baselines import (
    CalibratedStitch,
    align_rig,
    calibrated_stitch,
    depth_oracle_stitch,
    nominal_stitch,
    orientation_errors_deg,
    psnr,
    rotation_only_stitch,
    ssim,
    stitch_with_cameras,
)
from .checkpoint import load_checkpoint, load_model
from .config import EvalConfig, StitchConfig, TrainConfig, config_as_dict, config_from_dict, load_config
from .curves import plot_learning_curves
from .data.datasets import FolderDataset, GeneratedDataset, InfiniteGeneratedDataset
from .data.generate import SynthReport, contact_sheet, synthesise
from .data.sample import Sample, SynthConfig, make_sample, nominal_unwarp_grids, unwarp
from .data.visibility import SightLines, sight_lines
from .evaluation import EvalReport, evaluate
from .inference import read_fisheyes, stitch
from .network import build_model
from .network.depth import DepthStitchNet
from .network.losses import LossConfig, StitchLoss, VGG16Features, load_vgg16
from .network.model import ModelConfig, StitchNet, StitchOutput
from .training import TrainingError, TrainReport, train

__version__ = "0.1.0"

__all__ = [
    "CalibratedStitch",
    "ConfigError",
    "DepthStitchNet",
    "EvalConfig",
    "EvalReport",
    "FolderDataset",
    "GeneratedDataset",
    "InfiniteGeneratedDataset",
    "LossConfig",
    "ModelConfig",
    "Sample",
    "SightLines",
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
    "build_model",
    "calibrated_stitch",
    "config_as_dict",
    "config_from_dict",
    "contact_sheet",
    "depth_oracle_stitch",
    "evaluate",
    "load_checkpoint",
    "load_config",
    "load_model",
    "load_vgg16",
    "make_sample",
    "nominal_stitch",
    "nominal_unwarp_grids",
    "orientation_errors_deg",
    "plot_learning_curves",
    "psnr",
    "read_fisheyes",
    "rotation_only_stitch",
    "sight_lines",
    "ssim",
    "stitch",
    "stitch_with_cameras",
    "synthesise",
    "train",
    "unwarp",
]
