"""Equirectangular panoramas from a rig's images: ``rigjax.render`` and ``rigjax render``.

Each image is warped onto the canvas through the camera model (remap tables from
:mod:`rigjax.rendering.remap`, sampled by ``cv2.remap``), its exposure, white balance and vignetting
undone where the project gives them (Hugin's ``Eev``, ``Er``, ``Eb``, ``Va``..``Vd``, ``Vx``, ``Vy``,
the ``p`` line's ``E``: :mod:`rigjax.camera.photometry`), optionally gain-compensated (OpenCV's
``GainCompensator``), and blended by one of OpenCV's blenders:

- ``"multiband"``: every canvas pixel belongs to the image whose centre is nearest (a seam
  along the bisectors of the image centres); a Laplacian pyramid blends across the seams
  (``cv2.detail.MultiBandBlender``), so exposure steps spread over a wide band and detail keeps
  its sharpness.
- ``"feather"``: every image's whole valid area, weighted by the distance to its edge
  (``cv2.detail.FeatherBlender``).
- ``"none"``: the nearest image's pixel, no blending.

A canvas of 360 degrees wraps: its left and right edges are neighbours. The blenders see a canvas
widened on both sides by columns of the other side (as far as a blend reaches: the pyramid's support,
or the feather's ramp) and the middle is kept, so that a seam at +-180 degrees is blended like any
other and the panorama has no step where a viewer joins its edges.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import NamedTuple

import cv2
import numpy as np

from ..camera.panorama import Equirect
from ..camera.photometry import is_neutral, to_panorama
from ..errors import RigjaxError
from ..pto.project import Project
from .images import ImageError, read_image
from .remap import canvas_size, pano_maps

BLENDERS = ("multiband", "feather", "none")
_FEATHER_SHARPNESS = 0.02  # cv2.detail.FeatherBlender's weight: distance to the mask's edge (px) x this, at most 1


def project_images(project: Project) -> list[np.ndarray]:
    """The images a project names (``n`` tokens), read relative to the project's folder."""
    folder = os.path.dirname(os.path.abspath(project.path)) if project.path else os.getcwd()
    images = []
    for k, image in enumerate(project.images):
        if not image.filename:
            raise ImageError(f"image {k}: the project names no file for it; pass the images explicitly")
        images.append(read_image(os.path.join(folder, image.filename)))
    return images


def _check_images(project: Project, images: Sequence[np.ndarray], names: Sequence[str]) -> None:
    if len(images) != len(project.images):
        raise ImageError(f"the project has {len(project.images)} images, {len(images)} were given")
    for k, (image, pixels) in enumerate(zip(project.images, images)):
        if pixels.ndim != 3 or pixels.shape[2] != 3 or pixels.dtype != np.uint8:
            raise ImageError(f"{names[k]}: expected an (h, w, 3) uint8 RGB image, got {pixels.dtype} {pixels.shape}")
        if pixels.shape[:2] != (image.height, image.width):
            raise ImageError(
                f"{names[k]}: is {pixels.shape[1]}x{pixels.shape[0]}, but image {k} of the project is "
                f"{image.width}x{image.height}"
            )


def render(
    project: Project,
    images: Sequence[np.ndarray] | None = None,
    *,
    width: int | None = None,
    blend: str = "multiband",
    bands: int | None = None,
    exposure: bool = False,
    names: Sequence[str] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Render the project's images onto its equirectangular canvas.

    Args:
        project: cameras and the ``p`` line (equirectangular).
        images: ``(h, w, 3)`` uint8 RGB per image (default: the files the project names).
        width: output width in pixels (default the ``p`` line's); the height keeps the canvas's
            aspect ratio.
        blend: ``"multiband"``, ``"feather"`` or ``"none"``.
        bands: pyramid levels of the multi-band blender (default: from the width).
        exposure: equalise the images' gains in their overlaps first.
        names: how errors name the images (default ``image K``).

    Returns ``(panorama, covered)``: ``(H, W, 3)`` uint8 RGB and ``(H, W)`` bool, False where no
    image sees the canvas.
    """
    if blend not in BLENDERS:
        raise RigjaxError(f"blend must be one of {', '.join(BLENDERS)}, got {blend!r}")
    images = project_images(project) if images is None else list(images)
    names = list(names) if names is not None else [f"image {k}" for k in range(len(images))]
    _check_images(project, images, names)
    canvas = project.canvas()
    if width is not None:
        if width < 8:
            raise RigjaxError(f"width must be at least 8 pixels, got {width}")
        scale = width / float(canvas.width)
        canvas = Equirect.create(width, max(1, int(round(float(canvas.height) * scale))), canvas.hfov)
    out_w, out_h = canvas_size(canvas)
    warped, masks, closeness = [], [], []
    for k, (image, valid, maps) in enumerate(_warped(project, images, canvas)):
        warped.append(image)
        masks.append(valid)
        # How central a canvas pixel is in image k: 1 at the image centre, 0 at its corners.
        half = np.array([images[k].shape[1], images[k].shape[0]], np.float32) / 2.0
        offset = (maps - (half - 0.5)) / np.linalg.norm(half)
        closeness.append(np.where(valid, 1.0 - np.linalg.norm(offset, axis=-1), -np.inf))
    covered = np.any(masks, axis=0)
    if exposure:
        _compensate(warped, masks)
    nearest = np.argmax(np.stack(closeness), axis=0)
    if blend == "none":
        pano = np.zeros((out_h, out_w, 3), np.uint8)
        for k, image in enumerate(warped):
            own = (nearest == k) & covered
            pano[own] = image[own]
        return pano, covered
    if blend == "multiband":
        levels = bands if bands is not None else max(1, min(7, int(np.log2(out_w / 64))))
        blender = cv2.detail.MultiBandBlender(0, levels)
        weights = [((nearest == k) & covered).astype(np.uint8) * 255 for k in range(len(warped))]
        reach = 4 << levels  # a pyramid of 5-tap filters: 2 (2^L - 1) pixels down, as many up
    else:
        blender = cv2.detail.FeatherBlender(_FEATHER_SHARPNESS)
        weights = [mask.astype(np.uint8) * 255 for mask in masks]
        reach = int(np.ceil(1.0 / _FEATHER_SHARPNESS)) + 2  # the weight ramps up over 1 / sharpness pixels
    margin = min(reach, out_w) if float(canvas.hfov) >= 360.0 else 0
    blender.prepare((0, 0, out_w + 2 * margin, out_h))
    for image, weight in zip(warped, weights):
        blender.feed(_wrapped(image.astype(np.int16), margin), _wrapped(weight, margin), (0, 0))
    pano, _ = blender.blend(None, None)
    pano = np.clip(pano[:, margin : margin + out_w], 0, 255).astype(np.uint8)
    pano[~covered] = 0
    return pano, covered


def _warped(project: Project, images: Sequence[np.ndarray], canvas: Equirect, which: Sequence[int] | None = None):
    """Images ``which`` (default: all) warped onto ``canvas`` with their photometry undone:
    ``(warped uint8, valid, maps)`` per image, one at a time."""
    cameras = project.cameras()
    for k in range(len(images)) if which is None else which:
        pixels = images[k]
        image = project.images[k]
        maps, valid = pano_maps(
            cameras.take(k), canvas, circle=image.projection == 2, crop=image.crop, circular_crop=image.circular_crop
        )
        warped = cv2.remap(pixels, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        if not is_neutral(project.images[k]) or project.panorama.exposure_value != 0.0:
            warped = _photometric(warped, project.images[k], maps, valid, project.panorama.exposure_value)
        yield warped, valid, maps


class SeamDisagreement(NamedTuple):
    """How two images of a project differ where both see the canvas (the seam ring of a dual
    fisheye): the absolute difference of their luminance (0-255, image a's scaled so that its median
    in the overlap is image b's: the figure is in b's grey levels), its median and 90th percentile,
    and how many canvas pixels the overlap holds."""

    median: float
    p90: float
    pixels: int


def seam_disagreement(
    project: Project, images: Sequence[np.ndarray], a: int = 0, b: int = 1, *, width: int = 2048
) -> SeamDisagreement:
    """How images ``a`` and ``b`` (``(h, w, 3)`` uint8 RGB, the project's) disagree where both see
    a canvas ``width`` wide (:class:`SeamDisagreement`): what a seam shows of a calibration's error
    (and of the scene's parallax, which no rotation removes). Exposure-normalised: a gain between
    the two does not count, so that the figure speaks of the geometry."""
    _check_images(project, images, [f"image {k}" for k in range(len(images))])
    canvas = project.canvas()
    canvas = Equirect.create(width, max(1, int(round(float(canvas.height) * width / float(canvas.width)))), canvas.hfov)
    (image_a, valid_a, _), (image_b, valid_b, _) = _warped(project, images, canvas, (a, b))
    both = valid_a & valid_b & (image_a.max(-1) > 0) & (image_b.max(-1) > 0)
    if not both.any():
        raise RigjaxError(f"images {a} and {b} of the project see no common part of the canvas")
    luma = np.array([0.299, 0.587, 0.114])
    la, lb = image_a[both] @ luma, image_b[both] @ luma
    difference = np.abs(la * (np.median(lb) / max(np.median(la), 1e-9)) - lb)
    return SeamDisagreement(float(np.median(difference)), float(np.percentile(difference, 90)), int(both.sum()))


def _photometric(warped: np.ndarray, image, maps: np.ndarray, valid: np.ndarray, exposure_value: float) -> np.ndarray:
    """An image's warped pixels as the panorama shows them: its exposure, white balance and
    vignetting undone at the image pixels ``maps`` they came from (:mod:`rigjax.camera.photometry`)."""
    xy = np.where(valid[..., None], maps, 0.0).astype(np.float64)
    values = to_panorama(warped.astype(np.float64), image, xy, exposure_value)
    return np.where(valid[..., None], np.clip(np.round(values), 0, 255), 0).astype(np.uint8)


def _wrapped(canvas: np.ndarray, margin: int) -> np.ndarray:
    """A 360-degree canvas with ``margin`` columns of each side appended to the other."""
    return np.concatenate([canvas[:, -margin:], canvas, canvas[:, :margin]], axis=1) if margin else canvas


def _compensate(warped: list[np.ndarray], masks: list[np.ndarray]) -> None:
    """Equalise gains in place with OpenCV's least-squares gain compensator."""
    compensator = cv2.detail.ExposureCompensator_createDefault(cv2.detail.ExposureCompensator_GAIN)
    corners = [(0, 0)] * len(warped)
    umasks = [cv2.UMat(m.astype(np.uint8) * 255) for m in masks]
    compensator.feed(corners, [cv2.UMat(w) for w in warped], umasks)
    for k, image in enumerate(warped):
        warped[k] = compensator.apply(k, (0, 0), image, masks[k].astype(np.uint8) * 255)
        if isinstance(warped[k], cv2.UMat):
            warped[k] = warped[k].get()
