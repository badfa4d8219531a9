"""Compiled programs kept across processes, so that a command's later runs do not trace again.

A jit-compiled function is traced to a jaxpr, lowered to StableHLO and compiled anew by every
process that calls it. XLA's persistent compilation cache keeps the last step (the machine code,
keyed by the lowered program), but tracing and lowering an LM stage cost more than loading its
code. :func:`persist` turns on both that cache and a store of *exports* (``jax.export``: the
lowered program with its argument and result structure, serialised): a :class:`Program` called
with arguments of a structure it has exported before loads the export and calls it, without
tracing the function, or even importing the module that defines it.

An export is keyed by everything that decides the program: the function, its static arguments,
the structure, shapes and dtypes of its arguments, the JAX version, backend and float width, and
the digest of rigjax's own source, so that a change of code never runs a stale program. A file
that cannot be read back is exported again; one that cannot be written costs the next process a
trace, nothing more.

Convention: without :func:`persist` (the Python API's default), a :class:`Program` is the plain
jit-compiled function, traced once per process and structure.
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import os
import sys
import tempfile
import threading
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path

_exports: Path | None = None  # where exports are kept, once persist() has been called
# JAX's settings persist() makes: the cache's folder, and the compile time below which nothing is kept
CACHE_SETTINGS = ("jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs")
_registered: set[type] = set()


def default_folder() -> Path:
    """``$RIGJAX_CACHE_DIR``, else ``$XDG_CACHE_HOME/rigjax/jax`` (``~/.cache/rigjax/jax``)."""
    folder = os.environ.get("RIGJAX_CACHE_DIR")
    if folder:
        return Path(folder)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "rigjax" / "jax"


def persist(folder: str | os.PathLike | None = None) -> Path:
    """Keep compiled programs in ``folder`` (default :func:`default_folder`) for later processes:
    XLA's compilation cache there, and :class:`Program` exports in its ``exports`` subfolder.

    Programs that compile in under 0.1 s (eager operations' own) are not written. Returns the folder.
    Before JAX is imported the settings go to the environment, where JAX reads them when it loads
    (and so do this process's children): a command that turns out not to need JAX never loads it.
    """
    global _exports
    folder = Path(folder) if folder is not None else default_folder()
    settings = dict(zip(CACHE_SETTINGS, (str(folder), 0.1)))
    if "jax" in sys.modules:
        import jax

        for name, value in settings.items():
            jax.config.update(name, value)
    else:
        os.environ.update({name.upper(): str(value) for name, value in settings.items()})
    _exports = folder / "exports"
    return folder


def persisting() -> bool:
    """Whether :func:`persist` was called: only then do :class:`Program` s load or keep exports."""
    return _exports is not None


def register(*types: type) -> None:
    """Let exports whose arguments or results hold these NamedTuples be written and read back."""
    from jax import export

    for cls in types:
        if cls not in _registered:
            export.register_namedtuple_serialization(cls, serialized_name=f"{cls.__module__}.{cls.__qualname__}")
            _registered.add(cls)


@functools.cache
def _environment() -> str:
    """What decides a program besides its function and arguments: versions, backend, float
    width, and rigjax's source."""
    import jax
    import jaxlib

    source = hashlib.sha256()
    package = Path(__file__).resolve().parent
    for path in sorted(package.rglob("*.py")):
        source.update(str(path.relative_to(package)).encode())
        source.update(path.read_bytes())
    return repr(
        (
            jax.__version__,
            jaxlib.__version__,
            jax.default_backend(),
            bool(jax.config.jax_enable_x64),
            source.hexdigest(),
        )
    )


class Program:
    """A jit-compiled function, called as it is, that after :func:`persist` is loaded from its
    export when one exists for the structure of its arguments.

    Args:
        module, name: where the function (``jax.jit`` of a pure function) is defined; imported
            only when it must be traced, or when nothing persists.
        static: the names of its static arguments, passed by keyword (part of the key, baked into
            the program); the positional arguments are its data.
        types: the NamedTuples among its arguments and results (:func:`register`).
    """

    def __init__(self, module: str, name: str, *, static: Sequence[str] = (), types: Sequence[type] = ()):
        self.module, self.name, self.static = module, name, tuple(static)
        register(*types)
        self._calls: dict[str, Callable] = {}  # key -> the loaded program, in this process
        self._lock = threading.Lock()  # threads solving one structure load it once

    @functools.cached_property
    def jitted(self) -> Callable:
        return getattr(importlib.import_module(self.module), self.name)

    def __call__(self, *args, **static):
        if not persisting():
            return self.jitted(*args, **static)
        key = self.key(args, static)
        call = self._calls.get(key)
        if call is None:
            with self._lock:
                call = self._calls.get(key) or self._load(key, args, static)
                self._calls[key] = call
        return call(*args)

    def key(self, args: tuple, static: dict) -> str:
        """The digest naming the program for these arguments (their values do not count)."""
        import jax
        import numpy as np

        if set(static) != set(self.static):
            raise TypeError(f"{self.name} takes the static arguments {self.static}, got {tuple(static)}")
        leaves, tree = jax.tree_util.tree_flatten(args)
        avals = [(np.shape(leaf), np.result_type(leaf).str) for leaf in leaves]
        text = repr((self.module, self.name, sorted(static.items()), str(tree), avals, _environment()))
        return hashlib.sha256(text.encode()).hexdigest()[:40]

    def _load(self, key: str, args: tuple, static: dict) -> Callable:
        """The program for ``key``, compiled (or loaded from XLA's cache) for ``args``' structure."""
        import jax
        import numpy as np
        from jax import export

        # The program depends on the arguments' shapes and dtypes only: whether they are NumPy
        # arrays or a device's (a previous stage's results) must not change what is compiled, or
        # XLA's cache would hold one program per kind.
        args = jax.tree_util.tree_map(lambda leaf: jax.ShapeDtypeStruct(np.shape(leaf), np.result_type(leaf)), args)
        path = _exports / f"{self.name}-{key}.jaxexport"
        try:
            data = path.read_bytes()
        except OSError:  # not exported yet (or no folder to read): export it
            data = None
        exported = None
        if data is not None:
            try:
                exported = export.deserialize(bytearray(_payload(data)))
            except Exception as error:  # a damaged or truncated file: export it again
                warnings.warn(f"{path}: cannot be read back ({error}); exporting {self.name} again", stacklevel=3)
        if exported is None:
            exported = export.export(self.jitted)(*args, **static)
            payload = bytes(exported.serialize())
            _write_atomically(path, _MAGIC + hashlib.sha256(payload).digest() + payload)
        return jax.jit(exported.call).lower(*args).compile()


_MAGIC = b"rigjax export 1\n"  # then the payload's SHA-256, then jax.export's serialisation


def _payload(data: bytes) -> bytes:
    """The serialised export in a file's bytes, checked whole."""
    head = len(_MAGIC) + 32
    if not data.startswith(_MAGIC) or len(data) < head:
        raise ValueError("not a rigjax export")
    if hashlib.sha256(data[head:]).digest() != data[len(_MAGIC) : head]:
        raise ValueError("its checksum does not match: the file is damaged or truncated")
    return data[head:]


def _write_atomically(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` whole or not at all: concurrent processes each replace the file
    with a complete copy. A folder that cannot be written only costs later processes a trace."""
    part = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path.parent, prefix=path.name, suffix=".part", delete=False) as f:
            part = f.name
            f.write(data)
        os.replace(part, path)
    except OSError as error:
        warnings.warn(f"cannot keep the compiled program {path}: {error}", stacklevel=4)
        if part is not None and os.path.exists(part):
            os.unlink(part)
