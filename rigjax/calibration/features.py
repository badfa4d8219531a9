"""Features and matches between a rig's images (OpenCV): SIFT or ORB, ratio test, mutual check.

Convention: feature positions are image pixels in Hugin's convention (x right, y down, ``(0, 0)``
the centre of the top-left pixel), which is also OpenCV's keypoint convention.

Detection is masked to where a lens sees anything: the image circle of a circular fisheye
(``f2``: half the hfov around the distortion centre), the whole frame otherwise.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np
from jaxtyping import Float, Int

from ..errors import RigjaxError

DETECTORS = ("sift", "orb")


class Features(NamedTuple):
    """Keypoints of one image: positions ``xy`` (n, 2) px, descriptors (n, d)."""

    xy: Float[np.ndarray, "n 2"]
    descriptors: np.ndarray


def lens_mask(width: int, height: int, *, circle_radius: float | None = None, centre=None) -> np.ndarray:
    """``(height, width)`` uint8 mask, 255 where features may be detected.

    ``circle_radius`` (px) restricts it to a circle around ``centre`` (default the image centre).
    """
    mask = np.full((height, width), 255, np.uint8)
    if circle_radius is not None:
        cx, cy = centre if centre is not None else (width / 2 - 0.5, height / 2 - 0.5)
        ys, xs = np.mgrid[0:height, 0:width]
        mask[(xs - cx) ** 2 + (ys - cy) ** 2 > circle_radius**2] = 0
    return mask


def detect(
    image: np.ndarray, *, detector: str = "sift", max_features: int = 4000, mask: np.ndarray | None = None
) -> Features:
    """Detect and describe up to ``max_features`` keypoints of an RGB (or grey) uint8 image."""
    if detector not in DETECTORS:
        raise RigjaxError(f"detector must be one of {', '.join(DETECTORS)}, got {detector!r}")
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    if detector == "sift":
        # The default upscaling of the first octave shifts keypoints by a fraction of a pixel, which
        # biased calibrations by ~1 arcmin; the precise upscale keeps Hugin's pixel-centre convention.
        engine = cv2.SIFT_create(nfeatures=max_features, enable_precise_upscale=True)
    else:
        engine = cv2.ORB_create(nfeatures=max_features, scoreType=cv2.ORB_FAST_SCORE)
    keypoints, descriptors = engine.detectAndCompute(grey, mask)
    xy = np.array([kp.pt for kp in keypoints], dtype=np.float64).reshape(-1, 2)
    if descriptors is None:
        descriptors = np.zeros((0, 128 if detector == "sift" else 32), np.float32 if detector == "sift" else np.uint8)
    return Features(xy, descriptors)


def match(a: Features, b: Features, *, ratio: float = 0.8, mutual: bool = True) -> Int[np.ndarray, "m 2"]:
    """Indices ``(i_a, i_b)`` of matched keypoints.

    Lowe's ratio test (nearest over second-nearest descriptor distance below ``ratio``) in both
    directions, and with ``mutual`` only pairs that are each other's nearest neighbour.
    """
    if len(a.xy) < 2 or len(b.xy) < 2:
        return np.zeros((0, 2), np.int64)
    norm = cv2.NORM_HAMMING if a.descriptors.dtype == np.uint8 else cv2.NORM_L2
    matcher = cv2.BFMatcher(norm)

    def one_way(x: Features, y: Features) -> dict[int, int]:
        best = {}
        for pair in matcher.knnMatch(x.descriptors, y.descriptors, k=2):
            if len(pair) == 2 and pair[0].distance < ratio * pair[1].distance:
                best[pair[0].queryIdx] = pair[0].trainIdx
        return best

    forward = one_way(a, b)
    if mutual:
        backward = one_way(b, a)
        pairs = [(i, j) for i, j in forward.items() if backward.get(j) == i]
    else:
        pairs = list(forward.items())
    return np.array(sorted(pairs), dtype=np.int64).reshape(-1, 2)
