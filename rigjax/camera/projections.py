"""The lens projection codes of a ``.pto`` ``i`` line (``f`` token), apart from their JAX maps
(:mod:`rigjax.camera.lenses`) so that the ``.pto`` reader loads without JAX."""

from __future__ import annotations

from enum import IntEnum


class Projection(IntEnum):
    """Image projection codes of a ``.pto`` ``i`` line (``f`` token)."""

    RECTILINEAR = 0
    CIRCULAR_FISHEYE = 2
    FULL_FRAME_FISHEYE = 3
    EQUIRECTANGULAR = 4
    ORTHOGRAPHIC = 8
    STEREOGRAPHIC = 10
    EQUISOLID = 21


SUPPORTED_PROJECTIONS: tuple[int, ...] = tuple(int(p) for p in Projection)
