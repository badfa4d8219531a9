"""rigjax: a jit-compiled, differentiable JAX toolkit for multi-camera fisheye rigs.

Cameras follow the PanoTools model of Hugin and PTGui, read from and written to Hugin ``.pto``
projects. Geometry is exact to Hugin's in float64: enable it with
``jax.config.update("jax_enable_x64", True)`` (the ``rigjax`` command does).
"""

from . import synthetic
from .calibration.initial import orientations_from_pairs
from .calibration.levy import LevyConfig, levy_starts
from .calibration.pipeline import (
    Calibration,
    CalibrationError,
    PairMatches,
    calibrate,
    calibrate_cameras,
    calibrate_matches,
    match_images,
    split_side_by_side,
)
from .calibration.ransac import ransac_rotation, rotation_from_bearings
from .calibration.seam import match_in_seam_band
from .calibration.template import CalibrateConfig, RigTemplate, load_template, template_from_dict
from .camera.distortion import distort_radius, max_radius, undistort_radius
from .camera.lenses import Projection, focal_length
from .camera.model import Camera, img_to_ray, ray_to_img
from .camera.panorama import Equirect, pano_to_ray, ray_to_pano
from .camera.rotation import world_from_cam, ypr_from_world_from_cam
from .camera.trafo import img_to_pano, pano_to_img, transform_points
from .errors import ConfigError, PtoError, RigjaxError, UnsupportedError
from .optimiser.config import OptimiseConfig, RobustConfig, config_from_dict, load_config
from .optimiser.lm import SolverOptions
from .optimiser.prune import PruneConfig, PrunedResult, optimise_pruned, point_errors
from .optimiser.schedule import ScheduleError, Stage, parse_schedule
from .optimiser.staged import Evaluation, Result, StageReport, evaluate, optimise, optimise_batch
from .pto.project import Project, load_project, parse_project
from .pto.records import ControlPoints, Image, Mask, OptVariable, PanoramaLine
from .rendering.blend import render
from .rendering.images import ImageError, read_image, read_video_frame, write_image

__version__ = "0.1.0"

__all__ = [
    "CalibrateConfig",
    "Calibration",
    "CalibrationError",
    "Camera",
    "ConfigError",
    "ControlPoints",
    "Equirect",
    "Evaluation",
    "Image",
    "ImageError",
    "LevyConfig",
    "Mask",
    "OptVariable",
    "OptimiseConfig",
    "PairMatches",
    "PanoramaLine",
    "Project",
    "Projection",
    "PruneConfig",
    "PrunedResult",
    "PtoError",
    "Result",
    "RigTemplate",
    "RigjaxError",
    "RobustConfig",
    "ScheduleError",
    "SolverOptions",
    "Stage",
    "StageReport",
    "UnsupportedError",
    "calibrate",
    "calibrate_cameras",
    "calibrate_matches",
    "config_from_dict",
    "distort_radius",
    "evaluate",
    "focal_length",
    "img_to_pano",
    "img_to_ray",
    "levy_starts",
    "load_config",
    "load_project",
    "load_template",
    "match_images",
    "match_in_seam_band",
    "max_radius",
    "optimise",
    "optimise_batch",
    "optimise_pruned",
    "orientations_from_pairs",
    "pano_to_img",
    "pano_to_ray",
    "parse_project",
    "parse_schedule",
    "point_errors",
    "ransac_rotation",
    "ray_to_img",
    "ray_to_pano",
    "read_image",
    "read_video_frame",
    "render",
    "rotation_from_bearings",
    "split_side_by_side",
    "synthetic",
    "template_from_dict",
    "transform_points",
    "undistort_radius",
    "world_from_cam",
    "write_image",
    "ypr_from_world_from_cam",
]
