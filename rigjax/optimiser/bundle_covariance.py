"""The covariance of a bundle adjustment's camera parameters (cluster-robust, with the offsets
that tracks may share) and the standard deviations reported from it: per letter, and per camera
orientation with the rig's own turn removed."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..camera.model import Camera
from ..camera.rotation import world_from_cam
from .bundle_model import BundleArgs, BundleConfig, Linearisation, reduce, stage_width
from .objective import LETTERS

# A direction of the camera parameters whose information, relative to what the observations give
# each parameter before the points are eliminated, is below this is one the matches leave free.
_FREE_RCOND = 1e-12
# A parameter is free when its unit vector has at least this share (squared) in the free directions.
_FREE_SHARE = 1e-6


def covariance(lin: Linearisation, args: BundleArgs, config: BundleConfig, n_params: int):
    """The covariance ``(params, params)`` of a stage's camera parameters at the linearisation
    ``lin`` of its optimum (the points eliminated; the anchor held where the centres do not fix the
    orientation) and ``sigma``,
    the residuals' scale (px per coordinate): ``sigma^2 = |r|^2 / (observations - unknowns)``, the
    unknowns counting each point's parameters that have a derivative. Padded parameters get 0.

    The textbook covariance ``sigma^2 S^-1`` assumes every observation's error its own. Tracks of
    neighbouring windows share theirs, and then it is too small by about the square root of how many
    share one. So the errors' covariance is estimated from the residuals, cluster by cluster
    (``args.cluster``): ``S^-1 (sum_c g_c g_c^T) S^-1`` with ``g_c`` the cluster's share of the
    reduced gradient (the cluster-robust "sandwich" of Liang and Zeger, 1986, with the small-sample
    factor ``C / (C - 1)`` of ``C`` clusters). With every point its own cluster and errors of one
    scale it estimates the textbook one. A prior is one more draw, of known variance: its weight
    squared, in the middle as in ``S``.

    Residuals show only the part of an error that the cameras cannot follow. Tracks of one region
    can be off together, across their epipolar lines (a period of a facade, an edge's direction),
    and where few points fix a direction (the yaw of a seam whose epipolar lines run along it)
    the fit turns the cameras to absorb it: the residuals then look clean and the estimate is off.
    ``args.cluster_error`` adds such an offset of known size: each cluster's later ends (a control
    point's second, a track's every one but its first) moved together by a draw of that standard
    deviation per coordinate, propagated through the Jacobian with the points eliminated
    (``A_k - B_k V_k^-1 B_k^T A_k`` for a point's camera rows ``A_k`` and its own ``B_k``),
    ``sigma_c^2 S^-1 (sum_c M_c M_c^T) S^-1`` with ``M_c`` the cluster's sum of their later ends' rows. Where the residuals do show the offsets as well,
    both count them: the deviations err large.

    **Free parameters.** Where the points can absorb a change of the cameras (a dual fisheye's
    lenses on one axis with their centres: a change of hfov is undone by the depths of points in the
    seam ring), ``S`` is singular, and its inverse is round-off: any value, even 0. So ``S`` is
    scaled by what the observations give each parameter before the points are eliminated
    (``diag(U)``, :class:`Reduced` ``.scale``) and split into its eigenvectors; directions whose
    eigenvalue is below ``_FREE_RCOND`` of the largest are free. They are left out of the inverse (a
    pseudo-inverse), and ``free`` ``(params,)`` marks the parameters with a share in them, whose
    variance is then unbounded.

    Returns ``(covariance, sigma, free, depth_sd)``: ``depth_sd`` ``(n,)``, each point's inverse
    depth's standard deviation with its cameras held (``sigma^2 V_k^-1``; ``inf`` for a point whose
    depth has no derivative: held at infinity, every centre at the origin, or left out of the solve),
    what tells a point's parallax from its noise."""
    r = reduce(lin, 0.0, args, config)
    used = args.weight > 0
    views = args.points
    estimated = jnp.any(r.to_params != 0.0, axis=0)  # the stage's parameters, not its padding
    unknowns = jnp.sum(jnp.where(used, r.point_rank, 0)) + jnp.sum(estimated)
    observations = 2 * jnp.sum(jnp.where(used[:, None], views.seen, 0.0))
    sigma2 = jnp.sum(lin.rows**2) / jnp.maximum(observations - unknowns, 1)
    scale = 1.0 / jnp.sqrt(r.scale)
    values, vectors = jnp.linalg.eigh((r.hessian + jnp.diag(~estimated)) * scale[:, None] * scale[None, :])
    kept = values > _FREE_RCOND * values[-1]
    free = estimated & (jnp.sum(jnp.where(kept, 0.0, vectors**2), axis=1) > _FREE_SHARE)
    inverse = (
        scale[:, None] * ((vectors * jnp.where(kept, 1.0 / jnp.where(kept, values, 1.0), 0.0)) @ vectors.T) * scale
    )
    n, slots = views.image.shape
    n_images, width = args.base.hfov.shape[0], stage_width(config)
    letters = r.to_params.reshape(n_images, width, n_params)[views.image]  # (n, K, L, params): each slot's camera's
    scores = jnp.einsum("nkl,nklp->np", r.point_scores.reshape(n, slots, width), letters)
    clusters = jnp.zeros_like(scores).at[args.cluster].add(scores * used[:, None])
    count = jnp.sum(jnp.zeros(used.shape).at[args.cluster].max(used.astype(scores.dtype)))
    meat = clusters.T @ clusters * (count / jnp.maximum(count - 1.0, 1.0)) + jnp.diag(args.prior_weight**2)
    # The shared offsets of the later ends (every slot but the first): each point's camera rows with
    # its own directions projected out, in the parameters, summed by cluster.
    later = lin.d_cameras[:, 2:] - jnp.einsum(
        "nrj,njk,nik->nri", lin.d_point[:, 2:], r.point_inverse, r.coupling[:, :-1]
    )
    shared = jnp.einsum("nrkl,nklp->npr", later.reshape(n, -1, slots, width), letters) * used[:, None, None]
    shared = jnp.zeros_like(shared).at[args.cluster].add(shared)
    meat = meat + args.cluster_error**2 * jnp.einsum("cpr,cqr->pq", shared, shared)
    sandwich = inverse @ meat @ inverse
    mask = estimated[:, None] & estimated[None, :]
    has_depth = jnp.any(lin.d_point[:, :, 2] != 0.0, axis=1)
    depth_sd = jnp.where(has_depth, jnp.sqrt(sigma2 * jnp.maximum(r.point_inverse[:, 2, 2], 0.0)), jnp.inf)
    return jnp.where(mask, sandwich, 0.0), jnp.sqrt(sigma2), free, depth_sd


def turn_jacobians(cameras: Camera) -> np.ndarray:
    """``(n, 3, 3)``: how each camera's world-frame turn ``omega`` (radians; ``R -> exp([omega]x) R``)
    moves with its yaw, pitch and roll (degrees), at the cameras' orientations."""

    def turn(ypr, base):
        m = world_from_cam(*(ypr + base)) @ world_from_cam(*base).T
        return 0.5 * jnp.stack([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]])

    base = jnp.stack([jnp.asarray(cameras.yaw), jnp.asarray(cameras.pitch), jnp.asarray(cameras.roll)], axis=-1)
    return np.asarray(jax.vmap(jax.jacfwd(turn))(jnp.zeros_like(base), base))


def standard_deviations(cov: np.ndarray, to_params: np.ndarray, letters: str, cameras: Camera, free=None):
    """Per camera and letter ``(n_images, 9)`` (VABCDEYPR; NaN where not estimated), per camera
    its orientation's ``(n_images,)`` (degrees: the RMS of the angle it may be turned by), and the
    covariance of each camera's turn ``(n_images, 3, 3)`` (degrees squared, world axes; its trace
    the orientation's variance), from the covariance ``cov`` of a stage's parameters
    (:func:`covariance`) through ``to_params`` ``(n_images x len(letters), params)``, each camera's
    ``letters``' derivatives along the parameters (the stage's camera Jacobian without its centres,
    :func:`~rigjax.optimiser.bundle_model.camera_jacobian`: a derived camera's orientation carries
    the deviations of those it is derived from).

    Images cannot tell the whole rig's orientation (the anchor's is held), or tell it only weakly,
    through the parallax of the centres; so the orientations are reported with that rotation
    removed: each camera's turn ``omega_i`` minus the mean turn of all cameras (the rotation that
    aligns the rig with another of the same shape, to first order). The anchor gets its own
    deviation like the others.

    ``free`` ``(params,)`` (:func:`covariance`): parameters the matches leave free; their letters'
    deviations, and the orientation of a camera with a free yaw, pitch or roll, are ``inf``.
    """
    columns = [LETTERS.index(letter) for letter in letters]
    width = len(columns)
    n_images = to_params.shape[0] // width
    estimated = np.any(to_params != 0.0, axis=1)
    c = to_params @ cov @ to_params.T  # (cameras x letters) squared
    turns = all(letter in letters for letter in "YPR")
    orientation = np.full(n_images, np.nan)
    turn_cov = np.full((n_images, 3, 3), np.nan)
    if turns:
        ypr = [letters.index(letter) for letter in "YPR"]
        jac = turn_jacobians(cameras)
        inverse = np.linalg.inv(jac)
        a = np.eye(n_images * width)
        for i in range(n_images):
            for j in range(n_images):
                rows, cols = i * width + np.array(ypr), j * width + np.array(ypr)
                a[np.ix_(rows, cols)] = inverse[i] @ jac[j] * ((i == j) - 1.0 / n_images)
        c = a @ c @ a.T
        for i in range(n_images):
            rows = i * width + np.array(ypr)
            turn_cov[i] = np.degrees(1.0) ** 2 * jac[i] @ c[np.ix_(rows, rows)] @ jac[i].T
            orientation[i] = np.sqrt(max(np.trace(turn_cov[i]), 0.0))  # round-off of a weakly known rig turn
            estimated[rows] = True
    deviations = np.full((n_images, len(LETTERS)), np.nan)
    deviations[:, columns] = np.where(estimated, np.sqrt(np.maximum(np.diag(c), 0.0)), np.nan).reshape(n_images, width)
    if free is not None:
        unbounded = np.zeros((n_images, len(LETTERS)), bool)
        unbounded[:, columns] = ((np.abs(to_params) @ np.asarray(free, float)) > 0.0).reshape(n_images, width)
        deviations[unbounded] = np.inf
        turned = unbounded[:, [LETTERS.index(letter) for letter in "YPR"]].any(axis=1) & np.isfinite(orientation)
        orientation[turned], turn_cov[turned] = np.inf, np.inf
    return deviations, orientation, turn_cov
