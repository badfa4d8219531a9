"""Typed configuration sections: a frozen dataclass per section of ``configs/stitch/*.yaml``,
filled from a YAML mapping with every key and type checked.

Supported field types (as written in the dataclasses' annotations): ``int``, ``float``, ``bool``,
``str``, ``str | None``, ``tuple[int, ...]`` and ``tuple[float, ...]``. An unknown key, a value of the wrong type or a
value the section's ``__post_init__`` refuses raises :class:`ConfigError` naming ``where.key``.
"""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

T = TypeVar("T")


class ConfigError(ValueError):
    """A learnstitch configuration, file or input that cannot be used; names the key or file."""


def _convert(kind: str, value: Any, where: str) -> Any:
    def wrong(expected: str):
        return ConfigError(f"{where}: expected {expected}, got {value!r}")

    if kind == "bool":
        if not isinstance(value, bool):
            raise wrong("true or false")
        return value
    if kind == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            raise wrong("an integer")
        return value
    if kind == "float":
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise wrong("a number")
        return float(value)
    if kind in ("str", "str | None"):
        if value is None and kind == "str | None":
            return None
        if not isinstance(value, str):
            raise wrong("a string" + (" or null" if kind == "str | None" else ""))
        return value
    if kind in ("tuple[int, ...]", "tuple[float, ...]"):
        item = kind[6:-6]
        if not isinstance(value, (list, tuple)) or not value:
            raise wrong(f"a non-empty list of {item}s")
        return tuple(_convert(item, v, f"{where}[{i}]") for i, v in enumerate(value))
    raise TypeError(f"unsupported config field type {kind!r} at {where}")  # a programming error, not user input


def typed_from_dict(cls: type[T], values: dict[str, Any] | None, where: str) -> T:
    """``cls(**values)`` with each value checked against ``cls``'s field annotations."""
    values = {} if values is None else values
    if not isinstance(values, dict):
        raise ConfigError(f"{where}: expected a mapping, got {values!r}")
    fields = {f.name: f.type for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - set(fields))
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(fields)}")
    typed = {key: _convert(str(fields[key]), value, f"{where}.{key}") for key, value in values.items()}
    try:
        return cls(**typed)
    except ConfigError as error:
        raise ConfigError(f"{where}: {error}") from None


def as_dict(section: Any) -> dict[str, Any]:
    """A config section as plain YAML/JSON values (tuples as lists)."""
    return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(section).items()}
