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
    baseline: np.ndarray | None = None,
) -> RansacResult:
    """RANSAC of ``b_from_a`` with minimal samples of 2 bearings, then a refit on the inliers.

    A match is an inlier when ``b_from_a @ u_a`` lies within ``threshold_deg`` of ``u_b``. With the
    cameras' ``baseline`` (camera b's centre from camera a's, in camera a's frame; any length), a
    match is one instead when ``u_b``, turned into camera a's frame, lies within ``threshold_deg``
    of the epipolar plane through the baseline and ``u_a``: a near point, which no rotation
    explains, still agrees, as long as its two rays meet. The rotation is refitted to the inliers
    it maps within ``threshold_deg`` (the far ones); it only starts the bundle adjustment. At most
    ``iterations`` samples are drawn; fewer when the best inlier ratio so far makes ``confidence``
    of having drawn an all-inlier sample (the classic adaptive stop). All hypotheses of a round
    are fitted and scored at once.
    """
    n = len(u_a)
    if n < 2:
        raise RigjaxError(f"RANSAC needs at least 2 matches, got {n}")
    rng = np.random.default_rng(seed)
    cos_threshold = np.cos(np.radians(threshold_deg))
    normal = None
    if baseline is not None and np.linalg.norm(baseline) > 0:
        normal = np.cross(np.asarray(baseline, float), u_a)  # each match's epipolar plane in camera a
        length = np.linalg.norm(normal, axis=-1, keepdims=True)
        planar = length[:, 0] > 1e-12  # a ray along the baseline has no plane
        normal = np.where(planar[:, None], normal / np.where(planar[:, None], length, 1.0), 0.0)

    def agree(rotations: np.ndarray) -> np.ndarray:
        """``(k, n)``: which matches each of the rotations ``(k, 3, 3)`` explains."""
        if normal is None:
            return np.einsum("kij,nj,ni->kn", rotations, u_a, u_b) >= cos_threshold
        in_a = np.einsum("kji,nj->kni", rotations, u_b)  # b_from_a.T @ u_b
        off_plane = np.abs(np.einsum("kni,ni->kn", in_a, normal))
        return (off_plane <= np.sqrt(1.0 - cos_threshold**2)) & planar

    best, best_count, drawn, batch = None, -1, 0, 64
    needed = iterations
    while drawn < min(iterations, needed):
        first = rng.integers(0, n, batch)
        second = (first + rng.integers(1, n, batch)) % n  # a different match
        sample = np.stack([first, second], axis=1)
        rotations = rotation_from_bearings(u_a[sample], u_b[sample])
        counts = agree(rotations).sum(axis=1)
        k = int(np.argmax(counts))
        if counts[k] > best_count:
            best, best_count = rotations[k], int(counts[k])
            ratio = best_count / n
            if ratio >= 1.0:
                needed = 0
            elif ratio > 0:
                needed = int(np.ceil(np.log(1 - confidence) / np.log(1 - ratio**2)))
        drawn += batch

    def far(rotation: np.ndarray, inliers: np.ndarray) -> np.ndarray:
        """The inliers a rotation explains too: with a baseline, the near points are left out of
        the refit, whose rotation they would pull."""
        if normal is None:
            return inliers
        return inliers & (np.einsum("ij,nj,ni->n", rotation, u_a, u_b) >= cos_threshold)

    inliers = agree(best[None])[0]
    for _ in range(3):  # refit on the inliers; the set can grow as the fit improves
        fitted = far(best, inliers)
        if fitted.sum() < 2:
            break
        best = rotation_from_bearings(u_a[fitted], u_b[fitted])
        refit = agree(best[None])[0]
        if np.array_equal(refit, inliers):
            break
        inliers = refit
    return RansacResult(best, inliers, drawn)


def _essential(u_a: np.ndarray, u_b: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)``: the essential matrix ``E`` of least ``sum (u_b^T E u_a)^2`` over unit
    ``E`` (the eight-point algorithm on bearings, batched over leading axes), projected onto
    essential matrices (two equal singular values, one zero)."""
    rows = np.einsum("...ni,...nj->...nij", u_b, u_a).reshape(*u_a.shape[:-1], 9)
    _, _, right_t = np.linalg.svd(rows)
    essential = right_t[..., -1, :].reshape(*u_a.shape[:-2], 3, 3)
    left, _, right_t = np.linalg.svd(essential)
    return left @ np.diag([1.0, 1.0, 0.0]) @ right_t


ALONE_SHARE = 0.9  # ransac_turn: the rotation alone where it explains this share of what E does


def ransac_turn(
    u_a: Float[np.ndarray, "n 3"],
    u_b: Float[np.ndarray, "n 3"],
    *,
    threshold_deg: float = 0.5,
    iterations: int = 512,
    seed: int = 0,
) -> RansacResult:
    """The rotation ``b_from_a`` of a camera that turned and may have moved between two views,
    its scene near or far: RANSAC of the essential matrix ``E = [t]x b_from_a`` (samples of 8
    bearings, :func:`_essential`), a match an inlier when ``u_b`` lies within ``threshold_deg`` of
    its epipolar plane (normal ``E u_a``), then ``E`` refitted to the inliers.

    :func:`ransac_rotation` (the rotation alone, same threshold) runs first. Where it explains at
    least :data:`ALONE_SHARE` of the matches, or as many as that share of the essential matrix's
    inliers, it is the answer: a camera that did not move fits every baseline, and the eight-point
    fit spreads its noise over them. Otherwise, of the two rotations the essential matrix holds
    (``R``, and ``R`` turned half a turn about the baseline), the one nearer the rotation alone is
    taken, so that no depth has to be told apart. Fewer than 8 matches: the rotation alone.
    """
    u_a, u_b = np.asarray(u_a, np.float64), np.asarray(u_b, np.float64)
    n = len(u_a)
    alone = ransac_rotation(u_a, u_b, threshold_deg=threshold_deg, iterations=iterations, seed=seed)
    if n < 8 or alone.inliers.sum() >= ALONE_SHARE * n:
        return alone
    rng = np.random.default_rng(seed)
    sin_threshold = np.sin(np.radians(threshold_deg))

    def agree(essential: np.ndarray) -> np.ndarray:
        """``(k, n)``: which matches lie near the epipolar planes of each of ``essential (k, 3, 3)``."""
        normal = np.einsum("kij,nj->kni", essential, u_a)
        length = np.linalg.norm(normal, axis=-1)
        return np.abs(np.einsum("kni,ni->kn", normal, u_b)) <= sin_threshold * np.maximum(length, 1e-12)

    best, best_count = None, -1
    for _ in range(max(1, iterations // 64)):
        sample = np.argsort(rng.random((64, n)), axis=1)[:, :8]  # 8 different matches each
        essential = _essential(u_a[sample], u_b[sample])
        counts = agree(essential).sum(axis=1)
        k = int(np.argmax(counts))
        if counts[k] > best_count:
            best, best_count = essential[k], int(counts[k])
    inliers = agree(best[None])[0]
    for _ in range(3):
        if inliers.sum() < 8:
            break
        best = _essential(u_a[inliers], u_b[inliers])
        refit = agree(best[None])[0]
        if np.array_equal(refit, inliers):
            break
        inliers = refit
    left, _, right_t = np.linalg.svd(best)
    half = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    candidates = []
    for w in (half, half.T):
        rotation = left @ w @ right_t
        candidates.append(rotation * np.sign(np.linalg.det(rotation)))
    if alone.inliers.sum() >= ALONE_SHARE * inliers.sum():
        return alone
    nearest = min(candidates, key=lambda r: np.linalg.norm(r - alone.b_from_a))
    return RansacResult(nearest, inliers, max(1, iterations // 64) * 64)
