"""rigjax: a jit-compiled, differentiable JAX toolkit for multi-camera fisheye rigs.

Cameras follow the PanoTools model of Hugin and PTGui, read from and written to Hugin ``.pto``
projects. Geometry is exact to Hugin's in float64: enable it with
``jax.config.update("jax_enable_x64", True)`` (the ``rigjax`` command does).
"""

from .lazy import lazy_exports

__version__ = "0.1.0"

# The public API, by intent: what the README and the guides use. Everything else stays importable
# from its module (``from rigjax.calibration.ransac import ransac_rotation``). Each module and the
# public names it defines, imported on first use (see rigjax.lazy); tests/test_imports.py lists them.
_EXPORTS = {
    # the camera model and its transforms
    ".camera.projections": ("Projection",),
    ".camera.model": ("Camera", "img_to_ray", "ray_to_img"),
    ".camera.panorama": ("Equirect", "pano_to_ray", "ray_to_pano"),
    ".camera.rotation": ("world_from_cam", "ypr_from_world_from_cam"),
    ".camera.trafo": ("img_to_pano", "pano_to_img", "transform_points"),
    # .pto projects
    ".pto.project": ("Project", "load_project", "parse_project"),
    ".pto.records": ("ControlPoints", "Image", "OptVariable", "PanoramaLine"),
    # optimising a rig
    ".optimiser.bundle": ("bundle_adjust",),
    ".optimiser.config": ("OptimiseConfig", "PruneConfig", "RobustConfig", "config_from_dict", "load_config"),
    ".optimiser.job": ("OptimiseJob", "OptimiseOutcome", "optimise_job"),
    ".optimiser.options": ("SolverOptions",),
    ".optimiser.prune": ("optimise_pruned", "point_errors"),
    ".optimiser.result": ("OptimiseResult",),
    ".optimiser.staged": ("evaluate", "optimise", "optimise_batch"),
    # calibrating from images
    ".calibration.circle": ("find_image_circle", "lens_from_circle"),
    ".calibration.exposure": ("fit_exposure",),
    ".calibration.job": ("CalibrateJob", "CalibrateOutcome", "calibrate_job"),
    ".calibration.levy": ("LevyConfig",),
    ".calibration.motion": ("MotionConfig",),
    ".calibration.pipeline": (
        "Calibration",
        "CalibrationError",
        "calibrate",
        "calibrate_frames",
        "calibrate_matches",
        "calibrate_motion",
        "frames_of",
        "match_images",
        "pool_matches",
        "split_side_by_side",
    ),
    ".calibration.seam": ("match_in_seam_band",),
    ".calibration.start": ("cut_image", "with_start"),
    ".calibration.template": ("CalibrateConfig", "load_template", "template_from_dict"),
    # images, panoramas and processes
    ".rendering.blend": ("render", "seam_disagreement"),
    ".rendering.images": ("ImageError", "read_image", "read_video_frames", "write_image"),
    ".rendering.job": ("RenderJob", "RenderOutcome", "render_job"),
    ".compiled": ("persist",),
    ".worker": ("setup_worker",),
    ".synthetic": ("synthetic",),
    ".errors": ("ConfigError", "PtoError", "RigjaxError", "UnsupportedError"),
    ".optimiser.schedule": ("ScheduleError",),
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
