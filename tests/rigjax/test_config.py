"""The configuration system both packages share (rigjax/config.py), on a small tree of sections."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from rigjax.config import as_dict, typed_from_dict
from rigjax.errors import ConfigError, RigjaxError


@dataclass(frozen=True)
class Inner:
    rounds: int = 3
    scale: float = 1.5
    loss: str | None = "cauchy"

    def __post_init__(self) -> None:
        if self.rounds < 0:
            raise RigjaxError(f"rounds must be >= 0, got {self.rounds}")


@dataclass(frozen=True)
class Outer:
    cameras: int
    verbose: bool | None = None
    widths: tuple[int, ...] = (4, 8)
    pairs: tuple[tuple[int, int], ...] | None = None
    inner: Inner = field(default_factory=Inner)
    optional: Inner | None = field(default_factory=Inner)


def test_values_are_typed_and_nested():
    config = typed_from_dict(
        Outer,
        {"cameras": 2, "widths": [16, 32], "pairs": [[0, 1]], "inner": {"scale": 2, "loss": None}, "optional": True},
        "x.yaml",
    )
    assert config == Outer(cameras=2, widths=(16, 32), pairs=((0, 1),), inner=Inner(scale=2.0, loss=None))
    assert isinstance(config.inner.scale, float)
    # false switches an optional setting off, except a flag, whose false is False
    off = typed_from_dict(Outer, {"cameras": 1, "optional": False, "verbose": False, "inner": {"loss": False}}, "x")
    assert off.optional is None and off.verbose is False and off.inner.loss is None


def test_as_dict_reads_back():
    config = Outer(cameras=3, pairs=((0, 1), (1, 2)), optional=None)
    plain = as_dict(config)
    assert plain["pairs"] == [[0, 1], [1, 2]] and plain["optional"] is None and plain["inner"]["rounds"] == 3
    assert typed_from_dict(Outer, plain, "x") == config


@pytest.mark.parametrize(
    "values, message",
    [
        ({"cameras": 2, "camera": 3}, r"^x.yaml: unknown key 'camera' \(allowed: cameras, verbose, widths, pairs"),
        ({}, r"^x.yaml: missing key 'cameras'$"),
        ({"cameras": True}, r"^x.yaml: cameras: expected an integer, got True$"),
        ({"cameras": 2, "inner": {"scale": "big"}}, r"^x.yaml: inner.scale: expected a number, got 'big'$"),
        (
            {"cameras": 2, "inner": {"round": 1}},
            r"^x.yaml: inner: unknown key 'round' \(allowed: rounds, scale, loss\)$",
        ),
        ({"cameras": 2, "inner": {"rounds": -1}}, r"^x.yaml: inner: rounds must be >= 0, got -1$"),
        ({"cameras": 2, "widths": []}, r"^x.yaml: widths: expected a non-empty list, got \[\]$"),
        ({"cameras": 2, "widths": [4, "8"]}, r"^x.yaml: widths\[1\]: expected an integer, got '8'$"),
        ({"cameras": 2, "pairs": [[0, 1, 2]]}, r"^x.yaml: pairs\[0\]: expected a list of 2 values, got \[0, 1, 2\]$"),
        ({"cameras": 2, "inner": [1]}, r"^x.yaml: inner: expected a mapping of rounds, scale, loss, got \[1\]$"),
    ],
)
def test_errors_name_the_file_and_the_key(values, message):
    with pytest.raises(ConfigError, match=message):
        typed_from_dict(Outer, values, "x.yaml")
