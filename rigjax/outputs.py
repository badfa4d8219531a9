"""Output paths checked before the work: a run that optimises for seconds or stitches for minutes
should not end in a traceback because its ``-o`` names a missing folder, a folder, or a suffix
nothing can write. Both command lines call :func:`check_output` on every output path first.
"""

from __future__ import annotations

import os
from os import PathLike

from .errors import RigjaxError


class OutputError(RigjaxError):
    """An output path that cannot be written; the message names it and says why."""


def check_output(path: str | PathLike[str], *, image: bool = False, what: str = "output") -> str:
    """``path`` as a string, if a file can be written there: its folder exists and is writable, it
    is not itself a folder, and (``image=True``) OpenCV has a writer for its suffix. Otherwise
    :class:`OutputError` naming the path and the reason."""
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    if os.path.isdir(path):
        raise OutputError(f"{what} {path}: is a folder; name a file in it")
    if not os.path.isdir(folder):
        raise OutputError(f"{what} {path}: the folder {folder} does not exist")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(f"{what} {path}: the folder {folder} is not writable")
    if image:
        import cv2

        if not cv2.haveImageWriter(path):
            suffix = os.path.splitext(path)[1] or "(none)"
            raise OutputError(f"{what} {path}: no image format for the suffix {suffix}; use .png, .jpg or .tif")
    return path
