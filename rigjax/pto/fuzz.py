"""Seeded mutations of ``.pto`` text and the properties every input must keep: the reader and writer's
robustness check (``tests/rigjax/test_pto_fuzz.py`` runs a few thousand inputs, ``benchmarks/pto_fuzz.py``
a hundred thousand).

:func:`mutate` applies one to three random edits to a project's text — a number replaced by an
extreme one (thousands of digits, ``nan``, ``1e999``, a 64-bit overflow), a token deleted,
duplicated or moved, a link pointed anywhere, characters inserted (quotes, tabs, a lone ``\\r``,
NUL, non-ASCII), lines deleted, duplicated or swapped, the file cut short — reproducibly from
``(text, seed)``. :func:`check` reads the result and returns its :class:`Outcome`: ``"loaded"`` or
``"refused"`` (a :class:`~rigjax.PtoError` naming the file, and a line when one is to blame), or
raises :class:`FuzzFailure` saying which property broke:

* any exception but ``PtoError`` is a failure, and so is a ``PtoError`` that names no file;
* a loaded project saves to text that loads again to the same values (images, control points,
  variables, masks), and that text saves to itself;
* an unedited project saves to its own text, up to what reading normalises: ``\\r\\n`` line ends,
  a missing final newline, and the optimiser switches Hugin writes, added when absent.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from ..errors import PtoError
from .project import Project, parse_project

_EXTREMES = (
    "nan",
    "inf",
    "-inf",
    "1e999",
    "-0",
    "0",
    "9223372036854775808",
    "99999999999999999999",
    "1e-320",
    "",
    "+",
    ".",
    "1e",
    "0x10",
    "1_000",
    "٣",
)
_CHARS = ('"', " ", "\t", "\r", "\x00", "=", "#", "é", "\ufeff", "\\", "-", "e")
_SWITCHES = ("#hugin_optimizerMasterSwitch 0", "#hugin_optimizerPhotoMasterSwitch 0")


class FuzzFailure(AssertionError):
    """An input that broke a property; the message says which."""


class Outcome(NamedTuple):
    status: str  # "loaded" or "refused"
    seconds: float  # reading time
    message: str  # the PtoError's, for "refused"


def mutate(text: str, seed: int) -> str:
    """``text`` with one to three random edits (see the module docstring), reproducible from ``seed``."""
    rng = np.random.default_rng(seed)
    lines = text.split("\n")
    for _ in range(int(rng.integers(1, 4))):
        lines = _EDITS[int(rng.integers(len(_EDITS)))](lines, rng)
        if not lines:
            lines = [""]
    return "\n".join(lines)


def _pick(rng: np.random.Generator, lines: list[str]) -> int:
    return int(rng.integers(len(lines)))


def _tokens(line: str) -> list[str]:
    return line.split(" ")


def _number(lines, rng):
    k = _pick(rng, lines)
    tokens = _tokens(lines[k])
    if len(tokens) > 1:
        j = int(rng.integers(1, len(tokens)))
        head = tokens[j][:1] if tokens[j][:1].isalpha() else ""
        choice = rng.integers(4)
        if choice == 0:
            value = str(rng.choice(_EXTREMES))
        elif choice == 1:
            value = "1" * int(rng.choice([20, 400, 5000]))
        elif choice == 2:
            value = "1" * int(rng.choice([50, 2000])) + "x"
        else:
            value = f"{rng.normal() * 10.0 ** rng.integers(-5, 12):.6g}"
        tokens[j] = head + value
        lines[k] = " ".join(tokens)
    return lines


def _link(lines, rng):
    images = [k for k, line in enumerate(lines) if line.startswith("i ")]
    if images:
        k = int(rng.choice(images))
        tokens = _tokens(lines[k])
        j = int(rng.integers(1, len(tokens))) if len(tokens) > 1 else 0
        if j:
            target = int(rng.integers(-2, len(images) + 2))
            tokens[j] = tokens[j][:1] + f"={target}"
            lines[k] = " ".join(tokens)
    return lines


def _token(lines, rng):
    k = _pick(rng, lines)
    tokens = _tokens(lines[k])
    if len(tokens) > 1:
        j = int(rng.integers(1, len(tokens)))
        op = rng.integers(3)
        if op == 0:
            del tokens[j]
        elif op == 1:
            tokens.insert(j, tokens[j])
        else:
            other = _tokens(lines[_pick(rng, lines)])
            tokens.insert(j, other[int(rng.integers(len(other)))])
        lines[k] = " ".join(tokens)
    return lines


def _chars(lines, rng):
    k = _pick(rng, lines)
    line = lines[k]
    at = int(rng.integers(len(line) + 1))
    lines[k] = line[:at] + str(rng.choice(_CHARS)) * int(rng.integers(1, 3)) + line[at:]
    return lines


def _lines(lines, rng):
    k, j = _pick(rng, lines), _pick(rng, lines)
    op = rng.integers(3)
    if op == 0:
        del lines[k]
    elif op == 1:
        lines.insert(j, lines[k])
    else:
        lines[k], lines[j] = lines[j], lines[k]
    return lines


def _truncate(lines, rng):
    text = "\n".join(lines)
    return text[: int(rng.integers(len(text) + 1))].split("\n")


_EDITS = (_number, _number, _link, _token, _token, _chars, _lines, _truncate)


def check(text: str, path: str = "fuzz.pto") -> Outcome:
    """Read ``text`` as the file ``path`` and check the properties of the module docstring."""
    started = time.perf_counter()
    try:
        project = parse_project(text, path=path)
    except PtoError as error:
        seconds = time.perf_counter() - started
        if not str(error).startswith(path):
            raise FuzzFailure(f"the error names no file: {error}") from None
        return Outcome("refused", seconds, str(error))
    except Exception as error:  # noqa: BLE001 - any other exception is the failure being looked for
        raise FuzzFailure(f"{type(error).__name__} instead of a PtoError: {error}") from error
    seconds = time.perf_counter() - started
    try:
        saved = project.to_text()
    except Exception as error:  # noqa: BLE001
        raise FuzzFailure(f"saving a loaded project raised {type(error).__name__}: {error}") from error
    if saved != _normalised(text):
        raise FuzzFailure("an unedited project was not written back as read")
    try:
        again = parse_project(saved, path=path)
    except PtoError as error:
        raise FuzzFailure(f"a saved project cannot be read back: {error}") from None
    if not _same_values(project, again):
        raise FuzzFailure("a saved project reads back to other values")
    if again.to_text() != saved:
        raise FuzzFailure("a saved project does not save to itself")
    return Outcome("loaded", seconds, "")


def _normalised(text: str) -> str:
    """What an unedited project saves to: ``\\r\\n`` read as ``\\n``, a final newline, and Hugin's
    optimiser switches when the file has none."""
    lines = [line.removesuffix("\r") for line in text.split("\n")]
    if lines[-1] == "":
        lines.pop()
    names = {line.split(" ")[0] for line in lines}
    lines += [switch for switch in _SWITCHES if switch.split(" ")[0] not in names]
    return "\n".join(lines) + "\n"


def _same_values(a: Project, b: Project) -> bool:
    ca, cb = a.control_points, b.control_points
    return (
        a.panorama == b.panorama
        and a.images == b.images
        and a.variables == b.variables
        and len(a.masks) == len(b.masks)
        and all(ma.equals(mb) for ma, mb in zip(a.masks, b.masks))
        and ca.equals(cb)
    )
