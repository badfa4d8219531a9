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
class PruneConfig:
    """Settings of :func:`rigjax.optimiser.prune.optimise_pruned` (see :mod:`rigjax.optimiser.prune`)."""

    rounds: int = 10
    grid: int = 4
    fraction: float = 0.25
    factor: float = 3.0
    min_error_px: float = 2.0
    rms_threshold: float = 0.0
    start_loss: str | None = "cauchy"  # round 0's robust loss (None: the caller's loss)
    start_scale_px: float = 2.0  # its smallest scale (each stage's is the median error where it starts)
    readmit: bool = True  # removed points that fit the final cameras come back for one more solve

    def __post_init__(self) -> None:
        if self.start_loss not in ROBUST_LOSSES or not self.start_scale_px > 0:
            raise RigjaxError(
                f"prune start_loss must be one of huber, cauchy or none and start_scale_px > 0, got "
                f"{self.start_loss!r} and {self.start_scale_px!r}"
            )
        if self.rounds < 0 or self.grid < 1:
            raise RigjaxError(f"prune rounds must be >= 0 and grid >= 1, got {self.rounds} and {self.grid}")
        if not 0.0 < self.fraction <= 1.0:
            raise RigjaxError(f"prune fraction must be in (0, 1], got {self.fraction!r}")
        if not (self.factor > 0 and self.min_error_px >= 0 and self.rms_threshold >= 0):
            raise RigjaxError("prune factor must be > 0, min_error_px and rms_threshold >= 0")


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
    """The settings of :func:`rigjax.optimise` (``rigjax.optimise(project, config)``), of
    :func:`rigjax.optimise_pruned`, which alone reads ``prune``, and of :func:`rigjax.optimise_batch`.

    ``objective`` picks the solver: ``transfer``, ``sphere`` and ``hugin`` the rotation-only stages
    (:mod:`rigjax.optimiser.staged`), ``reprojection`` the bundle adjustment
    (:mod:`rigjax.optimiser.bundle`), which alone reads ``centres`` and ``priors``.
    :meth:`solve_kwargs` turns the settings into the chosen solver's arguments.
    """

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

    def solve_kwargs(self) -> dict[str, Any]:
        """The keyword arguments these settings give the solver their objective picks, the one place
        they are made: :func:`rigjax.optimiser.problem.prepare`'s (the rotation-only objectives), or
        :func:`rigjax.optimiser.bundle.bundle_adjust`'s (``reprojection``: ``centres`` instead of
        ``objective``). A call's data (weights, nominal cameras) are the caller's to add; ``prune``
        is not a setting of one solve (:func:`rigjax.optimiser.prune.optimise_pruned`)."""
        kwargs = dict(
            schedule=self.schedule,
            pto_vars=self.pto_vars,
            robust=self.robust.loss,
            robust_scale=self.robust.scale,
            anchor=self.anchor,
            solver=self.solver,
            priors=self.priors.as_dict(),
        )
        if self.objective == "reprojection":
            return dict(kwargs, centres=self.centres)
        return dict(kwargs, objective=self.objective)


def as_config(config: OptimiseConfig | str | None) -> OptimiseConfig:
    """``config`` itself; for a string, the default settings with that schedule (``"YPR,VBYPR"``);
    for None, the defaults."""
    if config is None:
        return OptimiseConfig()
    if isinstance(config, str):
        return OptimiseConfig(schedule=config)
    if not isinstance(config, OptimiseConfig):
        raise RigjaxError(
            f"config must be an OptimiseConfig or a schedule such as 'YPR,VBYPR', got {type(config).__name__} {config!r}"
        )
    return config


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
