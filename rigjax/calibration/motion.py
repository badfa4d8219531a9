"""Lenses from the camera's own motion: a rig calibrated from several frames between which it turned.

The ring where two back-to-back fisheyes overlap cannot tell their lenses: points at one radius of
both circles, at unknown depths, leave the hfov free to a degree or more and the distortion and the
optical centres entirely (:mod:`rigjax.calibration.checks`). A camera that turns between frames sees
the same far content at different radii of one lens: that is panorama self-calibration, the recipe
Hugin users follow by hand for these cameras (frames of a slow turn, each lens matched with itself
across frames, positions optimised, then the lens).

Here the frames become one project of ``F x L`` images (frame ``f``'s lens ``l`` is image
``f L + l``), each the camera's turn in frame ``f`` times lens ``l``'s mounting (in the bundle
adjustment, frame ``f > 0``'s lenses other than lens 0 follow their frame's lens 0: the rig is
rigid), and the lens letters of frame ``f > 0``'s images linked to frame 0's (Hugin's ``v=0``
links), so that each lens has one hfov, distortion ``a``, ``b``, ``c`` and optical centre ``d``, ``e``. Its control points are

* each frame's ring matches between its lenses, as the template makes them for one frame
  (:func:`rigjax.calibration.pipeline.match_images`), and
* each lens matched with itself across every pair of frames (SIFT in the image circle):
  the same lens at two orientations.

Every pair's matches pass RANSAC on bearings of the template's lens, its centre shifts started from
the image circle (:func:`rigjax.calibration.circle.find_image_circle`, for circular fisheyes); the
pairs' rotations place the images in closed form (:func:`rigjax.calibration.initial.orientations_from_pairs`);
the bundle adjustment (:func:`solve_motion`: the rig held rigid across frames, each frame's ring seen
from the lenses' own centres with its near points at their own depths, the matches across frames at
infinity; standard deviations included) solves the template's ``motion.schedule``, the template's
lens a weak prior (``motion.priors``), each optical centre held about its image circle's centre
(``motion.circle_centre_px``: the matches across frames of a camera whose lenses move as it turns
pull the centres a pixel or two off, and the circle does not move), pruning as the template's
``optimise.prune`` says.

The rig written is frame 0's images: each lens as solved, lens 0 where the template puts it and
every other lens at its mounting relative to lens 0; the camera's turn from frame 0 to each frame is
lens 0's (:attr:`MotionFit.turns`). A template enables this with a
``motion:`` section, or ``rigjax calibrate --motion`` with these defaults
(``configs/rig/dual_fisheye.yaml`` shows it)::

    motion:
      schedule: YPR,VDEYPR,VABCDEYPR     # per lens: hfov, then centre shifts, then a, b, c
      priors: {v: 5, a: 0.5, b: 0.5, c: 0.5, d: 30, e: 30}   # the template's lens, held weakly
      circle: true                       # start d, e from the image circle (circular fisheyes)
      circle_centre_px: 1                # and hold them about its centre, sd 1 px (null: priors' d, e)
      min_turn_deg: 5                    # frames that turned less are refused
      max_spread_deg: 0.1                # so is a lens whose mounting differs more between frames
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..camera.model import img_to_ray, map_points
from ..camera.rotation import world_from_cam, ypr_from_world_from_cam
from ..errors import RigjaxError
from ..optimiser.config import OptimiseConfig, Priors
from ..optimiser.prune import PrunedResult, optimise_pruned
from ..optimiser.schedule import parse_schedule
from ..optimiser.staged import optimise
from ..pto.project import Project
from ..pto.records import ControlPoints, Image, OptVariable
from .circle import ImageCircle, find_image_circle, lens_from_circle
from .features import detect, lens_mask, match
from .initial import orientations_from_pairs
from .ransac import ransac_rotation

LENS_LINKS = "vabcde"


def _weak_lens() -> Priors:
    return Priors(v=5.0, a=0.5, b=0.5, c=0.5, d=30.0, e=30.0)


@dataclass(frozen=True)
class MotionConfig:
    """A template's ``motion:`` section: how several frames of a turning camera calibrate its
    lenses (module docstring). ``schedule``: the bundle adjustment's stages (per-lens letters follow
    the lens links: one value per lens); ``priors``: the template's lens as a weak prior (standard
    deviations: ``v`` degrees, ``a``, ``b``, ``c`` the project's units, ``d``, ``e`` px); ``circle``:
    start the centre shifts from each circular fisheye's image circle; ``circle_centre_px``: where
    that circle was found on every lens, each lens's optical centre held about its circle's centre
    with this standard deviation (px; with the circle's own, :func:`circle_priors`) in place of
    ``priors``' ``d``, ``e`` (None: the priors' alone);
    ``tracks``: each lens's matches across frames chained into tracks, one scene point each, whose
    depth is estimated where its parallax shows (:func:`across_tracks`, :func:`solve_motion`; the
    lenses' centres are needed, the template's ``rig.centres``: without them every match stays at
    infinity); off by default (every match across frames held at infinity): on the lens-from-motion
    benchmark's clips it helps one and harms another (the design note);
    ``min_turn_deg``: frames whose
    largest turn from each other is less tell nothing of the lenses, and the calibration is refused;
    ``max_spread_deg``: a lens whose mounting, as each frame's own matches pull it (every image
    turned freely from the rigid fit), differs more than this between frames says that the frames
    disagree (near content seen from lenses that moved, wrong matches),
    and the calibration is refused."""

    schedule: str = "YPR,VDEYPR,VABCDEYPR"
    priors: Priors = field(default_factory=_weak_lens)
    circle: bool = True
    circle_centre_px: float | None = 1.0
    tracks: bool = False
    min_turn_deg: float = 5.0  # the camera must turn this much between two of the frames
    max_spread_deg: float = 0.1  # a lens's mounting may differ this much between frames

    def __post_init__(self) -> None:
        for key in ("min_turn_deg", "max_spread_deg"):
            value = getattr(self, key)
            if not (math.isfinite(value) and value > 0.0):
                raise RigjaxError(f"motion.{key}: expected degrees (> 0), got {value!r}")
        if not isinstance(self.tracks, bool):
            raise RigjaxError(f"motion.tracks: expected true or false, got {self.tracks!r}")
        px = self.circle_centre_px
        number = isinstance(px, (int, float)) and not isinstance(px, bool)
        if px is not None and not (number and math.isfinite(px) and px > 0.0):
            raise RigjaxError(f"motion.circle_centre_px: expected a standard deviation in px (> 0) or null, got {px!r}")
        for stage in parse_schedule(self.schedule):
            if "X" in stage.per_camera:
                raise RigjaxError(
                    f"motion.schedule {self.schedule!r}: the lenses' centres are the template's (rig.centres), "
                    "held: X does not apply"
                )
        if self.priors.x is not None:
            raise RigjaxError("motion.priors: x (centres) does not apply: the lenses' centres are the template's, held")


class MotionFit(NamedTuple):
    """What :func:`solve_motion` found: the ``rig`` (frame 0's images, each lens as solved, the rig
    rigid), ``turns`` ``(F, 3)``: yaw, pitch and roll of the camera's turn from frame 0 to every frame
    (lens 0's), degrees; ``mounting_spread_deg`` ``(L,)``: the largest angle between a lens's mounting
    as each frame's own matches pull it (every image turned freely from the rigid fit) and its mean
    (0 for lens 0: it defines the frames' turns);
    ``result`` and ``pruned``: the bundle adjustment of the ``F x L`` images (``result.project``)."""

    rig: Project
    turns: np.ndarray
    mounting_spread_deg: np.ndarray
    result: object
    pruned: PrunedResult | None


def frame_image(f: int, lens: int, lenses: int) -> int:
    """The index of frame ``f``'s lens ``lens`` in the frames' project."""
    return f * lenses + lens


def frames_project(rig: Project, turns: np.ndarray, names: Sequence[Sequence[str]]) -> Project:
    """The ``F x L`` images of a rig seen in ``F`` frames: frame ``f``'s lens ``l`` is the rig's image
    ``l`` turned by ``turns[f]`` (``(F, 3, 3)`` world-from-camera rotations of the whole rig) and
    named ``names[f][l]``, its lens letters linked to frame 0's image ``l``; no control points."""
    mounting = np.asarray(world_from_cam(*(np.array([im.value(x) for im in rig.images]) for x in "ypr")))
    images = []
    for f, turn in enumerate(np.asarray(turns, float)):
        ypr = np.asarray(ypr_from_world_from_cam(turn[None] @ mounting))
        for lens, image in enumerate(rig.images):
            links = {letter: lens for letter in LENS_LINKS} if f else {}
            y, p, r = (float(x) for x in ypr[lens])
            images.append(image.replace(yaw=y, pitch=p, roll=r, filename=names[f][lens], links=links))
    return Project.new(rig.panorama, images)


def vignetting_linked(frames: Project, lenses: int) -> Project:
    """A frames' project (:func:`frames_project`'s layout) whose every frame's image of a lens shares
    frame 0's vignetting (``Vb``, ``Vc``, ``Vd`` linked, as Hugin links them), each image keeping its
    own exposure and white balance: what :func:`~rigjax.calibration.exposure.fit_exposure` fits one
    ``V(r)`` per lens across the frames with, where the camera's turn shows each direction to a lens
    at several radii."""
    images = []
    for k, image in enumerate(frames.images):
        lens = k % lenses
        if k >= lenses:
            shared = frames.images[lens]
            image = image.replace(
                vignetting_b=shared.vignetting_b,
                vignetting_c=shared.vignetting_c,
                vignetting_d=shared.vignetting_d,
                links={**image.links, **dict.fromkeys(("Vb", "Vc", "Vd"), lens)},
            )
        images.append(image)
    return frames.replace(images=tuple(images))


def _chordal_mean(rotations: np.ndarray) -> np.ndarray:
    """The rotation closest to the mean of ``rotations`` ``(n, 3, 3)`` (Frobenius norm)."""
    u, _, vt = np.linalg.svd(rotations.mean(axis=0))
    return u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The angle of the rotation between ``a`` and ``b`` (``(..., 3, 3)``), degrees, from their chordal
    distance (precise for small angles too)."""
    chord = np.linalg.norm(a - b, axis=(-2, -1))
    return np.degrees(2.0 * np.arcsin(np.clip(chord / (2.0 * math.sqrt(2.0)), 0.0, 1.0)))


def _frames_world(frames: Project, lenses: int) -> np.ndarray:
    """``(F, L, 3, 3)``: every frame's images' world-from-camera rotations."""
    world = world_from_cam(*(np.array([im.value(x) for im in frames.images]) for x in "ypr"))
    return np.asarray(world, np.float64).reshape(-1, lenses, 3, 3)


def frame_turns(frames: Project, lenses: int) -> np.ndarray:
    """``(F, 3)``: yaw, pitch and roll of the camera's turn from frame 0 to every frame of a frames'
    project (lens 0's ``R_f R_0^T``)."""
    world = _frames_world(frames, lenses)
    return np.asarray(ypr_from_world_from_cam(world[:, 0] @ world[0, 0].T))


def split_rig(frames: Project, lenses: int, kept: np.ndarray | None = None) -> tuple[Project, np.ndarray, np.ndarray]:
    """The rig of a solved frames' project (:func:`frames_project`'s layout): frame 0's images,
    lens 0 as solved and every other lens at its mean mounting relative to lens 0 over the frames,
    frame 0's control points between them (those ``kept``: pruning's; default all), every lens
    letter and each mounting but lens 0's as variables: the rig as frame 0 sees it; each frame's
    turn from frame 0 ``(F, 3)`` (yaw, pitch, roll of lens 0's ``R_f R_0^T``); each lens's largest
    departure from its mean mounting, degrees (0 where the frames were solved as a rigid rig)."""
    world = _frames_world(frames, lenses)
    relative = np.swapaxes(world[:, :1], -1, -2) @ world  # each lens in lens 0's frame, per frame
    means = np.stack([_chordal_mean(relative[:, k]) for k in range(lenses)])
    spread = np.array([float(_angle_deg(relative[:, k], means[k][None]).max()) for k in range(lenses)])
    rig_world = world[0, 0][None] @ means
    ypr = np.asarray(ypr_from_world_from_cam(rig_world))
    images = [im.replace(yaw=float(y), pitch=float(p), roll=float(r)) for im, (y, p, r) in zip(frames.images, ypr)]
    turns = frame_turns(frames, lenses)
    cps = frames.control_points
    ring = (cps.image_a < lenses) & (cps.image_b < lenses) & (True if kept is None else kept)
    ring_points = ControlPoints(cps.image_a[ring], cps.image_b[ring], cps.xy_a[ring], cps.xy_b[ring], cps.kind[ring])
    variables = [OptVariable(x, k) for k in range(1, lenses) for x in "ypr"]
    variables += [OptVariable(x, k) for k in range(lenses) for x in LENS_LINKS]
    return Project.new(frames.panorama, images, ring_points, variables), turns, spread


def _optimise_settings(motion: MotionConfig, optimise_config: OptimiseConfig, centres: np.ndarray) -> OptimiseConfig:
    """The template's solver, loss and pruning with the motion's schedule and priors, the images'
    ``centres`` held."""
    return optimise_config.replace(
        schedule=motion.schedule,
        pto_vars=False,
        objective="reprojection",
        anchor=0,
        centres=tuple(map(tuple, np.asarray(centres, float))),
        priors=motion.priors,
    )


def frames_centres(frames: Project, lenses: int, centres=None) -> np.ndarray:
    """``(F x L, 3)``: each image's centre in a frames' project (:func:`frames_project`'s layout):
    the rig's lens ``centres`` ``(L, 3)`` (the rig frame, frame 0's; None: every lens at the origin)
    turned as the rig turned from frame 0 (lens 0's turn, :func:`rigid_frames`' rig)."""
    world = _frames_world(frames, lenses)
    if centres is None:
        return np.zeros((world.shape[0] * lenses, 3))
    turns = world[:, 0] @ world[0, 0].T
    return np.einsum("fij,lj->fli", turns, np.asarray(centres, float)).reshape(-1, 3)


def rigid_frames(frames: int, lenses: int) -> np.ndarray:
    """``(F x L, 3)``: the rig of a frames' project (:func:`frames_project`'s layout) for
    :func:`rigjax.optimiser.bundle.bundle_adjust`'s ``rigid``: frame ``f > 0``'s lens ``l > 0`` is
    frame 0's lens ``l`` turned as frame ``f``'s lens 0 turned from frame 0, ``(f L, 0, l)``; the
    other images are their own."""
    rows = np.full((frames * lenses, 3), -1, np.int64)
    for f in range(1, frames):
        for lens in range(1, lenses):
            rows[frame_image(f, lens, lenses)] = (frame_image(f, 0, lenses), 0, lens)
    return rows


def across_frames(frames: Project, lenses: int) -> np.ndarray:
    """``(n_control_points,)`` bool: the control points of a frames' project between images of two
    frames (a lens matched with itself), not a frame's ring."""
    cps = frames.control_points
    return np.asarray(cps.image_a) // lenses != np.asarray(cps.image_b) // lenses


def across_tracks(frames: Project, lenses: int) -> np.ndarray:
    """``(n_control_points,)`` int: the matches across frames of a frames' project chained into
    tracks by the features they share (a lens's features are detected once per frame, so two of
    its matches that end at one pixel of one image end at one feature: :func:`lens_matches`),
    numbered from 0; -1 for a frame's ring, a match no other shares a feature with, and the
    matches of a chain that reaches one image at two pixels (a wrong match joined two features)."""
    cps = frames.control_points
    across = np.flatnonzero(across_frames(frames, lenses))
    tracks = np.full(len(cps), -1, np.int64)
    if not across.size:
        return tracks
    ends = np.concatenate(
        [
            np.column_stack([np.asarray(cps.image_a)[across], np.asarray(cps.xy_a)[across]]),
            np.column_stack([np.asarray(cps.image_b)[across], np.asarray(cps.xy_b)[across]]),
        ]
    )
    keys, node = np.unique(ends, axis=0, return_inverse=True)
    node = node.reshape(2, -1)
    parent = np.arange(len(keys))

    def root(k: int) -> int:
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    for a, b in node.T:
        ra, rb = root(int(a)), root(int(b))
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    chain = np.array([root(k) for k in range(len(keys))])
    # a chain that holds two pixels of one image joined two features of it: each match its own
    pixels, count = np.unique(np.column_stack([chain, keys[:, 0].astype(np.int64)]), axis=0, return_counts=True)
    split = pixels[count > 1, 0]
    matches = np.bincount(chain[node[0]], minlength=len(keys))
    kept = ~np.isin(chain[node[0]], split) & (matches[chain[node[0]]] >= 2)
    number = np.unique(chain[node[0]][kept], return_inverse=True)[1].reshape(-1)
    tracks[across[kept]] = number
    return tracks


def solve_motion(
    start: Project,
    lenses: int,
    motion: MotionConfig,
    optimise_config: OptimiseConfig,
    cluster_error_px: float = 0.0,
    centres=None,
    spread: bool = True,
) -> MotionFit:
    """The bundle adjustment of a frames' project (:func:`frames_project`, with control points)
    from its values, the lens priors about them, pruned as ``optimise_config.prune`` says;
    ``cluster_error_px``: the tracks' shared bias the deviations allow for (the template's
    ``features.track_bias_px`` where the ring is tracked); ``centres``: the rig's lens centres
    ``(L, 3)`` (None: the lenses at one point); ``spread``: measure each frame's pull on the
    mounting (else :attr:`MotionFit.mounting_spread_deg` is zeros: a pass that only places the next
    tracks).

    The rig is rigid (:func:`rigid_frames`): each lens's matches across frames measure one turn of
    the camera, which tells the lenses' mounting where the turns have different axes. Each frame's
    ring is seen from the lenses' own centres (:func:`frames_centres`, placed with the start's turns):
    a near object across the seam is seen from places centimetres apart, and a rotation-only ring
    bends the lenses to fit it. A ring point gets its own depth where its parallax shows
    (:func:`near_points`), and is held at infinity otherwise: a depth is never negative, so free
    depths of far points absorb their noise on one side only and bias the lenses' radial scale at the
    ring. A lens matched with itself across frames moved a few millimetres between them, and a depth
    per match only trades against the lens's hfov: the matches are held at infinity, or with
    ``motion.tracks`` chained into tracks (:func:`across_tracks`), one depth a feature over every
    frame that sees it, gated as the ring's points are. The centres, placed with the start's own turns, say nothing
    of the rig's orientation: frame 0's lens 0 is held. The mounting's spread is each frame's own
    pull: every image turned freely from the rigid fit, the lenses held, the kept points alone."""
    settings = _optimise_settings(motion, optimise_config, frames_centres(start, lenses, centres))
    located = np.any(np.asarray(settings.centres))
    tracks = across_tracks(start, lenses) if motion.tracks and located else None
    across = across_frames(start, lenses)
    data = dict(
        nominal=start.cameras(host=True),
        cluster_error_px=cluster_error_px,
        at_infinity=across if tracks is None else across & (tracks < 0),
        hold_anchor=True,
        rigid=rigid_frames(len(start.images) // lenses, lenses),
        tracks=tracks,
    )
    if located:
        first = optimise(start, settings.replace(prune=None), **data)  # every ring point's and track's depth free
        data["at_infinity"] = data["at_infinity"] | ~near_points(first, cluster_error_px)
        start = first.project
        settings = _optimise_settings(motion, optimise_config, frames_centres(start, lenses, centres))
    pruned, kept = None, None
    if settings.prune is not None:
        pruned = optimise_pruned(start, settings, **data)
        result, kept = pruned.result, pruned.kept
    else:
        result = optimise(start, settings, **data)
    rig, turns, _ = split_rig(result.project, lenses, kept)
    if not spread:
        return MotionFit(rig, turns, np.zeros(lenses), result, pruned)
    # Each frame's own pull on the mounting: every image turned freely from the rigid fit (the
    # lenses held), the kept points' matches alone.
    weights = None if kept is None else kept.astype(float)
    own = optimise(
        result.project, settings.replace(schedule="YPR", prune=None), weights=weights, **dict(data, rigid=None)
    )
    return MotionFit(rig, turns, split_rig(own.project, lenses)[2], result, pruned)


# A point whose inverse depth is this many of its standard deviations from infinity is near:
# one-sided, a far point passes for near about once in 700.
NEAR_SIGMAS = 3.0


def near_points(result, shared_px: float = 0.0) -> np.ndarray:
    """``(n_control_points,)`` bool: the points of a bundle adjustment (``result``, the depths of the
    ring's points and of the tracks free) whose inverse depth is at least :data:`NEAR_SIGMAS` of its standard deviation from
    infinity: their parallax shows above their noise. The deviation is the point's own with its
    cameras held (``result.inverse_depth_sd``, from the residuals' scale ``sigma``) and an offset of
    ``shared_px`` (px per coordinate) that tracks of one region share, which the residuals cannot
    show and which moves a point's depth as ``shared_px / sigma`` of its noise does."""
    scale = math.sqrt(1.0 + (shared_px / result.sigma) ** 2) if result.sigma > 0.0 else 1.0
    with np.errstate(invalid="ignore"):
        return np.asarray(result.inverse_depths) >= NEAR_SIGMAS * scale * np.asarray(result.inverse_depth_sd)


class PairFit(NamedTuple):
    """One pair of the frames' images: its matches, RANSAC's rotation (``b_from_a``) and inliers."""

    a: int
    b: int
    xy_a: np.ndarray
    xy_b: np.ndarray
    b_from_a: np.ndarray | None
    inliers: np.ndarray  # bool (n,)


def ransac_pairs(
    pairs: Sequence[tuple[int, int, np.ndarray, np.ndarray]],
    rig: Project,
    *,
    threshold_deg: float,
    iterations: int,
    seed: int,
) -> list[PairFit]:
    """RANSAC of each pair's rotation (images of the frames' project, :func:`frame_image`) on bearings
    of ``rig``'s lenses, orientations aside."""
    lenses = len(rig.images)
    lens = rig.cameras()
    lens = lens._replace(yaw=np.zeros_like(lens.yaw), pitch=np.zeros_like(lens.yaw), roll=np.zeros_like(lens.yaw))
    out = []
    for a, b, xy_a, xy_b in pairs:
        if len(xy_a) < 2:
            out.append(PairFit(a, b, xy_a, xy_b, None, np.zeros(len(xy_a), bool)))
            continue
        u_a, ok_a = map_points(img_to_ray, lens.take(a % lenses), xy_a)
        u_b, ok_b = map_points(img_to_ray, lens.take(b % lenses), xy_b)
        fit = ransac_rotation(u_a, u_b, threshold_deg=threshold_deg, iterations=iterations, seed=seed)
        out.append(PairFit(a, b, xy_a, xy_b, fit.b_from_a, fit.inliers & ok_a & ok_b))
    return out


def start_from_pairs(
    rig: Project,
    frames: int,
    fits: Sequence[PairFit],
    names: Sequence[Sequence[str]],
    *,
    min_inliers: int,
    max_points_per_pair: int,
    seed: int,
) -> Project:
    """The frames' project LM starts from: ``rig``'s lenses, each image placed in closed form over
    the pairs with ``min_inliers`` or more RANSAC inliers (image 0 where the rig puts lens 0), and
    those pairs' inliers (at most ``max_points_per_pair`` each, a seeded subset) as control points.
    Raises, naming the frames and lenses, when an image shares no such pair with the others."""
    lenses = len(rig.images)
    used = [fit for fit in fits if fit.b_from_a is not None and fit.inliers.sum() >= min_inliers]
    rotations = {(fit.a, fit.b): (fit.b_from_a, int(fit.inliers.sum())) for fit in used}
    anchor = np.asarray(world_from_cam(*(rig.images[0].value(x) for x in "ypr")))
    flat = [name for frame in names for name in frame]
    try:
        world, _ = orientations_from_pairs(frames * lenses, rotations, anchor=0, anchor_world_from_cam=anchor)
    except RigjaxError as error:
        raise RigjaxError(
            f"{error}: image k is frame k // {lenses}'s lens k % {lenses} ({', '.join(flat)}); frames "
            "whose lens content does not overlap another frame's cannot be placed (turn less between them)"
        ) from None
    project = frames_project(rig, np.tile(np.eye(3), (frames, 1, 1)), names)  # placed below
    ypr = np.asarray(ypr_from_world_from_cam(world))
    images = [im.replace(yaw=float(y), pitch=float(p), roll=float(r)) for im, (y, p, r) in zip(project.images, ypr)]
    rng = np.random.default_rng(seed)
    kept = []
    for fit in used:
        index = np.flatnonzero(fit.inliers)
        if len(index) > max_points_per_pair:
            index = np.sort(rng.choice(index, max_points_per_pair, replace=False))
        kept.append((fit.a, fit.b, fit.xy_a[index], fit.xy_b[index]))
    return project.replace(images=tuple(images), control_points=ControlPoints.from_pairs(kept))


def circle_start(image: Image, views: Sequence[np.ndarray], circle_deg: float) -> tuple[Image, ImageCircle | None, str]:
    """``image`` (a circular fisheye's nominal lens) with its centre shifts ``d``, ``e`` put where
    its image circle is in ``views`` (its frames), the circle (None: not found), and a line saying so
    or why not. The circle's centre deviation counts how far each frame's own circle lies from it
    (their largest distance): a lens whose edge each frame shows differently (dark content or a
    camera's body at the rim) is known no better than its frames agree."""
    try:
        circle = find_image_circle(views)
    except RigjaxError as error:
        return image, None, f"the image circle was not found ({error}): d, e start at 0"
    spread = 0.0
    for view in views if len(views) > 1 else ():
        with contextlib.suppress(RigjaxError):  # a frame that shows too little of the edge alone
            spread = max(spread, float(np.linalg.norm(find_image_circle([view]).centre - circle.centre)))
    circle = dataclasses.replace(circle, centre_sd=math.hypot(circle.centre_sd, spread))
    _, d, e, _ = lens_from_circle(image, circle, circle_deg)
    line = (
        f"image circle at ({circle.centre[0]:.1f}, {circle.centre[1]:.1f}) ± {circle.centre_sd:.2f}, radius "
        f"{circle.radius:.1f} px ({circle.points} edge points; the frames' own within {spread:.2f} px)"
    )
    return image.replace(d=d, e=e), circle, f"{line}: d {d:+.1f}, e {e:+.1f} px"


def circle_priors(motion: MotionConfig, circles: Sequence[ImageCircle | None]) -> tuple[MotionConfig, str | None]:
    """The settings a motion calibration solves with, and a note saying so: where
    ``motion.circle_centre_px`` is set and every lens's image circle was found (``circles``, the lenses
    started at their centres by :func:`circle_start`), the priors' ``d``, ``e`` about that start become
    ``circle_centre_px`` and the least certain circle centre's standard deviation together (their
    root sum of squares: one prior for every lens); else ``motion`` itself, the same object."""
    px = motion.circle_centre_px
    if px is None or not circles:
        return motion, None
    missing = [lens for lens, circle in enumerate(circles) if circle is None]
    if missing:
        lenses = ", ".join(map(str, missing))
        return motion, f"d, e not held to the image circles: lens {lenses}'s was not found (motion.priors d, e)"
    sd = math.hypot(px, max(circle.centre_sd for circle in circles))
    priors = dataclasses.replace(motion.priors, d=sd, e=sd)
    note = f"d, e held about the image circles' centres, sd {sd:.2f} px (motion.circle_centre_px {px:g})"
    return dataclasses.replace(motion, priors=priors), note


# Features this share of the image circle's radius inside its edge and beyond are not used: their
# descriptors see the edge, which stays where it is in the image while the scene turns.
EDGE_SHARE = 0.03


def lens_matches(
    views: Sequence[np.ndarray],
    image: Image,
    *,
    circle_radius: float | None = None,
    detector: str,
    max_features: int,
    ratio: float,
    mutual: bool,
) -> list[tuple[int, int, np.ndarray, np.ndarray]]:
    """One lens matched with itself across frames: ``(f, g, xy_f, xy_g)`` for every pair of its
    ``views`` (one per frame), features detected within its image circle for a circular fisheye
    (about its centre shifts; ``circle_radius`` px, default the frame's half size), :data:`EDGE_SHARE`
    of the radius clear of its edge."""
    width, height = image.width, image.height
    circle = None
    if image.projection == 2:
        centre = (width / 2 - 0.5 + image.d, height / 2 - 0.5 + image.e)
        radius = min(width, height) / 2 if circle_radius is None else circle_radius
        circle = dict(circle_radius=(1.0 - EDGE_SHARE) * radius, centre=centre)
    mask = lens_mask(width, height, **(circle or {}))
    features = [detect(view, detector=detector, max_features=max_features, mask=mask) for view in views]
    out = []
    for f in range(len(views)):
        for g in range(f + 1, len(views)):
            index = match(features[f], features[g], ratio=ratio, mutual=mutual)
            out.append((f, g, features[f].xy[index[:, 0]], features[g].xy[index[:, 1]]))
    return out


def turn_between_deg(turns: np.ndarray) -> np.ndarray:
    """``(F, F)``: the angle between the camera's orientations in every two frames (``turns``, yaw,
    pitch and roll per frame)."""
    world = np.asarray(world_from_cam(*(np.asarray(turns, float)[:, k] for k in range(3))), np.float64)
    return _angle_deg(world[:, None], world[None, :])


__all__ = [
    "MotionConfig",
    "MotionFit",
    "PairFit",
    "across_frames",
    "across_tracks",
    "circle_priors",
    "circle_start",
    "frame_image",
    "frame_turns",
    "frames_centres",
    "frames_project",
    "lens_matches",
    "near_points",
    "ransac_pairs",
    "rigid_frames",
    "solve_motion",
    "split_rig",
    "start_from_pairs",
    "turn_between_deg",
]
