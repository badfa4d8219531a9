"""Typed configuration of ``rigjax optimise``, read from YAML (``configs/rig/*.yaml``).

Example::

    schedule: YPR,VBYPR        # or pto_vars: true
    objective: transfer        # transfer | sphere | hugin
    robust: {loss: huber, scale: 2.0}
    anchor: 0
    solver: {max_steps: 100, xtol: 1.0e-10, ftol: 1.0e-12, rms_threshold: 0.0, backend: optimistix}
    prune: {rounds: 10, grid: 4, fraction: 0.25, factor: 3.0, min_error_px: 2.0,
            start_loss: cauchy, start_scale_px: 2.0, readmit: true}   # or prune: false

Unknown keys and bad values are errors that name the file, the key and what is allowed.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field
from os import PathLike
from typing import Any

import yaml

from ._errors import RigjaxError
from ._optimise import BACKENDS, OBJECTIVES, ROBUST_LOSSES, SolverOptions
from ._prune import PruneConfig
from ._schedule import parse_schedule


class ConfigError(RigjaxError):
    """A configuration file or value that cannot be used; names the file and the key."""


@dataclass(frozen=True)
class RobustConfig:
    loss: str | None = None
    scale: float = 2.0


@dataclass(frozen=True)
class OptimiseConfig:
    schedule: str = "YPR,VBYPR"
    pto_vars: bool = False
    objective: str = "transfer"
    robust: RobustConfig = field(default_factory=RobustConfig)
    anchor: int = 0
    solver: SolverOptions = field(default_factory=SolverOptions)
    prune: PruneConfig | None = field(default_factory=PruneConfig)  # None: no pruning

    def replace(self, **changes: Any) -> "OptimiseConfig":
        return dataclasses.replace(self, **changes)


def _typed(value: Any, kind: type | tuple[type, ...], where: str) -> Any:
    if isinstance(kind, tuple):  # one of several types, e.g. a mapping or false
        if float in kind and int not in kind and isinstance(value, int) and not isinstance(value, bool):
            return float(value)
        for option in kind:
            if isinstance(value, option) and not (option is int and isinstance(value, bool)):
                return value
        raise ConfigError(f"{where}: expected {' or '.join(k.__name__ for k in kind)}, got {value!r}")
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if kind is int and isinstance(value, bool):
        raise ConfigError(f"{where}: expected an integer, got {value!r}")
    if not isinstance(value, kind):
        raise ConfigError(f"{where}: expected {kind.__name__}, got {value!r}")
    return value


def _section(data: Any, where: str, types: dict[str, type]) -> dict[str, Any]:
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping of {', '.join(types)}, got {data!r}")
    unknown = sorted(set(data) - set(types))
    if unknown:
        raise ConfigError(f"{where}: unknown key {unknown[0]!r} (allowed: {', '.join(types)})")
    return {key: _typed(value, types[key], f"{where}.{key}") for key, value in data.items()}


_PRUNE_TYPES = {"rounds": int, "grid": int, "fraction": float, "factor": float, "min_error_px": float,
                "rms_threshold": float, "start_loss": (str, bool), "start_scale_px": float, "readmit": bool}


def config_from_dict(data: Any, source: str = "<config>") -> OptimiseConfig:
    """Validate a parsed YAML document into an :class:`OptimiseConfig`."""
    top = _section(data, source, {"schedule": str, "pto_vars": bool, "objective": str, "robust": dict,
                                  "anchor": int, "solver": dict, "prune": (dict, bool)})  # fmt: skip
    prune_data = top.pop("prune", False if top.get("objective") == "hugin" else None)  # Hugin does not prune
    if prune_data is True:
        prune_data = None
    prune = None if prune_data is False else _section(prune_data, f"{source}: prune", _PRUNE_TYPES)
    if prune is not None and prune.get("start_loss") is False:  # start_loss: false -> the configured loss
        prune["start_loss"] = None
    robust = _section(top.pop("robust", None), f"{source}: robust", {"loss": str, "scale": float})
    solver = _section(top.pop("solver", None), f"{source}: solver",
                      {"max_steps": int, "xtol": float, "ftol": float, "rms_threshold": float, "backend": str})  # fmt: skip
    if robust.get("loss") not in ROBUST_LOSSES:
        raise ConfigError(f"{source}: robust.loss must be one of huber, cauchy, got {robust['loss']!r}")
    if top.get("objective", "transfer") not in OBJECTIVES:
        raise ConfigError(f"{source}: objective must be one of {', '.join(OBJECTIVES)}, got {top['objective']!r}")
    if solver.get("backend", "optimistix") not in BACKENDS:
        raise ConfigError(f"{source}: solver.backend must be one of {', '.join(BACKENDS)}, got {solver['backend']!r}")
    try:
        config = OptimiseConfig(robust=RobustConfig(**robust), solver=SolverOptions(**solver),
                                prune=None if prune is None else PruneConfig(**prune), **top)  # fmt: skip
        parse_schedule(config.schedule)
    except RigjaxError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    return config


def read_yaml(path: str, what: str = "config") -> Any:
    """A YAML file's document; errors name the file."""
    try:
        with open(path, encoding="utf-8") as f:
            return yaml.safe_load(f)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the {what}: {exc.strerror}") from exc
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from exc


def load_config(path: str | PathLike[str]) -> OptimiseConfig:
    """An optimiser config file, or the ``optimise`` section of a rig template (a file with a
    ``rig`` section, see :mod:`rigjax._template`), so calibration and re-optimisation agree."""
    path = os.fspath(path)
    data = read_yaml(path)
    if isinstance(data, dict) and "rig" in data:
        return config_from_dict(data.get("optimise") or {}, f"{path}: optimise")
    return config_from_dict(data, path)
