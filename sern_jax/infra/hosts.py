"""The one reader of this host's CPU count and of the ``SERN_*`` environment variables that
size thread pools.

* ``SERN_CPU_THREADS``: a Ray task's share of a node (set by :mod:`sern_jax.infra.distributed`
  for each task); the engines and the context pools use at most that many threads.
* ``SERN_CONTEXT_THREADS``: the threads that settle one batch's resting poses (the grasp
  contexts), where the user wants fewer than the cores (``1``: one after another).
* ``SERN_PIN_CORES``: ``1`` where a Ray task pins itself to its share of cores.
* ``SERN_GPU_NONDETERMINISTIC``: ``1`` to leave XLA's GPU autotuning and non-deterministic
  kernels on (:func:`use_deterministic_xla`; by default the ``sern`` commands turn them off,
  so that a rerun of the same command on a GPU gives the same bits).

Values that are not positive integers are ignored (the default applies).
"""

from __future__ import annotations

import os

__all__ = [
    "DETERMINISTIC_XLA_FLAGS",
    "MANY_CORES",
    "context_threads",
    "cpu_threads",
    "env_threads",
    "many_cores",
    "pin_cores_requested",
    "usable_cores",
    "use_deterministic_xla",
]

MANY_CORES = 8  # a host with at least this many usable cores counts as many-core


def usable_cores() -> int:
    """The cores this process may run on (its affinity mask where the OS has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def env_threads(name: str) -> int | None:
    """The positive integer in environment variable ``name``, else None."""
    value = os.environ.get(name, "").strip()
    if value.isdigit() and int(value) >= 1:
        return int(value)
    return None


def cpu_threads() -> int:
    """Threads this process should use: ``SERN_CPU_THREADS`` where set (a Ray task's share of
    a node), else :func:`usable_cores`."""
    return env_threads("SERN_CPU_THREADS") or usable_cores()


def context_threads() -> int:
    """Threads that settle the resting poses of one batch: ``SERN_CONTEXT_THREADS`` where set,
    else :func:`cpu_threads`."""
    return env_threads("SERN_CONTEXT_THREADS") or cpu_threads()


def many_cores() -> bool:
    """Whether this process may use at least :data:`MANY_CORES` cores (the cores it may run
    on, or its task's share ``SERN_CPU_THREADS`` where that is less)."""
    cores = usable_cores()
    share = env_threads("SERN_CPU_THREADS")
    if share is not None:
        cores = min(cores, share)
    return cores >= MANY_CORES


def pin_cores_requested() -> bool:
    """Whether this process was asked to pin itself to its share of cores (a Ray task)."""
    return os.environ.get("SERN_PIN_CORES") == "1"


# XLA's GPU options for bit-identical reruns: deterministic kernels (no atomics in reductions and
# scatters), and no autotuning (which times candidate kernels and may pick another one on a
# busy GPU). Both are ignored by the CPU backend, whose results are deterministic already.
DETERMINISTIC_XLA_FLAGS = ("--xla_gpu_deterministic_ops=true", "--xla_gpu_autotune_level=0")


def use_deterministic_xla() -> bool:
    """Adds :data:`DETERMINISTIC_XLA_FLAGS` to ``XLA_FLAGS`` (options the user set there win)
    unless ``SERN_GPU_NONDETERMINISTIC=1``; returns whether they are in effect.

    XLA reads ``XLA_FLAGS`` when a backend starts, so this must run before the first JAX
    computation of the process (the ``sern`` entry point calls it first thing).
    """
    if os.environ.get("SERN_GPU_NONDETERMINISTIC") == "1":
        return False
    flags = os.environ.get("XLA_FLAGS", "").split()
    names = {f.split("=", 1)[0] for f in flags}
    extra = [f for f in DETERMINISTIC_XLA_FLAGS if f.split("=", 1)[0] not in names]
    if extra:
        os.environ["XLA_FLAGS"] = " ".join(flags + extra)
    return all(f in os.environ["XLA_FLAGS"].split() for f in DETERMINISTIC_XLA_FLAGS)
