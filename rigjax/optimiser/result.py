"""What :func:`rigjax.optimise` returns, whichever solver the objective picks.

The rotation-only objectives return a :class:`~rigjax.optimiser.staged.Result`, ``reprojection``
a :class:`~rigjax.optimiser.bundle.BundleResult`. Both are an :class:`OptimiseResult`: a caller
that prints, checks or prunes a result reads it through this protocol and never asks which it has.
What only one solver estimates (standard deviations, centres, scene points) is None in the other's.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import numpy as np

from ..pto.project import Project


class StageOutcome(Protocol):
    """What a stage did, in either solver's report (``StageReport``, ``BundleStageReport``); RMS
    values in pixels (the transfer error, or the reprojection error per observation)."""

    @property
    def name(self) -> str: ...
    @property
    def parameters(self) -> tuple[str, ...]: ...
    @property
    def status(self) -> str: ...  # one of rigjax.optimiser.options.STATUS
    @property
    def steps(self) -> int: ...
    @property
    def rms_initial(self) -> float: ...
    @property
    def rms_final(self) -> float: ...
    @property
    def seconds(self) -> float: ...


@runtime_checkable
class OptimiseResult(Protocol):
    """An optimisation's outcome: the optimised project, a report per stage, and the errors at the end."""

    @property
    def project(self) -> Project: ...
    @property
    def stages(self) -> Sequence[StageOutcome]: ...
    @property
    def rms(self) -> float:
        """The final RMS error, px: the transfer error (rotation-only), or the reprojection error per
        observation (``reprojection``)."""
        ...

    @property
    def ok(self) -> bool:
        """Whether the solve converged (each solver says what that takes)."""
        ...

    @property
    def not_optimised(self) -> tuple[str, ...]:
        """With ``pto_vars``: the ``v``-line variables left out, each with the reason."""
        ...

    @property
    def standard_deviations(self) -> np.ndarray | None:
        """``(n_images, 9)``: each camera's letters ``VABCDEYPR`` (NaN where not estimated, inf where
        the matches leave it free); None where the objective estimates none (rotation-only)."""
        ...

    @property
    def orientation_sd_deg(self) -> np.ndarray | None:
        """``(n_images,)`` degrees: each camera's orientation's standard deviation; None as above."""
        ...

    @property
    def centres(self) -> np.ndarray | None:
        """``(n_images, 3)``: the cameras' centres in the rig frame; None where every camera sees from
        one point (rotation-only)."""
        ...

    @property
    def points(self) -> np.ndarray | None:
        """``(n_points, 3)``: each control point's scene point (``inf`` at infinity); None as above."""
        ...

    def point_errors(self) -> np.ndarray:
        """``(n_points,)`` px: per control point, the larger of its two errors (transfer, or
        reprojection): what pruning ranks."""
        ...

    def format_stages(self) -> str:
        """The per-stage table the command line prints."""
        ...

    def format_rms(self) -> str:
        """The final RMS as the command line prints it, its kind named: ``"0.4123 px (reprojection)"``."""
        ...

    def format_deviations(self) -> str:
        """The standard deviations as the command line prints them; ``""`` where there are none."""
        ...
