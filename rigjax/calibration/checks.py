"""What a calibration's matches did not determine: the parameters ``rigjax calibrate`` refuses to
report as a success.

A least-squares fit always ends somewhere. Where the matches cannot tell a parameter (a dual
fisheye's hfov from points in the seam ring at unknown depths: a common change of the lens is undone
by the points' depths), it ends wherever the valley of the cost is flattest, and its residuals look
as good as a real calibration's. Two things show it: the parameter's standard deviation (the bundle
adjustment's covariance, :mod:`rigjax.optimiser.bundle_covariance`), and a value outside what the
lens can be. A template's ``checks:`` section sets both limits::

    checks:
      hfov_range: [170, 210]    # degrees; default: the template's hfov ± 15 %
      max_hfov_sd_deg: 1.0      # an hfov known worse than this (1 standard deviation) is undetermined
      max_turn_sd_deg: 0.5      # a camera's orientation known worse than this, too
      max_prior_sigmas: 3.0     # a lens or orientation this many of its prior's deviations from nominal
      max_turn_from_nominal_deg: null   # degrees: a camera turned further from the template's layout
      frames_max_ray_deg: 0.5   # frames pooled: each frame calibrated alone too; frames that differ
      frames_max_sigmas: 4.0    # by both this much (rays) and this many deviations disagree, and a
                                # pool most trusted frames' own contradict is pooled again without
                                # the others, or refused (rigjax.calibration.agreement); null: unchecked

The rotation-only objectives report no standard deviations: only the range applies to them.

A third sign is a parameter with a prior (the template's ``optimise.priors``: the lens's tolerance,
the mounting's) that ends further from its nominal value than the tolerance allows: the matches pull
it where no camera of the template's can be. Wrong matches that agree with each other do that (a
tracked region locked onto the neighbouring period of a facade, which a point's free depth
explains), and so does a template whose lens or layout is not the camera's; the calibration's own
standard deviations, computed as if every match were right, do not show it. A rig built to a
tolerance (two lenses of a 360 camera back to back within a degree or two) can say so without a
prior: ``max_turn_from_nominal_deg``, each camera's turn from the template's orientations once the
rig's own turn is removed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..camera.rotation import world_from_cam
from ..errors import RigjaxError
from ..optimiser.result import OptimiseResult
from ..optimiser.schedule import LENS_LETTERS, UNIT
from ..pto.project import Project
from .ransac import rotation_from_bearings

# The plausible lens without a checks.hfov_range: the template's hfov within this share of itself.
_DEFAULT_HFOV_SHARE = 0.15
# A lens letter whose standard deviation is at least this share of its prior's is the prior's.
_FROM_PRIOR_SHARE = 0.8


@dataclass(frozen=True)
class ChecksConfig:
    """A template's limits on what a calibration may leave undetermined (module docstring)."""

    hfov_range: tuple[float, float] | None = None
    max_hfov_sd_deg: float = 1.0
    max_turn_sd_deg: float = 0.5
    max_prior_sigmas: float = 3.0
    max_turn_from_nominal_deg: float | None = None
    frames_max_ray_deg: float | None = 0.5
    frames_max_sigmas: float = 4.0

    def __post_init__(self) -> None:
        if self.hfov_range is not None:
            low, high = self.hfov_range
            if not 0.0 < low < high <= 360.0:
                raise RigjaxError(
                    f"hfov_range: expected [low, high] degrees with 0 < low < high <= 360, got {low!r}, {high!r}"
                )
        for key in ("max_hfov_sd_deg", "max_turn_sd_deg"):
            value = getattr(self, key)
            if not (math.isfinite(value) and value > 0.0):
                raise RigjaxError(f"{key}: expected a standard deviation in degrees (> 0), got {value!r}")
        if self.max_turn_from_nominal_deg is not None and not 0.0 < self.max_turn_from_nominal_deg <= 180.0:
            raise RigjaxError(
                f"max_turn_from_nominal_deg: expected degrees in (0, 180], got {self.max_turn_from_nominal_deg!r}"
            )
        if self.frames_max_ray_deg is not None and not 0.0 <= self.frames_max_ray_deg < 180.0:
            raise RigjaxError(
                f"frames_max_ray_deg: expected degrees in [0, 180) or null, got {self.frames_max_ray_deg!r}"
            )
        if not self.frames_max_sigmas > 0.0:
            raise RigjaxError(
                f"frames_max_sigmas: expected a number of standard deviations (> 0), got {self.frames_max_sigmas!r}"
            )
        if not self.max_prior_sigmas > 0.0:
            raise RigjaxError(
                f"max_prior_sigmas: expected a number of standard deviations (> 0), got {self.max_prior_sigmas!r}"
            )

    def plausible_hfov(self, nominal: float) -> tuple[float, float]:
        """The hfov range (degrees) a lens of nominal hfov ``nominal`` may end in."""
        if self.hfov_range is not None:
            return self.hfov_range
        return nominal * (1.0 - _DEFAULT_HFOV_SHARE), min(nominal * (1.0 + _DEFAULT_HFOV_SHARE), 360.0)


def _lenses(project: Project, hfov_sd: np.ndarray | None) -> list[tuple[list[int], float, float]]:
    """The distinct lenses ``(cameras, hfov, its standard deviation or NaN)``: cameras whose hfov
    links to one image (``v=K``) share a lens and report its value and deviation once."""
    groups: dict[int, list[int]] = {}
    for k, image in enumerate(project.images):
        groups.setdefault(image.links.get("v", k), []).append(k)
    return [
        (cameras, float(project.images[root].hfov), math.nan if hfov_sd is None else float(hfov_sd[root]))
        for root, cameras in groups.items()
    ]


def _who(cameras: list[int]) -> str:
    if len(cameras) == 1:
        return f"camera {cameras[0]}"
    return f"cameras {', '.join(map(str, cameras))} (one lens)"


def _spread(sd: float) -> str:
    return "" if not math.isfinite(sd) else f" ± {sd:.2f}"


def _why(sd: float, key: str, limit: float) -> str:
    if sd == math.inf:
        return "not determined by the matches (they leave it free)"
    return f"not determined by the matches (standard deviation above checks.{key} {limit:g})"


def undetermined(
    project: Project, result: OptimiseResult, checks: ChecksConfig, nominal_hfov: float, prior_v: float | None = None
) -> tuple[str, ...]:
    """One line per parameter of the calibrated ``project`` that the matches do not determine or that
    no lens of the template's can have (``result``: the last solve's; a
    :class:`~rigjax.optimiser.bundle.BundleResult` gives standard deviations, ``inf`` where the
    matches leave a parameter free; a rotation-only result gives none), naming the camera, the
    parameter, its value and the limit it breaks. Empty: nothing to refuse. An hfov with a prior (``prior_v``, degrees: the template's
    ``optimise.priors.v``) is the template's knowledge where the matches lack it: only its range is
    checked (:func:`held_by_prior` says when the prior decided it)."""
    deviations, orientation_sd = result.standard_deviations, result.orientation_sd_deg
    lines = []
    low, high = checks.plausible_hfov(nominal_hfov)
    for cameras, hfov, sd in _lenses(project, None if deviations is None else deviations[:, 0]):
        value = f"hfov {hfov:.2f}{_spread(sd)} deg"
        if not low <= hfov <= high:
            lines.append(f"{_who(cameras)}: {value} is outside the plausible {low:g}-{high:g} deg (checks.hfov_range)")
        elif prior_v is None and sd > checks.max_hfov_sd_deg:
            lines.append(
                f"{_who(cameras)}: {value} is {_why(sd, 'max_hfov_sd_deg', checks.max_hfov_sd_deg)}: give it a "
                "prior (optimise.priors: {v: 2}) or hold it (a schedule without V)"
            )
    if orientation_sd is not None:
        for k in np.flatnonzero(orientation_sd > checks.max_turn_sd_deg):
            sd = orientation_sd[k]
            why = _why(sd, "max_turn_sd_deg", checks.max_turn_sd_deg)
            lines.append(
                f"camera {k}: orientation{_spread(sd)} deg is {why}: too few matches, or too close to the seam's middle"
            )
    return tuple(lines)


_PRIOR_LETTERS = {"v": "hfov", "y": "yaw", "p": "pitch", "r": "roll"}


def beyond_priors(
    project: Project, nominal: Project, priors: dict[str, float], checks: ChecksConfig
) -> tuple[str, ...]:
    """One line per lens (``v``) or camera orientation letter (``y``, ``p``, ``r``) of the calibrated
    ``project`` that ends more than ``checks.max_prior_sigmas`` of its prior's standard deviations
    (``priors``: the template's ``optimise.priors.as_dict()``, upper-case letters) from its value in
    ``nominal`` (the template's rig): see the module docstring. Angles compare the short way round."""
    lines = []
    for letter, name in _PRIOR_LETTERS.items():
        sd = priors.get(letter.upper())
        if sd is None:
            continue
        groups = _lenses(project, None) if letter == "v" else [([k], 0.0, 0.0) for k in range(len(project.images))]
        for cameras, _, _ in groups:
            value, start = project.images[cameras[0]].value(letter), nominal.images[cameras[0]].value(letter)
            offset = (value - start + 180.0) % 360.0 - 180.0 if letter != "v" else value - start
            if abs(offset) > checks.max_prior_sigmas * sd:
                lines.append(
                    f"{_who(cameras)}: {name} {value:.2f} deg is {abs(offset) / sd:.1f} standard deviations of its "
                    f"prior from the template's {start:.2f} (optimise.priors {letter}: {sd:g}, checks.max_prior_sigmas "
                    f"{checks.max_prior_sigmas:g}): wrong matches that agree, or a template that is not this camera's"
                )
    return tuple(lines)


def beyond_mounting(project: Project, nominal: Project, checks: ChecksConfig) -> tuple[str, ...]:
    """One line per camera of the calibrated ``project`` turned more than
    ``checks.max_turn_from_nominal_deg`` from its orientation in ``nominal`` (the template's), the
    rig's own turn removed (the one rotation that brings the calibrated cameras closest to the
    nominal ones, Kabsch: with two cameras, each gets half of their relative turn); none without
    that limit."""
    limit = checks.max_turn_from_nominal_deg
    if limit is None:
        return ()
    got, want = (
        np.asarray(world_from_cam(*(np.array([im.value(x) for im in p.images]) for x in "ypr")), np.float64)
        for p in (project, nominal)
    )
    # The rig's turn maps each calibrated camera's axes onto its nominal ones: Wahba's problem on them.
    turn = rotation_from_bearings(np.swapaxes(got, 1, 2).reshape(-1, 3), np.swapaxes(want, 1, 2).reshape(-1, 3))
    chord = np.linalg.norm(turn @ got - want, axis=(-2, -1))
    angles = np.degrees(2.0 * np.arcsin(np.clip(chord / (2.0 * math.sqrt(2.0)), 0.0, 1.0)))
    return tuple(
        f"camera {k}: turned {angles[k]:.2f} deg from the template's layout (checks.max_turn_from_nominal_deg "
        f"{limit:g}): wrong matches that agree, or a template that is not this camera's"
        for k in np.flatnonzero(angles > limit)
    )


def held_by_prior(
    project: Project, result: OptimiseResult, priors: dict[str, float], section: str = "optimise.priors"
) -> tuple[str, ...]:
    """A line per lens letter whose prior (``priors``: upper-case lens letters and their standard
    deviations, as the template's ``section`` gives them) rather than the matches fixes it: its
    standard deviation at least 80 % of the prior's. The value is then the template's nominal lens,
    moved a little; a calibration may stand on it, but says so."""
    if result.standard_deviations is None:  # no deviations (rotation-only)
        return ()
    lines = []
    for column, letter in enumerate(LENS_LETTERS):
        prior = priors.get(letter)
        if prior is None:
            continue
        name, unit, digits = {"V": ("hfov", " deg", 2), "D": ("d", " px", 2), "E": ("e", " px", 2)}.get(
            letter, (letter.lower(), "", 4)
        )
        groups: dict[int, list[int]] = {}
        for k, image in enumerate(project.images):
            groups.setdefault(image.links.get(letter.lower(), k), []).append(k)
        for root, cameras in groups.items():
            sd = float(result.standard_deviations[root, column]) * UNIT[letter]  # the solver's units to the project's
            if math.isfinite(sd) and sd >= _FROM_PRIOR_SHARE * prior:
                value = project.images[root].value(letter.lower())
                lines.append(
                    f"note: {_who(cameras)}: {name} {value:.{digits}f} ± {sd:.{digits}f}{unit} comes from its prior "
                    f"({section} {letter.lower()}: {prior:g}), not from the matches"
                )
    return tuple(lines)
