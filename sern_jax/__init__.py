"""sern_jax: SERN (Shannon-entropy-regularised neural contextual bandits) in JAX.

Core modules (jax, numpy, optax, scipy only), re-exported lazily: ``import sern_jax`` imports
none of them (so ``sern --help`` stays instant); ``sern_jax.executor`` imports that module on
first use, like ``from sern_jax import executor``.

* ``types``, ``policies``, ``schedules``, ``estimators``, ``problems``: the pure pieces;
* ``simulate``: ``make_run(config) -> run(key, params)`` for one seed; ``fast_softmax``: the
  exact fast runner for SERN softmax with local estimators;
* ``executor``: ``run_seeds`` over thousands of seeds (chunks, threads, meshes);
* ``theory``, ``stats``: closed forms of Theorems 1–5; intervals and Holm;
* ``sharding``, ``io``: device meshes; run directories and checkpoints;
* ``timing``, ``benchmarks``: the timing helper; the bandit benchmark and its NumPy reference
  (``sern bench bandit``).

The grasp layer (``sern_jax.grasp``) imports mujoco, mjx and flax and is not imported here.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

__version__ = "0.1.0"

_MODULES = ("types", "policies", "schedules", "estimators", "problems", "simulate",
            "fast_softmax", "executor", "theory", "stats", "sharding", "io", "timing",
            "benchmarks")

__all__ = ["__version__", *_MODULES]

if TYPE_CHECKING:  # for type checkers and IDEs; at run time the modules load lazily
    from sern_jax import (benchmarks, estimators, executor, fast_softmax, io,  # noqa: F401
                          policies, problems, schedules, sharding, simulate, stats, theory,
                          timing, types)


def __getattr__(name: str):
    if name in _MODULES:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_MODULES))
