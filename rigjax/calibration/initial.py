"""Initial orientations in closed form from pairwise rotations, over a maximum spanning tree.

Every pair of images with enough RANSAC inliers gives a rotation ``b_from_a``
(:mod:`rigjax.calibration.ransac`). Starting from the anchor, whose orientation is given, images join one
at a time in order of most inliers (Prim's algorithm on the match graph with inlier counts as
weights: a maximum spanning tree), each from the image already placed that shares the most
inliers with it: ``world_from_cam(b) = world_from_cam(a) @ b_from_a.T``.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from jaxtyping import Float

from ..errors import RigjaxError


def orientations_from_pairs(
    n_images: int,
    pairs: Mapping[tuple[int, int], tuple[Float[np.ndarray, "3 3"], int]],
    *,
    anchor: int = 0,
    anchor_world_from_cam: Float[np.ndarray, "3 3"] | None = None,
) -> tuple[Float[np.ndarray, "n 3 3"], list[tuple[int, int]]]:
    """``world_from_cam`` of every image, and the tree's edges ``(placed, joined)`` in order.

    ``pairs[(a, b)] = (b_from_a, inliers)``. Raises, naming the images, when some image is not
    connected to the anchor by any pair.
    """
    rotations = np.zeros((n_images, 3, 3))
    rotations[anchor] = np.eye(3) if anchor_world_from_cam is None else anchor_world_from_cam
    placed, edges = {anchor}, []
    while len(placed) < n_images:
        best = None
        for (a, b), (b_from_a, count) in pairs.items():
            if (a in placed) == (b in placed) or count <= 0:
                continue
            if best is None or count > best[0]:
                best = (count, a, b, b_from_a)
        if best is None:
            missing = sorted(set(range(n_images)) - placed)
            raise RigjaxError(
                f"images {missing} share no matched pair with images {sorted(placed)}; "
                "they cannot be placed (more overlap, or a template with their orientations)"
            )
        _, a, b, b_from_a = best
        if a in placed:
            rotations[b] = rotations[a] @ b_from_a.T
            edges.append((a, b))
            placed.add(b)
        else:
            rotations[a] = rotations[b] @ b_from_a
            edges.append((b, a))
            placed.add(a)
    return rotations, edges
