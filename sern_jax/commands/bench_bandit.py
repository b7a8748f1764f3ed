"""``sern bench bandit``: seed-rounds per second of SERN softmax, side by side with NumPy.

Workload (issue 2): SERN softmax(r̂/α) with the add-half estimator, K Bernoulli arms with
means U[0, 1] drawn per seed, constant α, T rounds, S seeds; every round samples one arm by
inverse CDF with one uniform, draws the reward, updates r̂, and accumulates the outputs of
``simulate.RunOutput`` (realised and Rao–Blackwellised regret, compensator Σπ, min π, counts)
on the log-spaced checkpoint grid.

Four ways of running that same workload, in one process:

* ``run_seeds``: ``executor.run_seeds``, the entry point users call: it picks the fast runner
  below and, on CPU, runs one jitted call per core at once (a compiled call uses one core
  there), copying outputs to NumPy; timed end to end;
* ``fast``: :mod:`sern_jax.fast_softmax` as one jitted call (one core on CPU; exact, same
  random streams as the general runner);
* ``general``: ``executor.batched_runner(config)`` = ``jit(vmap(simulate.make_run(config)))``,
  the engine's general runner;
* ``numpy``: a NumPy reference vectorised over seeds with a Python loop over t (float32,
  inverse CDF with one uniform per round, the same outputs); it may run fewer seeds
  (``--numpy-seeds``).

Compile time (``.lower().compile()``) is measured separately and excluded from throughput;
each figure is the median of ``--repeats`` timed runs ending in ``block_until_ready``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time

import numpy as np

from sern_jax import io

__all__ = ["add_parser", "run", "numpy_reference"]


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Registers ``bandit`` under ``sern bench``."""
    p = subparsers.add_parser(
        "bandit",
        help="SERN softmax throughput (JAX fast/general paths vs NumPy) on one workload",
        description=__doc__.split("\n\n")[0] + " Prints one JSON object with --json.",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--arms", type=int, default=64, help="K (default 64)")
    p.add_argument("--horizon", type=int, default=10_000, help="T (default 10,000)")
    p.add_argument("--seeds", type=int, default=10_000, help="S for JAX (default 10,000)")
    p.add_argument("--alpha", type=float, default=0.05, help="constant α (default 0.05)")
    p.add_argument("--repeats", type=int, default=3, help="timed runs per path (median)")
    p.add_argument("--numpy-seeds", type=int, default=1000,
                   help="seeds of the NumPy reference (default 1,000; 0 skips it)")
    p.add_argument("--general-repeats", type=int, default=1,
                   help="timed runs of the general runner (default 1; 0 skips it)")
    p.add_argument("--devices", type=int, default=0,
                   help="shard the seed axis over this many devices (0: one device)")
    p.add_argument("--chunk", type=int, default=-1,
                   help="seeds per lax.map step of the fast path (-1: 256 on CPU, all on "
                        "GPU; 0: all)")
    p.add_argument("--seed", type=int, default=0, help="root seed")
    p.set_defaults(func=run)
    return p


# ----------------------------------------------------------------------------- NumPy reference


def numpy_reference(num_seeds: int, num_arms: int, horizon: int, alpha: float,
                    checkpoints: np.ndarray, seed: int = 0) -> dict[str, np.ndarray]:
    """The same workload in NumPy: vectorised over seeds, a Python loop over rounds.

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


# ----------------------------------------------------------------------------- helpers


def _stats(times: list[float]) -> dict[str, float]:
    return {"median_s": statistics.median(times), "min_s": min(times), "max_s": max(times),
            "times_s": [round(x, 4) for x in times]}


def _mean_se(x: np.ndarray) -> tuple[float, float]:
    x = np.asarray(x, np.float64)
    return float(x.mean()), float(x.std(ddof=1) / np.sqrt(x.size)) if x.size > 1 else 0.0


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _validate(args) -> None:
    for name, value, low in (("--arms", args.arms, 2), ("--horizon", args.horizon, 1),
                             ("--seeds", args.seeds, 1), ("--repeats", args.repeats, 1),
                             ("--numpy-seeds", args.numpy_seeds, 0),
                             ("--general-repeats", args.general_repeats, 0),
                             ("--devices", args.devices, 0), ("--chunk", args.chunk, -1)):
        if value < low:
            raise ValueError(f"{name} must be >= {low}, got {value}")
    if not (args.alpha > 0 and np.isfinite(args.alpha)):
        raise ValueError(f"--alpha must be finite and > 0, got {args.alpha}")
    if args.numpy_seeds == 1:
        raise ValueError("--numpy-seeds must be 0 (skip) or >= 2 (for a standard error)")
    for name, value, high in (("--arms", args.arms, 2**20), ("--seeds", args.seeds, 2**31 - 1),
                              ("--numpy-seeds", args.numpy_seeds, 2**31 - 1),
                              ("--repeats", args.repeats, 1000),
                              ("--general-repeats", args.general_repeats, 1000),
                              ("--horizon", args.horizon, 2**24 - 1),
                              ("--seed", args.seed, 2**32 - 1)):
        if value > high:
            raise ValueError(f"{name} must be <= {high}, got {value}")
    if args.seed < 0:
        raise ValueError(f"--seed must be >= 0, got {args.seed}")


def _check_memory(args, config) -> None:
    """Refuses a workload whose outputs and per-seed state cannot fit in this machine's memory."""
    from sern_jax import executor

    need = args.seeds * executor.bytes_per_seed(config)
    need += args.numpy_seeds * (4 * args.arms + 64) * 8  # the NumPy reference's state
    avail = executor.available_memory_bytes()
    if need > avail:
        raise ValueError(
            f"--seeds {args.seeds} x --arms {args.arms} needs about {need / 2**30:.3g} GiB of "
            f"outputs and state, more than the {avail / 2**30:.3g} GiB available")


# ----------------------------------------------------------------------------- main


def run(args) -> int:
    """Runs the benchmark; prints one JSON object (``--json``) or a short table."""
    _validate(args)
    load_before = os.getloadavg()
    import jax

    from sern_jax import executor, fast_softmax, problems, sharding
    from sern_jax import simulate as sim

    config = sim.RunConfig(policy="softmax", estimator="addhalf", schedule="constant",
                           num_arms=args.arms, horizon=args.horizon, random_means=True)
    # random_means=True: each seed draws its own U[0,1] means; the problem only fixes K.
    params = sim.default_params(config, problems.bernoulli(np.full(args.arms, 0.5)),
                                alpha0=args.alpha)
    sim.validate(config, params, args.seeds)
    _check_memory(args, config)
    if not fast_softmax.supports(config, params):
        raise ValueError(f"alpha={args.alpha} is below the fast path's minimum "
                         f"{fast_softmax.min_alpha(config.dtype)} for float32")
    backend = jax.default_backend()
    mesh = None
    num_devices = 1
    if args.devices:
        mesh = sharding.seed_mesh(args.devices)
        num_devices = args.devices
    chunk_target = args.chunk if args.chunk >= 0 else (
        fast_softmax.DEFAULT_CPU_CHUNK if backend == "cpu" else 0)
    chunk, padded = fast_softmax.chunk_layout(args.seeds, chunk_target, num_devices)
    root = jax.random.key(args.seed)
    work = args.seeds * args.horizon  # seed-rounds counted: padding seeds are not

    def put(keys):
        if mesh is None:
            return keys
        spec = jax.sharding.PartitionSpec(mesh.axis_names[0])
        return jax.device_put(keys, jax.sharding.NamedSharding(mesh, spec))

    def timed(compiled, keys, repeats):
        times, out = [], None
        for _ in range(repeats):
            t0 = time.perf_counter()
            out = compiled(keys, params)
            jax.block_until_ready(out)
            times.append(time.perf_counter() - t0)
        return times, out

    result: dict = {"benchmark": "sern bench bandit", "workload": {
        "policy": "softmax", "estimator": "addhalf", "num_arms": args.arms,
        "horizon": args.horizon, "seeds": args.seeds, "alpha": args.alpha,
        "random_means": "U[0,1] per seed", "dtype": "float32",
        "checkpoints": int(sim.checkpoint_times(config).size)}}

    # ---- fast path
    fast_fn = jax.jit(fast_softmax.make_batched(config, chunk=chunk, mesh=mesh))
    fast_keys = put(sim.seed_keys(root, padded))
    t0 = time.perf_counter()
    fast_c = fast_fn.lower(fast_keys, params).compile()
    fast_compile = time.perf_counter() - t0
    fast_times, fast_out = timed(fast_c, fast_keys, args.repeats)
    fast_out = jax.tree.map(lambda x: np.asarray(x)[:args.seeds], fast_out)
    fast_rate = work / statistics.median(fast_times)
    result["fast"] = {"engine_path": "sern_jax.fast_softmax.make_batched", "chunk": chunk,
                      "padded_seeds": padded, "compile_s": fast_compile,
                      "seed_rounds_per_s": fast_rate, **_stats(fast_times)}

    # ---- run_seeds: the public entry point users call (the fast runner here, with one call per
    # CPU core at once, outputs copied to NumPy): timed end to end, compile apart
    plan = executor.plan_run(config, params, args.seeds, mesh=mesh)
    t0 = time.perf_counter()
    plan.fn.lower(jax.ShapeDtypeStruct((plan.chunk,), root.dtype), params).compile()
    rs_compile = time.perf_counter() - t0
    rs_times, rs_out = [], None
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        rs_out = executor.run_seeds(config, params, args.seed, args.seeds, mesh=mesh)
        rs_times.append(time.perf_counter() - t0)
    rs_rate = work / statistics.median(rs_times)
    result["run_seeds"] = {"engine_path": "sern_jax.executor.run_seeds", "fast": plan.fast,
                           "seeds_per_call": plan.chunk, "concurrent_calls": plan.workers,
                           "compile_s": rs_compile, "seed_rounds_per_s": rs_rate,
                           **_stats(rs_times)}
    result["fast"]["concurrent_calls"] = 1

    # ---- general path
    general_rate = None
    general_out = None
    if args.general_repeats:
        general_fn = executor.batched_runner(config, mesh)
        g_seeds = -(-args.seeds // num_devices) * num_devices
        g_keys = put(sim.seed_keys(root, g_seeds))
        t0 = time.perf_counter()
        general_c = general_fn.lower(g_keys, params).compile()
        general_compile = time.perf_counter() - t0
        g_times, general_out = timed(general_c, g_keys, args.general_repeats)
        general_out = jax.tree.map(lambda x: np.asarray(x)[:args.seeds], general_out)
        general_rate = work / statistics.median(g_times)
        result["general"] = {"engine_path": "sern_jax.simulate.make_run (jit(vmap))",
                             "compile_s": general_compile, "seed_rounds_per_s": general_rate,
                             **_stats(g_times)}

    # ---- NumPy reference
    numpy_rate = None
    numpy_out = None
    if args.numpy_seeds:
        np_times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            numpy_out = numpy_reference(args.numpy_seeds, args.arms, args.horizon, args.alpha,
                                        sim.checkpoint_times(config), seed=args.seed)
            np_times.append(time.perf_counter() - t0)
        numpy_rate = args.numpy_seeds * args.horizon / statistics.median(np_times)
        result["numpy"] = {"seeds": args.numpy_seeds, "seed_rounds_per_s": numpy_rate,
                           "dtype": "float32", **_stats(np_times)}

    # ---- agreement of mean regret (different random streams: compare with standard errors)
    agree: dict = {}
    fm, fse = _mean_se(fast_out.regret[:, -1])
    agree["fast_mean_regret_T"] = fm
    agree["fast_se"] = fse
    fm_rb, fse_rb = _mean_se(fast_out.regret_rb[:, -1])
    agree["fast_mean_regret_rb_T"] = fm_rb
    agree["run_seeds_counts_equal_fast"] = bool(np.array_equal(rs_out.counts, fast_out.counts))
    if general_out is not None:
        gm, gse = _mean_se(general_out.regret[:, -1])
        agree["general_mean_regret_T"] = gm
        agree["general_se"] = gse
        agree["fast_general_counts_identical_fraction"] = float(np.mean(np.all(
            fast_out.counts[:, -1] == general_out.counts[:, -1], axis=-1)))
    if numpy_out is not None:
        nm, nse = _mean_se(numpy_out["regret"][:, -1])
        agree["numpy_mean_regret_T"] = nm
        agree["numpy_se"] = nse
        agree["numpy_mean_regret_rb_T"] = _mean_se(numpy_out["regret_rb"][:, -1])[0]
        agree["z_fast_vs_numpy"] = (fm - nm) / max(np.hypot(fse, nse), 1e-12)
    result["regret_agreement"] = agree

    # ---- headline
    rates = {"fast": fast_rate, "run_seeds": rs_rate, "general": general_rate}
    best_path = max((k for k, v in rates.items() if v is not None), key=rates.get)
    best_rate = rates[best_path]
    devices = jax.devices()[:num_devices]
    result.update({
        "seed_rounds_per_s": best_rate,
        "engine_path": result[best_path]["engine_path"],
        "compile_s": result[best_path]["compile_s"],
        "best_path": best_path,
        "fast_seed_rounds_per_s": fast_rate,
        "run_seeds_seed_rounds_per_s": rs_rate,
        "run_seeds_concurrent_calls": plan.workers,
        "general_seed_rounds_per_s": general_rate,
        "numpy_seed_rounds_per_s": numpy_rate,
        "numpy_seeds": args.numpy_seeds,
        "speedup_vs_numpy": best_rate / numpy_rate if numpy_rate else None,
        "general_speedup_vs_numpy": (general_rate / numpy_rate
                                     if numpy_rate and general_rate else None),
        "repeats": args.repeats,
        "general_repeats": args.general_repeats,
        "peak_rss_mb": io.peak_rss_mb(),
        "machine": {"cpu": _cpu_model(), "cpu_count": os.cpu_count(),
                    "platform": platform.platform(), "python": platform.python_version(),
                    "loadavg_before": [round(x, 2) for x in load_before],
                    "loadavg_after": [round(x, 2) for x in os.getloadavg()]},
        "device": {"backend": backend, "num_devices": num_devices,
                   "kind": devices[0].device_kind, "devices": [str(d) for d in devices]},
        "jax_version": jax.__version__,
        "jax_threefry_partitionable": bool(jax.config.jax_threefry_partitionable),
    })
    if args.json:
        print(json.dumps(result, default=float))
        return 0
    print(f"sern bench bandit: K={args.arms} T={args.horizon} S={args.seeds} α={args.alpha} "
          f"on {backend} ({devices[0].device_kind} ×{num_devices})")
    print(f"{'path':10s} {'seeds':>7s} {'seed-rounds/s':>15s} {'compile s':>10s} "
          f"{'median s':>9s} {'mean R_T':>10s}")
    rows = [("run_seeds", args.seeds, rs_rate, rs_compile, result["run_seeds"]["median_s"],
             _mean_se(rs_out.regret[:, -1])[0]),
            ("fast", args.seeds, fast_rate, fast_compile, result["fast"]["median_s"], fm)]
    if general_rate is not None:
        rows.append(("general", args.seeds, general_rate, result["general"]["compile_s"],
                     result["general"]["median_s"], agree["general_mean_regret_T"]))
    if numpy_rate is not None:
        rows.append(("numpy", args.numpy_seeds, numpy_rate, float("nan"),
                     result["numpy"]["median_s"], agree["numpy_mean_regret_T"]))
    for name, seeds, rate, comp, med, reg in rows:
        print(f"{name:10s} {seeds:7d} {rate:15,.0f} {comp:10.2f} {med:9.3f} {reg:10.2f}")
    if numpy_rate:
        print(f"speed-up of the best path ({best_path}) vs NumPy: "
              f"{result['speedup_vs_numpy']:.1f}×; run_seeds ran {plan.workers} call(s) at "
              f"once, fast and numpy one; "
              f"peak RSS {result['peak_rss_mb']:.0f} MB")
    sys.stdout.flush()
    return 0
