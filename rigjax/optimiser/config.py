"""Typed configuration of ``rigjax optimise``, read from YAML (``configs/rig/*.yaml``).

Example::

    schedule: YPR,VBYPR        # or pto_vars: true
    objective: transfer        # transfer | sphere | hugin | reprojection
    centres: [[0, 0, 0.4], ...]  # reprojection only: each camera's centre (else the project's)
    priors: {v: 1.0}             # reprojection only: how far each lens (or centre, x) may be from nominal
    robust: {loss: huber, scale: 2.0}
    anchor: 0
    solver: {max_steps: 100, xtol: 1.0e-10, ftol: 1.0e-12, rms_threshold: 0.0, backend: optimistix}
    prune: {rounds: 10, grid: 4, fraction: 0.25, factor: 3.0, min_error_px: 2.0,
            start_loss: cauchy, start_scale_px: 2.0, readmit: true}   # or prune: false

Unknown keys and bad values are errors that name the file, the key and what is allowed
(:mod:`rigjax.config`). ``configs/rig/optimise.yaml`` lists every key at its default.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field
from os import PathLike
from typing import Any

from ..config import read_yaml, typed_from_dict
from ..errors import RigjaxError
from .options import SolverOptions
from .problem import OBJECTIVES
from .prune import PruneConfig
from .residuals import ROBUST_LOSSES
from .schedule import has_centres, parse_schedule


@dataclass(frozen=True)
class RobustConfig:
    loss: str | None = None  # None (least squares), "huber" or "cauchy"
    scale: float = 2.0  # pixels

    def __post_init__(self) -> None:
        if self.loss not in ROBUST_LOSSES:
            raise RigjaxError(f"loss must be one of huber, cauchy or null, got {self.loss!r}")
        if not self.scale > 0.0:  # a negative scale was used as its absolute value
            raise RigjaxError(f"scale must be a positive number of pixels, got {self.scale!r}")


@dataclass(frozen=True)
class Priors:
    """Standard deviations of letters about their nominal values (the project's where the
    optimisation starts): ``v`` degrees, ``a``, ``b``, ``c`` as in the project, ``d``, ``e`` px,
    ``y``, ``p``, ``r`` degrees (the cameras' mounting tolerance), ``x`` each coordinate of a
    camera's centre, in the centres' unit; None: no prior. The bundle adjustment adds
    ``(value - nominal) / sd`` for every estimated parameter of that letter to its residuals
    (:func:`rigjax.optimiser.bundle.bundle_adjust`)."""

    v: float | None = None
    a: float | None = None
    b: float | None = None
    c: float | None = None
    d: float | None = None
    e: float | None = None
    y: float | None = None
    p: float | None = None
    r: float | None = None
    x: float | None = None

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            sd = getattr(self, f.name)
            if sd is not None and not sd > 0.0:
                raise RigjaxError(f"{f.name} must be a positive standard deviation or null, got {sd!r}")

    def as_dict(self) -> dict[str, float]:
        """The letters that have a prior, upper case, and their standard deviations."""
        fields = dataclasses.fields(self)
        return {f.name.upper(): getattr(self, f.name) for f in fields if getattr(self, f.name) is not None}


@dataclass(frozen=True)
class OptimiseConfig:
    schedule: str = "YPR,VBYPR"
    pto_vars: bool = False
    objective: str = "transfer"
    robust: RobustConfig = field(default_factory=RobustConfig)
    anchor: int = 0
    solver: SolverOptions = field(default_factory=SolverOptions)
    prune: PruneConfig | None = field(default_factory=PruneConfig)  # None: no pruning
    centres: tuple[tuple[float, float, float], ...] | None = None  # reprojection: one per image, else the project's
    priors: Priors = field(default_factory=Priors)  # reprojection only

    def __post_init__(self) -> None:
        if self.objective not in OBJECTIVES + ("reprojection",):
            raise RigjaxError(
                f"objective must be one of {', '.join(OBJECTIVES + ('reprojection',))}, got {self.objective!r}"
            )
        parse_schedule(self.schedule)
        if self.priors.as_dict() and self.objective != "reprojection":
            raise RigjaxError(f"priors apply to objective reprojection only, not {self.objective!r}")
        if not self.pto_vars and has_centres(self.schedule):
            if self.objective != "reprojection":
                raise RigjaxError(f"schedule {self.schedule!r} estimates centres (X): set objective reprojection")
            if self.priors.x is None:
                raise RigjaxError(
                    f"schedule {self.schedule!r} estimates centres (X): give priors.x, their standard deviation "
                    "about the nominal centres, which fixes the rig's scale (images cannot tell it)"
                )

    def replace(self, **changes: Any) -> OptimiseConfig:
        return dataclasses.replace(self, **changes)


def with_prune_default(data: Any) -> Any:
    """Without a ``prune`` key, objective ``hugin`` does not prune (Hugin's optimum needs every
    point); the other objectives do."""
    if isinstance(data, dict) and "prune" not in data and data.get("objective") == "hugin":
        return {**data, "prune": False}
    return data


def config_from_dict(data: Any, source: str = "<config>") -> OptimiseConfig:
    """Validate a parsed YAML document into an :class:`OptimiseConfig`."""
    return typed_from_dict(OptimiseConfig, with_prune_default(data), source)


def load_config(path: str | PathLike[str]) -> OptimiseConfig:
    """An optimiser config file, or the ``optimise`` section of a rig template (a file with a
    ``rig`` section, see :mod:`rigjax.calibration.template`), so calibration and re-optimisation agree."""
    path = os.fspath(path)
    data = read_yaml(path)
    if isinstance(data, dict) and "rig" in data:
        return config_from_dict(data.get("optimise") or {}, f"{path}: optimise")
    return config_from_dict(data, path)
