"""Matching two cameras in a common equirectangular band around their seam: features matched
there (narrow overlaps), or a grid of points tracked from one band into the other (matches over
the whole overlap, for rigs whose cameras sit apart).

Back-to-back fisheyes (dual-fisheye 360 cameras) overlap in a thin ring at the edge of each image
circle, where the lens squeezes the scene and each camera sees it turned by 180 degrees: features
match poorly there, or not at all. Instead, both images are resampled with the template's nominal
geometry onto one equirectangular band whose equator is the seam, the great circle of directions
equally far from both optical axes, so that both bands show the overlap alike. Features are
detected and matched in the bands, and each match is mapped back to its image's pixels through
the same nominal model, exactly: only the resampling, not the nominal geometry's error, enters
the matched positions.

Band frame: its ``y`` axis (the band's pole) is the difference of the two optical axes, so its
equator is the seam; longitude 0 lies towards the sum of the axes (or, for cameras exactly back to
back, towards the world's ``y`` axis made perpendicular). The band spans 360 degrees of longitude and
``band_deg`` either side of the seam, at the cameras' own pixel scale (their mean focal length).
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

from ..camera.model import Camera, map_points, ray_to_img
from ..camera.panorama import Equirect, pano_to_ray
from ..camera.rotation import ypr_from_world_from_cam
from ..errors import RigjaxError
from ..rendering.remap import pano_maps
from .features import detect, match
from .ransac import ransac_rotation


def band_from_world(axis_a: np.ndarray, axis_b: np.ndarray) -> np.ndarray:
    """The rotation from world rays to the seam band's frame of two cameras' optical axes."""
    pole = np.asarray(axis_a, float) - np.asarray(axis_b, float)
    if np.linalg.norm(pole) < 1e-6:
        raise RigjaxError("the two cameras look the same way: they have no seam to match in")
    pole /= np.linalg.norm(pole)
    front = np.asarray(axis_a, float) + np.asarray(axis_b, float)
    front -= pole * (pole @ front)
    if np.linalg.norm(front) < 1e-3:  # back to back: any direction on the seam will do
        helper = np.eye(3)[np.argmin(np.abs(pole))] if abs(pole[1]) > 0.9 else np.array([0.0, 1.0, 0.0])
        front = helper - pole * (pole @ helper)
    front /= np.linalg.norm(front)
    return np.stack([np.cross(pole, front), pole, front])


def _band_rotation(camera_a: Camera, camera_b: Camera) -> np.ndarray:
    """:func:`band_from_world` of two cameras (batch shape ``()``)."""
    return band_from_world(np.asarray(camera_a.world_from_cam)[:, 2], np.asarray(camera_b.world_from_cam)[:, 2])


def _in_band_frame(camera: Camera, rotation: np.ndarray) -> Camera:
    ypr = np.asarray(ypr_from_world_from_cam(rotation @ np.asarray(camera.world_from_cam)))
    return camera._replace(
        **{k: np.asarray(v, np.asarray(camera.hfov).dtype) for k, v in zip(("yaw", "pitch", "roll"), ypr)}
    )


def seam_bands(
    image_a: np.ndarray,
    image_b: np.ndarray,
    camera_a: Camera,
    camera_b: Camera,
    *,
    band_deg: float,
    circle: bool = False,
) -> tuple[list[np.ndarray], list[np.ndarray], list[Camera], Equirect]:
    """Both images resampled onto their seam band: ``(bands, masks, cameras in the band frame, canvas)``.

    ``masks`` (uint8, 255 where a feature may be detected) keep a few pixels away from where an
    image ends, so that its border is not taken for a feature. With ``circle`` (circular
    fisheyes) an image ends at half its hfov off the optical axis.
    """
    rotation = _band_rotation(camera_a, camera_b)
    focal = 0.5 * (float(camera_a.focal) + float(camera_b.focal))
    width = int(round(2 * np.pi * focal))
    height = 2 * int(np.ceil(np.radians(band_deg) * focal))
    canvas = Equirect.create(width, height, 360.0, dtype=np.asarray(camera_a.hfov).dtype)
    bands, masks, cameras = [], [], []
    for image, camera in ((image_a, camera_a), (image_b, camera_b)):
        camera = _in_band_frame(camera, rotation)
        maps, valid = pano_maps(camera, canvas, circle=circle)
        band = cv2.remap(image, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        band[~valid] = 0
        bands.append(band)
        masks.append(cv2.erode(valid.astype(np.uint8) * 255, np.ones((9, 9), np.uint8)))
        cameras.append(camera)
    return bands, masks, cameras, canvas


def _to_images(cameras: list[Camera], canvas: Equirect, band_a: np.ndarray, band_b: np.ndarray):
    """Matched band pixels mapped back to their images' pixels through the cameras that made the
    bands: ``(xy_a, xy_b)``, the matches that both cameras map."""
    out = [
        map_points(ray_to_img, camera, np.asarray(pano_to_ray(canvas, np.asarray(xy, np.float64))))
        for camera, xy in zip(cameras, (band_a, band_b))
    ]
    keep = out[0][1] & out[1][1]
    return out[0][0][keep], out[1][0][keep]


class _BandMatches(NamedTuple):
    """The feature matches of two bands: positions in band a and b."""

    xy_a: np.ndarray
    xy_b: np.ndarray

    @classmethod
    def of(
        cls,
        bands: list[np.ndarray],
        masks: list[np.ndarray],
        *,
        detector: str = "sift",
        max_features: int = 4000,
        ratio: float = 0.8,
        mutual: bool = True,
    ) -> _BandMatches:
        features = [
            detect(band, detector=detector, max_features=max_features, mask=mask) for band, mask in zip(bands, masks)
        ]
        index = match(features[0], features[1], ratio=ratio, mutual=mutual)
        return cls(features[0].xy[index[:, 0]], features[1].xy[index[:, 1]])

    def consistent(self, canvas: Equirect, baseline: np.ndarray | None, threshold_deg: float) -> _BandMatches:
        """The matches that one small turn of band b explains: their rays (band frame) within
        ``threshold_deg`` of each other or, with the cameras' ``baseline`` (band frame), of the
        epipolar plane of the nominal centres, so that near points stay (RANSAC,
        :func:`~rigjax.calibration.ransac.ransac_rotation`). Fewer than 3 matches stay as they are."""
        if len(self.xy_a) < 3:
            return self
        rays = [np.asarray(pano_to_ray(canvas, xy.astype(np.float64))) for xy in (self.xy_a, self.xy_b)]
        kept = ransac_rotation(*rays, threshold_deg=threshold_deg, baseline=baseline).inliers
        return _BandMatches(self.xy_a[kept], self.xy_b[kept])

    def guess(self, points: np.ndarray, reverse: bool = False, k: int = 7) -> np.ndarray:
        """Where ``points`` of band a (of band b, ``reverse``) lie in the other band: each moved by
        the median displacement of its ``k`` nearest matches (not moved, with fewer than ``k``)."""
        here, there = (self.xy_b, self.xy_a) if reverse else (self.xy_a, self.xy_b)
        if len(here) < k:
            return points.copy()
        nearest = np.argsort(np.sum((points[:, None, :] - here[None, :, :]) ** 2, axis=-1), axis=1)[:, :k]
        return points + np.median((there - here)[nearest], axis=1)


def match_in_seam_band(
    image_a: np.ndarray,
    image_b: np.ndarray,
    camera_a: Camera,
    camera_b: Camera,
    *,
    band_deg: float,
    circle: bool = False,
    detector: str = "sift",
    max_features: int = 4000,
    ratio: float = 0.8,
    mutual: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Matched pixels ``(xy_a, xy_b)`` of two images, found in their seam band (module docstring).

    ``camera_a``, ``camera_b``: the images' nominal cameras (batch shape ``()``).
    """
    bands, masks, cameras, canvas = seam_bands(image_a, image_b, camera_a, camera_b, band_deg=band_deg, circle=circle)
    matched = _BandMatches.of(bands, masks, detector=detector, max_features=max_features, ratio=ratio, mutual=mutual)
    return _to_images(cameras, canvas, matched.xy_a, matched.xy_b)


def _normalised(grey: np.ndarray, mask: np.ndarray, sigma_px: float = 8.0) -> np.ndarray:
    """``grey`` less its local mean, over its local spread (Gaussian ``sigma_px``), as uint8: the
    two cameras' gains and vignetting, which fall off in opposite directions across a seam and
    would pull Lucas-Kanade's estimates apart, are gone. Outside ``mask``, the mean grey."""
    image = grey.astype(np.float32)
    weight = cv2.GaussianBlur((mask > 0).astype(np.float32), (0, 0), sigma_px) + 1e-6
    mean = cv2.GaussianBlur(image * (mask > 0), (0, 0), sigma_px) / weight
    detail = (image - mean) * (mask > 0)
    spread = np.sqrt(cv2.GaussianBlur(detail * detail, (0, 0), sigma_px) / weight) + 2.0
    return np.clip(128.0 + 32.0 * detail / spread, 0, 255).astype(np.uint8)


def track_in_seam_band(
    image_a: np.ndarray,
    image_b: np.ndarray,
    camera_a: Camera,
    camera_b: Camera,
    *,
    band_deg: float,
    circle: bool = False,
    step_px: int = 4,
    window_px: int = 21,
    consistency_px: float = 0.5,
    min_texture: float = 1e-4,
    baseline: np.ndarray | None = None,
    seed_threshold_deg: float | None = 2.0,
    seeded: bool = True,
    **features,
) -> tuple[np.ndarray, np.ndarray]:
    """Matched pixels ``(xy_a, xy_b)`` of two images, tracked from a grid over their seam band.

    Both bands show the overlap alike up to the nominal geometry's error and the parallax, a
    few pixels for most of the scene, so each textured point of band a is followed into band b
    by pyramidal Lucas-Kanade (OpenCV), to the overlap's edges, where features are few. Points
    lie on a grid of ``step_px`` band pixels where band a has texture (the smaller eigenvalue of
    its structure tensor over 7 x 7 pixels, grey levels in [0, 1], at least ``min_texture``); a
    point is kept where tracking it back from band b returns within ``consistency_px`` of where
    it started (occlusions, repeated texture and lost tracks do not). Each point is tracked on
    its own, so a near object's large parallax disturbs only its own points. Each way starts from
    the median displacement of the nearest feature matches in the bands (``features``: the options
    of :func:`match_in_seam_band`), those of them that one small turn of band b explains within
    ``seed_threshold_deg`` (RANSAC; ``None``: all of them) — with ``baseline`` (camera b's centre
    less camera a's, world frame), up to each match's epipolar plane through the nominal centres,
    so that near points seed their neighbours too. Without ``seeded`` (the cameras are a
    calibration's, whose bands show far content in place), each way starts where it is.
    """
    bands, masks, cameras, canvas = seam_bands(image_a, image_b, camera_a, camera_b, band_deg=band_deg, circle=circle)
    grey = [cv2.cvtColor(band, cv2.COLOR_RGB2GRAY) if band.ndim == 3 else band for band in bands]
    height, width = grey[0].shape
    texture = cv2.cornerMinEigenVal(grey[0].astype(np.float32) / 255.0, 7, 3)
    grey = [_normalised(g, mask) for g, mask in zip(grey, masks)]
    ys, xs = np.mgrid[step_px // 2 : height : step_px, step_px // 2 : width : step_px]
    ys, xs = ys.ravel(), xs.ravel()
    chosen = (masks[0][ys, xs] > 0) & (texture[ys, xs] >= min_texture)
    start = np.stack([xs[chosen], ys[chosen]], axis=-1).astype(np.float32).reshape(-1, 1, 2)
    if len(start) == 0:
        return np.zeros((0, 2)), np.zeros((0, 2))
    lk = dict(winSize=(window_px, window_px), maxLevel=3)
    # Both directions start from a guess of their own (the bands differ by the nominal geometry's
    # error, several pixels that vary along the band, and by parallax): close enough, tracking
    # does not lock on a neighbouring period of a periodic texture (a facade's windows), and the
    # way back checks the way there.
    # The feature matches that seed them are few (tens) and a third of them can be wrong: those one
    # small turn of the band (and, with the centres, the epipolar constraint) does not explain go.
    if seeded:
        matched = _BandMatches.of(bands, masks, **features)
        if seed_threshold_deg is not None:
            if baseline is not None:
                baseline = _band_rotation(camera_a, camera_b) @ np.asarray(baseline, float)
            matched = matched.consistent(canvas, baseline, seed_threshold_deg)
    else:  # the cameras are calibrated: far content lies where it is in both bands
        matched = _BandMatches(np.zeros((0, 2)), np.zeros((0, 2)))
    guess = matched.guess(start[:, 0].astype(np.float64))[:, None].astype(np.float32)
    end, found, _ = cv2.calcOpticalFlowPyrLK(grey[0], grey[1], start, guess, flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **lk)
    guess_back = matched.guess(end[:, 0].astype(np.float64), reverse=True)[:, None].astype(np.float32)
    back, found_back, _ = cv2.calcOpticalFlowPyrLK(
        grey[1], grey[0], end, guess_back, flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **lk
    )
    start, end, back = start[:, 0], end[:, 0], back[:, 0]
    column, row = np.round(end).astype(int).T
    inside_b = (column >= 0) & (column < width) & (row >= 0) & (row < height)
    inside_b[inside_b] = masks[1][row[inside_b], column[inside_b]] > 0
    keep = (
        (found[:, 0] == 1)
        & (found_back[:, 0] == 1)
        & inside_b
        & (np.linalg.norm(back - start, axis=-1) < consistency_px)
    )
    return _to_images(cameras, canvas, start[keep], end[keep])


__all__ = ["band_from_world", "match_in_seam_band", "seam_bands", "track_in_seam_band"]
