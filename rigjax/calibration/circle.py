"""A circular fisheye's image circle, found in its images, and the lens it implies.

A circular fisheye records nothing beyond its image circle, and the circle's edge lies at the field
angle its maker states (a 190-degree lens's edge is 95 degrees off axis). So the circle's centre is
the lens's optical centre in the image (the panotools shifts ``d``, ``e``) and its radius, with that
angle, sets the focal length: the hfov. Matches in a dual fisheye's seam ring cannot tell the hfov
(:mod:`rigjax.calibration.checks`); the edge tells it from the images alone, as well as the edge is
found and the stated angle is right.

**The edge.** Along ``rays`` rays from a start centre, the brightest of the frames' luminance
profiles (so that dark content inside the circle in one frame does not pass for its edge), the radius
where it falls most steeply (a drop of at least ``min_drop`` grey levels over a pixel; rays that
find none are left out), to a fraction of a pixel by a parabola through the largest drop and its
neighbours; a drop at the frame's border is the border's (a circle larger than the frame is cut
there) and left out too. Dark content at the rim, the camera's body or a hand cut the edge on some rays and put
a drop elsewhere on others, so the circle is the one most of those points agree on: the largest set
within 1.5 px of one circle (circles through three of them drawn at random, seeded; the best fitted
again by Kasa's algebraic least squares on the points it holds until they no longer change). Where
fewer than 15 % of the points (or 8) lie on one circle, the edge is not a circle, and that is an
error. The radius's and the centre's standard deviations are the geometric fit's, from the kept
points' spread about the circle: a short arc tells the centre less than the whole circle does.

Convention: Hugin's pixel coordinates, pixel centres at integers.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from ..camera.model import ray_to_img
from ..errors import RigjaxError
from ..pto.project import Project
from ..pto.records import Image, PanoramaLine

_STEP_PX = 0.25  # the profiles' sampling along each ray
_OUTLIER_PX = 1.5
_MIN_SUPPORT = 0.15  # the share of the edge points found that must lie on the circle
# Random circles tried: enough that one passes through three points of a circle that holds
# _MIN_SUPPORT of them but for one time in a thousand.
_TRIES = math.ceil(math.log(1e-3) / math.log(1.0 - _MIN_SUPPORT**3))
_PANORAMA = PanoramaLine(width=360, height=180)  # a camera needs a project; its canvas is not used


@dataclass(frozen=True)
class ImageCircle:
    """A fisheye's image circle: ``centre`` ``(2,)`` and ``radius`` (px), the radius's standard
    deviation and the centre's (px, along its least certain direction), the edge points the fit kept
    and their RMS distance from the circle (px). The deviations are the geometric fit's, from the
    points' spread: an arc of the circle tells its centre less than the whole circle does."""

    centre: np.ndarray
    radius: float
    radius_sd: float
    centre_sd: float
    points: int
    rms: float


def _consensus(points: np.ndarray, radii: tuple[float, float]) -> tuple[np.ndarray, np.ndarray, float]:
    """The largest set of ``points`` within :data:`_OUTLIER_PX` of one circle whose radius lies
    within ``radii`` (where the edge was searched: a straight run of edge is a circle too, of a radius
    far beyond), as ``(kept, centre, radius)``: :data:`_TRIES` circles through three points drawn at
    random (seeded: the same points, the same circle), the best fitted again (:func:`_fit`) on the
    points it holds until they no longer change (or a fit leaves ``radii``): ``centre`` and ``radius``
    are the fit to ``kept``. ``kept`` is all False where no circle lies within ``radii``."""
    a, b, c = points[np.random.default_rng(0).integers(0, len(points), (3, _TRIES))]
    # Each triple's circumcircle: the centre equidistant from the three points.
    twice_area = 2.0 * (a[:, 0] * (b[:, 1] - c[:, 1]) + b[:, 0] * (c[:, 1] - a[:, 1]) + c[:, 0] * (a[:, 1] - b[:, 1]))
    sa, sb, sc = (np.sum(p**2, axis=1) for p in (a, b, c))
    with np.errstate(divide="ignore", invalid="ignore"):  # collinear or repeated points: no circle
        centres = np.stack(
            [
                (sa * (b[:, 1] - c[:, 1]) + sb * (c[:, 1] - a[:, 1]) + sc * (a[:, 1] - b[:, 1])) / twice_area,
                (sa * (c[:, 0] - b[:, 0]) + sb * (a[:, 0] - c[:, 0]) + sc * (b[:, 0] - a[:, 0])) / twice_area,
            ],
            axis=1,
        )
        radius = np.linalg.norm(a - centres, axis=1)
    usable = np.isfinite(radius) & (radius >= radii[0]) & (radius <= radii[1])
    if not usable.any():
        return np.zeros(len(points), bool), np.zeros(2), 0.0
    centres, radius = centres[usable], radius[usable]
    near = np.abs(np.linalg.norm(points[None] - centres[:, None], axis=2) - radius[:, None]) <= _OUTLIER_PX
    best = int(np.argmax(near.sum(axis=1)))
    kept = near[best]
    fitted = kept, centres[best], float(radius[best])
    for _ in range(10):
        centre, radius = _fit(points[kept])
        if not radii[0] <= radius <= radii[1]:
            break
        fitted = kept, centre, radius
        now = np.abs(np.linalg.norm(points - centre, axis=1) - radius) <= _OUTLIER_PX
        if now.sum() < 3 or (now == kept).all():
            break
        kept = now
    return fitted


def _fit(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Kasa's circle through ``points`` ``(n, 2)``: ``x^2 + y^2 + D x + E y + F = 0`` by least squares."""
    a = np.column_stack([points, np.ones(len(points))])
    b = -np.sum(points**2, axis=1)
    d, e, f = np.linalg.lstsq(a, b, rcond=None)[0]
    centre = np.array([-d / 2.0, -e / 2.0])
    return centre, math.sqrt(max(centre @ centre - f, 0.0))


def _deviations(points: np.ndarray, centre: np.ndarray, radius: float) -> tuple[float, float, float]:
    """``(rms, radius_sd, centre_sd)`` px of the circle through ``points``: their RMS distance from it,
    and the standard deviations of its radius and of its centre along the least certain direction,
    from the geometric fit's normal equations (the distances' derivatives along the centre and the
    radius) scaled by that RMS."""
    offset = points - centre
    distance = np.linalg.norm(offset, axis=1)
    rms = float(np.sqrt(np.mean((distance - radius) ** 2)))
    jacobian = np.column_stack([-offset / distance[:, None], -np.ones(len(points))])
    covariance = rms**2 * np.linalg.pinv(jacobian.T @ jacobian)
    return rms, math.sqrt(covariance[2, 2]), math.sqrt(float(np.linalg.eigvalsh(covariance[:2, :2]).max()))


def find_image_circle(
    images: Sequence[np.ndarray],
    *,
    centre: Sequence[float] | None = None,
    radius: float | None = None,
    search: float = 0.2,
    rays: int = 720,
    min_drop: float = 20.0,
) -> ImageCircle:
    """The image circle of one circular fisheye in its ``images`` (one or more frames, ``(h, w, 3)``
    uint8 RGB, all of one size): module docstring. ``centre`` and ``radius`` start the search
    (default: the frame's centre and half its shorter side), which looks ``search`` of the radius
    either side."""
    if not images:
        raise RigjaxError("find_image_circle: no images")
    height, width = images[0].shape[:2]
    for k, image in enumerate(images):
        if image.shape[:2] != (height, width):
            raise RigjaxError(
                f"find_image_circle: frame {k} is {image.shape[1]}x{image.shape[0]}, frame 0 {width}x{height}"
            )
    start = np.array([(width - 1) / 2.0, (height - 1) / 2.0] if centre is None else centre, float)
    r0 = min(width, height) / 2.0 if radius is None else float(radius)
    radii = np.arange((1.0 - search) * r0, (1.0 + search) * r0, _STEP_PX)
    angles = np.linspace(0.0, 2.0 * np.pi, rays, endpoint=False)
    xs = (start[0] + np.cos(angles)[:, None] * radii[None, :]).astype(np.float32)
    ys = (start[1] + np.sin(angles)[:, None] * radii[None, :]).astype(np.float32)
    profile = None
    for image in images:
        luminance = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32)
        sampled = cv2.remap(luminance, xs, ys, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
        profile = sampled if profile is None else np.maximum(profile, sampled)
    per_px = int(round(1.0 / _STEP_PX))
    drop = profile[:, :-per_px] - profile[:, per_px:]  # fall over one pixel, at radii[i] + half a pixel
    best = np.argmax(drop, axis=1)
    found = (drop[np.arange(rays), best] >= min_drop) & (best > 0) & (best < drop.shape[1] - 1)
    rows, at = np.flatnonzero(found), best[found]
    left, mid, right = drop[rows, at - 1], drop[rows, at], drop[rows, at + 1]
    curvature = left - 2.0 * mid + right
    offset = np.where(curvature < 0.0, 0.5 * (left - right) / np.where(curvature < 0.0, curvature, -1.0), 0.0)
    edge = radii[at] + (np.clip(offset, -1.0, 1.0) + 0.5 * per_px) * _STEP_PX
    points = start + np.column_stack([np.cos(angles[rows]), np.sin(angles[rows])]) * edge[:, None]
    # A circle larger than the frame is cut by its border, where the profile falls to the black
    # beyond it: that fall is the frame's edge, not the circle's.
    points = points[np.all((points >= 1.0) & (points <= np.array([width, height]) - 2.0), axis=1)]
    if len(points) < 8:
        raise RigjaxError(
            f"find_image_circle: the circle's edge was found on {len(points)} of {rays} rays (a drop of "
            f"{min_drop:g} grey levels within {search:.0%} of radius {r0:.1f} px around {start.round(1).tolist()}, "
            "inside the frame's border)"
        )
    keep, fitted_centre, fitted_radius = _consensus(points, (radii[0], radii[-1]))
    if keep.sum() < max(8, _MIN_SUPPORT * len(points)):
        raise RigjaxError(
            f"find_image_circle: the edge found on {len(points)} of {rays} rays is not a circle: at most "
            f"{int(keep.sum())} of those points lie within {_OUTLIER_PX:g} px of one"
        )
    rms, radius_sd, centre_sd = _deviations(points[keep], fitted_centre, fitted_radius)
    return ImageCircle(fitted_centre, fitted_radius, radius_sd, centre_sd, int(keep.sum()), rms)


def lens_from_circle(image: Image, circle: ImageCircle, circle_deg: float) -> tuple[float, float, float, float]:
    """``(hfov, d, e, hfov_sd)``: the lens of ``image`` (its projection and distortion ``a``, ``b``,
    ``c`` as given) whose image circle, ``circle_deg`` across, is ``circle``: the hfov that puts a ray
    ``circle_deg / 2`` off axis at the circle's radius, the shifts that put the axis at its centre,
    and the hfov's standard deviation from the radius's."""
    if not 0.0 < circle_deg <= 360.0:
        raise RigjaxError(f"circle_deg: expected the lens's field of view in degrees (0, 360], got {circle_deg!r}")
    theta = math.radians(circle_deg / 2.0)
    edge_ray = np.array([math.sin(theta), 0.0, math.cos(theta)])

    def camera(hfov: float):  # the lens looking along z, unshifted
        lens = dataclasses.replace(image, hfov=hfov, d=0.0, e=0.0, yaw=0.0, pitch=0.0, roll=0.0, links={})
        return Project.new(_PANORAMA, [lens]).cameras().take(0)

    def radius(hfov: float) -> float:  # the edge ray's distance from the axis's pixel, one call for both
        xy, ok = ray_to_img(camera(hfov), np.stack([edge_ray, [0.0, 0.0, 1.0]]))
        return float(xy[0, 0] - xy[1, 0]) if bool(ok[0]) else math.inf

    low, high = 1.0, 359.0  # the radius falls as the hfov grows (a shorter focal length)
    for _ in range(60):
        mid = 0.5 * (low + high)
        if radius(mid) > circle.radius:
            low = mid
        else:
            high = mid
    hfov = 0.5 * (low + high)
    step = 1e-3 * hfov
    slope = (radius(hfov + step) - radius(hfov - step)) / (2.0 * step)  # px per degree
    axis, _ = ray_to_img(camera(hfov), np.array([0.0, 0.0, 1.0]))
    d, e = (np.asarray(circle.centre) - np.asarray(axis)).tolist()
    return hfov, d, e, abs(circle.radius_sd / slope)
