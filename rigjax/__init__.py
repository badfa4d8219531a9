"""rigjax: a jit-compiled, differentiable JAX toolkit for multi-camera fisheye rigs.

Cameras follow the PanoTools model of Hugin and PTGui, read from and written to Hugin ``.pto``
projects. Geometry is exact to Hugin's in float64: enable it with
``jax.config.update("jax_enable_x64", True)`` (the ``rigjax`` command does).
"""

from .lazy import lazy_exports

__version__ = "0.1.0"

# Each module and the public names it defines, imported on first use (see rigjax.lazy).
_EXPORTS = {
    ".synthetic": ("synthetic",),
    ".calibration.initial": ("orientations_from_pairs",),
    ".calibration.levy": ("LevyConfig", "levy_starts"),
    ".calibration.pipeline": (
        "Calibration",
        "CalibrationError",
        "PairMatches",
        "calibrate",
        "calibrate_cameras",
        "calibrate_frames",
        "calibrate_matches",
        "frames_of",
        "match_images",
        "pool_matches",
        "split_side_by_side",
    ),
    ".calibration.job": ("CalibrateJob", "CalibrateOutcome", "calibrate_job"),
    ".calibration.checks": ("ChecksConfig", "undetermined"),
    ".calibration.circle": ("ImageCircle", "find_image_circle", "lens_from_circle"),
    ".calibration.exposure": ("ExposureFit", "fit_exposure"),
    ".calibration.ransac": ("ransac_rotation", "rotation_from_bearings"),
    ".calibration.seam": ("match_in_seam_band",),
    ".calibration.template": ("CalibrateConfig", "RigTemplate", "load_template", "template_from_dict"),
    ".camera.distortion": ("distort_radius", "max_radius", "undistort_radius"),
    ".camera.lenses": ("Projection", "focal_length"),
    ".camera.model": ("Camera", "img_to_ray", "ray_to_img"),
    ".camera.photometry": ("image_gain", "to_panorama", "vignetting"),
    ".camera.panorama": ("Equirect", "pano_to_ray", "ray_to_pano"),
    ".camera.rotation": ("world_from_cam", "ypr_from_world_from_cam"),
    ".camera.trafo": ("img_to_pano", "pano_to_img", "transform_points"),
    ".compiled": ("persist",),
    ".errors": ("ConfigError", "PtoError", "RigjaxError", "UnsupportedError"),
    ".optimiser.bundle": ("BundleResult", "BundleStageReport", "bundle_adjust"),
    ".optimiser.config": ("OptimiseConfig", "PruneConfig", "RobustConfig", "config_from_dict", "load_config"),
    ".optimiser.options": ("SolverOptions",),
    ".optimiser.prune": ("PrunedResult", "optimise_pruned", "point_errors"),
    ".optimiser.result": ("OptimiseResult",),
    ".optimiser.schedule": ("ScheduleError", "Stage", "parse_schedule"),
    ".optimiser.staged": ("Evaluation", "Result", "StageReport", "evaluate", "optimise", "optimise_batch"),
    ".pto.project": ("Project", "load_project", "parse_project"),
    ".pto.records": ("ControlPoints", "Image", "Mask", "OptVariable", "PanoramaLine"),
    ".rendering.blend": ("SeamDisagreement", "render", "seam_disagreement"),
    ".rendering.images": ("ImageError", "read_image", "read_video_frame", "read_video_frames", "write_image"),
    ".rendering.job": ("RenderJob", "RenderOutcome", "render_job"),
    ".worker": ("setup_worker",),
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
