"""A package's public names loaded on first use (PEP 562), so that importing one light submodule of a package (its
options, for the command line's flags) does not run the package's heavy modules (numba kernels, scipy)."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any


def lazy_attributes(package: str, where: dict[str, str], namespace: dict[str, Any]) -> Callable[[str], Any]:
    """The ``__getattr__`` of ``package``: a name of ``where`` (name -> submodule) is imported from its submodule,
    any other name as a submodule (``engine.patchmatch.kernels`` used as an attribute); each is then kept in the
    package's ``namespace`` (its ``globals()``)."""
    def __getattr__(name: str) -> Any:
        if name in where:
            value = getattr(importlib.import_module(f"{package}.{where[name]}"), name)
        else:
            try:
                value = importlib.import_module(f"{package}.{name}")
            except ModuleNotFoundError as exc:
                if exc.name != f"{package}.{name}":
                    raise
                raise AttributeError(f"module {package!r} has no attribute {name!r}") from None
        namespace[name] = value
        return value

    return __getattr__
