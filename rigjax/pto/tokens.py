"""Tokens of a ``.pto`` line: splitting, number parsing and Hugin's number formatting.

Hugin separates tokens by single spaces (not tabs) and lets quoted strings (``n"a b.jpg"``) hold
spaces. A token is ``<name><value>``, the name matched case-sensitively. Numbers follow the C
locale. rigjax keeps each line's separators so that a line can be written back byte for byte.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from ..errors import PtoError, RigjaxError, shorten

# A token: runs of characters other than space and '"', or quoted strings.
_TOKEN = re.compile(r'(?:[^ "]|"[^"]*")+')
_SPACES = re.compile(r"( +)")
# One way to match each literal (no nested choice between digit runs): linear time on any input.
_NUMBER = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?")
_INTEGER = re.compile(r"[+-]?\d+")
# Hugin reads integers (sizes, lens types, image numbers, control point types) into C ints.
INT_MIN, INT_MAX = -(2**31), 2**31 - 1


@dataclass(frozen=True)
class Where:
    """A position in a project file, for error messages."""

    path: str | None
    line: int

    def error(self, message: str, token: str | None = None) -> PtoError:
        return PtoError(message, path=self.path, line=self.line, token=token)


def split_tokens(text: str, where: Where) -> tuple[list[str], list[str]]:
    """Split a line into tokens and the separators around them.

    Returns ``(tokens, seps)`` with ``len(seps) == len(tokens) + 1`` so that
    ``seps[0] + tokens[0] + seps[1] + ... + tokens[-1] + seps[-1] == text``.
    """
    if '"' not in text:  # the common case: runs of spaces apart, tokens in between
        parts = _SPACES.split(text)
        tokens, seps = parts[0::2], ["", *parts[1::2], ""]
        if tokens[0] == "":  # leading spaces
            del tokens[0], seps[0]
        if tokens and tokens[-1] == "":  # trailing spaces
            del tokens[-1], seps[-1]
        return tokens, seps
    tokens = []
    seps = []
    pos = 0
    for match in _TOKEN.finditer(text):
        seps.append(text[pos : match.start()])
        tokens.append(match.group())
        pos = match.end()
    seps.append(text[pos:])
    for k, sep in enumerate(seps):
        if '"' in sep:  # a quote the token pattern could not close
            start = text.index('"', sum(len(s) + len(t) for s, t in zip(seps[:k], tokens[:k])))
            start = text.rfind(" ", 0, start) + 1
            raise where.error("unterminated quoted string", text[start:].split(" ")[0])
    return tokens, seps


def join_tokens(tokens: list[str], seps: list[str]) -> str:
    out = [seps[0]]
    for token, sep in zip(tokens, seps[1:]):
        out += [token, sep]
    return "".join(out)


def parse_float(text: str, token: str, where: Where, what: str) -> float:
    """A C-locale floating-point literal; NaN, infinities and Python-only forms are errors."""
    if not _NUMBER.fullmatch(text):
        raise where.error(f"{what} needs a number, found {shorten(text)!r}", token)
    value = float(text)
    if not math.isfinite(value):
        raise where.error(f"{what} is out of range: {shorten(text)!r}", token)
    return value


def parse_int(text: str, token: str, where: Where, what: str) -> int:
    """A 32-bit integer; an integral float literal (``w4000.0``) is accepted as Hugin does."""
    if len(text) <= 9 and text.isascii() and text.isdigit():  # the common case, in range, without a pattern
        return int(text)
    if _INTEGER.fullmatch(text):
        # More than 10 significant digits is out of range; counted first, since Python refuses to
        # convert strings of over 4,300 digits.
        value = int(text) if len(text.lstrip("+-").lstrip("0")) <= 10 else INT_MAX + 1
    else:
        number = parse_float(text, token, where, what)
        if number != int(number):
            raise where.error(f"{what} needs an integer, found {shorten(text)!r}", token)
        value = int(number)
    if not INT_MIN <= value <= INT_MAX:
        raise where.error(f"{what} is out of range: {shorten(text)!r} (a 32-bit integer)", token)
    return value


def quoted(value: str, what: str) -> str:
    """``"value"`` for a string token; a quote or a line break inside would end it early."""
    if any(c in value for c in '"\r\n'):
        raise RigjaxError(f"{what} {value!r} cannot be written to a project: it holds a quote or a line break")
    return f'"{value}"'


def parse_string(text: str, token: str, where: Where, what: str) -> str:
    """The value of a quoted token, ``n"..."`` -> ``...``."""
    if len(text) < 2 or text[0] != '"' or text[-1] != '"':
        raise where.error(f"{what} needs a quoted string", token)
    return text[1:-1]


def format_number(value: float) -> str:
    """Hugin's number format: 15 significant digits, no ``-0``. NaN and infinities are refused: a
    project rigjax writes is one it can read."""
    if not math.isfinite(value):
        raise RigjaxError(f"cannot write {value!r} to a project: a .pto holds finite numbers")
    text = f"{value:.15g}"
    return "0" if text == "-0" else text
