"""Public names of a package that load their module on first use (PEP 562), so that
importing a package costs nothing until one of its names is used: ``import mscap`` and
the HDF5 store do not load PETSc and the FEM stack (``tests/test_api.py``)."""

from __future__ import annotations

import importlib
from typing import Callable

__all__ = ["lazy_names"]


def lazy_names(package: str, names: dict[str, str], eager: tuple[str, ...] = ()) -> tuple[list[str], Callable]:
    """``(__all__, __getattr__)`` of ``package``: ``names`` maps each public name to the
    module that defines it, relative to ``package`` (or absolute, ``mscap....``); ``eager``
    names are imported by the package itself and only listed."""

    def __getattr__(name: str):
        if name in names:
            module = names[name] if names[name].startswith("mscap.") else f"{package}.{names[name]}"
            return getattr(importlib.import_module(module), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return sorted([*eager, *names]), __getattr__
