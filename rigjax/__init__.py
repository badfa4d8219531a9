"""rigjax: a jit-compiled, differentiable JAX toolkit for multi-camera fisheye rigs.

Cameras follow the PanoTools model of Hugin and PTGui, read from and written to Hugin ``.pto``
projects. Geometry is exact to Hugin's in float64: enable it with
``jax.config.update("jax_enable_x64", True)`` (the ``rigjax`` command does).
"""

from ._camera import Camera, img_to_ray, ray_to_img
from ._errors import PtoError, RigjaxError, UnsupportedError
from ._panorama import Equirect, pano_to_ray, ray_to_pano
from ._project import Image, Project, load_project, parse_project
from ._project_lines import ControlPoints, Mask, OptVariable, PanoramaLine
from ._projection import Projection, focal_length
from ._radial import distort_radius, max_radius, undistort_radius
from ._rotation import world_from_cam
from ._config import ConfigError, OptimiseConfig, RobustConfig, config_from_dict, load_config
from ._optimise import Evaluation, Result, SolverOptions, StageReport, evaluate, optimise, optimise_batch
from ._schedule import ScheduleError, Stage, parse_schedule
from ._trafo import img_to_pano, pano_to_img, transform_points
from ._prune import PruneConfig, PrunedResult, optimise_pruned, point_errors
from ._levy import LevyConfig, levy_starts
from ._ransac import ransac_rotation, rotation_from_bearings
from ._initial import orientations_from_pairs
from ._rotation import ypr_from_world_from_cam
from ._images import ImageError, read_image, read_video_frame, write_image
from ._render import render
from ._template import CalibrateConfig, RigTemplate, load_template, template_from_dict
from ._calibrate import (Calibration, CalibrationError, PairMatches, calibrate, calibrate_cameras, calibrate_matches,
                         match_images, split_side_by_side)
from ._seam import match_in_seam_band
from . import synthetic

__version__ = "0.1.0"

__all__ = [
    "CalibrateConfig",
    "Calibration",
    "CalibrationError",
    "ImageError",
    "LevyConfig",
    "PairMatches",
    "PruneConfig",
    "PrunedResult",
    "RigTemplate",
    "calibrate",
    "calibrate_cameras",
    "calibrate_matches",
    "levy_starts",
    "load_template",
    "match_images",
    "match_in_seam_band",
    "optimise_pruned",
    "point_errors",
    "orientations_from_pairs",
    "ransac_rotation",
    "read_image",
    "read_video_frame",
    "render",
    "rotation_from_bearings",
    "split_side_by_side",
    "synthetic",
    "template_from_dict",
    "write_image",
    "ypr_from_world_from_cam",
    "Camera",
    "ConfigError",
    "Evaluation",
    "OptimiseConfig",
    "Result",
    "RobustConfig",
    "ScheduleError",
    "SolverOptions",
    "Stage",
    "StageReport",
    "config_from_dict",
    "evaluate",
    "load_config",
    "optimise",
    "optimise_batch",
    "parse_schedule",
    "ControlPoints",
    "Equirect",
    "Image",
    "Mask",
    "OptVariable",
    "PanoramaLine",
    "Project",
    "Projection",
    "PtoError",
    "RigjaxError",
    "UnsupportedError",
    "distort_radius",
    "focal_length",
    "img_to_pano",
    "img_to_ray",
    "load_project",
    "max_radius",
    "pano_to_img",
    "pano_to_ray",
    "parse_project",
    "ray_to_img",
    "ray_to_pano",
    "transform_points",
    "undistort_radius",
    "world_from_cam",
]
