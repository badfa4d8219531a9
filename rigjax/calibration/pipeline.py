"""From a rig's images to a calibrated project: ``rigjax.calibrate`` and ``rigjax calibrate``.

The pipeline (each step its own module; steps 2-6 are the stages of :func:`calibrate_matches`, a
function each in :mod:`rigjax.calibration.stages`):

1. features and matches of every pair (:mod:`rigjax.calibration.features`), or of the template's overlaps,
   in the images or, for narrow overlaps, in a band around each pair's seam (:mod:`rigjax.calibration.seam`);
   side-by-side images (dual fisheyes) are split into their two cameras first; with several frames of
   the rig, each frame is matched and each pair's matches pool into one set (:func:`calibrate_frames`;
   with ``features.retrack``, the frames are tracked again through the bands of the calibrated
   cameras and calibrated again, that many times);
2. RANSAC of each pair's rotation on bearing vectors of the nominal lens (:mod:`rigjax.calibration.ransac`;
   with the template's camera centres and objective ``reprojection``, a match agrees when it lies on
   its epipolar plane, so that near points stay); the inliers become control points;
3. initial orientations from the template, or in closed form over a maximum spanning tree of
   the match graph (:mod:`rigjax.calibration.initial`);
4. a Lévy-flight search for LM starts (:mod:`rigjax.calibration.levy`), solved in one ``optimise_batch``
   call with the template's schedule; the best result (lowest truncated cost) wins;
5. iterative pruning with the schedule's last stage (:mod:`rigjax.optimiser.prune`); with objective
   ``reprojection``, of the bundle adjustment (:mod:`rigjax.optimiser.bundle`) of every RANSAC
   inlier from the rotation-only search's cameras, and a warning for each camera whose yaw it knows
   worse than ``warn_yaw_sd_deg``;
6. the checks (:mod:`rigjax.calibration.checks`): the parameters the matches did not determine, or
   that no lens or layout of the template's can have (``Calibration.undetermined``; ``rigjax calibrate``
   refuses to write such a project unless asked).

:func:`match_images` (step 1) and :func:`calibrate_matches` (steps 2-6) can be called apart,
e.g. to inspect or edit matches.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from typing import NamedTuple

import numpy as np

from ..camera.model import Camera
from ..camera.photometry import PHOTOMETRIC_LETTERS
from ..errors import RigjaxError
from ..optimiser.prune import PrunedResult
from ..optimiser.result import OptimiseResult
from ..optimiser.schedule import LENS_LETTERS
from ..optimiser.staged import Result
from ..pto.project import Project
from ..pto.records import IMAGE_FIELDS
from .agreement import FrameSolution, agreeing_frames, contradicted_by
from .checks import beyond_mounting, held_by_prior
from .checks import undetermined as undetermined_lines
from .exposure import ExposureFit, fit_exposure, format_exposure
from .features import detect, lens_mask, match
from .motion import (
    MotionConfig,
    circle_priors,
    circle_start,
    frame_image,
    frame_turns,
    lens_matches,
    ransac_pairs,
    solve_motion,
    start_from_pairs,
    turn_between_deg,
    vignetting_linked,
)
from .seam import match_in_seam_band, track_in_seam_band
from .stages import (
    PairReport,
    check_stage,
    nominal_project,
    ransac_stage,
    refine_stage,
    rig_centres,
    search_stage,
    start_stage,
)
from .template import CalibrateConfig


class CalibrationError(RigjaxError):
    """Images that cannot be calibrated as given; the message names the images or the pair."""


class PairMatches(NamedTuple):
    """Matched pixels of one image pair: ``xy_a`` in image ``a``, ``xy_b`` in image ``b``."""

    a: int
    b: int
    xy_a: np.ndarray
    xy_b: np.ndarray


@dataclass(frozen=True, eq=False)
class Calibration:
    """What :func:`calibrate` found.

    ``project``: the calibrated rig, kept control points as ``c`` lines and pruned ones as
    comments; ``start``: the project LM started from (initial values, all RANSAC inliers);
    ``pairs``: matches and inliers per pair; ``result``: the final LM result (a :class:`Result`, or a
    :class:`~rigjax.optimiser.bundle.BundleResult` with objective reprojection);
    ``search``: the LM result of every start of the Lévy search (best first);
    ``pruned``: the pruning rounds (``None`` when pruning is off); ``undetermined``: a line per
    parameter the matches did not determine or no lens of the template's can have
    (:func:`rigjax.calibration.checks.undetermined`; empty: none); ``notes``: what the template's
    priors rather than the matches fixed (:func:`rigjax.calibration.checks.held_by_prior`);
    ``exposure``: the photometric fit (template ``photometry.fit``; ``None``: not fitted);
    ``turns``: with the template's ``motion`` over several frames, the camera's turn from frame 0 to
    every frame ``(F, 3)`` (yaw, pitch, roll, degrees; ``None`` otherwise), and ``mounting_spread_deg`` ``(L,)``, how far
    each lens's mounting, as each frame's own matches pull it, strays from its mean; ``result``, ``start`` and ``pairs`` are
    then those of every frame's images (:mod:`rigjax.calibration.motion`).
    """

    project: Project
    start: Project
    pairs: tuple[PairReport, ...]
    result: OptimiseResult
    search: tuple[Result, ...]
    pruned: PrunedResult | None
    warn_yaw_sd_deg: float = 0.1
    undetermined: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    exposure: ExposureFit | None = None  # with the template's photometry.fit
    turns: np.ndarray | None = None  # with the template's motion
    mounting_spread_deg: np.ndarray | None = None  # with the template's motion

    @property
    def warnings(self) -> list[str]:
        """Cameras whose yaw the bundle adjustment knows worse than ``warn_yaw_sd_deg`` (1 SD)."""
        if self.result.standard_deviations is None:  # a rotation-only result
            return []
        yaw = self.result.standard_deviations[: len(self.project.images), 6]  # the rig's (frame 0's, with motion)
        return [
            f"warning: camera {k}'s yaw is known to {yaw[k]:.3f} deg (1 standard deviation), worse than "
            f"{self.warn_yaw_sd_deg:g}: its matches are too few or too close to the seam's middle"
            for k in np.flatnonzero(yaw > self.warn_yaw_sd_deg)
        ]

    def summary(self) -> str:
        lines = ["pair      matches  inliers"]
        lines += [
            f"{p.a:>2}-{p.b:<5} {p.matches:>8} {p.inliers:>8}{'' if p.used else '  (not used)'}" for p in self.pairs
        ]
        lines.append(
            f"\ncontrol points: {len(self.start.control_points)} from RANSAC inliers; LM starts: {len(self.search)}"
        )
        lines.append((self.search[0] if self.search else self.result).format_stages())
        if self.pruned is not None:
            rounds = self.pruned.rounds
            lines.append(
                f"\npruning: removed {len(self.pruned.removed)} points in {sum(1 for r in rounds if r[2])} "
                "round(s); per LM solve (points, rms px, removed): "
                + ", ".join(f"({n}, {r:.3f}, {d})" for n, r, d in rounds)
                + (f"; {self.pruned.readmitted.size} readmitted" if self.pruned.readmitted.size else "")
            )
        lines.append(f"final rms {self.result.format_rms()}")
        if deviations := self.result.format_deviations():  # the bundle adjustment's
            lines.append(deviations)
        lines += self.warnings + list(self.notes)
        if self.exposure is not None:
            lines.append(format_exposure(self.exposure))
        if self.turns is not None:
            lines.append(
                "\ncamera's turn per frame (yaw, pitch, roll deg): "
                + "; ".join(f"{y:.2f}, {p:.2f}, {r:.2f}" for y, p, r in self.turns)
            )
        heads = ("hfov", "a", "b (K2)", "c", "d", "e", "yaw", "pitch", "roll")
        widths = (8, 8, 8, 8, 7, 7, 9, 9, 9)
        lines.append("\ncam " + " ".join(f"{h:>{w}}" for h, w in zip(heads, widths)))
        for k, im in enumerate(self.project.images):
            lines.append(
                f"{k:>3} {im.hfov:>8.3f} {im.a:>8.5f} {im.b:>8.5f} {im.c:>8.5f} {im.d:>7.2f} {im.e:>7.2f} "
                f"{im.yaw:>9.3f} {im.pitch:>9.3f} {im.roll:>9.3f}"
            )
        return "\n".join(lines)


def _check_inputs(config: CalibrateConfig, images: Sequence[np.ndarray], names: Sequence[str]) -> None:
    if len(images) != config.rig.cameras:
        raise CalibrationError(
            f"the template describes {config.rig.cameras} cameras, but {len(images)} images "
            f"were given ({', '.join(names)})"
        )
    for name, image in zip(names, images):
        if image.ndim not in (2, 3) or image.dtype != np.uint8:
            raise CalibrationError(f"{name}: expected an 8-bit image, got {image.dtype} {image.shape}")
    first = images[0].shape
    for name, image in zip(names, images):
        if config.rig.shared_lens and image.shape[:2] != first[:2]:
            raise CalibrationError(
                f"{name} is {image.shape[1]}x{image.shape[0]} but {names[0]} is {first[1]}x{first[0]}: "
                "the template says one lens for all cameras (shared_lens), so all images must be one size"
            )


def split_side_by_side(
    images: Sequence[np.ndarray], config: CalibrateConfig, names: Sequence[str] | None = None
) -> tuple[list[np.ndarray], list[str]]:
    """The template's cameras from side-by-side images (``rig.side_by_side``): each image's left
    half, then its right half. Names ``NAME.jpg`` become ``NAME-left.png`` and ``NAME-right.png``
    (the files ``rigjax calibrate`` writes beside the project)."""
    names = list(names) if names is not None else [f"image{k}.png" for k in range(len(images))]
    if 2 * len(images) != config.rig.cameras:
        raise CalibrationError(
            f"the template describes {config.rig.cameras} cameras side by side, two per image, "
            f"but {len(images)} images were given ({', '.join(names)})"
        )
    halves, half_names = [], []
    for name, image in zip(names, images):
        if image.ndim not in (2, 3) or image.shape[1] % 2:
            raise CalibrationError(f"{name}: a side-by-side image needs an even width, got {image.shape[1::-1]}")
        width, stem = image.shape[1] // 2, os.path.splitext(name)[0]
        halves += [np.ascontiguousarray(image[:, :width]), np.ascontiguousarray(image[:, width:])]
        half_names += [f"{stem}-left.png", f"{stem}-right.png"]
    return halves, half_names


def _pairs(config: CalibrateConfig) -> list[tuple[int, int]]:
    n = config.rig.cameras
    if config.rig.overlaps is not None:
        return sorted({(min(a, b), max(a, b)) for a, b in config.rig.overlaps})
    return [(a, b) for a in range(n) for b in range(a + 1, n)]


def match_images(
    images: Sequence[np.ndarray],
    config: CalibrateConfig,
    *,
    names: Sequence[str] | None = None,
    progress: Callable[[str], None] | None = None,
    cameras: Camera | None = None,
) -> list[PairMatches]:
    """Features of every image (masked to the lens's circle for circular fisheyes) and the
    matches of every pair to be matched; with ``features.seam_band_deg``, in each pair's seam band
    (with ``features.track_step_px``, points tracked there instead of features matched).

    ``images`` are the cameras' images (side-by-side ones already split: :func:`split_side_by_side`).
    ``cameras``: with seam bands, a calibration's cameras (one :class:`~rigjax.camera.model.Camera`
    of every image) to make them with instead of the template's nominal ones; tracks then start
    where the calibrated bands show far content, without feature seeds.
    """
    names = list(names) if names is not None else [f"image {k}" for k in range(len(images))]
    _check_inputs(config, images, names)
    options = dict(
        detector=config.features.detector,
        max_features=config.features.max_features,
        ratio=config.features.ratio,
        mutual=config.features.mutual,
    )
    if config.features.seam_band_deg is not None:
        sizes = [(image.shape[1], image.shape[0]) for image in images]
        seeded = cameras is None
        if seeded:
            cameras = nominal_project(config, sizes, names).cameras()
        centres = rig_centres(config)
        out = []
        for a, b in _pairs(config):
            if progress:
                progress(
                    f"matching {a}-{b} in their seam band" if seeded else f"tracking {a}-{b} in the calibrated band"
                )
            band = dict(band_deg=config.features.seam_band_deg, circle=config.rig.projection == 2)
            if config.features.track_step_px is not None:
                xy_a, xy_b = track_in_seam_band(
                    images[a],
                    images[b],
                    cameras.take(a),
                    cameras.take(b),
                    step_px=config.features.track_step_px,
                    baseline=None if centres is None else centres[b] - centres[a],
                    seed_threshold_deg=config.ransac.threshold_deg,
                    seeded=seeded,
                    **band,
                    **options,
                )
            else:
                xy_a, xy_b = match_in_seam_band(
                    images[a], images[b], cameras.take(a), cameras.take(b), **band, **options
                )
            out.append(PairMatches(a, b, xy_a, xy_b))
        return out
    features = []
    for name, image in zip(names, images):
        if progress:
            progress(f"features {name}")
        height, width = image.shape[:2]
        radius = 0.98 * width / 2 if config.rig.projection == 2 else None
        features.append(
            detect(
                image,
                detector=options["detector"],
                max_features=options["max_features"],
                mask=lens_mask(width, height, circle_radius=radius),
            )
        )
    out = []
    for a, b in _pairs(config):
        if progress:
            progress(f"matching {a}-{b}")
        index = match(features[a], features[b], ratio=options["ratio"], mutual=options["mutual"])
        out.append(PairMatches(a, b, features[a].xy[index[:, 0]], features[b].xy[index[:, 1]]))
    return out


def calibrate_matches(
    matches: Sequence[PairMatches],
    sizes: Sequence[tuple[int, int]],
    config: CalibrateConfig,
    *,
    names: Sequence[str] | None = None,
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
    frames: int = 1,
) -> Calibration:
    """RANSAC, initial values, Lévy-flight starts, staged LM and pruning on given matches, and the
    checks: the stages of :mod:`rigjax.calibration.stages`, in order.

    ``sizes`` are the images' ``(width, height)``; ``frames``: how many frames of the rig the
    matches pool (:func:`pool_matches`): each pair keeps ``features.max_points_per_pair`` inliers
    per frame.
    """
    names = list(names) if names is not None else [f"image {k}" for k in range(len(sizes))]
    if len(sizes) != config.rig.cameras:
        raise CalibrationError(
            f"the template describes {config.rig.cameras} cameras, but {len(sizes)} images were given"
        )
    nominal = nominal_project(config, sizes, names)
    inliers = ransac_stage(matches, nominal, config, names=names, seed=seed, frames=frames, progress=progress)
    _raise_failure(inliers.failure)
    start = start_stage(nominal, inliers, config, names=names)
    _raise_failure(start.failure)
    search = search_stage(start.project, config, seed=seed, progress=progress)
    refined = refine_stage(search, start.project, config, progress=progress)
    found = check_stage(refined, start.project, config)
    return Calibration(
        refined.project,
        start.project,
        inliers.reports,
        refined.result,
        search,
        refined.pruned,
        config.warn_yaw_sd_deg,
        found.undetermined,
        found.notes,
    )


def _raise_failure(failure: str | None) -> None:
    """A stage's failure (:mod:`rigjax.calibration.stages`) as the calibration's error."""
    if failure is not None:
        raise CalibrationError(failure)


def calibrate(
    images: Sequence[np.ndarray],
    config: CalibrateConfig,
    *,
    names: Sequence[str] | None = None,
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
) -> Calibration:
    """Calibrate a rig from one image per camera (``(h, w, 3)`` uint8 RGB), as the template says
    (with ``rig.side_by_side``: one image per two cameras, split by :func:`split_side_by_side`);
    or from several frames of the same rig, their images one frame after another
    (:func:`frames_of`), whose matches pool into one calibration (:func:`calibrate_frames`).

    ``names`` (file names) go into the project's ``n`` tokens (the first frame's) and into error
    messages.
    """
    names = list(names) if names is not None else [f"image{k}.png" for k in range(len(images))]
    return calibrate_frames(frames_of(images, config, names), config, seed=seed, progress=progress)


def frames_of(
    images: Sequence[np.ndarray], config: CalibrateConfig, names: Sequence[str]
) -> list[tuple[list[np.ndarray], list[str]]]:
    """The frames of one rig in ``images``, one frame's images after another: per frame, each
    camera's image and name (side-by-side images split: :func:`split_side_by_side`). A frame takes
    one image per camera, or per two cameras side by side."""
    per_frame = config.rig.cameras // 2 if config.rig.side_by_side else config.rig.cameras
    if not images or len(images) % per_frame:
        what = "side-by-side image" if config.rig.side_by_side else "image"
        raise CalibrationError(
            f"the template's rig takes {per_frame} {what}(s) per frame ({config.rig.cameras} cameras), "
            f"but {len(images)} images were given ({', '.join(names)}): one frame, or several one after another"
        )
    frames = []
    for start in range(0, len(images), per_frame):
        chunk, chunk_names = list(images[start : start + per_frame]), list(names[start : start + per_frame])
        if config.rig.side_by_side:
            chunk, chunk_names = split_side_by_side(chunk, config, chunk_names)
        frames.append((chunk, chunk_names))
    return frames


def pool_matches(per_frame: Sequence[Sequence[PairMatches]]) -> list[PairMatches]:
    """Each pair's matches of every frame as one: the frames see one rig, so one rotation (one
    geometry) explains them all."""
    pooled: dict[tuple[int, int], list[PairMatches]] = {}
    for matches in per_frame:
        for pair in matches:
            pooled.setdefault((pair.a, pair.b), []).append(pair)
    return [
        PairMatches(a, b, np.concatenate([m.xy_a for m in ms]), np.concatenate([m.xy_b for m in ms]))
        for (a, b), ms in sorted(pooled.items())
    ]


def calibrate_cameras(
    images: Sequence[np.ndarray],
    config: CalibrateConfig,
    *,
    names: Sequence[str],
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
) -> Calibration:
    """:func:`calibrate` from one image per camera (side-by-side images already split)."""
    return calibrate_frames([(list(images), list(names))], config, seed=seed, progress=progress)


def _tracking_passes(config: CalibrateConfig) -> int:
    """How many times the seam bands are matched: once, and ``features.retrack`` more with tracking."""
    return 1 + (config.features.retrack if config.features.track_step_px is not None else 0)


def _frame_sizes(frames: Sequence[tuple[Sequence[np.ndarray], Sequence[str]]]) -> list[tuple[int, int]]:
    """The first frame's image sizes ``(width, height)``; a frame whose images differ is refused, named."""
    sizes = [(image.shape[1], image.shape[0]) for image in frames[0][0]]
    for k, (frame, frame_names) in enumerate(frames):
        frame_sizes = [(image.shape[1], image.shape[0]) for image in frame]
        if frame_sizes != sizes:
            raise CalibrationError(
                f"frame {k + 1} ({', '.join(frame_names)}): its images are {frame_sizes}, the first frame's {sizes}"
            )
    return sizes


def calibrate_motion(
    frames: Sequence[tuple[Sequence[np.ndarray], Sequence[str]]],
    config: CalibrateConfig,
    *,
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
) -> Calibration:
    """Each lens from the camera's own motion over several ``frames`` (:func:`frames_of`), with the
    template's ``motion`` (:mod:`rigjax.calibration.motion`): every frame's ring matched as the
    template says, each lens matched with itself across frames, RANSAC, closed-form placement and the
    bundle adjustment of every frame's images, the lenses' letters linked (the template's ``motion``,
    or :class:`~rigjax.calibration.motion.MotionConfig`'s defaults). The project is the rig in frame
    0, with the template's centres; ``turns`` the camera's turn from frame 0 to every frame."""
    motion, lenses = config.motion or MotionConfig(), config.rig.cameras
    names = [list(frame_names) for _, frame_names in frames]
    sizes = _frame_sizes(frames)
    rig = nominal_project(config, sizes, names[0])
    rig = rig.replace(images=tuple(image.replace(links={}) for image in rig.images))  # each lens its own
    notes, circles = [], []
    if motion.circle and config.rig.projection == 2 and config.rig.lenses is None:  # else the start's centres
        images = list(rig.images)
        for lens in range(lenses):
            views = [frame[lens] for frame, _ in frames]
            images[lens], circle, line = circle_start(images[lens], views, config.rig.hfov)
            circles.append(circle)
            notes.append(f"lens {lens}: {line}")
        rig = rig.replace(images=tuple(images))
    solved, note = circle_priors(motion, circles)  # the priors' d, e about the circles' centres
    notes += [note] if note else []
    radii = [None if circle is None else circle.radius for circle in circles] or [None] * lenses
    options = dict(
        detector=config.features.detector,
        max_features=config.features.max_features,
        ratio=config.features.ratio,
        mutual=config.features.mutual,
    )
    lens_pairs = []
    for lens in range(lenses):
        if progress:
            progress(f"lens {lens} across frames")
        views = [frame[lens] for frame, _ in frames]
        for f, g, xy_f, xy_g in lens_matches(views, rig.images[lens], circle_radius=radii[lens], **options):
            lens_pairs.append((frame_image(f, lens, lenses), frame_image(g, lens, lenses), xy_f, xy_g))
    ransac, cameras = config.ransac, None
    fit_pairs = partial(
        ransac_pairs, rig=rig, threshold_deg=ransac.threshold_deg, iterations=ransac.iterations, seed=seed
    )
    if progress:
        progress("RANSAC")
    lens_fits = fit_pairs(lens_pairs)
    centres = config.optimise.centres or config.rig.centres
    # The ring is tracked with the template's geometry, then (features.retrack) again through the
    # calibrated lenses: a lens a few degrees or pixels off the template misplaces the first tracks.
    # A pass that only places the next one's tracks is solved without pruning; frames that turned
    # too little for the lenses are solved once.
    passes = _tracking_passes(config)
    for k in range(passes):
        ring_pairs = []
        for f, (frame, frame_names) in enumerate(frames):
            if progress:
                progress(f"frame {f + 1} of {len(frames)}")
            for m in match_images(frame, config, names=frame_names, progress=progress, cameras=cameras):
                ring_pairs.append((frame_image(f, m.a, lenses), frame_image(f, m.b, lenses), m.xy_a, m.xy_b))
        fits = fit_pairs(ring_pairs) + lens_fits
        try:
            start = start_from_pairs(
                rig,
                len(frames),
                fits,
                names,
                min_inliers=ransac.min_inliers,
                max_points_per_pair=config.features.max_points_per_pair,
                seed=seed,
            )
        except RigjaxError as error:
            raise CalibrationError(str(error)) from None
        turned = float(turn_between_deg(frame_turns(start, lenses)).max())
        last = k == passes - 1 or turned < motion.min_turn_deg
        settings = config.optimise if last else config.optimise.replace(prune=None)
        if progress:
            progress("bundle adjustment of every frame" + (" and pruning" if settings.prune else ""))
        bias = config.features.track_bias_px if config.features.track_step_px else 0.0
        fit = solve_motion(start, lenses, solved, settings, bias, centres, spread=last)
        cameras = fit.rig.cameras(host=True)
        if last:
            break
    reports = tuple(
        PairReport(p.a, p.b, len(p.xy_a), int(p.inliers.sum()), int(p.inliers.sum()) >= ransac.min_inliers)
        for p in fits
    )
    rig_written = fit.rig if centres is None else fit.rig.replace(centres=np.asarray(centres, float))
    first = dataclasses.replace(  # frame 0's images: the rig's lenses, lens 1.. relative to lens 0
        fit.result,
        standard_deviations=fit.result.standard_deviations[:lenses],
        orientation_sd_deg=fit.result.orientation_sd_deg[:lenses],
    )
    turned = float(turn_between_deg(fit.turns).max())
    if turned < motion.min_turn_deg:  # the one reason for whatever else the frames leave undetermined
        undetermined = (
            f"the camera turned at most {turned:.2f} deg between two frames (motion.min_turn_deg "
            f"{motion.min_turn_deg:g}): too little to tell its lenses; give frames of a turn",
        )
    else:
        undetermined = _motion_undetermined(fit, first, rig, config, solved, solved is not motion, notes)
    calibration = Calibration(
        rig_written,
        start,
        reports,
        fit.result,
        (),
        fit.pruned,
        config.warn_yaw_sd_deg,
        undetermined,
        tuple(notes),
        turns=fit.turns,
        mounting_spread_deg=fit.mounting_spread_deg,
    )
    if turned < motion.min_turn_deg:  # the same radii in every frame: frame 0's overlaps, as without motion
        return _with_exposure(calibration, frames[0][0], config, seed, progress)
    every_image = [image for frame, _ in frames for image in frame]
    return _with_exposure(
        calibration, every_image, config, seed, progress, vignetting_linked(fit.result.project, lenses)
    )


def _motion_undetermined(
    fit,
    first,
    nominal: Project,
    config: CalibrateConfig,
    motion: MotionConfig,
    held_by_circle: bool,
    notes: list[str],
) -> tuple[str, ...]:
    """What a motion calibration (``fit``; ``first``: its result's deviations for frame 0's images;
    ``motion``: the settings it solved with, :func:`~rigjax.calibration.motion.circle_priors`;
    ``held_by_circle``: their ``d``, ``e`` priors are the image circles') leaves undetermined: the
    template's checks of the hfov, orientations and mounting against the ``nominal`` rig, every lens
    letter the frames leave free, and a lens whose mounting differs between frames more than
    ``motion.max_spread_deg``. Appends to ``notes`` the spreads within it and the lens letters other
    than the hfov that their priors rather than the frames fix (the hfov's prior is weak: an hfov it
    fixes is refused by the checks, not noted), each named by where its prior came from."""
    lines = undetermined_lines(fit.rig, first, config.checks, config.rig.hfov)
    lines += beyond_mounting(fit.rig, nominal, config.checks)
    for column, letter in enumerate(LENS_LETTERS):
        for lens in np.flatnonzero(np.isinf(first.standard_deviations[:, column])):
            lines += (
                f"lens {lens}: {letter.lower()} is not determined by the frames (they leave it free): give it "
                f"a prior (motion.priors {letter.lower()}) or a schedule without {letter}",
            )
    for lens, spread in enumerate(fit.mounting_spread_deg[1:], start=1):
        line = f"lens {lens}: its mounting differs by up to {spread:.3f} deg between frames"
        if spread > motion.max_spread_deg:
            lines += (
                f"{line} (motion.max_spread_deg {motion.max_spread_deg:g}): the frames disagree (near content "
                "seen from lenses that moved between frames, or wrong matches)",
            )
        else:
            notes.append(line)
    priors = {letter: sd for letter, sd in motion.priors.as_dict().items() if letter != "V"}
    circle = {letter: priors.pop(letter) for letter in "DE" if letter in priors} if held_by_circle else {}
    notes += held_by_prior(fit.rig, first, priors, "motion.priors")
    notes += held_by_prior(fit.rig, first, circle, "motion.circle_centre_px")
    return lines


def _with_exposure(
    calibration: Calibration,
    images: Sequence[np.ndarray],
    config: CalibrateConfig,
    seed: int,
    progress: Callable[[str], None] | None,
    frames: Project | None = None,
) -> Calibration:
    """``calibration`` with the exposure, white balance and vignetting fitted in its overlaps of
    ``images`` (one frame) when the template's ``photometry.fit`` says so. ``frames``: a motion
    calibration's every frame's images as solved (:func:`~rigjax.calibration.motion.vignetting_linked`),
    ``images`` theirs: each lens's vignetting from the same directions seen at different radii in
    different frames, each image's exposure and white balance its own, the rig taking frame 0's."""
    photometry = config.photometry
    if not photometry.fit:
        return calibration
    if progress:
        progress("exposure and vignetting")
    fit = fit_exposure(
        calibration.project if frames is None else frames,
        images,
        white_balance=photometry.white_balance,
        vignetting_fit=photometry.vignetting,
        max_vignetting_sd=photometry.max_vignetting_sd,
        max_rms=photometry.max_rms_stops,
        seed=seed,
    )
    rig = calibration.project
    fitted = fit.project.images[: len(rig.images)]  # frame 0's images come first
    letters = {IMAGE_FIELDS[letter] for letter in PHOTOMETRIC_LETTERS}
    rig = rig.replace(
        images=tuple(im.replace(**{f: getattr(new, f) for f in letters}) for im, new in zip(rig.images, fitted))
    )
    return dataclasses.replace(calibration, project=rig, exposure=fit)


def calibrate_frames(
    frames: Sequence[tuple[Sequence[np.ndarray], Sequence[str]]],
    config: CalibrateConfig,
    *,
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
) -> Calibration:
    """:func:`calibrate` from one or more frames of the rig (:func:`frames_of`: per frame, one image
    per camera and their names). With the template's ``motion`` and more than one frame, each lens
    from the camera's motion (:func:`calibrate_motion`); else every frame matched, the matches pooled (:func:`pool_matches`) and
    calibrated at once, the project naming the first frame's images; with ``features.retrack``,
    tracked again through the calibrated cameras' bands and calibrated again. Several frames are
    also calibrated alone, and the pool checked against them (:func:`_pooled_and_checked`; the
    template's ``checks.frames_max_ray_deg`` null: pooled unchecked). With the template's
    ``photometry.fit``, the exposure, white balance and vignetting fitted in the overlaps of the
    calibrated rig's first frame (:func:`rigjax.calibration.exposure.fit_exposure`)."""
    if config.motion is not None and len(frames) > 1:
        return calibrate_motion(frames, config, seed=seed, progress=progress)
    if config.motion is not None:
        one_frame = "note: one frame: the lenses are calibrated from its ring, not from the camera's motion"
        calibration = calibrate_frames(frames, dataclasses.replace(config, motion=None), seed=seed, progress=progress)
        return dataclasses.replace(calibration, notes=calibration.notes + (one_frame,))
    if len(frames) > 1 and config.checks.frames_max_ray_deg is not None:
        return _pooled_and_checked(frames, config, seed, progress)
    return _with_exposure(_pooled(frames, config, seed, progress), frames[0][0], config, seed, progress)


def _pooled(
    frames: Sequence[tuple[Sequence[np.ndarray], Sequence[str]]],
    config: CalibrateConfig,
    seed: int,
    progress: Callable[[str], None] | None,
    names: Sequence[str] | None = None,
) -> Calibration:
    """Every frame matched, the matches pooled and calibrated at once, and tracked again
    (``features.retrack``) through the calibrated cameras' bands; the project naming ``names``
    (default the first frame's images)."""
    names, sizes = names or frames[0][1], _frame_sizes(frames)
    calibration = None
    for _ in range(_tracking_passes(config)):
        cameras = None if calibration is None else calibration.project.cameras(host=True)
        per_frame = []
        for k, (frame, frame_names) in enumerate(frames):
            if progress and len(frames) > 1:
                progress(f"frame {k + 1} of {len(frames)}")
            per_frame.append(match_images(frame, config, names=frame_names, progress=progress, cameras=cameras))
        calibration = calibrate_matches(
            pool_matches(per_frame), sizes, config, names=names, seed=seed, progress=progress, frames=len(frames)
        )
    return calibration


def _pooled_and_checked(
    frames: Sequence[tuple[Sequence[np.ndarray], Sequence[str]]],
    config: CalibrateConfig,
    seed: int,
    progress: Callable[[str], None] | None,
) -> Calibration:
    """Each frame calibrated alone, the frames compared (:mod:`rigjax.calibration.agreement`), and the
    pool of every frame (:func:`_pooled`) written unless most of the trusted frames' own calibrations
    contradict it, else the pool of the trusted frames; the frames outside said in the notes. No
    majority, or a pool that most trusted frames contradict: refused (a line in ``undetermined``). The project names
    the first frame's images, and the exposure is fitted in them, whichever frames were pooled."""
    checks = config.checks
    limits = dict(max_ray_deg=checks.frames_max_ray_deg, max_sigmas=checks.frames_max_sigmas)
    _frame_sizes(frames)  # frames of other sizes refused before any is calibrated
    solutions = []
    for k, frame in enumerate(frames):
        if progress:
            progress(f"frame {k + 1} of {len(frames)} calibrated alone, to check the pooled calibration against")
        try:
            own = _pooled([frame], config, seed, None)
        except CalibrationError as error:
            solutions.append(FrameSolution(frame[1][0], failure=str(error)))
            continue
        if not own.result.ok:  # stopped short of its optimum: no measure of the frame
            failure = f"its last solve did not converge: {own.result.stages[-1].status}"
            solutions.append(FrameSolution(frame[1][0], failure=failure))
            continue
        solutions.append(FrameSolution.of(frame[1][0], own.project, own.result))
    agreement = agreeing_frames(solutions, **limits)
    trusted = [solutions[k] for k in agreement.trusted]
    pooled = _pooled(frames, config, seed, progress)
    refusal, differing = agreement.refusal, ()
    if refusal is None:
        refusal, differing = contradicted_by(pooled.project, trusted, **limits)
    repooled = refusal is not None and agreement.refusal is None and len(trusted) < len(frames)
    if repooled:
        if progress:
            progress(f"the pool of every frame contradicts the frames' own: {len(trusted)} frames pooled again")
        pooled = _pooled([frames[k] for k in agreement.trusted], config, seed, progress, names=frames[0][1])
        refusal, differing = contradicted_by(pooled.project, trusted, **limits)
    if refusal is not None:
        said = "note: {}"
    elif repooled:
        said = "note: left out: {}"
    elif trusted:
        said = f"note: {{}}; the pool of every frame is written, checked against the {len(trusted)} trusted frames' own"
    else:
        said = "note: {}; the pool of every frame is written unchecked: no frame calibrates the rig alone"
    outliers = tuple(said.format(line) for line in agreement.outliers)
    pooled = dataclasses.replace(
        pooled,
        undetermined=pooled.undetermined + (() if refusal is None else (refusal,)),
        notes=pooled.notes + outliers + differing,
    )
    return _with_exposure(pooled, frames[0][0], config, seed, progress)


__all__ = [
    "Calibration",
    "CalibrationError",
    "PairMatches",
    "PairReport",
    "calibrate",
    "calibrate_cameras",
    "calibrate_frames",
    "calibrate_matches",
    "calibrate_motion",
    "frames_of",
    "match_images",
    "pool_matches",
    "split_side_by_side",
]
