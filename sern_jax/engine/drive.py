"""Running many seeds: plan the calls, pick the runner, chunk, thread, copy out.

:func:`run_seeds` is the entry point for a batch of seeds. It plans (:func:`plan_run`) which
runner to use (:mod:`sern_jax.engine.fast_softmax` where it is exact, ``simulate.make_run`` otherwise)
and the call shape (seeds per jitted call, seeds per ``lax.map`` step, calls at once from host
threads), then runs the seeds in fixed-shape calls, optionally sharded over a device mesh, and
copies outputs into numpy arrays (through page-locked host memory on an accelerator), or, with
``summary=True``, reduces over seeds on the device and returns a :class:`RunSummary` (means,
variances, exact min/max and histogram quantiles of every output, a few hundred kB whatever S).

Seed ``i`` always uses ``simulate.seed_keys(root, ·)[i] = fold_in(key(seed), i)``, so it gives
the same result whether it runs alone or among 10,000, in any chunking, on any mesh.

Layering: this module imports :mod:`sern_jax.engine.simulate` and :mod:`sern_jax.engine.fast_softmax`;
neither imports it (``fast_softmax`` imports ``simulate``; ``simulate`` imports neither).
"""

from __future__ import annotations

import concurrent.futures
import functools
import math
import os
import threading
from typing import Any, Callable, NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from sern_jax.core import estimators as est_lib
from sern_jax.engine import fast_softmax, fast_thompson
from sern_jax.engine.simulate import (Diagnostics, RunConfig, RunOutput, RunParams, checkpoint_times,
                               make_run, validate)

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
      fast: whether ``fn`` is :mod:`sern_jax.engine.fast_softmax`'s runner.
      chunk: seeds per call (a multiple of the mesh size; the last call is padded).
      inner: seeds per ``lax.map`` step inside a fast call (None: one step).
      workers: calls run at once from host threads (CPU without a mesh: one per core; a
        compiled call runs on one core at a time there, so this is where the second core's
        speed comes from).
      summary: ``fn`` is ``fn(keys, params, num_valid) -> {field: statistics}``, reducing
        over its seeds on the device (:func:`summarize_outputs`).
    """

    fn: Callable
    fast: bool
    chunk: int
    inner: Optional[int]
    workers: int
    summary: bool = False


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
    """CPU cores this process may use (its affinity mask where the OS has one), or
    ``SERN_CPU_THREADS`` where set (a Ray task's share of a node: :mod:`sern_jax.infra.distributed`)."""
    threads = os.environ.get("SERN_CPU_THREADS", "").strip()
    if threads.isdigit() and int(threads) >= 1:
        return int(threads)
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def concurrent_calls(mesh: "jax.sharding.Mesh | None" = None) -> int:
    """How many jitted calls :func:`run_seeds` runs at once: one per core on the CPU backend
    without a mesh (there a call runs on one core), otherwise 1 (the device is busy already)."""
    return host_workers() if mesh is None and jax.default_backend() == "cpu" else 1


def default_chunk_size(config: RunConfig, num_seeds: int, backend: str | None = None,
                       workers: int = 1, summary: bool = False) -> int:
    """Seeds per jitted call when ``chunk_size`` is not given: an equal share of the seeds for
    each of ``workers`` concurrent calls, capped so that one call holds at most 64 MiB of
    outputs and state on CPU (4 GiB on an accelerator; with ``summary`` a quarter of the
    device's memory where it reports it, since nothing per seed is copied out); calls are
    balanced."""
    backend = jax.default_backend() if backend is None else backend
    budget = _CPU_CALL_BYTES if backend == "cpu" else _ACCEL_CALL_BYTES
    if summary and backend != "cpu":
        try:
            limit = jax.devices()[0].memory_stats().get("bytes_limit", 0)
        except Exception:  # noqa: BLE001 - a backend without memory statistics
            limit = 0
        budget = max(budget, int(limit) // 4)
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
    summary: bool = False,
) -> RunPlan:
    """Chooses the runner and call shape for :func:`run_seeds` (host-side; compiles nothing).

    ``runner="auto"`` takes :mod:`sern_jax.engine.fast_softmax` whenever it reproduces
    :func:`make_run` (SERN softmax, one context, a local estimator, no diagnostics, α large
    enough for its float type; see ``fast_softmax.supports``), :mod:`sern_jax.engine.fast_thompson`
    for Thompson sampling with one context and no diagnostics, and the general runner
    otherwise;
    ``"fast"`` insists on the fast runner (``ValueError`` if unsupported), ``"general"`` on
    :func:`make_run`. ``summary``: the plan's ``fn`` reduces over seeds on the device.
    """
    if runner not in RUNNERS:
        raise ValueError(f"unknown runner {runner!r}; expected one of {RUNNERS}")
    if chunk_size is not None and (isinstance(chunk_size, bool) or int(chunk_size) < 1):
        raise ValueError(f"chunk_size must be a positive integer, got {chunk_size!r}")
    # fast_thompson beats the general runner on CPU (0.100M vs 0.047M seed-rounds/s, K = 64,
    # 2 cores) and, since its lanes draw ahead, on a GPU too (186M vs 97.4M seed-rounds/s on
    # one H100, K = 64, T = 2,000, 200,000 seeds, one process:
    # experiments/results/bench/bandit_thompson_h100_public.json; 71.7M before), and both
    # draw the same arms (tested), so "auto" takes it on every backend.
    thompson_fast = fast_thompson.supports(config)
    supported = runner != "general" and (fast_softmax.supports(config, params)
                                         or thompson_fast)
    if runner == "fast" and not supported:
        raise ValueError(
            f"runner='fast' needs policy='thompson' with one context and no diagnostics, or "
            f"policy='softmax', one context, an estimator in "
            f"{est_lib.LOCAL_ESTIMATORS}, diagnostics=False and alpha >= "
            f"{fast_softmax.min_alpha(config.dtype)} ({config.dtype}); got policy="
            f"{config.policy!r}, estimator={config.estimator!r}, "
            f"num_contexts={config.num_contexts}, diagnostics={config.diagnostics}")
    workers = concurrent_calls(mesh)
    chunk = (default_chunk_size(config, num_seeds, workers=workers, summary=summary)
             if chunk_size is None else int(chunk_size))
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
    return RunPlan(batched_runner(config, mesh, supported, inner, summary=summary), supported,
                   chunk, inner, workers, summary)


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
        :func:`default_chunk_size` (bounds memory).
      runner: ``"auto"`` (fast runner where it is exact), ``"fast"`` or ``"general"``; see
        :func:`plan_run`.
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
    validate(config, params, num_seeds)
    if isinstance(first_seed, bool) or int(first_seed) < 0:
        raise ValueError(f"first_seed must be a non-negative integer, got {first_seed!r}")
    if int(first_seed) + num_seeds > 2**32:
        raise ValueError(f"seed indices are uint32: first_seed + num_seeds must be <= 2^32, "
                         f"got {int(first_seed) + num_seeds}")
    plan = plan_run(config, params, num_seeds, mesh=mesh, chunk_size=chunk_size, runner=runner,
                    summary=summary)
    if summary:
        return _run_summary(plan, config, params, seed, num_seeds, int(first_seed), mesh,
                            progress)
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
        keys = _seed_keys_jit(root, plan.chunk, np.uint32(int(first_seed) + start))  # fixed shape
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
                   fast: bool = False, inner: int | None = None,
                   summary: bool = False) -> Callable:
    """The jitted batched runner ``fn(keys [S'], params) -> RunOutput`` that :func:`run_seeds`
    calls, cached per (config, mesh, fast, inner, summary): one compilation per call shape.

    Args:
      config: the run configuration.
      mesh: optional one-axis mesh; the seed axis (keys and outputs) is sharded over it.
      fast: :func:`sern_jax.engine.fast_softmax.make_batched` (needs ``fast_softmax.supports``) instead
        of ``jax.vmap(simulate.make_run(config))``.
      inner: seeds per ``lax.map`` step of the fast runner (None: one step).
      summary: ``fn(keys, params, num_valid) -> {field: statistics}`` instead, reducing the
        outputs over the first ``num_valid`` seeds on the device (:func:`summarize_outputs`).
    """
    mesh_key = None if mesh is None else (tuple(mesh.axis_names), mesh.devices.shape,
                                          tuple(d.id for d in mesh.devices.flat))
    cache_key = (config, mesh_key, fast, inner, summary)
    if cache_key not in _RUNNER_CACHE:
        if fast and config.policy == "thompson":
            batched = fast_thompson.make_batched(config, chunk=inner, mesh=mesh)
        elif fast:
            batched = fast_softmax.make_batched(config, chunk=inner, mesh=mesh)
        else:
            batched = jax.vmap(make_run(config), in_axes=(0, None))
        if summary and mesh is None:
            # Two compiled calls, the engine's (shared with the per-seed path) and the
            # reduction's, not one fused program: fused, XLA:GPU ran the engine itself slower
            # (one H100, 200,000 seeds, K = 64, T = 10^4: engine 1,934 ms alone, engine +
            # reduction 1,964 ms fused against 1,934 + 24 ms apart; with this commit's cheaper
            # reduction 1,989 ms fused, 18 ms apart: profile_summary2_h100.json).
            edges = summary_edges(config)
            engine = batched_runner(config, None, fast, inner)
            reduce = jax.jit(lambda out, num_valid: summarize_outputs(out, num_valid, edges))
            _RUNNER_CACHE[cache_key] = _EngineThenSummary(engine, reduce)
            return _RUNNER_CACHE[cache_key]
        if summary:
            edges = summary_edges(config)
            per_seed = batched

            def batched(keys, params, num_valid):
                return summarize_outputs(per_seed(keys, params), num_valid, edges)

            spec = (None if mesh is None else
                    jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec(
                        mesh.axis_names[0])))
            _RUNNER_CACHE[cache_key] = jax.jit(
                batched, in_shardings=None if mesh is None else (spec, None, None))
            return _RUNNER_CACHE[cache_key]
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


class _EngineThenSummary:
    """``fn(keys, params, num_valid) -> {field: statistics}`` as two jitted calls, the per-seed
    engine then :func:`summarize_outputs`; ``lower(...).compile()`` like a jitted function."""

    def __init__(self, engine, reduce):
        self.engine, self.reduce = engine, reduce

    def __call__(self, keys, params, num_valid):
        return self.reduce(self.engine(keys, params), num_valid)

    def lower(self, keys, params, num_valid):
        engine = self.engine.lower(keys, params)
        out = jax.eval_shape(self.engine, keys, params)
        return _LoweredPair(engine, self.reduce.lower(out, num_valid))


class _LoweredPair(NamedTuple):
    engine: Any  # jax.stages.Lowered
    reduce: Any  # jax.stages.Lowered

    def compile(self):
        engine, reduce = self.engine.compile(), self.reduce.compile()
        return lambda keys, params, num_valid: reduce(engine(keys, params), num_valid)


# ----------------------------------------------------------------------------- summaries
#
# ``run_seeds(..., summary=True)`` reduces over seeds on the device: each jitted call returns,
# per output field, the mean, the sum of squared deviations (both compensated: pairwise
# TwoSum, see :func:`compensated_sum`), the exact min and max and a fixed histogram, and the
# host merges calls with Chan et al.'s parallel formula (float64). Means, variances, min and
# max of the merged summary equal those of the per-seed arrays up to float rounding, whatever
# the chunking. Quantiles are the one approximation: exact quantiles across chunks need the
# values, so they come from the merged histograms, on fixed bins uniform in log(1 + x) over
# [0, t_g] (rewards and gaps lie in [0, 1], so regret and counts at checkpoint t_g do too);
# :meth:`SeedStats.quantile` returns the estimate with a bracket ``[lo, hi]`` that is
# guaranteed to hold the exact empirical quantile (NumPy's ``method="inverted_cdf"``).

SUMMARY_FIELDS = ("regret", "regret_paper", "regret_rb", "regret_rb_paper", "counts",
                  "compensator", "min_prob")
# Histogram bins per field; 0 keeps no histogram (no quantiles; exact min and max are kept).
# 512 bins in log(1 + x) over [0, 10^4] are 1.8% wide (relative) above x ~ 1; 64 for counts
# (one histogram per arm) are 15% wide. On a [G = 32, K = 64] run one call returns ~0.8 MB.
SUMMARY_BINS = {"regret": 512, "regret_paper": 512, "regret_rb": 512, "regret_rb_paper": 512,
                "counts": 64, "compensator": 0, "min_prob": 0}
SUMMARY_QUANTILES = (0.05, 0.25, 0.5, 0.75, 0.95)


class Quantile(NamedTuple):
    """A quantile over seeds from a histogram (:meth:`SeedStats.quantile`)."""

    estimate: np.ndarray  # [...] linear interpolation inside the bin holding the quantile
    lo: np.ndarray  # [...] lower end of that bin (tightened by the exact min): exact >= lo
    hi: np.ndarray  # [...] upper end (tightened by the exact max): exact <= hi


class SeedStats(NamedTuple):
    """Statistics over seeds of one per-seed output (host, numpy), mergeable across chunks.

    ``[...]`` is the output's per-seed shape: ``[G]`` (regret, min_prob) or ``[G, K]``.
    """

    count: int  # seeds n
    mean: np.ndarray  # [...] float64
    m2: np.ndarray  # [...] Σ_i (x_i − mean)², float64
    min: np.ndarray  # [...] exact minimum over seeds
    max: np.ndarray  # [...] exact maximum over seeds
    hist: Optional[np.ndarray]  # [..., B] int64 seeds per bin, or None (no quantiles)
    edges: Optional[np.ndarray]  # [G, B + 1] float64 bin edges (shared by trailing axes)

    @property
    def var(self) -> np.ndarray:
        """Sample variance over seeds (ddof = 1; NaN for one seed)."""
        if self.count < 2:
            return np.full_like(self.mean, np.nan)
        return self.m2 / (self.count - 1)

    @property
    def sd(self) -> np.ndarray:
        """Sample standard deviation over seeds (ddof = 1)."""
        return np.sqrt(self.var)

    def quantile(self, q: float) -> Quantile:
        """The q-quantile over seeds, from the histogram.

        The exact empirical quantile (the ⌈q·n⌉-th smallest value, NumPy's
        ``method="inverted_cdf"``) lies in ``[lo, hi]``, the bin that holds it narrowed by the
        exact min and max; ``estimate`` interpolates linearly inside it.
        """
        if self.hist is None:
            raise ValueError("this field keeps no histogram (SUMMARY_BINS is 0): no quantiles")
        if not 0.0 <= float(q) <= 1.0:
            raise ValueError(f"q must lie in [0, 1], got {q!r}")
        hist = self.hist
        num_bins = hist.shape[-1]
        rank = max(1, int(math.ceil(self.count * float(q))))
        cum = np.cumsum(hist, axis=-1)
        b = np.argmax(cum >= rank, axis=-1)  # [...] first bin reaching the rank
        edges = self.edges.reshape(self.edges.shape[:1] + (1,) * (hist.ndim - 2)
                                   + self.edges.shape[1:])
        edges = np.broadcast_to(edges, hist.shape[:-1] + (num_bins + 1,))
        lo = np.take_along_axis(edges, b[..., None], -1)[..., 0]
        hi = np.take_along_axis(edges, b[..., None] + 1, -1)[..., 0]
        lo = np.where(b == 0, -np.inf, lo)  # bin 0 also holds values below 0
        hi = np.where(b == num_bins - 1, np.inf, hi)  # the last bin those above t_g
        lo = np.maximum(lo, self.min)
        hi = np.minimum(hi, self.max)
        below = np.where(b > 0, np.take_along_axis(cum, np.maximum(b - 1, 0)[..., None],
                                                   -1)[..., 0], 0)
        in_bin = np.take_along_axis(hist, b[..., None], -1)[..., 0]
        frac = (rank - below - 0.5) / np.maximum(in_bin, 1)
        return Quantile(np.clip(lo + (hi - lo) * frac, lo, hi), lo, hi)


class RunSummary(NamedTuple):
    """What ``run_seeds(..., summary=True)`` returns: :class:`SeedStats` per output field."""

    regret: SeedStats  # [G]
    regret_paper: SeedStats  # [G]
    regret_rb: SeedStats  # [G]
    regret_rb_paper: SeedStats  # [G]
    counts: SeedStats  # [G, K]
    compensator: SeedStats  # [G, K]
    min_prob: SeedStats  # [G]

    @property
    def num_seeds(self) -> int:
        return self.regret.count


class _DeviceStats(NamedTuple):
    mean: jax.Array  # [...]
    m2: jax.Array  # [...]
    min: jax.Array  # [...]
    max: jax.Array  # [...]
    hist: Optional[jax.Array]  # [..., B] int32


def _two_sum(a, b):
    s = a + b
    bb = s - a
    return s, (a - (s - bb)) + (b - bb)


def compensated_sum(x: jax.Array) -> jax.Array:
    """Σ over axis 0 in compensated arithmetic of ``x``'s float type (jit-friendly).

    Pairwise halving with Knuth's TwoSum at every addition; the rounding errors are summed
    alongside and added at the end, so the error does not grow with the number of terms
    (2^25 float32 increments of 1e-3 sum exactly, where a sequential float32 sum stalls). The
    additions are elementwise, so the result does not depend on how XLA orders a reduction.

    Args:
      x: [S, ...] floats.

    Returns:
      [...] the sum.
    """
    s, c = x, jnp.zeros_like(x)
    rest = []
    level = 0
    while s.shape[0] > 1:
        if s.shape[0] % 2:
            rest.append((s[-1], c[-1]))
            s, c = s[:-1], c[:-1]
        h = s.shape[0] // 2
        s, e = _two_sum(s[:h], s[h:])
        c = c[:h] + c[h:] + e
        level += 1
        # a barrier every 4 levels: fused across all levels, each output would inline a
        # 2^levels-leaf expression tree (XLA:GPU spent minutes compiling it for 200,000 seeds);
        # one per level cost 2.9 ms on a [200,000, 30, 64] sum on one H100, every 4 levels
        # 2.1 ms, bit-identical (profile_summary_h100.json)
        if level % 4 == 0:
            s, c = jax.lax.optimization_barrier((s, c))
    total, comp = s[0], c[0]
    for s_r, c_r in rest:
        total, e = _two_sum(total, s_r)
        comp = comp + c_r + e
    return total + comp


def summary_edges(config: RunConfig) -> dict:
    """Histogram bin edges per summarised field: ``{field: [G, B + 1] float64}``.

    Edges are uniform in ``log(1 + x)`` over ``[0, t_g]`` at checkpoint ``g`` and rounded to
    the config's float type (the device compares against exactly these values).
    """
    grid = checkpoint_times(config).astype(np.float64)
    np_dtype = np.float64 if config.dtype == "float64" else np.float32
    out = {}
    for field, bins in SUMMARY_BINS.items():
        if not bins:
            continue
        steps = np.arange(bins + 1) / bins
        edges = np.expm1(np.log1p(grid)[:, None] * steps[None, :])
        edges[:, 0] = 0.0
        edges[:, -1] = grid
        out[field] = edges.astype(np_dtype).astype(np.float64)
    return out


def _bin_index(x, edges, dtype):
    """Bin of each value: ``[C, G, R]`` values, ``[G, B + 1]`` edges -> ``[C, G, R]`` int32."""
    num_bins = edges.shape[1] - 1
    top = edges[:, -1]  # [G] = t_g
    scale = (num_bins / jnp.log1p(top))[None, :, None]
    guess = jnp.floor(jnp.log1p(jnp.maximum(x, 0.0)) * scale)
    idx = jnp.clip(jnp.nan_to_num(guess), 0, num_bins - 1).astype(jnp.int32)
    # one correction step against the stored edges: float error in log1p moves a value by at
    # most one bin, and the histogram must agree exactly with the edges the host reports
    g = jnp.arange(edges.shape[0])[None, :, None]
    idx = idx - (x < edges[g, idx]).astype(jnp.int32)
    idx = idx + (x >= edges[g, jnp.minimum(idx + 1, num_bins)]).astype(jnp.int32)
    return jnp.clip(idx, 0, num_bins - 1)


# Integer fields (counts) whose bin table has at most this many entries look their bin up in
# a [G, t_max + 1] table instead of computing it (log1p, two edge gathers, two compares): on
# one H100 (200,000 seeds, K = 64, T = 10,000) the counts histogram took 9.3 ms of the 23 ms
# reduction (experiments/results/bench/profile_summary_h100.json).
_BIN_TABLE_MAX = 1 << 22


def _bin_table(edges: np.ndarray) -> np.ndarray:
    """``[G, t_max + 1]`` int32: the bin of each integer value 0..t_max at each checkpoint,
    the same bins as :func:`_bin_index` (``edges[i] <= x < edges[i + 1]``, the top value in
    the last bin), computed exactly on the host from the stored edges."""
    num_bins = edges.shape[1] - 1
    top = int(np.floor(edges[:, -1].max()))
    values = np.arange(top + 1, dtype=np.float64)
    table = np.stack([np.searchsorted(e, values, side="right") - 1 for e in edges])
    return np.clip(table, 0, num_bins - 1).astype(np.int32)


def _seed_block(top: int) -> int:
    """Seeds per exact int32 partial sum of an integer field bounded by ``top``."""
    return max(1, (2**31 - 1) // max(1, top))


def _int_field_sum(x: jax.Array, valid: jax.Array, top: int, dtype) -> jax.Array:
    """Σ over seeds of an integer field ``x`` [C, ...] (values in [0, top]) in exact int32
    partial sums (blocks of seeds small enough not to overflow), each split exactly into two
    floats and added in compensated arithmetic: the correctly rounded sum, like
    :func:`compensated_sum` of the values as floats, for one pass over ``x``."""
    size = x.shape[0]
    block = min(size, _seed_block(top))
    xi = jnp.where(valid.reshape((size,) + (1,) * (x.ndim - 1)), x, 0)
    pad = -size % block
    if pad:
        xi = jnp.concatenate([xi, jnp.zeros((pad,) + x.shape[1:], xi.dtype)])
    part = jnp.sum(xi.reshape((-1, block) + x.shape[1:]), axis=1)  # [nb, ...] exact
    hi = (part >> 12) << 12  # both halves exact in float32 (≤ 2^31 and < 2^12)
    lo = part - hi
    halves = jnp.concatenate([hi.astype(dtype), lo.astype(dtype)])
    return compensated_sum(halves)


def summarize_outputs(out: RunOutput, num_valid: jax.Array, edges: dict) -> dict:
    """Reduces a batch of per-seed outputs over its seed axis, on the device (traceable).

    Args:
      out: :class:`RunOutput` with leading axis C (a call's seeds, padding included).
      num_valid: [] int32; seeds ``[0, num_valid)`` count, the rest is padding.
      edges: :func:`summary_edges` (closed over as constants).

    Returns:
      ``{field: _DeviceStats}``: compensated mean and Σ(x − mean)², exact min and max, and
      the histogram counts, over the valid seeds.
    """
    dtype = out.regret.dtype
    size = out.regret.shape[0]
    valid = jnp.arange(size) < num_valid  # [C]
    n = num_valid.astype(dtype)
    stats = {}
    for field in SUMMARY_FIELDS:
        raw = getattr(out, field)
        x = raw.astype(dtype)  # counts are exact in float32 below 2^24
        mask = valid.reshape((size,) + (1,) * (x.ndim - 1))
        integer = jnp.issubdtype(raw.dtype, jnp.integer) and field in edges
        top = int(np.floor(edges[field][:, -1].max())) if integer else 0
        if integer and top < 2**24:
            # exact integer partial sums: one pass instead of the pairwise tree's levels
            mean = _int_field_sum(raw, valid, top, dtype) / n
        else:
            mean = compensated_sum(jnp.where(mask, x, 0.0)) / n
        m2 = compensated_sum(jnp.where(mask, jnp.square(x - mean[None]), 0.0))
        lo = jnp.min(jnp.where(mask, x, jnp.inf), axis=0)
        hi = jnp.max(jnp.where(mask, x, -jnp.inf), axis=0)
        hist = None
        if SUMMARY_BINS[field]:
            e = jnp.asarray(edges[field], dtype)  # [G, B + 1]
            num_g, bins = e.shape[0], e.shape[1] - 1
            x3 = x.reshape(size, x.shape[1], -1)  # [C, G, R]
            if integer and num_g * (top + 1) <= _BIN_TABLE_MAX:
                table = jnp.asarray(_bin_table(edges[field]))  # [G, top + 1]
                g = jnp.arange(num_g, dtype=jnp.int32)[None, :, None]
                r3 = jnp.clip(raw.reshape(x3.shape), 0, top)
                idx = table.reshape(-1)[g * (top + 1) + r3]
            else:
                idx = _bin_index(x3, e, dtype)
            cols = jnp.arange(x3.shape[1] * x3.shape[2], dtype=jnp.int32).reshape(x3.shape[1:])
            num_cols = x3.shape[1] * x3.shape[2]
            # padding seeds go to an index past the end, which the scatter drops
            flat = jnp.where(valid[:, None, None], cols[None] * bins + idx, num_cols * bins)
            hist = jnp.zeros(num_cols * bins, jnp.int32).at[flat.reshape(-1)].add(
                1, mode="drop").reshape(x.shape[1:] + (bins,))
        stats[field] = _DeviceStats(mean, m2, lo, hi, hist)
    return stats


def _host_stats(dev: dict, count: int, edges: dict) -> RunSummary:
    """The device statistics of one call as a host :class:`RunSummary` (float64 / int64)."""
    fields = {}
    dev = jax.device_get(dev)  # one call: every transfer in flight at once
    for field in SUMMARY_FIELDS:
        d = dev[field]
        fields[field] = SeedStats(
            count=int(count), mean=np.asarray(d.mean, np.float64),
            m2=np.asarray(d.m2, np.float64), min=np.asarray(d.min, np.float64),
            max=np.asarray(d.max, np.float64),
            hist=None if d.hist is None else np.asarray(d.hist, np.int64),
            edges=edges.get(field))
    return RunSummary(**fields)


def merge_stats(a: SeedStats, b: SeedStats) -> SeedStats:
    """Statistics of the union of two disjoint seed sets (Chan, Golub & LeVeque's parallel
    update for the mean and Σ(x − mean)², in float64; histograms add; min/max combine)."""
    if a.count == 0:
        return b
    if b.count == 0:
        return a
    if (a.hist is None) != (b.hist is None) or (
            a.edges is not None and not np.array_equal(a.edges, b.edges)):
        raise ValueError("cannot merge summaries with different histogram bins")
    n = a.count + b.count
    delta = b.mean - a.mean
    return SeedStats(
        count=n, mean=a.mean + delta * (b.count / n),
        m2=a.m2 + b.m2 + np.square(delta) * (a.count * b.count / n),
        min=np.minimum(a.min, b.min), max=np.maximum(a.max, b.max),
        hist=None if a.hist is None else a.hist + b.hist, edges=a.edges)


def merge_summaries(parts) -> RunSummary:
    """Merges :class:`RunSummary` objects of disjoint seed sets, in the order given (merge in
    a fixed order, e.g. by first seed, for bitwise-reproducible float64 results)."""
    parts = list(parts)
    if not parts:
        raise ValueError("merge_summaries needs at least one summary")
    out = parts[0]
    for p in parts[1:]:
        out = RunSummary(*(merge_stats(x, y) for x, y in zip(out, p)))
    return out


_STAT_NAMES = ("count", "mean", "m2", "min", "max", "hist", "edges")


def summary_arrays(summary: RunSummary, prefix: str = "") -> dict:
    """Flat ``{prefix + field + "__" + stat: array}`` for ``np.savez`` (None entries left out)."""
    out = {}
    for field in SUMMARY_FIELDS:
        stats = getattr(summary, field)
        for name in _STAT_NAMES:
            value = getattr(stats, name)
            if value is not None:
                out[f"{prefix}{field}__{name}"] = np.asarray(value)
    return out


def summary_from_arrays(arrays, prefix: str = "") -> RunSummary:
    """The inverse of :func:`summary_arrays`."""
    fields = {}
    for field in SUMMARY_FIELDS:
        got = {name: arrays.get(f"{prefix}{field}__{name}") for name in _STAT_NAMES}
        if got["count"] is None or got["mean"] is None:
            raise ValueError(f"no summary of {prefix}{field} in these arrays")
        got["count"] = int(got["count"])
        fields[field] = SeedStats(**{k: (np.asarray(v) if v is not None and k != "count"
                                         else v) for k, v in got.items()})
    return RunSummary(**fields)


@functools.partial(jax.jit, static_argnums=1)
def _seed_keys_jit(root: jax.Array, num_seeds: int, start) -> jax.Array:
    """``seed_keys(root, num_seeds, start)`` as one compiled call (``start`` traced), for both
    run_seeds paths: the eager ``vmap`` of ``fold_in`` cost ~1.8 ms per call on the H100
    machine, 0.8 jitted (200,000 seeds; profile_summary_h100.json). Compiled on the first
    call of a chunk size (~0.25 s on the H100 machine, ~0.7 s on 2 CPU cores)."""
    return jax.vmap(lambda i: jax.random.fold_in(root, i))(
        jnp.arange(num_seeds, dtype=jnp.uint32) + jnp.asarray(start, jnp.uint32))


def _run_summary(plan: RunPlan, config: RunConfig, params: RunParams, seed: int,
                 num_seeds: int, first_seed: int, mesh, progress) -> RunSummary:
    """:func:`run_seeds` with ``summary=True``: fixed-shape calls that each reduce their seeds
    on the device; the small per-call statistics are merged on the host in seed order."""
    root = jax.random.key(seed)
    sharding = None
    if mesh is not None:
        sharding = jax.sharding.NamedSharding(
            mesh, jax.sharding.PartitionSpec(mesh.axis_names[0]))
    edges = summary_edges(config)
    fn = plan.fn
    num_struct = jax.ShapeDtypeStruct((), jnp.int32)
    if plan.workers > 1:
        # compiled here, once (worker threads must not trace: see run_seeds)
        fn = plan.fn.lower(jax.ShapeDtypeStruct((plan.chunk,), root.dtype), params,
                           num_struct).compile()

    def launch(start: int):
        keys = _seed_keys_jit(root, plan.chunk, np.uint32(first_seed + start))
        if sharding is not None:
            keys = jax.device_put(keys, sharding)
        size = min(plan.chunk, num_seeds - start)
        return fn(keys, params, jnp.asarray(size, jnp.int32))

    def collect(start: int, out) -> tuple[int, RunSummary]:
        size = min(plan.chunk, num_seeds - start)
        return size, _host_stats(out, size, edges)

    parts: dict[int, RunSummary] = {}
    done = 0
    starts = list(range(0, num_seeds, plan.chunk))
    if plan.workers == 1:
        previous = None  # the next call is in flight while this one's statistics come back
        for start in [*starts, None]:
            current = None if start is None else (start, launch(start))
            if previous is not None:
                size, parts[previous[0]] = collect(*previous)
                done += size
                if progress is not None:
                    progress(done)
            previous = current
    else:
        with concurrent.futures.ThreadPoolExecutor(plan.workers) as pool:
            pending = {pool.submit(lambda st: collect(st, launch(st)), start): start
                       for start in starts}
            try:
                for future in concurrent.futures.as_completed(pending):
                    size, parts[pending[future]] = future.result()
                    done += size
                    if progress is not None:
                        progress(done)
            except BaseException:
                for future in pending:
                    future.cancel()
                raise
    return merge_summaries(parts[start] for start in starts)
