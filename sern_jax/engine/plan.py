"""Planning a batch of seeds, once per call: what runs, in which call shape, where.

:func:`plan_run` (the tabular engine) and :func:`plan_neural` (the neural engine) each make
one frozen :class:`RunPlan` per call: the inputs are validated once, the checkpoint grid and
the summary's histogram edges are computed once, the runner is chosen once
(:mod:`sern_jax.engine.fast_softmax` where it is exact, :mod:`sern_jax.engine.fast_thompson`
for Thompson sampling, ``simulate.make_run`` otherwise; the neural engine's
``jit(vmap(scan))``), and so is the call shape (seeds per jitted call, seeds per ``lax.map``
step, calls at once from host threads, copies through pinned host memory). The one seed
driver, :func:`sern_jax.engine.drive.run_plan`, executes a plan; nothing here compiles.

Layering: this module imports :mod:`sern_jax.engine.simulate`, the fast runners and
:mod:`sern_jax.engine.summary`; none of them imports it.
"""

from __future__ import annotations

import dataclasses
import math
import os
from typing import Any, Callable, NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from sern_jax.core import estimators as est_lib
from sern_jax.engine import fast_softmax, fast_thompson, pallas_softmax
from sern_jax.engine import simulate as sim
from sern_jax.engine import summary as summary_lib
from sern_jax.engine.simulate import Diagnostics, RunConfig, RunParams
from sern_jax.infra import hosts

__all__ = [
    "RUNNERS",
    "RunPlan",
    "plan_run",
    "plan_neural",
    "batched_runner",
    "bytes_per_seed",
    "available_memory_bytes",
    "default_chunk_size",
    "host_workers",
    "concurrent_calls",
    "use_pinned_host",
]

RUNNERS = ("auto", "fast", "general", "pallas")
# Bytes of outputs and per-seed state one jitted call may hold on the host backend: seeds run in
# calls of this size (one compilation), results are written into preallocated arrays, so peak
# memory is the final O(S·G·K) outputs plus one call's worth, whatever S is.
_CPU_CALL_BYTES = 64 * 2**20
_ACCEL_CALL_BYTES = 4 * 2**30


@dataclasses.dataclass(frozen=True, eq=False)
class RunPlan:
    """How the seed driver runs one batch of seeds: the jitted call and its fixed shape.

    Attributes:
      fn: ``fn(keys [chunk], *args) -> outputs`` (jitted; one compilation per call shape);
        with ``summary``, ``fn(keys [chunk], *args, num_valid) -> {field: statistics}``,
        reducing over its first ``num_valid`` seeds on the device
        (:func:`sern_jax.engine.summary.summarize_outputs`).
      args: the arguments after the keys that every call takes (the traced parameters), or ().
      runner: ``"fast"`` (fast_softmax), ``"thompson"`` (fast_thompson), ``"pallas"`` (the
        fused GPU kernel, :mod:`sern_jax.engine.pallas_softmax`), ``"general"``
        (``vmap(simulate.make_run)``) or ``"neural"`` (``vmap(neural.make_run)``).
      num_seeds: S, the seeds of the batch.
      first_seed: index of the first seed (seed i of the batch is ``first_seed + i``).
      chunk: seeds per call (a multiple of the mesh size; the last call is padded).
      inner: seeds per ``lax.map`` step inside a fast call (None: one step).
      workers: calls run at once from host threads (CPU without a mesh: one per core; a
        compiled tabular call runs on one core at a time there).
      summary: ``fn`` reduces over seeds (see ``fn``).
      mesh: optional one-axis ``jax.sharding.Mesh``: the seed axis is sharded over it.
      pinned: outputs come to the host through page-locked memory (:func:`use_pinned_host`).
      overlap: with one worker, the next call is launched before the previous call's outputs
        are copied out, so on an accelerator the copy overlaps the next call's compute.
      grid: [G] checkpoint rounds of the outputs (tabular plans), else None.
      edges: the summary's histogram edges (summary plans), else None.
    """

    fn: Callable
    args: tuple
    runner: str
    num_seeds: int
    first_seed: int
    chunk: int
    inner: Optional[int]
    workers: int
    summary: bool = False
    mesh: Any = None
    pinned: bool = False
    overlap: bool = True
    grid: Optional[np.ndarray] = None
    edges: Optional[dict] = None

    @property
    def fast(self) -> bool:
        """Whether ``fn`` is one of the fast tabular runners (fast_softmax, fast_thompson, or
        the fused kernel, which draws fast_softmax's arms)."""
        return self.runner in ("fast", "thompson", "pallas")

    @property
    def starts(self) -> range:
        """The first seed (relative to ``first_seed``) of every call, in seed order."""
        return range(0, self.num_seeds, self.chunk)


# ----------------------------------------------------------------------------- call shape


def bytes_per_seed(config: RunConfig, num_checkpoints: int | None = None) -> int:
    """Host bytes one seed's outputs and scan state take (an upper estimate).
    ``num_checkpoints``: G where the caller has the grid already."""
    g = sim.checkpoint_times(config).size if num_checkpoints is None else int(num_checkpoints)
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
    """CPU threads for the seed chunks: :func:`sern_jax.infra.hosts.cpu_threads`."""
    return hosts.cpu_threads()


def concurrent_calls(mesh: "jax.sharding.Mesh | None" = None) -> int:
    """How many jitted tabular calls run at once: one per core on the CPU backend without a
    mesh (there a call runs on one core), otherwise 1 (the device is busy already)."""
    return host_workers() if mesh is None and jax.default_backend() == "cpu" else 1


def use_pinned_host(mesh: "jax.sharding.Mesh | None" = None) -> bool:
    """Whether outputs move to the host through page-locked ("pinned_host") memory.

    On an accelerator a plain device-to-host copy lands in pageable memory, several times
    slower than a copy into pinned host memory, which numpy then views without a copy. On
    CPU the outputs are already in host memory.
    """
    devices = jax.devices() if mesh is None else list(mesh.devices.flat)
    if devices[0].platform == "cpu":
        return False
    return all("pinned_host" in {m.kind for m in d.addressable_memories()} for d in devices)


def default_chunk_size(config: RunConfig, num_seeds: int, backend: str | None = None,
                       workers: int = 1, summary: bool = False,
                       num_checkpoints: int | None = None) -> int:
    """Seeds per jitted call when ``chunk_size`` is not given: an equal share of the seeds for
    each of ``workers`` concurrent calls, capped so that one call holds at most 64 MiB of
    outputs and state on CPU (4 GiB on an accelerator; with ``summary`` a quarter of the
    device's memory where it reports it, since nothing per seed is copied out); calls are
    balanced. ``num_checkpoints``: G where the caller has the grid already."""
    backend = jax.default_backend() if backend is None else backend
    budget = _CPU_CALL_BYTES if backend == "cpu" else _ACCEL_CALL_BYTES
    if summary and backend != "cpu":
        try:
            limit = jax.devices()[0].memory_stats().get("bytes_limit", 0)
        except Exception:  # noqa: BLE001 - a backend without memory statistics
            limit = 0
        budget = max(budget, int(limit) // 4)
    share = -(-num_seeds // max(1, workers))
    cap = max(1, budget // bytes_per_seed(config, num_checkpoints))
    calls = -(-share // cap)
    return -(-share // calls)  # balanced: the padded last call wastes little


def _check_first_seed(first_seed, num_seeds: int) -> int:
    if isinstance(first_seed, bool) or int(first_seed) < 0:
        raise ValueError(f"first_seed must be a non-negative integer, got {first_seed!r}")
    if int(first_seed) + num_seeds > 2**32:
        raise ValueError(f"seed indices are uint32: first_seed + num_seeds must be <= 2^32, "
                         f"got {int(first_seed) + num_seeds}")
    return int(first_seed)


# ----------------------------------------------------------------------------- tabular plans


def pallas_by_default(config: RunConfig, params: RunParams,
                      mesh: "jax.sharding.Mesh | None" = None) -> bool:
    """Whether ``runner="auto"`` takes the fused kernel: on one GPU (no mesh), for the
    configurations where it draws the fast runner's arms (``pallas_softmax.supports``), and
    where this jax still lowers Pallas to Triton (``pallas_softmax.available``)."""
    return (mesh is None and jax.default_backend() == "gpu"
            and pallas_softmax.supports(config, params) and pallas_softmax.available())


def _choose_runner(config: RunConfig, params: RunParams, runner: str,
                   mesh: "jax.sharding.Mesh | None" = None) -> str:
    """``"fast"``, ``"thompson"``, ``"pallas"`` or ``"general"`` for a validated config (see
    plan_run)."""
    if runner == "general":
        return "general"
    if runner == "pallas":
        if mesh is not None or not pallas_softmax.supports(config, params):
            raise ValueError(
                f"runner='pallas' needs one device (no mesh) and what the fused kernel "
                f"reproduces: {pallas_softmax.SUPPORTS_TEXT}; got policy={config.policy!r}, "
                f"estimator={config.estimator!r}, num_arms={config.num_arms}, "
                f"dtype={config.dtype!r}")
        return "pallas"
    if runner == "auto" and pallas_by_default(config, params, mesh):
        return "pallas"
    # fast_thompson draws the same arms as the general runner (tested) and is faster on
    # every backend, so "auto" takes it wherever it applies
    if fast_thompson.supports(config, validated=True):
        return "thompson"
    if fast_softmax.supports(config, params, validated=True):
        return "fast"
    if runner == "fast":
        raise ValueError(
            f"runner='fast' needs policy='thompson' with one context and no diagnostics, or "
            f"policy='softmax', one context, an estimator in "
            f"{est_lib.LOCAL_ESTIMATORS}, diagnostics=False and alpha >= "
            f"{fast_softmax.min_alpha(config.dtype)} ({config.dtype}); got policy="
            f"{config.policy!r}, estimator={config.estimator!r}, "
            f"num_contexts={config.num_contexts}, diagnostics={config.diagnostics}")
    return "general"


def plan_run(
    config: RunConfig,
    params: RunParams,
    num_seeds: int,
    *,
    first_seed: int = 0,
    mesh: "jax.sharding.Mesh | None" = None,
    chunk_size: int | None = None,
    runner: str = "auto",
    summary: bool = False,
) -> RunPlan:
    """The plan of a tabular ``run_seeds`` call (host-side; compiles nothing).

    Validates ``config``, ``params``, the seeds and the options once. ``runner="auto"``
    takes the fused kernel on one GPU where it applies (:func:`pallas_by_default`: the same
    arms, counts, regret, compensator and min π as fast_softmax; the Rao–Blackwellised regret
    may differ in its last bits), else
    :mod:`sern_jax.engine.fast_softmax` whenever it reproduces ``simulate.make_run``
    (SERN softmax, one context, a local estimator, no diagnostics, α large enough for its
    float type; see ``fast_softmax.supports``), :mod:`sern_jax.engine.fast_thompson` for
    Thompson sampling with one context and no diagnostics, and the general runner otherwise;
    ``"fast"`` insists on a fast runner (``ValueError`` if unsupported), ``"general"`` on
    ``simulate.make_run``, ``"pallas"`` on the fused kernel (off a GPU in Pallas'
    interpreter: slow, for tests). ``summary``: the plan's ``fn`` reduces over seeds on the device.
    Arguments as in :func:`sern_jax.engine.drive.run_seeds`.
    """
    sim.validate(config, params, num_seeds)
    first_seed = _check_first_seed(first_seed, num_seeds)
    if runner not in RUNNERS:
        raise ValueError(f"unknown runner {runner!r}; expected one of {RUNNERS}")
    if chunk_size is not None and (isinstance(chunk_size, bool) or int(chunk_size) < 1):
        raise ValueError(f"chunk_size must be a positive integer, got {chunk_size!r}")
    grid = sim.checkpoint_times(config)
    kind = _choose_runner(config, params, runner, mesh)
    fast = kind != "general"
    workers = concurrent_calls(mesh)
    chunk = (default_chunk_size(config, num_seeds, workers=workers, summary=summary,
                                num_checkpoints=grid.size)
             if chunk_size is None else int(chunk_size))
    n_dev = 1 if mesh is None else mesh.devices.size
    if kind == "pallas":  # whole programs of seeds: no padding inside the kernel's calls
        inner = None
        chunk = pallas_softmax.pad_seeds(chunk, pallas_softmax.DEFAULT_SEEDS_PER_PROGRAM)
    elif fast:
        target = fast_softmax.DEFAULT_CPU_CHUNK if jax.default_backend() == "cpu" else None
        inner, chunk = fast_softmax.chunk_layout(chunk, target, n_dev)
        if inner * n_dev >= chunk:
            inner = None
    else:
        inner = None
        chunk = int(math.ceil(chunk / n_dev) * n_dev)
    workers = max(1, min(workers, -(-num_seeds // chunk)))
    edges = summary_lib.summary_edges(config, grid) if summary else None
    fn = batched_runner(config, mesh, fast, inner, summary=summary, edges=edges,
                        pallas=kind == "pallas")
    return RunPlan(fn=fn, args=(params,), runner=kind, num_seeds=int(num_seeds),
                   first_seed=first_seed, chunk=chunk, inner=inner, workers=workers,
                   summary=summary, mesh=mesh, pinned=use_pinned_host(mesh), overlap=True,
                   grid=grid, edges=edges)


_RUNNER_CACHE: dict = {}


def batched_runner(config: RunConfig, mesh: "jax.sharding.Mesh | None" = None,
                   fast: bool = False, inner: int | None = None,
                   summary: bool = False, edges: dict | None = None,
                   pallas: bool = False) -> Callable:
    """The jitted batched runner ``fn(keys [S'], params) -> RunOutput`` of a tabular plan,
    cached per (config, mesh, fast, inner, summary): one compilation per call shape.

    Args:
      config: the run configuration.
      mesh: optional one-axis mesh; the seed axis (keys and outputs) is sharded over it.
      fast: :func:`sern_jax.engine.fast_softmax.make_batched` (or, for Thompson sampling,
        :func:`sern_jax.engine.fast_thompson.make_batched`; needs their ``supports``) instead
        of ``jax.vmap(simulate.make_run(config))``.
      inner: seeds per ``lax.map`` step of the fast runner (None: one step).
      summary: ``fn(keys, params, num_valid) -> {field: statistics}`` instead, reducing the
        outputs over the first ``num_valid`` seeds on the device
        (:func:`sern_jax.engine.summary.summarize_outputs`).
      edges: the summary's ``summary_edges(config)`` where the caller has them already.
      pallas: the fused kernel (:func:`sern_jax.engine.pallas_softmax.make_pallas_run`; in
        Pallas' interpreter off a GPU) instead of the fast runner.
    """
    mesh_key = None if mesh is None else (tuple(mesh.axis_names), mesh.devices.shape,
                                          tuple(d.id for d in mesh.devices.flat))
    cache_key = (config, mesh_key, fast, inner, summary, pallas)
    if cache_key in _RUNNER_CACHE:
        return _RUNNER_CACHE[cache_key]
    if summary and edges is None:
        edges = summary_lib.summary_edges(config)
    if summary and mesh is None:
        # Two compiled calls, the engine's (shared with the per-seed path) and the
        # reduction's, not one fused program: fused, XLA:GPU ran the engine itself slower.
        engine = batched_runner(config, None, fast, inner, pallas=pallas)
        reduce = jax.jit(lambda out, num_valid: summary_lib.summarize_outputs(
            out, num_valid, edges))
        fn = _EngineThenSummary(engine, reduce)
    else:
        if pallas:
            batched = pallas_softmax.make_pallas_run(
                config, interpret=jax.default_backend() != "gpu")
        elif fast and config.policy == "thompson":
            batched = fast_thompson.make_batched(config, chunk=inner, mesh=mesh)
        elif fast:
            batched = fast_softmax.make_batched(config, chunk=inner, mesh=mesh)
        else:
            batched = jax.vmap(sim.make_run(config), in_axes=(0, None))
        spec = (None if mesh is None else
                jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec(
                    mesh.axis_names[0])))
        if summary:
            per_seed = batched

            def batched(keys, params, num_valid):
                return summary_lib.summarize_outputs(per_seed(keys, params), num_valid, edges)

            fn = jax.jit(batched, in_shardings=(spec, None, None))
        elif mesh is None:
            fn = jax.jit(batched)
        else:
            fn = jax.jit(batched, in_shardings=(spec, None), out_shardings=spec)
    _RUNNER_CACHE[cache_key] = fn
    return fn


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


# ----------------------------------------------------------------------------- neural plans


def plan_neural(batched: Callable, num_seeds: int, *, first_seed: int = 0,
                chunk_size: int | None = None, workers: int | None = None,
                params=None) -> RunPlan:
    """The plan of a neural ``run_seeds`` call (host-side; compiles nothing).

    Args:
      batched: the jitted ``vmap`` of one seed's run: ``fn(keys)``, or ``fn(keys, params)``
        when ``params`` is given (:func:`sern_jax.engine.neural.run_seeds` makes it).
      num_seeds: S ≥ 1.
      first_seed: index of the first seed.
      chunk_size: seeds per call (default: an equal share for each worker).
      workers: calls at once from host threads (default 1: one call at a time, which XLA
        parallelises inside; two concurrent calls of a Neural-Linear program on a 2-core CPU
        were seen to hang with both threads waiting, the intra-op thread pool starved).
      params: the problem's traced parameters, cast to float32 once here, or None.
    """
    if isinstance(num_seeds, bool) or not isinstance(num_seeds, (int, np.integer)) \
            or num_seeds < 1:
        raise ValueError(f"--seeds must be an integer >= 1, got {num_seeds!r}")
    first_seed = _check_first_seed(first_seed, num_seeds)
    workers = 1 if workers is None else max(1, int(workers))
    chunk = -(-num_seeds // workers) if chunk_size is None else int(chunk_size)
    if chunk < 1:
        raise ValueError(f"--chunk-size must be >= 1, got {chunk_size!r}")
    args = ()
    if params is not None:
        args = (jax.tree.map(lambda v: jnp.asarray(v, jnp.float32), params),)
    workers = max(1, min(workers, -(-num_seeds // chunk)))
    # On CPU a launched call runs beside the one being collected: not done, for the same
    # reason as ``workers`` (XLA's intra-op pool is the parallelism there).
    return RunPlan(fn=batched, args=args, runner="neural", num_seeds=int(num_seeds),
                   first_seed=first_seed, chunk=chunk, inner=None, workers=workers,
                   pinned=use_pinned_host(None), overlap=jax.default_backend() != "cpu")
