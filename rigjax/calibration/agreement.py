"""A calibration pooled from several frames of a rig, checked against each frame's own.

Pooling frames multiplies the matches, and with them the calibration's confidence; it also lets one
frame whose matches agree with each other on something wrong (a near object in the seam, a
repeated facade locked on its neighbouring period) pull every frame's result with it, and the pooled
standard deviations, small as they are, do not show it. So each frame is also calibrated alone, from
its own matches, and the frames are compared, two at a time, through:

* their rays: the angle between the two calibrations' rays through a raster of each image's pixels,
  95th percentile, once the one rotation of the whole rig that the images cannot tell is removed
  (:func:`ray_angles_deg`, the same measure the benchmarks judge a calibration by); and
* their deviations: the largest difference of a parameter (a lens letter, a yaw, pitch or roll)
  in standard deviations of the difference, each frame's own from its bundle adjustment.

Two frames disagree when both exceed the template's limits (``checks.frames_max_ray_deg``,
``checks.frames_max_sigmas``): a difference too small to matter is let pass however sure the frames
are, and one within what the frames know (a frame that cannot tell its hfov, say) however large.
The defaults, 0.5 degrees and 4 deviations, come from the dual-fisheye benchmark: one frame's ring
calibrates a dual fisheye commonly within half a degree of the truth while its deviations say a
tenth, so smaller differences say nothing against a frame; the failures the check is for (a lens
knocked between frames, a near wall's tracks locked on a wrong tilt) are degrees.
A frame that agrees with at least half of the others is trusted (one pair of frames that differ a
little more than the limits allow does not cost the rest a calibration); more than half of the
frames must be trusted, else (two frames that disagree, three that all differ) the calibration is
refused.

A frame not trusted may still hold good matches (its own calibration can fail where its
matches help a pool: a frame whose seam holds one near object), so the pool of every frame is
written unless more than half of the trusted frames' own calibrations contradict it, each judged
through that frame's deviations alone (the pool holds its matches); one frame alone cannot veto
it, as one frame's ring alone can end degrees off while its deviations say a tenth. Where they do,
the trusted frames alone are pooled, and checked the same way; where that pool too is
contradicted, the calibration is refused. A written calibration is never one most of its trusted
frames contradict.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..camera.model import img_to_ray
from ..camera.rotation import world_from_cam
from ..optimiser.schedule import LENS_LETTERS, UNIT
from ..pto.project import Project
from .ransac import angle_between, rotation_from_bearings


@dataclass(frozen=True)
class FrameSolution:
    """One frame's own calibration, or a pooled one: ``project``; its standard deviations
    ``(n_images, 9)``, letters VABCDEYPR in the solver's units, and each camera's turn covariance
    ``(n_images, 3, 3)`` (degrees squared, world axes, the rig's own turn removed), as the bundle
    adjustment reports them (:class:`~rigjax.optimiser.bundle.BundleResult`; None: a rotation-only
    result reports none); or ``failure``, why its matches alone do not calibrate the rig."""

    name: str
    project: Project | None = None
    deviations: np.ndarray | None = None
    turn_covariance: np.ndarray | None = None
    failure: str | None = None

    @classmethod
    def of(cls, name: str, project: Project, result) -> FrameSolution:
        """From a calibration's ``project`` and last ``result`` (its deviations where it has them)."""
        return cls(name, project, result.standard_deviations, getattr(result, "turn_covariance", None))


def ray_angles_deg(
    project: Project, truth: Project, *, grid: int = 48, field_deg: float | None = None, margin_deg: float = 2.0
) -> list[np.ndarray]:
    """Per image, the angles (degrees) between ``project``'s and ``truth``'s rays through a ``grid x
    grid`` raster of its pixels whose true ray lies within the lens's field less ``margin_deg`` off its
    axis (``field_deg``: the lens's field of view; default each image's hfov), after the one rotation
    of all images together that fits the calibrated rays to the true ones best (the rig's own, which
    images cannot tell): a calibration judged through its rays, not its parameters."""
    got, want, owner = [], [], []
    true_cameras, cameras = truth.cameras(), project.cameras()
    axes = np.asarray(true_cameras.world_from_cam)[..., :, 2]
    for k, image in enumerate(truth.images):
        ticks_x = (np.arange(grid) + 0.5) / grid * image.width - 0.5
        ticks_y = (np.arange(grid) + 0.5) / grid * image.height - 0.5
        xy = np.stack(np.meshgrid(ticks_x, ticks_y), -1).reshape(-1, 2)
        ray, ok = img_to_ray(cameras.take(k), xy)
        true_ray, true_ok = img_to_ray(true_cameras.take(k), xy)
        field = image.hfov if field_deg is None else field_deg
        inside = np.degrees(angle_between(np.asarray(true_ray), axes[k][None])) <= field / 2.0 - margin_deg
        keep = np.asarray(ok) & np.asarray(true_ok) & inside
        got.append(np.asarray(ray)[keep])
        want.append(np.asarray(true_ray)[keep])
        owner.append(np.full(int(keep.sum()), k))
    got, want, owner = np.concatenate(got), np.concatenate(want), np.concatenate(owner)
    angle = np.degrees(angle_between(got @ rotation_from_bearings(got, want).T, want))
    return [angle[owner == k] for k in range(len(truth.images))]


def ray_difference_deg(a: Project, b: Project) -> float:
    """How far two calibrations of one rig differ through their rays: the 95th percentile over every
    image of :func:`ray_angles_deg` (``b``'s fields)."""
    angles = np.concatenate(ray_angles_deg(a, b))
    return float(np.percentile(angles, 95)) if angles.size else math.inf


def _turns_deg(a: Project, b: Project) -> np.ndarray:
    """Each camera's turn from ``b`` to ``a`` ``(n, 3)`` (a rotation vector, degrees, world axes:
    ``R_a = exp([omega]x) R_b``), less the mean turn of all cameras: the rig's own, which the
    images cannot tell (removed as the deviations remove it)."""
    turns = []
    for image_a, image_b in zip(a.images, b.images):
        m = (
            np.asarray(world_from_cam(image_a.yaw, image_a.pitch, image_a.roll))
            @ np.asarray(world_from_cam(image_b.yaw, image_b.pitch, image_b.roll)).T
        )
        axis = 0.5 * np.array([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]])
        sine = np.linalg.norm(axis)
        angle = math.atan2(sine, (np.trace(m) - 1.0) / 2.0)
        turns.append(np.degrees(axis * (angle / sine if sine > 1e-12 else 1.0)))
    turns = np.array(turns)
    return turns - turns.mean(axis=0)


def sigmas_apart(a: FrameSolution, b: FrameSolution) -> tuple[float, str]:
    """The largest difference between two calibrations in standard deviations of the difference
    (their deviations added; a side without them counts as exact), and which (``"camera 1's hfov"``,
    ``"camera 1's turn"``); ``(nan, "")`` where neither knows a deviation.

    A lens letter is compared alone (a side that holds it, NaN, knows it exactly), where its combined
    deviation is a positive number (held by both: 0; left free: inf). A camera's orientation is compared as its turn from one calibration to
    the other with the rig's own turn removed, by its Mahalanobis distance under the sum of the turn
    covariances: the frame the deviations are reported in (:mod:`rigjax.optimiser.bundle_covariance`)."""
    if a.deviations is None and b.deviations is None:
        return math.nan, ""
    worst, what = -math.inf, ""
    n = len(a.project.images)
    held = [
        np.zeros((n, 9)) if s.deviations is None else np.nan_to_num(s.deviations, nan=0.0, posinf=np.inf)
        for s in (a, b)
    ]
    for k, (image_a, image_b) in enumerate(zip(a.project.images, b.project.images)):
        for column, letter in enumerate(LENS_LETTERS):
            sd = math.hypot(held[0][k, column], held[1][k, column]) * UNIT[letter]
            if math.isfinite(sd) and sd > 0.0:
                difference = abs(image_a.value(letter.lower()) - image_b.value(letter.lower())) / sd
                if difference > worst:
                    worst, what = difference, f"camera {k}'s {'hfov' if letter == 'V' else letter.lower()}"
    turns = _turns_deg(a.project, b.project)
    covariance = sum(
        (np.zeros((n, 3, 3)) if s.turn_covariance is None else np.asarray(s.turn_covariance)) for s in (a, b)
    )
    for k in range(n):
        if np.all(np.isfinite(covariance[k])) and np.trace(covariance[k]) > 0.0:
            distance = math.sqrt(max(float(turns[k] @ np.linalg.pinv(covariance[k]) @ turns[k]), 0.0))
            if distance > worst:
                worst, what = distance, f"camera {k}'s turn"
    return (worst, what) if math.isfinite(worst) else (math.nan, "")


@dataclass(frozen=True)
class Agreement:
    """The frames' own calibrations compared: ``trusted``, the frames that agree with at least half
    of the others (indices; empty with a ``refusal``, or where no frame could be calibrated alone);
    ``outliers``, a line for each other frame: whom it disagrees with and how far, or why it could
    not be calibrated alone; ``refusal``, a line where no majority of the frames calibrated alone is
    trusted (None: a majority is, or none could be calibrated alone)."""

    trusted: tuple[int, ...]
    outliers: tuple[str, ...] = ()
    refusal: str | None = None


def _apart(a: FrameSolution, b: FrameSolution, max_ray_deg: float, max_sigmas: float) -> str | None:
    """Why two frames' own calibrations disagree, or None where they do not."""
    rays = ray_difference_deg(a.project, b.project)
    if rays <= max_ray_deg:
        return None
    sigmas, what = sigmas_apart(a, b)
    if sigmas <= max_sigmas:  # nan (no deviations known) compares False: the rays decide alone
        return None
    known = f", {what} {sigmas:.1f} standard deviations" if math.isfinite(sigmas) else ""
    return f"{rays:.2f} deg apart (rays, 95th percentile){known}"


def agreeing_frames(solutions: Sequence[FrameSolution], *, max_ray_deg: float, max_sigmas: float) -> Agreement:
    """The frames whose own calibrations a pooled one must agree with: each that agrees with at
    least half of the other frames (module docstring), if they are more than half of the frames that
    could be calibrated alone."""
    solved = [k for k, s in enumerate(solutions) if s.failure is None]
    outliers = {
        k: f"{s.name}: its matches alone do not calibrate the rig ({s.failure})"
        for k, s in enumerate(solutions)
        if s.failure is not None
    }
    if not solved:  # nothing to check the pool against: it stands on its own checks
        return Agreement((), tuple(outliers.values()))
    why = {
        (i, j): _apart(solutions[i], solutions[j], max_ray_deg, max_sigmas)
        for i, j in itertools.combinations(solved, 2)
    }

    def agrees(k: int, j: int) -> bool:
        return why[min(k, j), max(k, j)] is None

    trusted = tuple(k for k in solved if 2 * sum(agrees(k, j) for j in solved if j != k) >= len(solved) - 1)
    if 2 * len(trusted) <= len(solved):
        pairs = "; ".join(f"{solutions[i].name} and {solutions[j].name}: {w}" for (i, j), w in why.items() if w)
        refusal = f"the frames' own calibrations disagree and no majority of them agrees ({pairs})"
        return Agreement((), tuple(outliers.values()), refusal)
    for k in solved:
        if k not in trusted:
            outliers[k] = f"{solutions[k].name}: its own calibration disagrees with " + ", ".join(
                f"{solutions[j].name}'s ({why[min(k, j), max(k, j)]})" for j in trusted if not agrees(k, j)
            )
    return Agreement(trusted, tuple(outliers[k] for k in sorted(outliers)))


def contradicted_by(
    pooled: Project, solutions: Sequence[FrameSolution], *, max_ray_deg: float, max_sigmas: float
) -> tuple[str | None, tuple[str, ...]]:
    """The pooled calibration against each trusted frame's own, beyond what that frame knows (its
    own deviations alone: the pool holds its matches): a refusal line where more than half of them
    contradict it (None: they do not), and a note for each of a minority that does."""
    found = []
    for solution in solutions:
        rays = ray_difference_deg(pooled, solution.project)
        if rays <= max_ray_deg:
            continue
        sigmas, what = sigmas_apart(FrameSolution("pooled", pooled), solution)
        if not sigmas <= max_sigmas:
            known = f", {what} {sigmas:.1f} of its standard deviations" if math.isfinite(sigmas) else ""
            found.append(f"{solution.name}'s own by {rays:.2f} deg (rays, 95th percentile){known}")
    if 2 * len(found) > len(solutions):
        return (
            f"the calibration pooled from the frames differs from {'; '.join(found)}: the frames do not make one rig",
            (),
        )
    return None, tuple(
        f"note: the calibration pooled from the frames differs from {line}; the other frames' agree with it"
        for line in found
    )


__all__ = [
    "Agreement",
    "FrameSolution",
    "agreeing_frames",
    "contradicted_by",
    "ray_angles_deg",
    "ray_difference_deg",
    "sigmas_apart",
]
