"""Running many seeds: plan the calls, pick the runner, chunk, thread, copy out.

:func:`run_seeds` is the entry point for a batch of seeds. It plans (:func:`plan_run`) which
runner to use (:mod:`sern_jax.fast_softmax` where it is exact, ``simulate.make_run`` otherwise)
and the call shape (seeds per jitted call, seeds per ``lax.map`` step, calls at once from host
threads), then runs the seeds in fixed-shape calls, optionally sharded over a device mesh, and
copies outputs into numpy arrays (through page-locked host memory on an accelerator).

Seed ``i`` always uses ``simulate.seed_keys(root, ·)[i] = fold_in(key(seed), i)``, so it gives
the same result whether it runs alone or among 10,000, in any chunking, on any mesh.

Layering: this module imports :mod:`sern_jax.simulate` and :mod:`sern_jax.fast_softmax`;
neither imports it (``fast_softmax`` imports ``simulate``; ``simulate`` imports neither).
"""

from __future__ import annotations

import concurrent.futures
import math
import os
import threading
from typing import Callable, NamedTuple, Optional

import jax
import numpy as np

from sern_jax import estimators as est_lib
from sern_jax import fast_softmax
from sern_jax.simulate import (Diagnostics, RunConfig, RunOutput, RunParams, checkpoint_times,
                               make_run, seed_keys, validate)

__all__ = [
    "RUNNERS",
    "RunPlan",
    "run_seeds",
    "plan_run",
    "batched_runner",
    "bytes_per_seed",
    "available_memory_bytes",
    "default_chunk_size",
    "host_workers",
    "concurrent_calls",
    "use_pinned_host",
]

RUNNERS = ("auto", "fast", "general")
# Bytes of outputs and per-seed state one jitted call may hold on the host backend: seeds run in
# calls of this size (one compilation), results are written into preallocated arrays, so peak
# memory is the final O(S·G·K) outputs plus one call's worth, whatever S is.
_CPU_CALL_BYTES = 64 * 2**20
_ACCEL_CALL_BYTES = 4 * 2**30


class RunPlan(NamedTuple):
    """How :func:`run_seeds` executes: the jitted batched runner and its fixed call shape.

    Attributes:
      fn: ``fn(keys [chunk], params) -> RunOutput`` (jitted; one compilation per plan).
      fast: whether ``fn`` is :mod:`sern_jax.fast_softmax`'s runner.
      chunk: seeds per call (a multiple of the mesh size; the last call is padded).
      inner: seeds per ``lax.map`` step inside a fast call (None: one step).
      workers: calls run at once from host threads (CPU without a mesh: one per core; a
        compiled call runs on one core at a time there, so this is where the second core's
        speed comes from).
    """

    fn: Callable
    fast: bool
    chunk: int
    inner: Optional[int]
    workers: int


def bytes_per_seed(config: RunConfig) -> int:
    """Host bytes one seed's outputs and scan state take (an upper estimate)."""
    g = checkpoint_times(config).size
    item = 8 if config.dtype == "float64" else 4
    k, m = config.num_arms, config.num_contexts
    num_diag = len(Diagnostics._fields) if config.diagnostics else 0
    outputs = g * (k * (4 + item) + (5 + num_diag) * item)
    state = (4 * m * k + 16 * k + 64) * item
    return outputs + state


def available_memory_bytes() -> int:
    """Memory this machine can still give (``MemAvailable`` on Linux, else physical memory)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def host_workers() -> int:
    """CPU cores this process may use (its affinity mask where the OS has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def concurrent_calls(mesh: "jax.sharding.Mesh | None" = None) -> int:
    """How many jitted calls :func:`run_seeds` runs at once: one per core on the CPU backend
    without a mesh (there a call runs on one core), otherwise 1 (the device is busy already)."""
    return host_workers() if mesh is None and jax.default_backend() == "cpu" else 1


def default_chunk_size(config: RunConfig, num_seeds: int, backend: str | None = None,
                       workers: int = 1) -> int:
    """Seeds per jitted call when ``chunk_size`` is not given: an equal share of the seeds for
    each of ``workers`` concurrent calls, capped so that one call holds at most 64 MiB of
    outputs and state on CPU (4 GiB on an accelerator); calls are balanced."""
    backend = jax.default_backend() if backend is None else backend
    budget = _CPU_CALL_BYTES if backend == "cpu" else _ACCEL_CALL_BYTES
    share = -(-num_seeds // max(1, workers))
    cap = max(1, budget // bytes_per_seed(config))
    calls = -(-share // cap)
    return -(-share // calls)  # balanced: the padded last call wastes little


def plan_run(
    config: RunConfig,
    params: RunParams,
    num_seeds: int,
    *,
    mesh: "jax.sharding.Mesh | None" = None,
    chunk_size: int | None = None,
    runner: str = "auto",
) -> RunPlan:
    """Chooses the runner and call shape for :func:`run_seeds` (host-side; compiles nothing).

    ``runner="auto"`` takes :mod:`sern_jax.fast_softmax` whenever it reproduces
    :func:`make_run` (SERN softmax, one context, a local estimator, no diagnostics, α large
    enough for its float type; see ``fast_softmax.supports``) and the general runner otherwise;
    ``"fast"`` insists on the fast runner (``ValueError`` if unsupported), ``"general"`` on
    :func:`make_run`.
    """
    if runner not in RUNNERS:
        raise ValueError(f"unknown runner {runner!r}; expected one of {RUNNERS}")
    if chunk_size is not None and (isinstance(chunk_size, bool) or int(chunk_size) < 1):
        raise ValueError(f"chunk_size must be a positive integer, got {chunk_size!r}")
    supported = runner != "general" and fast_softmax.supports(config, params)
    if runner == "fast" and not supported:
        raise ValueError(
            f"runner='fast' needs policy='softmax', one context, an estimator in "
            f"{est_lib.LOCAL_ESTIMATORS}, diagnostics=False and alpha >= "
            f"{fast_softmax.min_alpha(config.dtype)} ({config.dtype}); got policy="
            f"{config.policy!r}, estimator={config.estimator!r}, "
            f"num_contexts={config.num_contexts}, diagnostics={config.diagnostics}")
    workers = concurrent_calls(mesh)
    chunk = (default_chunk_size(config, num_seeds, workers=workers) if chunk_size is None
             else int(chunk_size))
    n_dev = 1 if mesh is None else mesh.devices.size
    if supported:
        target = fast_softmax.DEFAULT_CPU_CHUNK if jax.default_backend() == "cpu" else None
        inner, chunk = fast_softmax.chunk_layout(chunk, target, n_dev)
        if inner * n_dev >= chunk:
            inner = None
    else:
        inner = None
        chunk = int(math.ceil(chunk / n_dev) * n_dev)
    workers = max(1, min(workers, -(-num_seeds // chunk)))
    return RunPlan(batched_runner(config, mesh, supported, inner), supported, chunk, inner,
                   workers)


def run_seeds(
    config: RunConfig,
    params: RunParams,
    seed: int = 0,
    num_seeds: int = 1000,
    *,
    first_seed: int = 0,
    mesh: "jax.sharding.Mesh | None" = None,
    chunk_size: int | None = None,
    runner: str = "auto",
    progress: Callable[[int], None] | None = None,
) -> RunOutput:
    """Runs seeds ``first_seed … first_seed + num_seeds − 1``; outputs have a leading [S] axis.

    Args:
      config: static configuration.
      params: traced parameters shared by all seeds.
      seed: root seed; seed ``i`` uses ``fold_in(key(seed), i)``.
      num_seeds: S ≥ 1.
      first_seed: index of the first seed (runs split into pieces give the same results).
      mesh: optional ``jax.sharding.Mesh`` with one axis: the seed axis is sharded over it.
        Results equal the single-device run.
      chunk_size: seeds per jitted call. Every call has this shape (the last one is padded), so
        runs of any ``num_seeds`` with the same ``chunk_size`` share one compilation. Default:
        :func:`default_chunk_size` (bounds memory).
      runner: ``"auto"`` (fast runner where it is exact), ``"fast"`` or ``"general"``; see
        :func:`plan_run`.
      progress: called with the number of seeds finished after each call.

    Returns:
      :class:`RunOutput` of numpy arrays with leading axis S.
    """
    validate(config, params, num_seeds)
    if isinstance(first_seed, bool) or int(first_seed) < 0:
        raise ValueError(f"first_seed must be a non-negative integer, got {first_seed!r}")
    if int(first_seed) + num_seeds > 2**32:
        raise ValueError(f"seed indices are uint32: first_seed + num_seeds must be <= 2^32, "
                         f"got {int(first_seed) + num_seeds}")
    plan = plan_run(config, params, num_seeds, mesh=mesh, chunk_size=chunk_size, runner=runner)
    root = jax.random.key(seed)
    sharding = None
    if mesh is not None:
        sharding = jax.sharding.NamedSharding(
            mesh, jax.sharding.PartitionSpec(mesh.axis_names[0]))

    key_struct = jax.ShapeDtypeStruct((plan.chunk,), root.dtype)
    fn = plan.fn
    if plan.workers > 1:
        # Compiled here, once: worker threads do not inherit thread-local configuration such as
        # ``jax.enable_x64()``, so they must not trace. (Shares ``plan.fn``'s compilation cache.)
        fn = plan.fn.lower(key_struct, params).compile()

    result = None
    lock = threading.Lock()

    def launch(start: int):
        keys = seed_keys(root, plan.chunk, int(first_seed) + start)  # fixed call shape
        if sharding is not None:
            keys = jax.device_put(keys, sharding)
        return fn(keys, params)  # asynchronous on an accelerator

    # Pinned outputs are always copied into numpy arrays of our own (below), so the pinned
    # buffers go back to JAX's pool at once and the next call reuses them: page-locking a new
    # buffer costs about as much as the pageable copy it replaces.
    pinned = use_pinned_host(mesh)

    def collect(start: int, out) -> int:
        nonlocal result
        if pinned:
            # page-locked host buffers: one DMA per output, and numpy views them without a copy
            out = jax.device_put(out, jax.tree.map(
                lambda x: x.sharding.with_memory_kind("pinned_host"), out))
        else:
            for leaf in jax.tree.leaves(out):
                leaf.copy_to_host_async()  # all outputs' transfers in flight at once
        size = min(plan.chunk, num_seeds - start)
        if size == num_seeds and not pinned:  # one call, host arrays: keep them, no copy
            result = jax.tree.map(lambda x: np.asarray(x)[:size], out)
            return size
        with lock:  # allocated from the first finished call: no extra trace for the shapes
            if result is None:
                result = jax.tree.map(
                    lambda x: np.empty((num_seeds,) + x.shape[1:], x.dtype), out)
        for dst, src in zip(jax.tree.leaves(result), jax.tree.leaves(out)):
            dst[start:start + size] = np.asarray(src)[:size]
        return size

    starts = range(0, num_seeds, plan.chunk)
    done = 0
    if plan.workers == 1:
        # the next call is launched before the previous one's outputs are copied to the host,
        # so on an accelerator the copy overlaps the next call's compute
        previous = None
        for start in [*starts, None]:
            current = None if start is None else (start, launch(start))
            if previous is not None:
                done += collect(*previous)
                if progress is not None:
                    progress(done)
            previous = current
        return result
    with concurrent.futures.ThreadPoolExecutor(plan.workers) as pool:
        pending = [pool.submit(lambda st: collect(st, launch(st)), start) for start in starts]
        try:
            for future in concurrent.futures.as_completed(pending):
                done += future.result()
                if progress is not None:
                    progress(done)
        except BaseException:
            for future in pending:
                future.cancel()
            raise
    return result


def use_pinned_host(mesh: "jax.sharding.Mesh | None" = None) -> bool:
    """Whether run_seeds moves outputs to the host through page-locked ("pinned_host") memory.

    On an accelerator a plain device-to-host copy lands in pageable memory: measured on one
    H100, 1.17 GB/s for a 1.5 GB output, against 50 GB/s into pinned host memory, which numpy
    then views without a copy. On CPU the outputs are already in host memory.
    """
    devices = jax.devices() if mesh is None else list(mesh.devices.flat)
    if devices[0].platform == "cpu":
        return False
    return all("pinned_host" in {m.kind for m in d.addressable_memories()} for d in devices)


_RUNNER_CACHE: dict = {}


def batched_runner(config: RunConfig, mesh: "jax.sharding.Mesh | None" = None,
                   fast: bool = False, inner: int | None = None) -> Callable:
    """The jitted batched runner ``fn(keys [S'], params) -> RunOutput`` that :func:`run_seeds`
    calls, cached per (config, mesh, fast, inner): one compilation per call shape.

    Args:
      config: the run configuration.
      mesh: optional one-axis mesh; the seed axis (keys and outputs) is sharded over it.
      fast: :func:`sern_jax.fast_softmax.make_batched` (needs ``fast_softmax.supports``) instead
        of ``jax.vmap(simulate.make_run(config))``.
      inner: seeds per ``lax.map`` step of the fast runner (None: one step).
    """
    mesh_key = None if mesh is None else (tuple(mesh.axis_names), mesh.devices.shape,
                                          tuple(d.id for d in mesh.devices.flat))
    cache_key = (config, mesh_key, fast, inner)
    if cache_key not in _RUNNER_CACHE:
        if fast:
            batched = fast_softmax.make_batched(config, chunk=inner, mesh=mesh)
        else:
            batched = jax.vmap(make_run(config), in_axes=(0, None))
        if mesh is None:
            _RUNNER_CACHE[cache_key] = jax.jit(batched)
        else:
            spec = jax.sharding.PartitionSpec(mesh.axis_names[0])
            _RUNNER_CACHE[cache_key] = jax.jit(
                batched,
                in_shardings=(jax.sharding.NamedSharding(mesh, spec), None),
                out_shardings=jax.sharding.NamedSharding(mesh, spec),
            )
    return _RUNNER_CACHE[cache_key]
