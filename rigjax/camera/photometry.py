"""Hugin's photometric model of an image: exposure, white balance and radial vignetting.

An image records the scene's light ``L`` (in the panorama's units at exposure value 0) as

    I = L * V(r) * 2^-Eev * (Er, 1, Eb)                       (red, green, blue)
    V(r) = Va + Vb r^2 + Vc r^4 + Vd r^6
    r = |xy - centre| / sqrt((w / 2)^2 + (h / 2)^2),   centre = ((w - 1) / 2 + Vx, (h - 1) / 2 + Vy)

and a panorama of exposure value ``E`` (its ``p`` line) shows ``L * 2^-E``, so the panorama pixel
drawn from image pixel ``xy`` is ``I * 2^(Eev - E) / (V(r) * (Er, 1, Eb))`` — Hugin's
``ResponseTransform`` with its ``calcVigFactor`` (radial mode), ``SrcPanoImage::getExposure``
(``1 / 2^Eev``) and ``getRadialVigCorrCenter``, for a linear camera response: rigjax applies the
model to the pixel values as they are (Hugin's camera response curve, ``Ra``..``Re``, is kept in the
project but not applied).

Convention: ``xy`` in Hugin's pixel coordinates of the whole image, pixel centres at integers,
``(0, 0)`` the centre of the top-left pixel (as control points). The functions take NumPy or JAX
arrays alike.
"""

from __future__ import annotations

import numpy as np

from ..pto.records import IMAGE_DEFAULTS, Image

PHOTOMETRIC_LETTERS = ("Eev", "Er", "Eb", "Va", "Vb", "Vc", "Vd", "Vx", "Vy")


def is_neutral(image: Image) -> bool:
    """Whether the image's photometric letters are Hugin's defaults (no exposure, white balance or
    vignetting to undo)."""
    return all(image.value(letter) == IMAGE_DEFAULTS[letter] for letter in PHOTOMETRIC_LETTERS)


def radius_squared(image: Image, xy):
    """``r^2`` (module docstring) at pixels ``xy`` ``(..., 2)`` of ``image``: ``(...)``, in half
    diagonals squared about the vignetting centre."""
    centre_x = (image.width - 1) / 2.0 + image.vignetting_x
    centre_y = (image.height - 1) / 2.0 + image.vignetting_y
    return ((xy[..., 0] - centre_x) ** 2 + (xy[..., 1] - centre_y) ** 2) / (
        (image.width / 2.0) ** 2 + (image.height / 2.0) ** 2
    )


def vignetting_polynomial(r2, a, b, c, d):
    """``V = a + b r^2 + c r^4 + d r^6`` at ``r2`` (``r^2``), by Horner's rule."""
    return a + r2 * (b + r2 * (c + r2 * d))


def vignetting(image: Image, xy):
    """``V(r)`` (module docstring) at pixels ``xy`` ``(..., 2)`` of ``image``: ``(...)``."""
    return vignetting_polynomial(
        radius_squared(image, xy), image.vignetting_a, image.vignetting_b, image.vignetting_c, image.vignetting_d
    )


def image_gain(image: Image, xy):
    """``(..., 3)``: what the image multiplies the scene's light by at pixels ``xy`` ``(..., 2)``:
    ``V(r) * 2^-Eev * (Er, 1, Eb)`` (module docstring)."""
    scale = vignetting(image, xy) * 2.0 ** (-image.exposure_value)
    return scale[..., None] * np.array([image.white_balance_red, 1.0, image.white_balance_blue])


def to_panorama(values, image: Image, xy, exposure_value: float = 0.0):
    """``(..., 3)``: image pixel values ``values`` at ``xy`` as a panorama of exposure value
    ``exposure_value`` shows them: ``values * 2^-E / image_gain`` (module docstring)."""
    return values * 2.0 ** (-exposure_value) / image_gain(image, xy)
