"""Running many seeds: the one seed driver (chunks, threads, devices, progress).

:func:`run_plan` executes a :class:`~sern_jax.engine.plan.RunPlan` (made once per call by
:func:`~sern_jax.engine.plan.plan_run` or :func:`~sern_jax.engine.plan.plan_neural`): the
seeds run in fixed-shape jitted calls of ``plan.chunk`` seeds (the last one padded),
optionally sharded over a device mesh, ``plan.workers`` at a time from host threads (or, with
one worker, each call launched before the previous one's outputs are copied out), and every
call's outputs are either copied into numpy arrays with a leading [S] axis (through
page-locked host memory on an accelerator) or, for a summary plan, reduced over seeds on the
device and merged on the host in seed order (:mod:`sern_jax.engine.summary`). The tabular
engine (:func:`run_seeds`, per-seed arrays or a summary) and the neural engine
(:func:`sern_jax.engine.neural.run_seeds`) both run through it.

Seed ``i`` always uses ``simulate.seed_keys(root, ·)[i] = fold_in(key(seed), i)``, so it gives
the same result whether it runs alone or among 10,000, in any chunking, on any mesh.

Layering: this module imports :mod:`sern_jax.engine.plan` and :mod:`sern_jax.engine.summary`;
neither imports it.
"""

from __future__ import annotations

import concurrent.futures
import functools
import threading
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from sern_jax.engine import plan as plan_lib
from sern_jax.engine.plan import (RUNNERS, RunPlan, available_memory_bytes, batched_runner,
                                  bytes_per_seed, concurrent_calls, default_chunk_size,
                                  host_workers, plan_run, use_pinned_host)
from sern_jax.engine.simulate import RunConfig, RunOutput, RunParams
from sern_jax.engine.summary import (SUMMARY_BINS, SUMMARY_FIELDS, SUMMARY_QUANTILES,
                                     Quantile, RunSummary, SeedStats, compensated_sum,
                                     host_stats, merge_stats, merge_summaries,
                                     summarize_outputs, summary_arrays, summary_edges,
                                     summary_from_arrays)

__all__ = [
    "run_seeds",
    "run_plan",
    # the plan and the summaries, importable from here as before they had modules of their own
    "RUNNERS",
    "RunPlan",
    "plan_run",
    "batched_runner",
    "bytes_per_seed",
    "available_memory_bytes",
    "default_chunk_size",
    "host_workers",
    "concurrent_calls",
    "use_pinned_host",
    "SUMMARY_FIELDS",
    "SUMMARY_BINS",
    "SUMMARY_QUANTILES",
    "SeedStats",
    "Quantile",
    "RunSummary",
    "compensated_sum",
    "summary_edges",
    "summarize_outputs",
    "merge_stats",
    "merge_summaries",
    "summary_arrays",
    "summary_from_arrays",
]


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
    summary: bool = False,
) -> RunOutput | RunSummary:
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
        :func:`~sern_jax.engine.plan.default_chunk_size` (bounds memory).
      runner: ``"auto"`` (the fused kernel on one GPU where it applies, else the fast runner
        where it is exact), ``"fast"``, ``"general"`` or ``"pallas"``; see
        :func:`~sern_jax.engine.plan.plan_run`.
      progress: called with the number of seeds finished after each call.
      summary: reduce over seeds on the device instead of returning per-seed arrays: each
        call returns means, Σ(x − mean)² (compensated), exact min/max and histograms of every
        output field (``diag`` excepted), a few hundred kB whatever the number of seeds, and
        the calls are merged exactly (Chan et al.) in seed order. Quantiles come from the
        histograms with a guaranteed bracket (:meth:`SeedStats.quantile`).

    Returns:
      :class:`RunOutput` of numpy arrays with leading axis S, or with ``summary`` a
      :class:`RunSummary` over the S seeds.
    """
    plan = plan_lib.plan_run(config, params, num_seeds, first_seed=first_seed, mesh=mesh,
                             chunk_size=chunk_size, runner=runner, summary=summary)
    return run_plan(plan, seed, progress)


def run_plan(plan: RunPlan, seed: int = 0, progress: Callable[[int], None] | None = None):
    """Runs a plan's seeds from root seed ``seed``: the one seed driver.

    Returns the per-seed outputs as numpy arrays with a leading [S] axis (a pytree like one
    call's outputs), or with ``plan.summary`` the merged :class:`RunSummary`. ``progress`` is
    called with the number of seeds finished after each call.
    """
    sink = _Summaries(plan) if plan.summary else _SeedArrays(plan)
    _drive(plan, _launcher(plan, seed), sink.collect, progress)
    return sink.result()


def _launcher(plan: RunPlan, seed: int, fn: Callable | None = None) -> Callable:
    """``launch(start)``: the plan's compiled call on the seeds from ``start`` (keys
    ``fold_in(key(seed), first_seed + start + i)``), asynchronous on an accelerator. With
    several workers every call's keys are made here, in the calling thread: worker threads
    only run the compiled program (no tracing or eager dispatch in threads). ``fn``: the
    plan's ``_compiled`` call, when the caller already holds it."""
    root = jax.random.key(seed)
    sharding = None
    if plan.mesh is not None:
        sharding = jax.sharding.NamedSharding(
            plan.mesh, jax.sharding.PartitionSpec(plan.mesh.axis_names[0]))
    fn = fn or _compiled(plan, root.dtype)

    def keys_of(start: int):
        keys = _seed_keys_jit(root, plan.chunk, np.uint32(plan.first_seed + start))
        if sharding is not None:
            keys = jax.device_put(keys, sharding)
        return keys

    premade = {start: keys_of(start) for start in plan.starts} if plan.workers > 1 else {}

    def launch(start: int):
        keys = premade.pop(start) if premade else keys_of(start)
        size = min(plan.chunk, plan.num_seeds - start)
        extra = (jnp.asarray(size, jnp.int32),) if plan.summary else ()
        return fn(keys, *plan.args, *extra)

    return launch


def _compiled(plan: RunPlan, key_dtype) -> Callable:
    """``plan.fn``, compiled here, once, when worker threads will call it: they do not inherit
    thread-local configuration such as ``jax.enable_x64()``, so they must not trace. (The
    compilation is shared with ``plan.fn``'s cache.)"""
    if plan.workers == 1:
        return plan.fn
    structs = [jax.ShapeDtypeStruct((plan.chunk,), key_dtype), *plan.args]
    if plan.summary:
        structs.append(jax.ShapeDtypeStruct((), jnp.int32))
    return plan.fn.lower(*structs).compile()


def _drive(plan: RunPlan, launch: Callable, collect: Callable[..., int],
           progress: Callable[[int], None] | None) -> None:
    """Launches and collects every call of the plan; ``collect(start, out)`` returns the
    number of seeds it finished."""
    done = 0
    if plan.workers == 1:
        previous = None
        for start in plan.starts:
            current = (start, launch(start))
            if not plan.overlap:
                previous, current = current, None
            if previous is not None:
                done += collect(*previous)
                if progress is not None:
                    progress(done)
            previous = current
        if previous is not None:
            done += collect(*previous)
            if progress is not None:
                progress(done)
        return
    with concurrent.futures.ThreadPoolExecutor(plan.workers) as pool:
        pending = [pool.submit(lambda st: collect(st, launch(st)), start)
                   for start in plan.starts]
        try:
            for future in concurrent.futures.as_completed(pending):
                done += future.result()
                if progress is not None:
                    progress(done)
        except BaseException:
            for future in pending:
                future.cancel()
            raise


class _SeedArrays:
    """Per-seed outputs copied into numpy arrays with a leading [S] axis.

    Pinned outputs are always copied into numpy arrays of our own, so the pinned buffers go
    back to JAX's pool at once and the next call reuses them: page-locking a new buffer costs
    about as much as the pageable copy it replaces.
    """

    def __init__(self, plan: RunPlan):
        self.plan = plan
        self.out = None
        self.lock = threading.Lock()

    def collect(self, start: int, out) -> int:
        plan = self.plan
        if plan.pinned:
            # page-locked host buffers: one DMA per output, and numpy views them without a copy
            out = jax.device_put(out, jax.tree.map(
                lambda x: x.sharding.with_memory_kind("pinned_host"), out))
        else:
            for leaf in jax.tree.leaves(out):
                leaf.copy_to_host_async()  # all outputs' transfers in flight at once
        size = min(plan.chunk, plan.num_seeds - start)
        if size == plan.num_seeds and not plan.pinned:  # one call, host arrays: no copy
            self.out = jax.tree.map(lambda x: np.asarray(x)[:size], out)
            return size
        with self.lock:  # allocated from the first finished call: no extra trace for shapes
            if self.out is None:
                self.out = jax.tree.map(
                    lambda x: np.empty((plan.num_seeds,) + x.shape[1:], x.dtype), out)
        for dst, src in zip(jax.tree.leaves(self.out), jax.tree.leaves(out)):
            dst[start:start + size] = np.asarray(src)[:size]
        return size

    def result(self):
        return self.out


class _Summaries:
    """Each call's on-device statistics, brought to the host and merged in seed order."""

    def __init__(self, plan: RunPlan):
        self.plan = plan
        self.parts: dict[int, RunSummary] = {}

    def collect(self, start: int, out) -> int:
        size = min(self.plan.chunk, self.plan.num_seeds - start)
        self.parts[start] = host_stats(out, size, self.plan.edges)
        return size

    def result(self) -> RunSummary:
        return merge_summaries(self.parts[start] for start in self.plan.starts)


@functools.partial(jax.jit, static_argnums=1)
def _seed_keys_jit(root: jax.Array, num_seeds: int, start) -> jax.Array:
    """``seed_keys(root, num_seeds, start)`` as one compiled call (``start`` traced): the eager
    ``vmap`` of ``fold_in`` dispatches several operations per call. Compiled on the first call
    of a chunk size."""
    return jax.vmap(lambda i: jax.random.fold_in(root, i))(
        jnp.arange(num_seeds, dtype=jnp.uint32) + jnp.asarray(start, jnp.uint32))
