"""The exceptions rigjax and learnstitch raise on bad input. All subclass ``RigjaxError``, a ``ValueError``.

Both command lines print any of them as one ``error:`` line and exit with status 2."""

from __future__ import annotations

from os import PathLike

EXIT_BAD_INPUT = 2  # the exit status of both command lines on bad input, as argparse's usage errors
# a solve that did not converge, or a calibration its matches do not determine: named, nothing written
EXIT_UNRELIABLE = 3


class RigjaxError(ValueError):
    """Base class of the input errors of rigjax and learnstitch."""


class ConfigError(RigjaxError):
    """A configuration file or value that cannot be used; names the file and the key."""


class PtoError(RigjaxError):
    """A ``.pto`` project that cannot be read: names the file, the line and the token.

    Attributes:
        path: the file (``None`` for text that came from memory).
        line: 1-based line number, or ``None`` for errors about the whole file.
        token: the offending token, or ``None``.
    """

    def __init__(
        self,
        message: str,
        *,
        path: str | PathLike[str] | None = None,
        line: int | None = None,
        token: str | None = None,
    ) -> None:
        self.path = None if path is None else str(path)
        self.line = line
        self.token = token
        where = self.path or "<text>"
        if line is not None:
            where += f":{line}"
        what = f" token {shorten(token)!r}:" if token is not None else ""
        super().__init__(f"{where}:{what} {message}")


def shorten(text: str, limit: int = 40) -> str:
    """``text``, or its first characters and its length when longer than ``limit``: a message
    stays one readable line whatever the input."""
    return text if len(text) <= limit else f"{text[: limit - 8]}... ({len(text)} characters)"


class UnsupportedError(RigjaxError):
    """Valid Hugin input that rigjax's camera model does not cover (e.g. lens shear ``g``/``t``)."""
