"""The rotation between two cameras from matched bearings: closed form and RANSAC.

Convention: bearings are unit rays in each camera's own frame (x right, y down, z forward). The
rotation ``b_from_a`` takes camera a's bearings to camera b's: ``u_b = b_from_a @ u_a`` for a
world direction seen by both (the rig has no parallax: the scene is far away, or the cameras
share a centre). With world_from_cam rotations ``W_a``, ``W_b``: ``b_from_a = W_b.T @ W_a``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from jaxtyping import Bool, Float

from ..errors import RigjaxError


def rotation_from_bearings(
    u_a: Float[np.ndarray, "*batch n 3"], u_b: Float[np.ndarray, "*batch n 3"], weights=None
) -> Float[np.ndarray, "*batch 3 3"]:
    """The rotation ``R`` minimising ``sum w |u_b - R u_a|^2`` (Kabsch / Wahba by SVD).

    Batched over leading axes. A proper rotation (det +1) always; degenerate inputs (all
    bearings parallel) give one of the rotations that fit them.
    """
    u_a, u_b = np.asarray(u_a, float), np.asarray(u_b, float)
    if weights is not None:
        u_a = u_a * np.asarray(weights, float)[..., None]
    covariance = np.einsum("...ni,...nj->...ij", u_b, u_a)  # sum u_b u_a^T
    left, _, right_t = np.linalg.svd(covariance)
    sign = np.sign(np.linalg.det(left @ right_t))
    sign = np.where(sign == 0, 1.0, sign)
    fix = np.ones(covariance.shape[:-1])
    fix[..., 2] = sign
    return (left * fix[..., None, :]) @ right_t


def angle_between(u: Float[np.ndarray, "... 3"], v: Float[np.ndarray, "... 3"]) -> Float[np.ndarray, ...]:
    """Angle between unit vectors, radians, accurate for small angles too."""
    return 2.0 * np.arctan2(np.linalg.norm(u - v, axis=-1), np.linalg.norm(u + v, axis=-1))


class RansacResult(NamedTuple):
    b_from_a: Float[np.ndarray, "3 3"]
    inliers: Bool[np.ndarray, " n"]
    iterations: int


def ransac_rotation(
    u_a: Float[np.ndarray, "n 3"],
    u_b: Float[np.ndarray, "n 3"],
    *,
    threshold_deg: float = 1.0,
    iterations: int = 500,
    confidence: float = 0.999,
    seed: int = 0,
) -> RansacResult:
    """RANSAC of ``b_from_a`` with minimal samples of 2 bearings, then a refit on the inliers.

    A match is an inlier when ``b_from_a @ u_a`` lies within ``threshold_deg`` of ``u_b``. At most
    ``iterations`` samples are drawn; fewer when the best inlier ratio so far makes ``confidence``
    of having drawn an all-inlier sample (the classic adaptive stop). All hypotheses of a round
    are fitted and scored at once.
    """
    n = len(u_a)
    if n < 2:
        raise RigjaxError(f"RANSAC needs at least 2 matches, got {n}")
    rng = np.random.default_rng(seed)
    cos_threshold = np.cos(np.radians(threshold_deg))
    best, best_count, drawn, batch = None, -1, 0, 64
    needed = iterations
    while drawn < min(iterations, needed):
        first = rng.integers(0, n, batch)
        second = (first + rng.integers(1, n, batch)) % n  # a different match
        sample = np.stack([first, second], axis=1)
        rotations = rotation_from_bearings(u_a[sample], u_b[sample])
        predicted = np.einsum("kij,nj->kni", rotations, u_a)
        counts = (np.einsum("kni,ni->kn", predicted, u_b) >= cos_threshold).sum(axis=1)
        k = int(np.argmax(counts))
        if counts[k] > best_count:
            best, best_count = rotations[k], int(counts[k])
            ratio = best_count / n
            if ratio >= 1.0:
                needed = 0
            elif ratio > 0:
                needed = int(np.ceil(np.log(1 - confidence) / np.log(1 - ratio**2)))
        drawn += batch
    inliers = np.einsum("ij,nj,ni->n", best, u_a, u_b) >= cos_threshold
    for _ in range(3):  # refit on the inliers; the set can grow as the fit improves
        if inliers.sum() < 2:
            break
        best = rotation_from_bearings(u_a[inliers], u_b[inliers])
        refit = np.einsum("ij,nj,ni->n", best, u_a, u_b) >= cos_threshold
        if np.array_equal(refit, inliers):
            break
        inliers = refit
    return RansacResult(best, inliers, drawn)
