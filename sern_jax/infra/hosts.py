"""The one reader of this host's CPU count and of the ``SERN_*`` environment variables that
size thread pools.

* ``SERN_CPU_THREADS``: a Ray task's share of a node (set by :mod:`sern_jax.infra.distributed`
  for each task); the engines and the context pools use at most that many threads.
* ``SERN_CONTEXT_THREADS``: the threads that settle one batch's resting poses (the grasp
  contexts), where the user wants fewer than the cores (``1``: one after another).
* ``SERN_PIN_CORES``: ``1`` where a Ray task pins itself to its share of cores.

Values that are not positive integers are ignored (the default applies).
"""

from __future__ import annotations

import os

__all__ = [
    "MANY_CORES",
    "context_threads",
    "cpu_threads",
    "env_threads",
    "many_cores",
    "pin_cores_requested",
    "usable_cores",
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
