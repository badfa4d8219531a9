"""A Hugin project as the rig ``rigjax calibrate`` starts from (``--start rig.pto``).

A camera calibrated before, by Hugin, by PTGui through Hugin or by ``rigjax calibrate``, comes as a
project: each camera's lens (``v``, ``a``, ``b``, ``c``, centre shifts ``d``, ``e``), orientation
and crop (``S``). :func:`with_start` makes it the template's rig (``rig.lenses``,
``rig.orientations``): the calibration starts there, and the template's priors are about it rather
than about one nominal lens. The template keeps the rest: what to match, the schedule, the priors'
widths, the checks, the cameras' centres.

Hugin's templates for dual-fisheye cameras state every ``i`` line as the whole side-by-side frame,
each lens kept to its half by its crop; ``rigjax calibrate`` calibrates the halves. Such an image is
cut to its half (:func:`cut_image`): the same ray for the same pixel, in the half's pixels.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence

import numpy as np

from ..camera.lenses import focal_length, hfov_from_focal
from ..errors import RigjaxError
from ..pto.project import Project
from ..pto.records import Image, crop_circle
from .template import CalibrateConfig, LensStart


def cut_image(image: Image, left: int, top: int, width: int, height: int) -> Image:
    """``image``'s camera seen through its pixels ``left .. left + width - 1``,
    ``top .. top + height - 1`` as an image of its own, whose pixel ``(x, y)`` is ``image``'s
    ``(left + x, top + y)`` and sees the same ray: the focal length is kept (the hfov is the new
    width's), the centre's shifts ``d``, ``e``, the vignetting centre's ``Vx``, ``Vy`` and the crop
    move with the corner, and the vignetting polynomial is rescaled to the new half diagonal that
    normalises its radius. The radial polynomial is normalised by half the shorter side, and its
    ``a``, ``b``, ``c`` cannot be rescaled exactly (their complement ``1 - a - b - c`` is fixed), so
    the cut must keep that side (the halves of a 2:1 frame do); another raises ``RigjaxError``."""
    if min(width, height) != min(image.width, image.height) and (image.a, image.b, image.c) != (0.0, 0.0, 0.0):
        raise RigjaxError(
            f"a {width}x{height} cut of a {image.width}x{image.height} image changes the radius that "
            "normalises its distortion a, b, c (half the shorter side), which cannot be rescaled exactly"
        )
    try:
        hfov = hfov_from_focal(image.projection, width, float(focal_length(image.projection, image.width, image.hfov)))
    except ValueError as error:
        raise RigjaxError(f"a {width}x{height} cut of a {image.width}x{image.height} image: {error}") from None
    # The centre is at (W / 2 - 0.5, H / 2 - 0.5) of each image (rigjax.camera.model)
    shift_x = (image.width - width) / 2.0 - left
    shift_y = (image.height - height) / 2.0 - top
    diagonal_ratio_sq = (width**2 + height**2) / (image.width**2 + image.height**2)
    crop = image.crop
    return image.replace(
        width=width,
        height=height,
        hfov=hfov,
        d=image.d + shift_x,
        e=image.e + shift_y,
        vignetting_x=image.vignetting_x + shift_x,
        vignetting_y=image.vignetting_y + shift_y,
        vignetting_b=image.vignetting_b * diagonal_ratio_sq,
        vignetting_c=image.vignetting_c * diagonal_ratio_sq**2,
        vignetting_d=image.vignetting_d * diagonal_ratio_sq**3,
        crop=None if crop is None else (crop[0] - left, crop[1] - left, crop[2] - top, crop[3] - top),
    )


def _half(image: Image) -> int:
    """Which half of the whole side-by-side frame an image of Hugin's form is (0 left, 1 right):
    where its crop's centre lies, or without a crop its lens's centre."""
    centre = crop_circle(image.crop)[0] if image.crop is not None else image.width / 2.0 - 0.5 + image.d
    return int(centre >= image.width / 2.0)


def _as_calibrated(
    images: Sequence[Image], size: tuple[int, int], side_by_side: bool, where: str
) -> tuple[list[Image], list[int]]:
    """A start project's images as images of ``size``, and the camera each is: as they are, or,
    side by side, each cut to its half of the whole frame it states (Hugin's form), the camera its
    half's (images ``2j`` and ``2j + 1`` the two halves of frame image ``j``, in either order)."""
    width, height = size
    out, cameras = [], []
    for k, image in enumerate(images):
        if (image.width, image.height) == (width, height):
            out.append(image)
            cameras.append(k)
            continue
        if not (side_by_side and (image.width, image.height) == (2 * width, height)):
            halves = f", or the whole {2 * width}x{height} side-by-side frame" if side_by_side else ""
            raise RigjaxError(
                f"{where}, image {k}: it is {image.width}x{image.height}, but the calibrated images are "
                f"{width}x{height}: give a project of {width}x{height} images{halves}"
            )
        half = _half(image)
        try:
            out.append(cut_image(image, half * width, 0, width, height))
        except RigjaxError as error:
            raise RigjaxError(f"{where}, image {k}: {error}") from None
        cameras.append(2 * (k // 2) + half)
    if sorted(cameras) != list(range(len(images))):
        twice = next(c for c in cameras if cameras.count(c) > 1)
        both = [k for k, c in enumerate(cameras) if c == twice]
        raise RigjaxError(
            f"{where}: images {both[0]} and {both[1]} (crops {images[both[0]].crop}, {images[both[1]].crop}) are "
            f"both the {'right' if twice % 2 else 'left'} half of the side-by-side frame: give each lens its half"
        )
    return out, cameras


def with_start(
    config: CalibrateConfig, project: Project, size: tuple[int, int], *, source: str | os.PathLike[str] | None = None
) -> CalibrateConfig:
    """``config`` with ``project``'s cameras as its rig: each image's lens (``v``, ``a``, ``b``,
    ``c``, ``d``, ``e``), vignetting and crop as ``rig.lenses``, its yaw, pitch and roll as
    ``rig.orientations``, and one lens for all cameras (``rig.shared_lens``) where every image
    links ``v``, ``a``, ``b`` and ``c`` to the first. ``size`` is the ``(width, height)`` of the
    images to be calibrated (each half of a side-by-side frame); an image of the project is that
    size, or, with ``rig.side_by_side``, the whole frame (:func:`cut_image`), the camera of the half
    its crop is in. ``source`` names the project in errors (default its path). The project must
    have the template's number of cameras and one lens type."""
    where = os.fspath(source or project.path or "the start project")
    rig = config.rig
    images = project.images
    if len(images) != rig.cameras:
        raise RigjaxError(f"{where}: {len(images)} images, but the template describes {rig.cameras} cameras")
    types = sorted({image.projection for image in images})
    if len(types) > 1:
        raise RigjaxError(f"{where}: its images are of lens types {types}; a rig to calibrate has one")
    cut, cameras = _as_calibrated(images, tuple(size), rig.side_by_side, where)
    order = np.argsort(cameras)  # the project's image of each camera
    cut = [cut[k] for k in order]
    lenses = tuple(
        LensStart(
            i.hfov,
            i.a,
            i.b,
            i.c,
            i.d,
            i.e,
            i.crop,
            vignetting=(i.vignetting_b, i.vignetting_c, i.vignetting_d),
            vignetting_centre=(i.vignetting_x, i.vignetting_y),
        )
        for i in cut
    )
    shared = all(len({i.links.get(x, k) for k, i in enumerate(images)}) == 1 for x in "vabc")  # one lens
    return dataclasses.replace(
        config,
        rig=dataclasses.replace(
            rig,
            projection=types[0],
            hfov=sum(lens.v for lens in lenses) / len(lenses),
            b=lenses[0].b,
            shared_lens=shared,
            orientations=tuple((i.yaw, i.pitch, i.roll) for i in cut),
            lenses=lenses,
            image_size=(int(size[0]), int(size[1])),
        ),
    )


def start_sizes(images: Sequence, names: Sequence[str]) -> tuple[int, int]:
    """The one ``(width, height)`` of the images to be calibrated, which :func:`with_start` takes;
    images of different sizes raise, naming two."""
    sizes = {(image.shape[1], image.shape[0]) for image in images}
    if len(sizes) > 1:
        first = images[0].shape
        other = next(k for k, image in enumerate(images) if image.shape[:2] != first[:2])
        raise RigjaxError(
            f"{names[other]} is {images[other].shape[1]}x{images[other].shape[0]} but {names[0]} is "
            f"{first[1]}x{first[0]}: a start project's lenses are of one image size"
        )
    return next(iter(sizes))


__all__ = ["cut_image", "start_sizes", "with_start"]
