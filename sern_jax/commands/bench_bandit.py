"""``sern bench bandit``: seed-rounds per second of SERN softmax, side by side with NumPy.

The workload, the four ways of running it (``run_seeds``, ``fast``, ``general``, ``numpy``) and
the JSON fields are :mod:`sern_jax.bench.bandit` (``bandit_benchmark``); this module parses and
checks the flags, calls it, and prints one JSON object (``--json``) or a short table.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

__all__ = ["add_parser", "run"]


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Registers ``bandit`` under ``sern bench``."""
    p = subparsers.add_parser(
        "bandit",
        help="SERN softmax throughput (JAX fast/general paths vs NumPy) on one workload",
        description="Seed-rounds per second of SERN softmax, side by side with NumPy "
                    "(sern_jax.bench.bandit.bandit_benchmark). Prints one JSON object with --json.",
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
    p.add_argument("--policy", default="softmax",
                   help="SERN softmax (default) or Beta-Bernoulli Thompson sampling")
    p.add_argument("--naive-repeats", type=int, default=1,
                   help="timed runs of the naive jit(vmap(scan)) JAX peer (default 1; 0 skips)")
    p.add_argument("--summary-repeats", type=int, default=-1,
                   help="timed runs of run_seeds(summary=True) (-1: --repeats; 0 skips)")
    p.add_argument("--smpybandits-seeds", type=int, default=0,
                   help="seeds of SMPyBandits' Thompson on the same instance, one at a time "
                        "(--policy thompson; needs SMPyBandits installed; default 0 skips)")
    p.add_argument("--pallas", action="store_true",
                   help="also time the fused Pallas kernel (sern_jax.engine.pallas_softmax; softmax, "
                        "one GPU) and compare its outputs with the fast path's seed by seed")
    p.set_defaults(func=run)
    return p


def _validate(args) -> None:
    for name, value, low in (("--arms", args.arms, 2), ("--horizon", args.horizon, 1),
                             ("--seeds", args.seeds, 1), ("--repeats", args.repeats, 1),
                             ("--numpy-seeds", args.numpy_seeds, 0),
                             ("--general-repeats", args.general_repeats, 0),
                             ("--naive-repeats", args.naive_repeats, 0),
                             ("--summary-repeats", args.summary_repeats, -1),
                             ("--smpybandits-seeds", args.smpybandits_seeds, 0),
                             ("--devices", args.devices, 0), ("--chunk", args.chunk, -1)):
        if value < low:
            raise ValueError(f"{name} must be >= {low}, got {value}")
    if args.policy not in ("softmax", "thompson"):
        raise ValueError(f"--policy must be softmax or thompson, got {args.policy!r}")
    if not (args.alpha > 0 and np.isfinite(args.alpha)):
        raise ValueError(f"--alpha must be finite and > 0, got {args.alpha}")
    if args.numpy_seeds == 1:
        raise ValueError("--numpy-seeds must be 0 (skip) or >= 2 (for a standard error)")
    if args.smpybandits_seeds == 1:
        raise ValueError("--smpybandits-seeds must be 0 (skip) or >= 2 (for a standard error)")
    if args.smpybandits_seeds and args.policy != "thompson":
        raise ValueError("--smpybandits-seeds needs --policy thompson (SMPyBandits' softmax "
                         "is not SERN's: it divides by 1 + N)")
    for name, value, high in (("--arms", args.arms, 2**20), ("--seeds", args.seeds, 2**31 - 1),
                              ("--numpy-seeds", args.numpy_seeds, 2**31 - 1),
                              ("--smpybandits-seeds", args.smpybandits_seeds, 2**31 - 1),
                              ("--repeats", args.repeats, 1000),
                              ("--general-repeats", args.general_repeats, 1000),
                              ("--naive-repeats", args.naive_repeats, 1000),
                              ("--summary-repeats", args.summary_repeats, 1000),
                              ("--horizon", args.horizon, 2**24 - 1),
                              ("--seed", args.seed, 2**32 - 1)):
        if value > high:
            raise ValueError(f"{name} must be <= {high}, got {value}")
    if args.seed < 0:
        raise ValueError(f"--seed must be >= 0, got {args.seed}")
    if args.smpybandits_seeds:
        from sern_jax.bench import bandit as benchmarks

        try:
            benchmarks.smpybandits_thompson()
        except ImportError as e:
            raise ValueError(f"--smpybandits-seeds: {e}") from None
    if args.pallas:
        if args.policy != "softmax":
            raise ValueError("--pallas needs --policy softmax (the kernel is SERN softmax's)")
        if args.devices > 1:
            raise ValueError("--pallas runs on one device: use --devices 0 or 1")
        from sern_jax.engine import pallas_softmax

        if not 2 <= args.arms <= pallas_softmax.MAX_ARMS or args.arms & (args.arms - 1):
            raise ValueError(f"--pallas needs --arms a power of two in [2, "
                             f"{pallas_softmax.MAX_ARMS}], got {args.arms}")
        import jax

        if jax.default_backend() != "gpu":
            raise ValueError(f"--pallas needs a GPU (backend {jax.default_backend()!r}); "
                             "off-GPU the kernel only runs in Pallas' slow interpreter")


def _workload(args):
    from sern_jax.bench import bandit as benchmarks

    return benchmarks.BanditWorkload(
        arms=args.arms, horizon=args.horizon, seeds=args.seeds, alpha=args.alpha,
        repeats=args.repeats, numpy_seeds=args.numpy_seeds,
        general_repeats=args.general_repeats, devices=args.devices, chunk=args.chunk,
        seed=args.seed, policy=args.policy, naive_repeats=args.naive_repeats,
        summary_repeats=args.summary_repeats, smpybandits_seeds=args.smpybandits_seeds,
        pallas=args.pallas)


def _check_memory(workload) -> None:
    """Refuses a workload whose outputs and per-seed state cannot fit in this machine's memory."""
    from sern_jax.bench import bandit as benchmarks
    from sern_jax.engine import drive as executor

    need = benchmarks.bandit_memory_bytes(workload)
    avail = executor.available_memory_bytes()
    if need > avail:
        raise ValueError(
            f"--seeds {workload.seeds} x --arms {workload.arms} needs about {need / 2**30:.3g} "
            f"GiB of outputs and state, more than the {avail / 2**30:.3g} GiB available")


def run(args) -> int:
    """Runs the benchmark; prints one JSON object (``--json``) or a short table."""
    _validate(args)
    from sern_jax.bench import bandit as benchmarks

    workload = _workload(args)
    _check_memory(workload)
    result = benchmarks.bandit_benchmark(workload)  # ValueError for an α the fast path can't run
    if args.json:
        print(json.dumps(result, default=float))
        return 0
    print(_table(result, workload))
    sys.stdout.flush()
    return 0


def _table(result: dict, w) -> str:
    dev = result["device"]
    agree = result["regret_agreement"]
    lines = [f"sern bench bandit ({w.policy}): K={w.arms} T={w.horizon} S={w.seeds} α={w.alpha} "
             f"on {dev['backend']} ({dev['kind']} ×{dev['num_devices']})",
             f"{'path':17s} {'seeds':>7s} {'seed-rounds/s':>15s} {'compile s':>10s} "
             f"{'median s':>9s} {'mean R_T':>10s}"]
    rows = [("run_seeds", w.seeds, "run_seeds_mean_regret_T"),
            ("run_seeds_summary", w.seeds, "run_seeds_summary_mean_regret_T"),
            ("fast", w.seeds, "fast_mean_regret_T"),
            ("naive_jax", w.seeds, "naive_jax_mean_regret_T"),
            ("general", w.seeds, "general_mean_regret_T"),
            ("numpy", w.numpy_seeds, "numpy_mean_regret_T"),
            ("smpybandits", w.smpybandits_seeds, "smpybandits_mean_regret_T"),
            ("pallas", w.seeds, "pallas_mean_regret_T")]
    for name, seeds, regret in rows:
        if name not in result:
            continue
        r = result[name]
        lines.append(f"{name:17s} {seeds:7d} {r['seed_rounds_per_s']:15,.0f} "
                     f"{r.get('compile_s', float('nan')):10.2f} {r['median_s']:9.3f} "
                     f"{agree[regret]:10.2f}")
    rs = result["run_seeds"]
    if "bound" in rs:
        lines.append(f"run_seeds per-seed outputs {rs['output_bytes'] / 1e6:.3g} MB: copy to "
                     f"host {rs['output_copy_s']:.4g} s ({rs['copy_fraction']:.0%} of the "
                     f"{rs['call_s']:.4g} s call, "
                     f"{rs['output_copy_bytes_per_s'] / 1e9:.3g} GB/s), compute alone "
                     f"{rs['compute_s']:.4g} s: bound by {rs['bound']}")
    if result["numpy_seed_rounds_per_s"]:
        lines.append(f"speed-up of the best path ({result['best_path']}) vs NumPy: "
                     f"{result['speedup_vs_numpy']:.1f}×; run_seeds ran "
                     f"{result['run_seeds_concurrent_calls']} call(s) at once, fast and numpy "
                     f"one; peak RSS {result['peak_rss_mb']:.0f} MB")
    return "\n".join(lines)
