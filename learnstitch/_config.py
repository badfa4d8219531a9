"""Typed configuration of learnstitch, read from YAML (``configs/stitch/*.yaml``).

A file has one section per part of the pipeline; today ``data`` (:class:`learnstitch.SynthConfig`).
Unknown sections and keys, and values of the wrong type or range, are errors that name the file
and the key.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path

import yaml

from .synth import ConfigError, SynthConfig


@dataclass(frozen=True)
class StitchConfig:
    data: SynthConfig = field(default_factory=SynthConfig)
    name: str = ""


_SECTIONS = ("data",)


def config_from_dict(values: dict, where: str = "config") -> StitchConfig:
    if not isinstance(values, dict):
        raise ConfigError(f"{where}: expected a mapping of sections {list(_SECTIONS)}, got {type(values).__name__}")
    unknown = sorted(set(values) - set(_SECTIONS))
    if unknown:
        raise ConfigError(f"{where}: unknown section(s) {unknown}; allowed: {list(_SECTIONS)}")
    data = values.get("data") or {}
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: data: expected a mapping, got {data!r}")
    return StitchConfig(SynthConfig.from_dict(data, f"{where}: data"), Path(where).stem)

def load_config(path: str | PathLike) -> StitchConfig:
    """Read ``configs/stitch/NAME.yaml``; errors name the file and the key."""
    path = Path(path)
    try:
        values = yaml.safe_load(path.read_text())
    except OSError as error:
        raise ConfigError(f"{path}: cannot read: {error.strerror}") from None
    except yaml.YAMLError as error:
        raise ConfigError(f"{path}: not valid YAML: {error}") from None
    return config_from_dict(values or {}, str(path))
