"""A package's public names imported on first use (PEP 562).

``import rigjax`` then costs the package's ``__init__`` alone, not JAX, OpenCV and the solvers, so
that ``rigjax --help`` and a command that needs only the ``.pto`` reader start at once. The first
``rigjax.optimise`` (or ``from rigjax import optimise``) imports its module, and the name stays
bound in the package from then on.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping


def lazy_exports(
    package: str, exports: Mapping[str, tuple[str, ...]]
) -> tuple[Callable[[str], object], Callable[[], list[str]], list[str]]:
    """``(__getattr__, __dir__, __all__)`` for ``package``.

    ``exports`` maps a module (relative to ``package``, or absolute) to the public names it defines;
    a name that is the module's own last component stands for the module itself.
    """
    module_of = {name: module for module, names in exports.items() for name in names}
    if len(module_of) != sum(len(names) for names in exports.values()):
        raise ValueError(f"{package}: a public name is exported by two modules")

    def __getattr__(name: str) -> object:
        module_name = module_of.get(name)
        if module_name is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        module = importlib.import_module(module_name, package)
        value = module if module_name.rpartition(".")[2] == name else getattr(module, name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(module_of))

    return __getattr__, __dir__, sorted(module_of)
