"""The script folders (``experiments/``, ``figures/``, ``proofs_check/``) as the commands see them.

Installed (a wheel or ``pip install -e .``), the repository's top-level script folders are the
subpackages ``sern_jax.experiments``, ``sern_jax.figures`` and ``sern_jax.proofs_check`` (the
build's ``package-dir`` mapping), so installing adds only ``sern_jax`` to the import namespace.
In a clone that was not installed (``python -m sern_jax.commands.main`` from the repository
root) they are the top-level folders. The command modules are the only ones that import them.
"""

from __future__ import annotations

import importlib
import pkgutil
from types import ModuleType

__all__ = ["SCRIPT_FOLDERS", "script_package", "script_module", "experiment_names"]

SCRIPT_FOLDERS = ("experiments", "figures", "proofs_check")


def script_package(folder: str) -> ModuleType:
    """``sern_jax.<folder>`` where installed, else the clone's top-level ``<folder>``."""
    if folder not in SCRIPT_FOLDERS:
        raise ValueError(f"not a script folder: {folder!r}")
    try:
        return importlib.import_module(f"sern_jax.{folder}")
    except ModuleNotFoundError as exc:
        if exc.name != f"sern_jax.{folder}":
            raise  # the folder exists but something it imports is missing
    return importlib.import_module(folder)


def script_module(folder: str, name: str) -> ModuleType:
    """The module ``name`` of a script folder, e.g. ``script_module("experiments", "grasp_learning")``."""
    return importlib.import_module(f"{script_package(folder).__name__}.{name}")


def experiment_names() -> list[str]:
    """The modules of the experiments folder (without importing them)."""
    return sorted(m.name for m in pkgutil.iter_modules(script_package("experiments").__path__)
                  if not m.name.startswith("_"))
