"""The host-side set-up of a bundle adjustment's stage: the points' start values (triangulated
rays), their clusters, the priors' means and weights, the parameters where a stage starts, and the
stage's arguments for the compiled solve (:func:`rigjax.optimiser.bundle_solve.solve`)."""

from __future__ import annotations

from typing import NamedTuple

import jax
import numpy as np

from ..camera.model import Camera, img_to_ray
from ..camera.rotation import world_from_cam
from ..errors import RigjaxError
from ..pto.records import ControlPoints
from .bundle_model import BundleArgs, Views
from .objective import (
    LETTERS,
    theta_of,
)
from .options import SolverOptions
from .problem import PADDED_POINTS, initial_params, parameter_count, round_up, slot_matrix
from .schedule import CENTRE_KEYS, LENS_LETTERS, UNIT, Layout


def centres_fix_orientation(centres: np.ndarray) -> bool:
    """Whether the centres ``(n, 3)`` (world frame, about the origin) tell the rig's orientation:
    only rotations about a line through the origin that holds every centre leave them all in
    place, so centres that span a plane with the origin fix it, and the images' parallax measures
    it. Centres all on one line through the origin (every one at the origin, too) leave a turn about
    that line free: the anchor's yaw, pitch and roll are held instead."""
    singular = np.linalg.svd(np.asarray(centres, float), compute_uv=False)
    return bool(singular[0] > 0.0 and singular[1] > 1e-6 * singular[0])


def tangent_frames(directions: np.ndarray) -> np.ndarray:
    """``(n, 3, 3)``: each unit direction and two unit tangents, orthogonal to it and each other."""
    helper = np.where(np.abs(directions[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    e1 = np.cross(directions, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(directions, e1)
    return np.stack([directions, e1, e2], axis=1)


def triangulate(ray_a: np.ndarray, ray_b: np.ndarray, centre_a: np.ndarray, centre_b: np.ndarray):
    """Start values ``(directions, inverse depths)`` of points seen along unit world rays ``ray_a``
    from ``centre_a`` and ``ray_b`` from ``centre_b`` (each ``(n, 3)``): the midpoint of the rays'
    closest approach where both reach it ahead of their cameras, else at infinity along the mean
    ray (parallel rays, rays that meet behind a camera, or every centre at the origin)."""
    baseline = centre_b - centre_a
    cos = np.sum(ray_a * ray_b, axis=1)
    along_a, along_b = np.sum(ray_a * baseline, axis=1), np.sum(ray_b * baseline, axis=1)
    parallel = 1.0 - cos**2
    safe = np.where(parallel > 1e-12, parallel, 1.0)
    s, t = (along_a - cos * along_b) / safe, (cos * along_a - along_b) / safe
    point = 0.5 * (centre_a + s[:, None] * ray_a + centre_b + t[:, None] * ray_b)
    distance = np.linalg.norm(point, axis=1)
    near = (parallel > 1e-12) & (s > 0.0) & (t > 0.0) & (distance > 0.0)
    mean = ray_a + ray_b
    directions = np.where(
        near[:, None],
        point / np.where(near, distance, 1.0)[:, None],
        mean / np.linalg.norm(mean, axis=1, keepdims=True),
    )
    return directions, np.where(near, 1.0 / np.where(near, distance, 1.0), 0.0)


def world_rays(cameras: Camera, views: Views) -> np.ndarray:
    """``(n, K, 3)``: each point's observed rays in the world frame, slot by slot, through ``cameras``."""
    image, xy = np.asarray(views.image), np.asarray(views.xy)
    rays = img_to_ray(cameras.take(image.reshape(-1)), xy.reshape(-1, 2))[0]
    return np.asarray(rays).reshape(*image.shape, 3)


def clusters(views: Views, cell_px: float) -> np.ndarray:
    """``(n,)`` int32: one number for the points seen in the same images whose first ends fall in
    one square cell of ``cell_px`` pixels (``0``: every point its own)."""
    n = len(views.image)
    if cell_px <= 0.0:
        return np.arange(n, dtype=np.int32)
    cells = np.floor(np.asarray(views.xy[:, 0], float) / cell_px).astype(np.int64)
    keys = np.column_stack([np.asarray(views.image), cells])
    return np.unique(keys, axis=0, return_inverse=True)[1].reshape(-1).astype(np.int32)


class PointViews(NamedTuple):
    """A bundle adjustment's points (:func:`point_views`) and where each control point lies in them."""

    views: Views  # padded with copies of the first point, of weight 0
    weight: np.ndarray  # (n_points,) 1 where every control point of the point is in use, else 0
    padded_weight: np.ndarray  # (n_padded,)
    finite: np.ndarray  # (n_padded,) 1 where the point's depth is estimated, 0 where held at infinity
    point: np.ndarray  # (n_control_points,) each control point's point
    slots: np.ndarray  # (n_control_points, 2) the slots of its two ends


def point_views(cps: ControlPoints, weight: np.ndarray, finite: np.ndarray, tracks=None) -> PointViews:
    """The points of control points ``cps``: each its own (two slots: image a, image b), or, where
    ``tracks`` ``(n,)`` gives control points one number ``>= 0``, one point for all of them, seen in
    every image their ends name (a feature followed through frames; its slots' images in the order
    the control points name them, every first end before the second ends: slots 0 and 1 place the
    point's start, and the later ones share a cluster's offset). A point is in use where all its
    control points are (``weight``) and its depth estimated where theirs is (``finite``); padded to
    a multiple of ``PADDED_POINTS``.

    Raises naming the track where its control points disagree on the depth, or name one image at
    two pixels (matches that joined two features of one image)."""
    n = len(cps)
    tracks = np.full(n, -1) if tracks is None else np.asarray(tracks)
    if tracks.shape != (n,) or not np.issubdtype(tracks.dtype, np.integer) or np.any(tracks < -1):
        raise RigjaxError(f"tracks must be integers >= -1 of shape ({n},) (one per control point), got {tracks.shape}")
    # each track one point, each control point outside one its own; points in order of first appearance
    key = np.where(tracks >= 0, tracks, -1 - np.arange(n))
    _, first, point = np.unique(key, return_index=True, return_inverse=True)
    rank = np.empty(len(first), np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    point = rank[point.reshape(-1)]
    count = len(first)
    # every end (a ends, then b ends) and the slot of its image in its point
    ends_point = np.concatenate([point, point])
    ends_image = np.concatenate([np.asarray(cps.image_a), np.asarray(cps.image_b)]).astype(np.int64)
    ends_xy = np.concatenate([np.asarray(cps.xy_a, float), np.asarray(cps.xy_b, float)])
    # a slot per image of a track; a control point of its own keeps two slots, whatever its images
    side = np.where(np.concatenate([tracks, tracks]) >= 0, 0, np.repeat([0, 1], n))
    pair_key = (ends_point * (int(ends_image.max(initial=0)) + 1) + ends_image) * 2 + side
    _, seen_first, distinct = np.unique(pair_key, return_index=True, return_inverse=True)
    distinct = distinct.reshape(-1)
    order = np.lexsort((seen_first, ends_point[seen_first]))  # by point, then by first appearance
    start = np.searchsorted(ends_point[seen_first][order], np.arange(count))
    slot_of = np.empty(len(seen_first), np.int64)
    slot_of[order] = np.arange(len(order)) - start[ends_point[seen_first][order]]
    slots_per_point = np.bincount(ends_point[seen_first], minlength=count)
    width = int(slots_per_point.max(initial=2))
    off = np.abs(ends_xy - ends_xy[seen_first][distinct]).max(axis=1) > 1e-6
    if off.any():
        k = int(np.flatnonzero(off)[0]) % n
        raise RigjaxError(
            f"tracks: track {int(tracks[k])} sees image {int(ends_image[np.flatnonzero(off)[0]])} at two pixels "
            "(control points that join two features of one image): split the track there"
        )
    image = np.zeros((count, width), np.int64)
    xy = np.zeros((count, width, 2))
    used = np.zeros((count, width))
    rows, columns = ends_point[seen_first], slot_of
    image[rows, columns], xy[rows, columns], used[rows, columns] = ends_image[seen_first], ends_xy[seen_first], 1.0
    padding = used == 0.0  # an unused slot repeats the first's image and pixel
    image[padding] = np.broadcast_to(image[:, :1], image.shape)[padding]
    xy[padding] = np.broadcast_to(xy[:, :1], xy.shape)[padding]
    point_weight = np.ones(count)
    np.minimum.at(point_weight, point, (np.asarray(weight) > 0).astype(float))
    lowest, highest = np.ones(count), np.zeros(count)
    np.minimum.at(lowest, point, finite)
    np.maximum.at(highest, point, finite)
    if np.any(lowest != highest):
        cp = int(np.sort(first)[np.flatnonzero(lowest != highest)[0]])  # the point's first control point
        raise RigjaxError(f"at_infinity: track {int(tracks[cp])} has control points held at infinity and others not")
    size = max(PADDED_POINTS, round_up(count, PADDED_POINTS))
    pad = np.zeros(size - count, np.int64)
    views = Views(*(np.concatenate([a, a[pad]]) for a in (image.astype(np.int32), xy, used)))
    return PointViews(
        views,
        point_weight,
        np.concatenate([point_weight, np.zeros(size - count)]),
        np.concatenate([lowest, np.ones(size - count)]),
        point,
        slot_of[distinct].reshape(2, n).T,
    )


_PRIOR_LETTERS = LENS_LETTERS + "YPRX"


def check_priors(priors) -> dict[str, float]:
    """``priors`` (a mapping of lens letters, ``y``, ``p``, ``r``, or ``x`` for the centres, to
    standard deviations, or None) with upper-case letters; an error names a letter that cannot
    have a prior or a deviation that is not > 0."""
    checked = {}
    for letter, sd in (priors or {}).items():
        if str(letter).upper() not in _PRIOR_LETTERS:
            raise RigjaxError(f"priors: {letter!r} cannot have a prior (one of {', '.join(_PRIOR_LETTERS.lower())})")
        if not (isinstance(sd, (int, float)) and sd > 0.0 and np.isfinite(sd)):
            raise RigjaxError(f"priors: {letter} must be a positive standard deviation, got {sd!r}")
        checked[str(letter).upper()] = float(sd)
    return checked


def prior_arrays(
    slot: np.ndarray, centre_slot: np.ndarray, nominal: Camera, nominal_centres, priors: dict[str, float], n_params: int
):
    """``(mean, weight)`` ``(n_params,)`` of the priors (:func:`check_priors`'s letters): each
    estimated parameter of a letter with a prior at its cameras' mean ``nominal`` value (a centre
    coordinate at ``nominal_centres``'), with weight ``1 / sd`` in the parameter's units (``0``:
    no prior)."""
    values = np.concatenate([theta_of(jax.tree_util.tree_map(np.asarray, nominal), np), nominal_centres], axis=1)
    slots = np.concatenate([slot, centre_slot], axis=1)
    units = {**UNIT, "X": 1.0}
    total, count, weight = np.zeros(n_params), np.zeros(n_params), np.zeros(n_params)
    for letter, sd in priors.items():
        centre = range(len(LETTERS), len(LETTERS) + 3)  # the columns after the letters'
        for k in centre if letter == "X" else [LETTERS.index(letter)]:
            for i in np.flatnonzero(slots[:, k] >= 0):
                p = slots[i, k]
                total[p] += values[i, k]
                count[p] += 1
                weight[p] = units[letter] / sd
    return np.where(count > 0, total / np.maximum(count, 1), 0.0), weight


def centre_matrix(layout: Layout) -> np.ndarray:
    """``(n_images, 3)`` int32: the parameter index of each camera's centre coordinates, or -1."""
    return np.stack([layout.slot[key] for key in CENTRE_KEYS], axis=-1)


def start_params(layout: Layout, cameras: Camera, centres, size: int = 0) -> np.ndarray:
    """A stage's parameters where it starts (padded as :func:`rigjax.optimiser.problem.initial_params`,
    to at least ``size``): the cameras' letters and, with ``X``, their ``centres``."""
    params = initial_params(layout, cameras, size)
    slot = centre_matrix(layout)
    params[slot[slot >= 0]] = np.asarray(centres, float)[slot >= 0]
    return params


def stage_args(
    cameras: Camera,
    centres,
    layout: Layout,
    points: Views,
    weight,
    rays: np.ndarray,
    directions,
    solver: SolverOptions,
    preliminary: bool,
    robust_scale: float = 2.0,
    median_scale_floor: float | None = None,
    cluster_px: float = 0.0,
    priors: dict[str, float] | None = None,
    nominal: Camera | None = None,
    nominal_centres=None,
    cluster_error_px: float = 0.0,
    finite=None,
    rigid=None,
    size: int = 0,
) -> BundleArgs:
    """A stage's data for :func:`rigjax.optimiser.bundle_solve.solve`: its layout, the cameras' ``centres``
    where it starts, the points' start ``directions`` (their frames), each observation's ray (``rays``:
    :func:`world_rays` through ``cameras``) in its camera's frame, the stopping rules (``preliminary``: a
    later stage optimises the same parameters again), the robust loss's scale, the points' clusters
    (:func:`clusters`) and the offset they may share (``cluster_error_px``,
    :func:`rigjax.optimiser.bundle_covariance.covariance`), the priors (:func:`check_priors`' letters;
    their means ``nominal``'s values and ``nominal_centres``, else ``cameras``' and ``centres``), and
    which points' depths are estimated (``finite``, ``(n_padded,)`` 0/1; default all) and the cameras
    whose orientations are derived from others' (``rigid``, ``(n_images, 3)``; default none); the
    parameter vector padded to at least ``size`` (:func:`start_params`)."""
    rotation = np.asarray(world_from_cam(cameras.yaw, cameras.pitch, cameras.roll))
    observed = np.einsum("nkji,nkj->nki", rotation[np.asarray(points.image)], rays)
    ftol = max(solver.ftol, solver.preliminary_ftol) if preliminary else solver.ftol
    slot, centre_slot = slot_matrix(layout), centre_matrix(layout)
    centres = np.asarray(centres, float)
    prior_mean, prior_weight = prior_arrays(
        slot,
        centre_slot,
        cameras if nominal is None else nominal,
        centres if nominal_centres is None else np.asarray(nominal_centres, float),
        priors or {},
        parameter_count(layout, size),
    )
    return BundleArgs(
        cameras,
        slot,
        centres,
        centre_slot,
        points,
        weight,
        tangent_frames(directions),
        observed,
        np.ones(len(weight)) if finite is None else np.asarray(finite, float),
        np.full((len(centres), 3), -1, np.int32) if rigid is None else np.asarray(rigid, np.int32),
        clusters(points, cluster_px),
        np.asarray(cluster_error_px, float),
        prior_mean,
        prior_weight,
        np.asarray(robust_scale, float),
        np.asarray(-1.0 if median_scale_floor is None else median_scale_floor, float),
        np.asarray(solver.max_steps, np.int32),
        np.asarray(solver.xtol),
        np.asarray(ftol),
    )
