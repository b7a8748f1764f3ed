"""sern_jax: SERN (Shannon-entropy-regularised neural contextual bandits) in JAX.

The folder tree is the architecture (docs/ARCHITECTURE.md); imports point one way, down:

* ``core``: problems, policies, schedules, estimators (jax, numpy, optax only);
* ``analysis``: closed forms of Theorems 1-5 (``theory``) and statistics (``stats``);
* ``learners``: exploration strategies as ``Learner(init, act, update)`` and their registry;
* ``engine``: one seed (``simulate``), the fast runners, and ``drive.run_seeds`` over thousands;
* ``grasp``: the MuJoCo/MJX grasp world, the quality network, online grasp learning;
* ``experiment``: what ``sern regret`` and ``sern reproduce`` run;
* ``infra``: run directories, Ray, meshes, timing, flag checks; ``bench``: ``sern bench``;
* ``commands``: the ``sern`` CLI (not re-exported here: the library never imports it).

``import sern_jax`` imports none of them (so ``sern --help`` stays instant); each subpackage
loads on first use, like ``from sern_jax.engine import drive``.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

__version__ = "0.1.0"

_MODULES = ("core", "analysis", "learners", "engine", "grasp", "experiment", "infra",
            "bench")

__all__ = ["__version__", *_MODULES]

if TYPE_CHECKING:  # for type checkers and IDEs; at run time the packages load lazily
    from sern_jax import (analysis, bench, core, engine, experiment, grasp,  # noqa: F401
                          infra, learners)


def __getattr__(name: str):
    if name in _MODULES:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_MODULES))
