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

The rotation-only objectives report no standard deviations: only the range applies to them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import RigjaxError
from ..optimiser.bundle import BundleResult
from ..pto.project import Project

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
    project: Project, result, checks: ChecksConfig, nominal_hfov: float, prior_v: float | None = None
) -> tuple[str, ...]:
    """One line per parameter of the calibrated ``project`` that the matches do not determine or that
    no lens of the template's can have (``result``: the last solve's; a
    :class:`~rigjax.optimiser.bundle.BundleResult` gives standard deviations, ``inf`` where the
    matches leave a parameter free), naming the camera, the parameter, its value and the limit it
    breaks. Empty: nothing to refuse. An hfov with a prior (``prior_v``, degrees: the template's
    ``optimise.priors.v``) is the template's knowledge where the matches lack it: only its range is
    checked (:func:`held_by_prior` says when the prior decided it)."""
    bundle = isinstance(result, BundleResult)
    lines = []
    low, high = checks.plausible_hfov(nominal_hfov)
    for cameras, hfov, sd in _lenses(project, result.standard_deviations[:, 0] if bundle else None):
        value = f"hfov {hfov:.2f}{_spread(sd)} deg"
        if not low <= hfov <= high:
            lines.append(f"{_who(cameras)}: {value} is outside the plausible {low:g}-{high:g} deg (checks.hfov_range)")
        elif prior_v is None and sd > checks.max_hfov_sd_deg:
            lines.append(
                f"{_who(cameras)}: {value} is {_why(sd, 'max_hfov_sd_deg', checks.max_hfov_sd_deg)}: give it a "
                "prior (optimise.priors: {v: 2}) or hold it (a schedule without V)"
            )
    if bundle:
        for k in np.flatnonzero(result.orientation_sd_deg > checks.max_turn_sd_deg):
            sd = result.orientation_sd_deg[k]
            why = _why(sd, "max_turn_sd_deg", checks.max_turn_sd_deg)
            lines.append(
                f"camera {k}: orientation{_spread(sd)} deg is {why}: too few matches, or too close to the seam's middle"
            )
    return tuple(lines)


def held_by_prior(project: Project, result, prior: float | None) -> tuple[str, ...]:
    """A line per lens whose hfov its prior (``optimise.priors.v``, degrees; None: none) rather than
    the matches fixes: its standard deviation at least 80 % of the prior's. The value is then the
    template's nominal lens, moved a little; a calibration may stand on it, but says so."""
    if prior is None or not isinstance(result, BundleResult):
        return ()
    return tuple(
        f"note: {_who(cameras)}: hfov {hfov:.2f} ± {sd:.2f} deg comes from its prior (optimise.priors v: {prior:g}), "
        "not from the matches"
        for cameras, hfov, sd in _lenses(project, result.standard_deviations[:, 0])
        if math.isfinite(sd) and sd >= _FROM_PRIOR_SHARE * prior
    )
