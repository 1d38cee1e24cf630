"""PEP 562 lazy public names of a package: a package's ``__getattr__`` imports the submodule that defines a
name on first access and keeps the value in the package (later accesses do not come here). Standard library
only, so that importing a package's light submodules (e.g. for ``hadal.settings``) does not pull in NumPy/SciPy."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Mapping
from typing import Any


def lazy_attr(package: str, where: Mapping[str, str], name: str) -> Any:
    """The value of ``package.name``, from the submodule ``where[name]`` of ``package``; ``AttributeError`` for a
    name ``where`` does not list. Call it from the package's module ``__getattr__``."""
    if name in where:
        value = getattr(importlib.import_module(f"{package}.{where[name]}"), name)
        vars(sys.modules[package])[name] = value
        return value
    raise AttributeError(f"module {package!r} has no attribute {name!r}")
