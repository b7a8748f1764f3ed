"""The bandit benchmark: seed-rounds per second of SERN softmax, side by side with NumPy.

``sern bench bandit`` is :func:`bandit_benchmark` plus flags and printing; a library user calls
it directly::

    from sern_jax.bench import bandit
    result = bandit.bandit_benchmark(bandit.BanditWorkload(horizon=1_000, seeds=512))
    result["speedup_vs_numpy"], result["machine"]

Workload: SERN softmax(r̂/α) with the add-half estimator, K Bernoulli arms with
means U[0, 1] drawn per seed, constant α, T rounds, S seeds; every round samples one arm by
inverse CDF with one uniform, draws the reward, updates r̂, and accumulates the outputs of
``simulate.RunOutput`` (realised and Rao–Blackwellised regret, compensator Σπ, min π, counts)
on the log-spaced checkpoint grid.

Ways of running that same workload, in one process (each a ``_path_*`` function below taking
the shared :class:`BanditSetup`; a new way is one more such function and one more line in
:func:`bandit_benchmark`):

* ``run_seeds``: ``executor.run_seeds``, the entry point users call: it picks the fast runner
  below and, on CPU, runs one jitted call per core at once (a compiled call uses one core
  there), copying outputs to NumPy; timed end to end, and split into its compute alone and
  its output copy alone (:func:`_copy_split`: ``output_bytes``, ``output_copy_s``,
  ``compute_s``, ``copy_fraction``, ``bound``);
* ``fast``: :mod:`sern_jax.engine.fast_softmax` as one jitted call (one core on CPU; exact, same
  random streams as the general runner);
* ``general``: ``executor.batched_runner(config)`` = ``jit(vmap(simulate.make_run(config)))``,
  the engine's general runner;
* ``numpy``: :func:`numpy_reference`, vectorised over seeds with a Python loop over t (float32,
  inverse CDF with one uniform per round, the same outputs); it may run fewer seeds
  (``numpy_seeds``);
* ``run_seeds_summary``: ``executor.run_seeds(..., summary=True)``, the public path that
  reduces over seeds on the device (means, variances, histograms) and copies kilobytes;
* ``naive_jax``: :func:`naive_jax_bandit`, the ~40-line ``jit(vmap(scan))`` bandit a JAX
  user writes first (softmax recomputed every round, ``jax.random`` keys per round, plain
  float32 sums, final regret and counts only), the peer the engine must beat.
* ``pallas`` (``pallas=True``): :mod:`sern_jax.engine.pallas_softmax`, the fused
  kernel that keeps each seed's state on chip across rounds, on the fast path's keys; its
  outputs are compared with the fast path's seed by seed (``regret_agreement``).

``policy="thompson"`` runs Beta-Bernoulli Thompson sampling instead (Beta(1 + S, 1 + F)
posteriors, argmax): the fast path is :mod:`sern_jax.engine.fast_thompson`, the NumPy reference draws
its Beta variates with ``Generator.beta`` and the naive JAX peer with ``jax.random.beta``.

Compile time (``.lower().compile()``) is measured separately and excluded from throughput;
each figure is the median of ``repeats`` timed runs ending in ``block_until_ready``
(:func:`sern_jax.infra.timing.time_calls`). The JSON fields of the result are a contract
(``sern bench bandit --json``): add, don't rename.
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any, Callable, NamedTuple

import numpy as np

from sern_jax.infra import io, timing

__all__ = ["BanditWorkload", "BanditSetup", "BENCH_POLICIES", "bandit_config", "bandit_setup",
           "bandit_memory_bytes", "bandit_benchmark", "numpy_reference", "naive_jax_bandit",
           "mean_se", "smpybandits_thompson", "smpybandits_reference"]


@dataclasses.dataclass(frozen=True)
class BanditWorkload:
    """What ``sern bench bandit`` runs (its flags, same names without dashes)."""

    arms: int = 64  # K
    horizon: int = 10_000  # T
    seeds: int = 10_000  # S for the JAX paths
    alpha: float = 0.05  # constant α
    repeats: int = 3  # timed runs per path (median)
    numpy_seeds: int = 1000  # seeds of the NumPy reference (0 skips it)
    general_repeats: int = 1  # timed runs of the general runner (0 skips it)
    devices: int = 0  # shard the seed axis over this many devices (0: one device)
    chunk: int = -1  # seeds per lax.map step of the fast path (-1: 256 on CPU, all on GPU)
    seed: int = 0  # root seed
    policy: str = "softmax"  # or "thompson"
    naive_repeats: int = 1  # timed runs of the naive jit(vmap(scan)) peer (0 skips it)
    summary_repeats: int = -1  # timed runs of run_seeds(summary=True) (-1: repeats; 0 skips)
    smpybandits_seeds: int = 0  # seeds of SMPyBandits' Thompson (policy thompson; 0 skips)
    pallas: bool = False  # also the fused Pallas kernel (sern_jax.engine.pallas_softmax; softmax)


BENCH_POLICIES = ("softmax", "thompson")


def bandit_config(w: BanditWorkload):
    """``(simulate.RunConfig, simulate.RunParams)`` of the workload (no compile)."""
    from sern_jax.core import problems
    from sern_jax.engine import simulate as sim

    if w.policy not in BENCH_POLICIES:
        raise ValueError(f"policy must be one of {BENCH_POLICIES}, got {w.policy!r}")
    config = sim.RunConfig(policy=w.policy, estimator="addhalf", schedule="constant",
                           num_arms=w.arms, horizon=w.horizon, random_means=True)
    # random_means=True: each seed draws its own U[0,1] means; the problem only fixes K.
    params = sim.default_params(config, problems.bernoulli(np.full(w.arms, 0.5)),
                                alpha0=w.alpha)
    return config, params


def bandit_memory_bytes(w: BanditWorkload) -> int:
    """Bytes of outputs and per-seed state the workload holds at once (JAX + NumPy paths)."""
    from sern_jax.engine import drive as executor

    config, _ = bandit_config(w)
    # run_seeds' arrays, plus a device copy and a host copy of them while its output copy is
    # timed apart, plus the Pallas path's outputs
    return (w.seeds * executor.bytes_per_seed(config) * (4 if w.pallas else 3)
            + (w.numpy_seeds + w.smpybandits_seeds) * (4 * w.arms + 64) * 8)


class BanditSetup(NamedTuple):
    """What every path shares: the workload, its config and params, devices and keys."""

    workload: BanditWorkload
    config: Any  # simulate.RunConfig
    params: Any  # simulate.RunParams
    mesh: Any  # jax.sharding.Mesh or None
    num_devices: int
    root: Any  # jax.random.key(seed)
    backend: str  # jax.default_backend()
    work: int  # seed-rounds counted: S·T (padding seeds are not)
    put: Callable  # keys -> keys placed on the mesh (identity without one)


def bandit_setup(w: BanditWorkload) -> BanditSetup:
    """Builds the shared setup; raises ValueError where the fast path cannot run α."""
    import jax

    from sern_jax.engine import fast_softmax, fast_thompson
    from sern_jax.infra import sharding
    from sern_jax.engine import simulate as sim

    config, params = bandit_config(w)
    sim.validate(config, params, w.seeds)
    if w.policy == "thompson":
        if not fast_thompson.supports(config):
            raise ValueError("the fast Thompson runner needs the threefry PRNG in "
                             "partitionable mode")
    elif not fast_softmax.supports(config, params):
        raise ValueError(f"alpha={w.alpha} is below the fast path's minimum "
                         f"{fast_softmax.min_alpha(config.dtype)} for float32")
    mesh = sharding.seed_mesh(w.devices) if w.devices else None

    def put(keys):
        if mesh is None:
            return keys
        spec = jax.sharding.PartitionSpec(mesh.axis_names[0])
        return jax.device_put(keys, jax.sharding.NamedSharding(mesh, spec))

    return BanditSetup(w, config, params, mesh, w.devices or 1, jax.random.key(w.seed),
                       jax.default_backend(), w.seeds * w.horizon, put)


# ----------------------------------------------------------------------------- NumPy reference


def numpy_reference(num_seeds: int, num_arms: int, horizon: int, alpha: float,
                    checkpoints: np.ndarray, seed: int = 0,
                    policy: str = "softmax") -> dict[str, np.ndarray]:
    """The same workload in NumPy: vectorised over seeds, a Python loop over rounds.

    With ``policy="thompson"``: θ ~ Beta(1 + S, 1 + F) per arm by ``Generator.beta``, the
    argmax is played (π is its one-hot, so the Rao–Blackwellised regret equals the realised
    one and the compensator the counts), ``alpha`` is ignored.

    Args:
      num_seeds: S.
      num_arms: K.
      horizon: T.
      alpha: constant temperature α.
      checkpoints: [G] rounds (1-based) after which outputs are recorded.
      seed: ``np.random.default_rng`` seed (NumPy's own stream, not JAX's).

    Returns:
      dict of ``regret`` [S, G], ``regret_rb`` [S, G], ``counts`` [S, G, K],
      ``compensator`` [S, G, K], ``min_prob`` [S, G] (float32 arithmetic).
    """
    rng = np.random.default_rng(seed)
    f32 = np.float32
    means = rng.random((num_seeds, num_arms), dtype=f32)
    best = means.max(axis=1)
    counts = np.zeros((num_seeds, num_arms), np.int32)
    sums = np.zeros((num_seeds, num_arms), f32)
    comp = np.zeros((num_seeds, num_arms), f32)
    regret = np.zeros(num_seeds, f32)
    regret_rb = np.zeros(num_seeds, f32)
    min_prob = np.ones(num_seeds, f32)
    rows = np.arange(num_seeds)
    inv_alpha = f32(1.0 / alpha)
    grid = {int(t): g for g, t in enumerate(checkpoints)}
    out = {"regret": np.zeros((num_seeds, len(grid)), f32),
           "regret_rb": np.zeros((num_seeds, len(grid)), f32),
           "counts": np.zeros((num_seeds, len(grid), num_arms), np.int32),
           "compensator": np.zeros((num_seeds, len(grid), num_arms), f32),
           "min_prob": np.zeros((num_seeds, len(grid)), f32)}
    for t in range(1, horizon + 1):
        if policy == "thompson":
            theta = rng.beta(1.0 + sums, 1.0 + counts - sums)
            arm = theta.argmax(axis=1)
            probs = np.zeros((num_seeds, num_arms), f32)
            probs[rows, arm] = 1.0
        else:
            r_hat = (sums + f32(0.5)) / (counts + f32(1.0))
            w = np.exp((r_hat - r_hat.max(axis=1, keepdims=True)) * inv_alpha)
            probs = w / w.sum(axis=1, keepdims=True)
            cdf = np.cumsum(probs, axis=1)
            u = rng.random(num_seeds, dtype=f32)
            arm = np.minimum((cdf <= (u * cdf[:, -1])[:, None]).sum(axis=1), num_arms - 1)
        r_arm = means[rows, arm]
        reward = rng.random(num_seeds, dtype=f32) < r_arm
        regret += best - r_arm
        regret_rb += best - (probs * means).sum(axis=1)
        comp += probs
        np.minimum(min_prob, probs.min(axis=1), out=min_prob)
        counts[rows, arm] += 1
        sums[rows, arm] += reward
        if t in grid:
            g = grid[t]
            out["regret"][:, g] = regret
            out["regret_rb"][:, g] = regret_rb
            out["counts"][:, g] = counts
            out["compensator"][:, g] = comp
            out["min_prob"][:, g] = min_prob
    return out


def naive_jax_bandit(num_arms: int, horizon: int, alpha: float, policy: str = "softmax"):
    """The bandit a JAX user writes first: ``run(key) -> (regret, regret_rb, counts [K])``.

    One seed, a ``lax.scan`` over all T rounds; vmap and jit it over seeds. Each round splits
    a ``fold_in`` key, recomputes the add-half estimates and ``softmax(r̂/α)`` over all K
    arms and samples by inverse CDF with one uniform (Thompson: ``jax.random.beta`` per arm
    and the argmax); float32 sums without compensation; only the final regret and counts are
    returned. Means are U[0, 1] per seed, as in the workload (its own streams, not the
    engine's: compare means with standard errors).
    """
    import jax
    import jax.numpy as jnp

    def run(key):
        key_means, key_run = jax.random.split(key)
        means = jax.random.uniform(key_means, (num_arms,))
        best = jnp.max(means)

        def step(carry, t):
            counts, sums, regret, regret_rb = carry
            key_arm, key_reward = jax.random.split(jax.random.fold_in(key_run, t))
            if policy == "thompson":
                theta = jax.random.beta(key_arm, 1.0 + sums, 1.0 + counts - sums)
                arm = jnp.argmax(theta)
                probs = jax.nn.one_hot(arm, num_arms)
            else:
                probs = jax.nn.softmax((sums + 0.5) / (counts + 1.0) / alpha)
                u = jax.random.uniform(key_arm)
                arm = jnp.minimum(jnp.sum(jnp.cumsum(probs) <= u), num_arms - 1)
            reward = jax.random.uniform(key_reward) < means[arm]
            hot = jax.nn.one_hot(arm, num_arms)
            return (counts + hot, sums + hot * reward, regret + best - means[arm],
                    regret_rb + best - probs @ means), None

        zeros = jnp.zeros((num_arms,))
        init = (zeros, zeros, jnp.float32(0.0), jnp.float32(0.0))
        (counts, _, regret, regret_rb), _ = jax.lax.scan(step, init, jnp.arange(horizon))
        return regret, regret_rb, counts

    return run


def mean_se(x: np.ndarray) -> tuple[float, float]:
    """Mean and its standard error (SD / sqrt(n), 0 for one value) over seeds."""
    x = np.asarray(x, np.float64)
    return float(x.mean()), float(x.std(ddof=1) / np.sqrt(x.size)) if x.size > 1 else 0.0


def smpybandits_thompson():
    """SMPyBandits' ``Policies.Thompson`` class, or ImportError naming what to install.

    SMPyBandits 0.9.7 (its last release, 2019) imports ``scipy.special.btdtri`` at module
    level, which SciPy has since removed; it is set here to its equal,
    ``scipy.special.betaincinv`` (the Beta quantile; Thompson's ``sample`` does not use it). The
    library's import-time notes on numba go to stderr so ``--json`` stays one line.
    """
    import contextlib
    import sys

    import scipy.special

    if not hasattr(scipy.special, "btdtri"):
        scipy.special.btdtri = scipy.special.betaincinv
    try:
        with contextlib.redirect_stdout(sys.stderr):
            from SMPyBandits.Policies import Thompson
    except ImportError as e:
        raise ImportError(f"SMPyBandits is not importable ({e}); pip install SMPyBandits "
                          f"seaborn pandas") from e
    return Thompson


def smpybandits_reference(num_seeds: int, num_arms: int, horizon: int,
                          checkpoints: np.ndarray, seed: int = 0) -> dict[str, np.ndarray]:
    """SMPyBandits' Thompson sampling on the NumPy reference's instance, one seed at a time.

    The library has no seed axis: each seed is a ``Thompson(K)`` object whose ``choice()``
    draws Beta(1 + S, 1 + F) for every arm with ``numpy.random.beta`` (the global stream,
    seeded ``seed + i``) and plays an argmax (ties at random), and ``getReward`` updates the
    posterior. Means are the NumPy reference's (the first ``num_seeds`` rows of its
    ``default_rng(seed)`` U[0,1] draw), Bernoulli rewards come from ``default_rng(seed + 1)``.

    Returns:
      dict of ``regret`` [S, G] (realised: best mean − played mean, summed) and ``counts``
      [S, G, K].
    """
    thompson = smpybandits_thompson()
    means = np.random.default_rng(seed).random((num_seeds, num_arms), dtype=np.float32)
    reward_rng = np.random.default_rng(seed + 1)
    grid = {int(t): g for g, t in enumerate(checkpoints)}
    regret_out = np.zeros((num_seeds, len(grid)), np.float64)
    counts_out = np.zeros((num_seeds, len(grid), num_arms), np.int64)
    for i in range(num_seeds):
        np.random.seed((seed + i) % 2**32)
        policy = thompson(num_arms)
        policy.startGame()
        mu = means[i].astype(np.float64)
        best = mu.max()
        counts = np.zeros(num_arms, np.int64)
        regret = 0.0
        for t in range(1, horizon + 1):
            arm = int(policy.choice())
            policy.getReward(arm, float(reward_rng.random() < mu[arm]))
            counts[arm] += 1
            regret += best - mu[arm]
            if t in grid:
                regret_out[i, grid[t]] = regret
                counts_out[i, grid[t]] = counts
    return {"regret": regret_out, "counts": counts_out}

# ----------------------------------------------------------------------------- the paths
# Each returns (the path's JSON entry, its outputs [S, ...] as NumPy or None).


def _compile_s(fn, *args) -> tuple[Any, float]:
    """``fn.lower(*args).compile()`` and its seconds."""
    t = timing.time_calls(lambda: fn.lower(*args).compile(), repeats=1, warmup=0)
    return t.result, t.times_s[0]


def _path_fast(s: BanditSetup):
    import jax

    from sern_jax.engine import fast_softmax, fast_thompson
    from sern_jax.engine import simulate as sim

    w = s.workload
    chunk_target = w.chunk if w.chunk >= 0 else (
        fast_softmax.DEFAULT_CPU_CHUNK if s.backend == "cpu" else 0)
    chunk, padded = fast_softmax.chunk_layout(w.seeds, chunk_target, s.num_devices)
    module = fast_thompson if w.policy == "thompson" else fast_softmax
    fn = jax.jit(module.make_batched(s.config, chunk=chunk, mesh=s.mesh))
    keys = s.put(sim.seed_keys(s.root, padded))
    compiled, compile_s = _compile_s(fn, keys, s.params)
    t = timing.time_calls(lambda: compiled(keys, s.params), w.repeats, warmup=0)
    out = jax.tree.map(lambda x: np.asarray(x)[:w.seeds], t.result)
    entry = {"engine_path": f"{module.__name__}.make_batched", "chunk": chunk,
             "padded_seeds": padded, "compile_s": compile_s,
             "seed_rounds_per_s": s.work / t.median_s, **t.stats(), "concurrent_calls": 1}
    return entry, out


def _path_run_seeds(s: BanditSetup):
    import jax

    from sern_jax.engine import drive as executor

    w = s.workload
    plan = executor.plan_run(s.config, s.params, w.seeds, mesh=s.mesh)
    _, compile_s = _compile_s(plan.fn, jax.ShapeDtypeStruct((plan.chunk,), s.root.dtype),
                              s.params)
    t = timing.time_calls(
        lambda: executor.run_seeds(s.config, s.params, w.seed, w.seeds, mesh=s.mesh),
        w.repeats, warmup=0)
    entry = {"engine_path": "sern_jax.engine.drive.run_seeds", "fast": plan.fast,
             "runner": plan.runner,
             "seeds_per_call": plan.chunk, "concurrent_calls": plan.workers,
             "compile_s": compile_s, "seed_rounds_per_s": s.work / t.median_s, **t.stats()}
    entry.update(_copy_split(s, plan, t))
    return entry, t.result


COPY_BOUND_FRACTION = 0.5  # copy_fraction at or above which the per-seed path is copy-bound


def _copy_split(s: BanditSetup, plan, t: timing.Timing) -> dict[str, Any]:
    """Whether per-seed ``run_seeds`` is bounded by copying its outputs to the host.

    Replays ``drive.run_plan`` (same compiled call, keys, chunks, worker threads and overlap)
    twice per repeat: first with every call's outputs only waited for on the device
    (``block_until_ready``, kept there, never fetched): ``compute_s``; then those same device
    outputs go through the driver's own collector (``drive._SeedArrays``: pinned host memory or
    ``copy_to_host_async``, then into the [S, ...] numpy arrays) with nothing computed:
    ``output_copy_s``. Each is the best of ``repeats``; ``call_s`` is the best timed
    ``run_seeds`` call, the denominator of ``copy_fraction`` and ``compute_fraction``. With
    one worker on an accelerator the driver overlaps a call's copy with the next call's compute,
    so the two fractions may sum to more than 1. ``bound`` is ``"output copy"`` when
    ``copy_fraction >= COPY_BOUND_FRACTION``, else ``"compute"``.
    """
    import time

    import jax

    from sern_jax.engine import drive as executor

    w = s.workload
    fn = executor._compiled(plan, jax.random.key(w.seed).dtype)

    def size_of(start: int) -> int:
        return min(plan.chunk, plan.num_seeds - start)

    compute_times, copy_times, copied_bytes = [], [], 0
    for _ in range(w.repeats):
        held: dict[int, Any] = {}

        def keep(start, out):
            held[start] = jax.block_until_ready(out)
            return size_of(start)

        t0 = time.perf_counter()
        executor._drive(plan, executor._launcher(plan, w.seed, fn), keep, None)
        compute_times.append(time.perf_counter() - t0)
        copied_bytes = int(sum(x.nbytes for x in jax.tree.leaves(held)))

        sink = executor._SeedArrays(plan)
        t0 = time.perf_counter()
        executor._drive(plan, held.pop, sink.collect, None)
        copy_times.append(time.perf_counter() - t0)
        del held, sink

    output_bytes = int(sum(np.asarray(x).nbytes for x in jax.tree.leaves(t.result)))
    compute_s, copy_s, call_s = min(compute_times), min(copy_times), t.best_s
    copy_fraction = copy_s / call_s
    return {
        "output_bytes": output_bytes,  # Σ nbytes of the per-seed arrays run_seeds returns
        "output_copied_bytes": copied_bytes,  # what the calls hand over (padding seeds too)
        "output_copy_route": "pinned_host" if plan.pinned else "copy_to_host_async",
        "output_copy_s": copy_s,
        "output_copy_bytes_per_s": copied_bytes / copy_s,
        "output_copy_times_s": [round(x, 6) for x in copy_times],
        "compute_s": compute_s,
        "compute_times_s": [round(x, 6) for x in compute_times],
        "compute_seed_rounds_per_s": s.work / compute_s,
        "call_s": call_s,
        "copy_fraction": copy_fraction,
        "compute_fraction": compute_s / call_s,
        # the call's time spent on neither (planning, keys, threads); < 0 where copy overlaps
        "other_s": call_s - compute_s - copy_s,
        "bound": "output copy" if copy_fraction >= COPY_BOUND_FRACTION else "compute",
        "copy_split": "compute_s: run_plan replayed, outputs blocked on the device and not "
                      "fetched; output_copy_s: those device outputs through run_plan's "
                      "collector; best of repeats, fractions of the best run_seeds call",
    }


def _path_run_seeds_summary(s: BanditSetup):
    import jax
    import jax.numpy as jnp

    from sern_jax.engine import drive as executor

    w = s.workload
    plan = executor.plan_run(s.config, s.params, w.seeds, mesh=s.mesh, summary=True)
    _, compile_s = _compile_s(plan.fn, jax.ShapeDtypeStruct((plan.chunk,), s.root.dtype),
                              s.params, jax.ShapeDtypeStruct((), jnp.int32))
    repeats = w.repeats if w.summary_repeats < 0 else w.summary_repeats
    t = timing.time_calls(
        lambda: executor.run_seeds(s.config, s.params, w.seed, w.seeds, mesh=s.mesh,
                                   summary=True), repeats, warmup=0)
    arrays = executor.summary_arrays(t.result)
    entry = {"engine_path": "sern_jax.engine.drive.run_seeds(summary=True)", "fast": plan.fast,
             "runner": plan.runner,
             "seeds_per_call": plan.chunk, "concurrent_calls": plan.workers,
             "summary_bytes": int(sum(a.nbytes for a in arrays.values())),
             "compile_s": compile_s, "seed_rounds_per_s": s.work / t.median_s, **t.stats()}
    return entry, t.result


def _path_naive(s: BanditSetup):
    import jax

    w = s.workload
    fn = jax.jit(jax.vmap(naive_jax_bandit(w.arms, w.horizon, w.alpha, w.policy)))
    keys = jax.random.split(jax.random.key(w.seed + 1), w.seeds)
    compiled, compile_s = _compile_s(fn, keys)
    t = timing.time_calls(lambda: compiled(keys), w.naive_repeats, warmup=0)
    regret, regret_rb, counts = (np.asarray(x) for x in t.result)
    entry = {"engine_path": "benchmarks.naive_jax_bandit (jit(vmap(scan)))",
             "compile_s": compile_s, "seed_rounds_per_s": s.work / t.median_s, **t.stats()}
    return entry, {"regret": regret, "regret_rb": regret_rb, "counts": counts}


def _path_general(s: BanditSetup):
    import jax

    from sern_jax.engine import drive as executor
    from sern_jax.engine import simulate as sim

    w = s.workload
    fn = executor.batched_runner(s.config, s.mesh)
    g_seeds = -(-w.seeds // s.num_devices) * s.num_devices
    keys = s.put(sim.seed_keys(s.root, g_seeds))
    compiled, compile_s = _compile_s(fn, keys, s.params)
    t = timing.time_calls(lambda: compiled(keys, s.params), w.general_repeats, warmup=0)
    out = jax.tree.map(lambda x: np.asarray(x)[:w.seeds], t.result)
    entry = {"engine_path": "sern_jax.engine.simulate.make_run (jit(vmap))", "compile_s": compile_s,
             "seed_rounds_per_s": s.work / t.median_s, **t.stats()}
    return entry, out


def _path_numpy(s: BanditSetup):
    from sern_jax.engine import simulate as sim

    w = s.workload
    grid = sim.checkpoint_times(s.config)
    t = timing.time_calls(lambda: numpy_reference(w.numpy_seeds, w.arms, w.horizon, w.alpha,
                                                  grid, seed=w.seed, policy=w.policy),
                          w.repeats, warmup=0)
    entry = {"seeds": w.numpy_seeds, "seed_rounds_per_s": w.numpy_seeds * w.horizon
             / t.median_s, "dtype": "float32", **t.stats()}
    return entry, t.result


def _path_smpybandits(s: BanditSetup):
    from sern_jax.engine import simulate as sim

    w = s.workload
    grid = sim.checkpoint_times(s.config)
    t = timing.time_calls(lambda: smpybandits_reference(w.smpybandits_seeds, w.arms, w.horizon,
                                                        grid, seed=w.seed),
                          w.repeats, warmup=0)
    import SMPyBandits

    entry = {"seeds": w.smpybandits_seeds, "seed_rounds_per_s": w.smpybandits_seeds
             * w.horizon / t.median_s, "policy": "SMPyBandits.Policies.Thompson",
             "version": getattr(SMPyBandits, "__version__", None), **t.stats()}
    return entry, t.result


def _path_pallas(s: BanditSetup):
    """The fused kernel on the fast path's keys: its outputs are compared
    with the fast engine's seed by seed. Triton on a GPU, Pallas' interpreter elsewhere."""
    import jax

    from sern_jax.engine import pallas_softmax
    from sern_jax.engine import simulate as sim

    w = s.workload
    fn = pallas_softmax.make_pallas_run(s.config, interpret=s.backend != "gpu")
    keys = sim.seed_keys(s.root, w.seeds)  # fold_in keys: the fast path's first S seeds
    compiled, compile_s = _compile_s(jax.jit(fn), keys, s.params)
    t = timing.time_calls(lambda: compiled(keys, s.params), w.repeats, warmup=0)
    out = jax.tree.map(np.asarray, t.result)
    entry = {"engine_path": "sern_jax.engine.pallas_softmax.make_pallas_run", **fn.info,
             "compile_s": compile_s, "seed_rounds_per_s": s.work / t.median_s, **t.stats()}
    return entry, out


# ----------------------------------------------------------------------------- the benchmark


def bandit_benchmark(w: BanditWorkload = BanditWorkload()) -> dict[str, Any]:
    """Runs every path on the workload in this process; returns the JSON object of
    ``sern bench bandit --json`` (the headline ``seed_rounds_per_s`` is the best JAX path's,
    ``speedup_vs_numpy`` its ratio to the NumPy reference run in the same process)."""
    load_before = os.getloadavg()
    import jax

    from sern_jax.engine import simulate as sim

    s = bandit_setup(w)
    result: dict[str, Any] = {"benchmark": "sern bench bandit", "workload": {
        "policy": w.policy, "estimator": "addhalf", "num_arms": w.arms,
        "horizon": w.horizon, "seeds": w.seeds, "alpha": w.alpha,
        "random_means": "U[0,1] per seed", "dtype": "float32",
        "checkpoints": int(sim.checkpoint_times(s.config).size)}}

    result["fast"], fast_out = _path_fast(s)
    result["run_seeds"], rs_out = _path_run_seeds(s)
    summary_out = naive_out = None
    if w.summary_repeats != 0:
        result["run_seeds_summary"], summary_out = _path_run_seeds_summary(s)
    if w.naive_repeats:
        result["naive_jax"], naive_out = _path_naive(s)
    general_out = numpy_out = None
    if w.general_repeats:
        result["general"], general_out = _path_general(s)
    if w.numpy_seeds:
        result["numpy"], numpy_out = _path_numpy(s)
    smpy_out = None
    if w.smpybandits_seeds and w.policy == "thompson":
        result["smpybandits"], smpy_out = _path_smpybandits(s)
    pallas_out = None
    if w.pallas:
        result["pallas"], pallas_out = _path_pallas(s)

    # ---- agreement of mean regret (different random streams: compare with standard errors)
    agree: dict[str, Any] = {}
    fm, fse = mean_se(fast_out.regret[:, -1])
    agree["fast_mean_regret_T"] = fm
    agree["fast_se"] = fse
    agree["fast_mean_regret_rb_T"] = mean_se(fast_out.regret_rb[:, -1])[0]
    agree["run_seeds_counts_equal_fast"] = bool(np.array_equal(rs_out.counts, fast_out.counts))
    agree["run_seeds_mean_regret_T"] = mean_se(rs_out.regret[:, -1])[0]
    if summary_out is not None:
        sm = float(summary_out.regret.mean[-1])
        agree["run_seeds_summary_mean_regret_T"] = sm
        # the same seeds reduced on the device: equal to the fast path's mean up to rounding
        agree["summary_mean_rel_diff_vs_fast"] = abs(sm - fm) / max(abs(fm), 1e-12)
        agree["summary_counts_min_equal_fast"] = bool(np.array_equal(
            summary_out.counts.min, fast_out.counts.min(0)))
    if naive_out is not None:
        nvm, nvse = mean_se(naive_out["regret"])
        agree["naive_jax_mean_regret_T"] = nvm
        agree["naive_jax_se"] = nvse
        agree["z_fast_vs_naive_jax"] = (fm - nvm) / max(np.hypot(fse, nvse), 1e-12)
    if general_out is not None:
        gm, gse = mean_se(general_out.regret[:, -1])
        agree["general_mean_regret_T"] = gm
        agree["general_se"] = gse
        agree["fast_general_counts_identical_fraction"] = float(np.mean(np.all(
            fast_out.counts[:, -1] == general_out.counts[:, -1], axis=-1)))
    if numpy_out is not None:
        nm, nse = mean_se(numpy_out["regret"][:, -1])
        agree["numpy_mean_regret_T"] = nm
        agree["numpy_se"] = nse
        agree["numpy_mean_regret_rb_T"] = mean_se(numpy_out["regret_rb"][:, -1])[0]
        agree["z_fast_vs_numpy"] = (fm - nm) / max(np.hypot(fse, nse), 1e-12)
    if smpy_out is not None:
        sm_m, sm_se = mean_se(smpy_out["regret"][:, -1])
        agree["smpybandits_mean_regret_T"] = sm_m
        agree["smpybandits_se"] = sm_se
        agree["z_fast_vs_smpybandits"] = (fm - sm_m) / max(np.hypot(fse, sm_se), 1e-12)
    if pallas_out is not None:  # same keys as the fast path: compare seed by seed
        same = np.all(pallas_out.counts == fast_out.counts, axis=(1, 2))
        agree["pallas_mean_regret_T"] = mean_se(pallas_out.regret[:, -1])[0]
        agree["pallas_counts_equal_fast_fraction"] = float(same.mean())
        for name in ("regret", "regret_rb", "compensator", "min_prob"):
            a, b = getattr(pallas_out, name), getattr(fast_out, name)
            agree[f"pallas_{name}_equal_fast_fraction"] = float(np.mean(np.all(
                (a == b).reshape(a.shape[0], -1), axis=1)))
            agree[f"pallas_{name}_max_abs_diff_vs_fast"] = float(np.max(np.abs(
                a.astype(np.float64) - b)))
    result["regret_agreement"] = agree

    # ---- headline
    rates = {k: result[k]["seed_rounds_per_s"] for k in ("fast", "run_seeds", "general",
                                                         "run_seeds_summary") if k in result}
    best_path = max(rates, key=rates.get)
    best_rate = rates[best_path]
    numpy_rate = result["numpy"]["seed_rounds_per_s"] if "numpy" in result else None
    general_rate = rates.get("general")
    devices = jax.devices()[:s.num_devices]
    result.update({
        "seed_rounds_per_s": best_rate,
        "engine_path": result[best_path]["engine_path"],
        "compile_s": result[best_path]["compile_s"],
        "best_path": best_path,
        "fast_seed_rounds_per_s": rates["fast"],
        "run_seeds_seed_rounds_per_s": rates["run_seeds"],
        "run_seeds_concurrent_calls": result["run_seeds"]["concurrent_calls"],
        "general_seed_rounds_per_s": general_rate,
        "numpy_seed_rounds_per_s": numpy_rate,
        "numpy_seeds": w.numpy_seeds,
        "speedup_vs_numpy": best_rate / numpy_rate if numpy_rate else None,
        "general_speedup_vs_numpy": (general_rate / numpy_rate
                                     if numpy_rate and general_rate else None),
        # the public path with on-device summaries against the engine and the
        # naive jit(vmap(scan)) peer measured in this process
        "run_seeds_summary_seed_rounds_per_s": rates.get("run_seeds_summary"),
        "naive_jax_seed_rounds_per_s": (result["naive_jax"]["seed_rounds_per_s"]
                                        if "naive_jax" in result else None),
        "public_over_fast": (rates["run_seeds_summary"] / rates["fast"]
                             if "run_seeds_summary" in rates else None),
        "public_over_naive_jax": (rates["run_seeds_summary"]
                                  / result["naive_jax"]["seed_rounds_per_s"]
                                  if "run_seeds_summary" in rates and "naive_jax" in result
                                  else None),
        "fast_speedup_vs_numpy": rates["fast"] / numpy_rate if numpy_rate else None,
        # Thompson: SMPyBandits' Thompson on the same instance (--smpybandits-seeds)
        "smpybandits_seed_rounds_per_s": (result["smpybandits"]["seed_rounds_per_s"]
                                          if "smpybandits" in result else None),
        "speedup_vs_smpybandits": (best_rate / result["smpybandits"]["seed_rounds_per_s"]
                                   if "smpybandits" in result else None),
        "repeats": w.repeats,
        "general_repeats": w.general_repeats,
        "peak_rss_mb": io.peak_rss_mb(),
        "machine": {**io.machine(),
                    "loadavg_before": [round(x, 2) for x in load_before],
                    "loadavg_after": [round(x, 2) for x in os.getloadavg()]},
        "device": {"backend": s.backend, "num_devices": s.num_devices,
                   "kind": devices[0].device_kind, "devices": [str(d) for d in devices]},
        "jax_version": jax.__version__,
        "jax_threefry_partitionable": bool(jax.config.jax_threefry_partitionable),
    })
    # the fused Pallas kernel beside the engine's fast path (--pallas)
    result["pallas_seed_rounds_per_s"] = (result["pallas"]["seed_rounds_per_s"]
                                          if "pallas" in result else None)
    result["pallas_over_fast"] = (result["pallas"]["seed_rounds_per_s"] / rates["fast"]
                                  if "pallas" in result else None)
    return result
