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
any calibrated rig at full resolution (:mod:`learnstitch.fullres`) and a rig's clips into 360
video (:mod:`learnstitch.video`).
"""

from rigjax.lazy import lazy_exports

__version__ = "0.1.0"

# Each module and the public names it defines, imported on first use (see rigjax.lazy).
_EXPORTS = {
    "rigjax.errors": ("ConfigError",),
    ".baselines": (
        "calibrated_depth_stitch",
        "calibrated_stitch",
        "orientation_errors_deg",
        "psnr",
        "rig_template",
        "rotation_only_stitch",
        "ssim",
    ),
    ".checkpoint": ("load_model",),
    ".config": ("StitchConfig", "config_as_dict", "config_from_dict", "load_config"),
    ".curves": ("plot_learning_curves",),
    ".data.config": ("SynthConfig",),
    ".data.datasets": ("FolderDataset", "GeneratedDataset"),
    ".data.generate": ("synthesise",),
    ".data.sample": ("Sample", "make_sample"),
    ".evaluation": ("EvalReport", "evaluate"),
    ".fullres.config": ("RenderConfig",),
    ".fullres.rig": ("Rig", "load_rig"),
    ".fullres.stitcher": ("GivenDepth", "NetworkDepth", "PlaneSweep", "Stitched", "Stitcher"),
    ".inference": (
        "PreparedProject",
        "ProjectStitch",
        "prepare_project",
        "read_fisheyes",
        "stitch",
        "stitch_fisheyes",
        "stitch_project",
    ),
    ".network": ("build_model",),
    ".network.depth": ("DepthStitchNet",),
    ".network.losses": ("LossConfig", "StitchLoss"),
    ".network.model": ("ModelConfig", "StitchNet"),
    ".training": ("TrainingError", "TrainReport", "train"),
    ".video.batch": ("BatchReport", "stitch_batch"),
    ".video.pipeline": ("VideoReport", "stitch_video", "video_panoramas"),
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
