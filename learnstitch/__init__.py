"""learnstitch: supervised PyTorch stitching networks for multi-fisheye rigs.

Built on rigjax's camera model: procedural street scenes ray cast into three fisheyes with true
parallax and the ground-truth panorama from the rig's centre (:mod:`learnstitch.data.sample`),
datasets (:mod:`learnstitch.data.datasets`), the networks (:mod:`learnstitch.network.model`:
multi-homography warps, a displacement map, weight maps; :mod:`learnstitch.network.depth`: the
rig-aware warp, one inverse-depth map from a spherical sweep), their losses
(:mod:`learnstitch.network.losses`), training (:mod:`learnstitch.training`), evaluation against the
classical references and the depth oracle over the whole panorama, its seams and the pixels the
inputs see (:mod:`learnstitch.evaluation`, :mod:`learnstitch.baselines`,
:mod:`learnstitch.data.visibility`) and stitching of users' images (:mod:`learnstitch.inference`),
any calibrated rig at full resolution (:mod:`learnstitch.fullres`).
"""

from rigjax.lazy import lazy_exports

__version__ = "0.1.0"

# Each module and the public names it defines, imported on first use (see rigjax.lazy).
_EXPORTS = {
    "rigjax.errors": ("ConfigError",),
    ".baselines": (
        "CalibratedStitch",
        "align_rig",
        "calibrated_depth_stitch",
        "calibrated_stitch",
        "depth_oracle_stitch",
        "depth_stitch",
        "inverse_depth_map",
        "nominal_stitch",
        "orientation_errors_deg",
        "psnr",
        "rig_template",
        "rotation_only_stitch",
        "ssim",
        "stitch_with_cameras",
    ),
    ".checkpoint": ("load_checkpoint", "load_model"),
    ".config": ("EvalConfig", "StitchConfig", "TrainConfig", "config_as_dict", "config_from_dict", "load_config"),
    ".curves": ("plot_learning_curves",),
    ".data.config": ("SynthConfig",),
    ".data.datasets": ("FolderDataset", "GeneratedDataset", "InfiniteGeneratedDataset"),
    ".data.generate": ("SynthReport", "contact_sheet", "synthesise"),
    ".data.sample": ("Sample", "make_sample", "nominal_unwarp_grids", "unwarp"),
    ".data.visibility": ("SightLines", "sight_lines"),
    ".evaluation": ("EvalReport", "evaluate"),
    ".fullres.config": ("RenderConfig",),
    ".fullres.render": ("Stitched", "stitch_rig"),
    ".fullres.rig": ("Rig", "load_rig"),
    ".inference": ("ProjectStitch", "read_fisheyes", "stitch", "stitch_project"),
    ".network": ("build_model",),
    ".network.depth": ("DepthStitchNet",),
    ".network.losses": ("LossConfig", "StitchLoss", "VGG16Features", "load_vgg16"),
    ".network.model": ("ModelConfig", "StitchNet", "StitchOutput"),
    ".training": ("TrainingError", "TrainReport", "train"),
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
