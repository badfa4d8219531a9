"""A calibrated rig to stitch: its cameras, their centres and their full-resolution images, from a
Hugin ``.pto`` project as ``rigjax calibrate`` or Hugin writes it.

The images are the files the ``i`` lines name (``n"..."``), relative to the project's folder as
Hugin's ``nona`` reads them, or images passed in their place (in the ``i`` lines' order). Camera
centres come from the project's ``#-rigjax centre`` lines (world metres, rigjax's frame); a project
without them is stitched as if every camera sat at the rig's centre: a rotation-only stitch.
Bad input — fewer than two images, a missing or unreadable image, an image of another size than
its ``i`` line, a lens rigjax does not model — is a :class:`rigjax.errors.ConfigError` (or
``ImageError``) naming the project and the image's ``i`` line.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

import rigjax
from rigjax.camera.photometry import PHOTOMETRIC_LETTERS, vignetting
from rigjax.camera.projections import Projection
from rigjax.errors import ConfigError, RigjaxError
from rigjax.pto.project import Project
from rigjax.pto.records import IMAGE_DEFAULTS, crop_circle
from rigjax.rendering.images import ImageError

if TYPE_CHECKING:
    from rigjax import Camera


class Rig(NamedTuple):
    """A rig ready to stitch: ``N >= 2`` cameras."""

    cameras: Camera  # (N,) rigjax cameras, NumPy fields
    centres: np.ndarray  # (N, 3) world metres (zeros: a rotation-only stitch)
    images: list[np.ndarray]  # N (h_i, w_i, 3) uint8 RGB
    names: list[str]  # how errors and reports name each image
    width: int  # the project's panorama width (its p line)
    has_centres: bool  # whether the project gave the centres
    # (N,) pixels from each circular fisheye's distortion centre to where its content ends (NaN: no
    # circle measured; the hfov's, for a circular fisheye); the sight tables turn it into an angle
    circle_px: np.ndarray | None = None
    crops: tuple[tuple[int, int, int, int] | None, ...] | None = None  # the i lines' crops (S), None: none
    # Each camera's photometry as its i line states it (exposure, white balance, vignetting: Hugin's,
    # as rigjax calibrate fits it), undone before the stitch: each pixel's colours times
    # 2^(Eev - E) / V(r) / (Er, 1, Eb), (h, w, 3) float32, E the p line's; None: neutral, nothing to
    # undo (photometry_undone)
    undo: tuple[np.ndarray | None, ...] | None = None

    def permuted(self, order: Sequence[int]) -> Rig:
        """The same rig with its cameras in ``order``."""
        order = list(order)
        take = np.asarray(order)
        return self._replace(
            cameras=self.cameras._replace(**{f: np.asarray(v)[take] for f, v in self.cameras._asdict().items()}),
            centres=self.centres[take],
            images=[self.images[k] for k in order],
            names=[self.names[k] for k in order],
            circle_px=None if self.circle_px is None else np.asarray(self.circle_px)[take],
            crops=None if self.crops is None else tuple(self.crops[k] for k in order),
            undo=None if self.undo is None else tuple(self.undo[k] for k in order),
        )


def _image_lines(project: Project) -> list[str]:
    """``where`` of each image for errors: ``rig.pto:LINE (image K)``, the line of its ``i`` line."""
    label = project.path or "the project"
    lines: list[int | None] = [None] * len(project.images)
    if project.path and os.path.isfile(project.path):
        with open(project.path, encoding="utf-8", errors="replace") as f:
            numbers = [n for n, text in enumerate(f, start=1) if text.lstrip().startswith("i ")]
        lines[: len(numbers)] = numbers[: len(lines)]
    return [f"{label}:{n} (image {k})" if n else f"{label}, image {k}" for k, n in enumerate(lines)]


def load_rig(
    project: Project | str | os.PathLike, images: Sequence[np.ndarray | str | os.PathLike] | None = None
) -> Rig:
    """The :class:`Rig` of ``project`` (a :class:`rigjax.Project` or a ``.pto`` path); ``images``
    replace the files its ``i`` lines name (arrays or paths, in their order). See the module
    docstring for the errors."""
    if not isinstance(project, Project):
        project = rigjax.load_project(project)
    label = project.path or "the project"
    where = _image_lines(project)
    count = len(project.images)
    if count < 2:
        raise ConfigError(f"{label}: {count} image{'s' if count != 1 else ''}; stitching needs at least 2 cameras")
    if images is not None and len(images) != count:
        raise ConfigError(f"{label} has {count} images, {len(images)} were given")
    try:
        cameras = project.cameras(host=True)
    except RigjaxError as error:
        raise ConfigError(f"{label}: {error}") from None
    folder = Path(project.path).resolve().parent if project.path else Path.cwd()
    pixels, names = [], []
    for k, image in enumerate(project.images):
        given = None if images is None else images[k]
        if given is None or not isinstance(given, np.ndarray):
            if given is None and not image.filename:
                raise ConfigError(f'{where[k]}: names no image file (n"..."); pass the images explicitly')
            path = Path(given) if given is not None else folder / image.filename
            try:
                array = rigjax.read_image(path)
            except ImageError as error:
                raise ImageError(f"{where[k]}: {error}") from None
            name = str(path)
        else:
            array, name = given, f"image {k}"
            if array.ndim != 3 or array.shape[2] != 3 or array.dtype != np.uint8:
                raise ImageError(f"{where[k]}: expected an (h, w, 3) uint8 RGB image, got {array.dtype} {array.shape}")
        if array.shape[:2] != (image.height, image.width):
            raise ImageError(
                f"{name}: {array.shape[1]} x {array.shape[0]} pixels, but {where[k]} is {image.width} x {image.height}"
            )
        pixels.append(array)
        names.append(name)
    has_centres = project.centres is not None
    centres = np.asarray(project.centres, np.float64) if has_centres else np.zeros((count, 3))
    circles = image_circles_px(project, pixels)
    crops = image_crops(project)
    undo = photometry_undone(project)
    return Rig(cameras, centres, pixels, names, int(project.panorama.width), has_centres, circles, crops, undo)


def photometry_undone(project: Project) -> tuple[np.ndarray | None, ...] | None:
    """What undoes each image's photometry as its ``i`` line states it (:attr:`Rig.undo`): Hugin's
    ``V(r) 2^-Eev (Er, 1, Eb)`` (:func:`rigjax.camera.photometry.image_gain`), inverted, to the
    panorama's exposure ``E`` (its ``p`` line's, as :func:`~rigjax.camera.photometry.to_panorama`
    and Hugin's ``nona`` take it; pixel values linear, Hugin's camera response not applied); ``V`` at
    least :data:`_MIN_VIGNETTING` (beyond the image circle a fitted polynomial can reach 0). None for
    a neutral image, and None for a project of neutral images at ``E`` 0. The stitch's own colour
    fit then refines what remains."""
    panorama = project.panorama.exposure_value
    undo = []
    for image in project.images:
        stated = (image.value(letter) != IMAGE_DEFAULTS[letter] for letter in PHOTOMETRIC_LETTERS if letter != "Eev")
        if image.exposure_value == panorama and not any(stated):
            undo.append(None)
            continue
        y, x = np.mgrid[: image.height, : image.width].astype(np.float64)
        falloff = np.maximum(vignetting(image, np.stack([x, y], -1)), _MIN_VIGNETTING)
        scale = falloff * 2.0 ** (panorama - image.exposure_value)
        balance = np.array([image.white_balance_red, 1.0, image.white_balance_blue])
        undo.append((1.0 / (scale[..., None] * balance)).astype(np.float32))
    return None if all(u is None for u in undo) else tuple(undo)


# The least V(r) a stated vignetting is undone by (-4.3 stops): a polynomial fitted inside the image
# circle may reach 0 beyond it, where the image is black anyway
_MIN_VIGNETTING = 0.05
# A pixel beyond a fisheye's image circle is black up to sensor noise and compression: brighter than
# this (0-255, any channel) is the image's content.
_CONTENT_LEVEL = 24
# The share of content pixels the circle holds (a stray bright pixel outside it does not count).
_CONTENT_SHARE = 0.9995


def image_crops(project: Project) -> tuple[tuple[int, int, int, int] | None, ...]:
    """Each image's crop as the stitch honours it (the ``i`` lines' ``S``): a circular crop
    (:attr:`rigjax.Image.circular_crop`, the sight tables keep the camera inside its circle) as
    given; a rectangle that holds the whole frame as none. Another rectangle is refused, naming the
    image: the stitch bounds such a lens by its frame alone."""
    crops = []
    for k, image in enumerate(project.images):
        crop = image.crop
        if crop is not None and not image.circular_crop:
            left, right, top, bottom = crop
            if not (left <= 0 and top <= 0 and right >= image.width and bottom >= image.height):
                raise ConfigError(
                    f"{project.path or 'the project'}, image {k}: a crop (S) inside the frame is honoured on "
                    f"circular fisheyes (f2) only, this lens is f{image.projection}: take the crop away or cut "
                    "the frame into the images"
                )
            crop = None
        crops.append(crop)
    return tuple(crops)


def image_circles_px(project: Project, images: Sequence[np.ndarray]) -> np.ndarray:
    """``(N,)`` :func:`image_circle_px` of each of ``project``'s images (``images`` their pixels,
    in the ``i`` lines' order), its lens and crop (:func:`image_crops`) read from its ``i`` line."""
    return np.array(
        [
            image_circle_px(int(i.projection), float(i.d), float(i.e), pixels, crop)
            for i, pixels, crop in zip(project.images, images, image_crops(project))
        ]
    )


def image_circle_px(
    projection: int, d: float, e: float, pixels: np.ndarray, crop: tuple[int, int, int, int] | None = None
) -> float:
    """Pixels from an image's distortion centre (its lens's shift ``d, e`` from the image's centre)
    to where its content ends (its pixels brighter than black), for a circular fisheye
    (``projection`` 2); NaN for other lenses (their frame bounds what they see) and for an image
    with no content. A lens's circle rarely spans exactly its calibrated hfov, and a stitch that
    reads the black beyond it draws a dark seam; :func:`learnstitch.fullres.sight.sight_tables`
    turns the radius into an angle through the lens.

    With a ``crop`` (the ``i`` line's ``S``, Hugin's; :class:`rigjax.Image`), only the content
    inside the circle it bounds counts: in Hugin's form of a dual-fisheye template both lenses'
    images are the whole frame, and the crop is what keeps each to its own circle (the sight
    tables keep each camera inside its crop's circle, :mod:`learnstitch.fullres.sight`)."""
    if projection != int(Projection.CIRCULAR_FISHEYE):
        return float("nan")
    height, width = pixels.shape[:2]
    cx = width / 2.0 - 0.5 + d
    cy = height / 2.0 - 0.5 + e
    content = np.maximum(np.maximum(pixels[..., 0], pixels[..., 1]), pixels[..., 2]) > _CONTENT_LEVEL
    if crop is not None:
        crop_x, crop_y, crop_r = crop_circle(crop)
        columns, rows = (np.arange(width) - crop_x) ** 2, (np.arange(height) - crop_y) ** 2
        content &= rows[:, None] + columns[None, :] <= crop_r**2
    count = int(np.count_nonzero(content))
    if count == 0:
        return float("nan")
    q = (count - 1) * _CONTENT_SHARE
    low = int(np.floor(q))
    ranks = [low, min(low + 1, count - 1)]
    # The two order statistics lie far out: only the content outside a disc around the centre that
    # holds fewer content pixels than the lower rank (its area, less a margin for the lattice) is
    # gathered. Every pixel inside that disc ranks below every one outside, so the ranks carry over.
    inner = 0.98 * low / np.pi  # the disc's squared radius
    outer = _content_outside(content, cx, cy, inner)
    below = count - outer.size  # content pixels inside the disc
    if below > low:  # content packed closer than the lattice margin allows (tiny images): all of it
        outer, below = _content_outside(content, cx, cy, -1.0), 0
    ordered = np.partition(outer, [r - below for r in ranks])
    lower, upper = np.sqrt(ordered[ranks[0] - below]), np.sqrt(ordered[ranks[1] - below])
    return float(lower + (q - low) * (upper - lower)) + 0.5


def _content_outside(content: np.ndarray, cx: float, cy: float, inner: float) -> np.ndarray:
    """The squared distances from ``(cx, cy)`` of ``content``'s pixels at or beyond ``inner``
    (a squared distance; -1: all of them), each ``(x - cx)**2 + (y - cy)**2`` in float64."""
    height, width = content.shape
    if inner > 0:  # each row's span well inside the disc skipped, a pixel to spare
        dy = (np.arange(height) - cy) ** 2
        half = np.sqrt(np.maximum(inner - dy, 0.0)) - 1.0
        starts = np.clip(np.ceil(cx - half), 0, width).astype(int)
        stops = np.clip(np.floor(cx + half) + 1, 0, width).astype(int)
        content = content.copy()
        for row in np.flatnonzero(stops > starts):
            content[row, starts[row] : stops[row]] = False
    y, x = np.nonzero(content)
    squares = (x - cx) ** 2 + (y - cy) ** 2
    return squares[squares >= inner]
