"""The configuration system of rigjax and learnstitch: YAML files read into typed, frozen sections.

Every config is a tree of frozen dataclasses (``OptimiseConfig``, ``CalibrateConfig``,
``learnstitch.StitchConfig`` and their sections). :func:`typed_from_dict` fills one from a parsed
YAML mapping, checking every key against the dataclass's annotations:

* ``bool``, ``int``, ``float`` (an integer is accepted), ``str``;
* ``tuple[X, ...]`` (a non-empty list) and ``tuple[X, Y, Z]`` (a list of exactly that many);
* a nested dataclass: a mapping, its own section (``true`` stands for its defaults);
* ``X | None``: ``null`` or ``false`` switch the setting off (``prune: false``, ``levy: false``).

An unknown key, a missing required key, a value of the wrong type or a value that the section's
``__post_init__`` refuses raises :class:`~rigjax.errors.ConfigError` naming the file and the key
(``configs/rig/x.yaml: solver.max_steps: expected an integer, got 'many'``); :func:`read_yaml`
names the file it cannot read or parse.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from typing import Any, TypeVar

import yaml

from .errors import ConfigError, RigjaxError

T = TypeVar("T")


def read_yaml(path: str, what: str = "config") -> Any:
    """A YAML file's document; errors name the file."""
    try:
        with open(path, encoding="utf-8") as f:
            return yaml.safe_load(f)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the {what}: {exc.strerror}") from exc
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from exc


def _key_path(where: str, key: str) -> str:
    """``file: section.key``: the first key after the file name follows ``": "``, the others ``"."``."""
    return f"{where}.{key}" if ": " in where else f"{where}: {key}"


def typed_from_dict(cls: type[T], values: Any, where: str) -> T:
    """``cls(**values)``, every value checked against ``cls``'s annotations, nested sections too.

    ``values`` may be ``None`` (every key at its default). ``where`` names the file and the
    section (``"configs/stitch/x.yaml: model"``) in the errors.
    """
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    values = {} if values is None else values
    if not isinstance(values, dict):
        raise ConfigError(f"{where}: expected a mapping of {', '.join(fields)}, got {values!r}")
    unknown = [key for key in values if key not in fields]
    if unknown:
        raise ConfigError(f"{where}: unknown key {unknown[0]!r} (allowed: {', '.join(fields)})")
    required = [
        name
        for name, f in fields.items()
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]
    missing = [name for name in required if name not in values]
    if missing:
        raise ConfigError(f"{where}: missing key {missing[0]!r}")
    hints = typing.get_type_hints(cls)
    typed = {key: _convert(hints[key], value, _key_path(where, key)) for key, value in values.items()}
    try:
        return cls(**typed)
    except RigjaxError as error:  # the section's own checks (its __post_init__)
        raise ConfigError(f"{where}: {error}") from None


def as_dict(section: Any) -> dict[str, Any]:
    """A config as plain YAML/JSON values (tuples as lists, sections as mappings, off as null)."""

    def plain(value: Any) -> Any:
        if dataclasses.is_dataclass(value):
            return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value) if f.init}
        if isinstance(value, tuple):
            return [plain(v) for v in value]
        return value

    return plain(section)


_WORDS = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}


def _convert(kind: Any, value: Any, where: str) -> Any:
    origin, args = typing.get_origin(kind), typing.get_args(kind)
    if origin in (types.UnionType, typing.Union):
        options = [a for a in args if a is not type(None)]
        if len(options) != 1:
            raise TypeError(f"unsupported config field type {kind!r} at {where}")  # a programming error
        if value is None or (value is False and options[0] is not bool):
            return None
        return _convert(options[0], value, where)
    if dataclasses.is_dataclass(kind):
        return typed_from_dict(kind, {} if value is True else value, where)
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            if not isinstance(value, (list, tuple)) or not value:
                raise ConfigError(f"{where}: expected a non-empty list, got {value!r}")
            return tuple(_convert(args[0], v, f"{where}[{i}]") for i, v in enumerate(value))
        if not isinstance(value, (list, tuple)) or len(value) != len(args):
            raise ConfigError(f"{where}: expected a list of {len(args)} values, got {value!r}")
        return tuple(_convert(a, v, f"{where}[{i}]") for i, (a, v) in enumerate(zip(args, value)))
    if kind not in _WORDS:
        raise TypeError(f"unsupported config field type {kind!r} at {where}")  # a programming error
    if isinstance(value, bool) and kind is not bool:  # a bool is an int in Python, not in a config
        raise ConfigError(f"{where}: expected {_WORDS[kind]}, got {value!r}")
    if kind is float and isinstance(value, int):
        return float(value)
    if not isinstance(value, kind):
        raise ConfigError(f"{where}: expected {_WORDS[kind]}, got {value!r}")
    if kind is float and not math.isfinite(value):  # YAML's .nan and .inf: no setting means them
        raise ConfigError(f"{where}: expected a finite number, got {value!r}")
    return value
