"""The on-device summary reduction before and after its integer-count rewrite.

Profiles executor.summarize_outputs as of commit 959f9af against the rewrite of commit 2f59c8b
(counts: exact int32 partial sums for the mean, bins looked up in a table, padding dropped by
the scatter), each fused with the engine, then run_seeds(summary=True) end to end, and the
engine with lax.map chunks of seeds. Prints one JSON line.

Written against the summary code of commit 2f59c8b (``executor.*`` names; since the layout by
role the driver is sern_jax.engine.drive and the reduction sern_jax.engine.summary).
Run from the repository root:
    python experiments/diagnostics/summary_reduction_profile.py [SEEDS]
Record: experiments/results/bench/profile_summary2_h100.json (SEEDS 200000).
"""
import json
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from sern_jax.bench import bandit as benchmarks
from sern_jax.engine import drive as executor, fast_softmax, summary
from sern_jax.infra import io
from sern_jax.engine import simulate as sim


def timeit(fn, repeats=3):
    t0 = time.perf_counter()
    jax.block_until_ready(fn())  # warm-up (compile)
    first = time.perf_counter() - t0
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        ts.append(time.perf_counter() - t0)
    return {"median_ms": 1e3 * float(np.median(ts)), "times_ms": [round(1e3 * t, 3) for t in ts],
            "first_s": round(first, 3)}


def old_summarize_outputs(out, num_valid, edges):
    """executor.summarize_outputs as of commit 959f9af (before this change)."""
    dtype = out.regret.dtype
    size = out.regret.shape[0]
    valid = jnp.arange(size) < num_valid
    n = num_valid.astype(dtype)
    stats = {}
    for field in executor.SUMMARY_FIELDS:
        x = getattr(out, field).astype(dtype)
        mask = valid.reshape((size,) + (1,) * (x.ndim - 1))
        mean = executor.compensated_sum(jnp.where(mask, x, 0.0)) / n
        m2 = executor.compensated_sum(jnp.where(mask, jnp.square(x - mean[None]), 0.0))
        lo = jnp.min(jnp.where(mask, x, jnp.inf), axis=0)
        hi = jnp.max(jnp.where(mask, x, -jnp.inf), axis=0)
        hist = None
        if executor.SUMMARY_BINS[field]:
            e = jnp.asarray(edges[field], dtype)
            bins = e.shape[1] - 1
            x3 = x.reshape(size, x.shape[1], -1)
            idx = summary._bin_index(x3, e, dtype)
            cols = jnp.arange(x3.shape[1] * x3.shape[2], dtype=jnp.int32).reshape(x3.shape[1:])
            flat = cols[None] * bins + idx
            weight = jnp.broadcast_to(valid[:, None, None], x3.shape).astype(jnp.int32)
            hist = jnp.zeros(x3.shape[1] * x3.shape[2] * bins, jnp.int32).at[
                flat.reshape(-1)].add(weight.reshape(-1)).reshape(x.shape[1:] + (bins,))
        stats[field] = (mean, m2, lo, hi, hist)
    return stats


def main():
    seeds = int(sys.argv[1]) if len(sys.argv) > 1 else 200_000
    res = {"command": " ".join(sys.argv), "machine": io.machine(devices=True),
           "jax": jax.__version__, "seeds": seeds}
    t_start = time.perf_counter()
    w = benchmarks.BanditWorkload(seeds=seeds)
    s = benchmarks.bandit_setup(w)
    config, params = s.config, s.params
    keys = sim.seed_keys(s.root, seeds)
    edges = executor.summary_edges(config)
    n = jnp.asarray(seeds - 3, jnp.int32)  # 3 padding seeds: the masks matter
    engine = jax.jit(fast_softmax.make_batched(config, chunk=None))
    res["engine"] = timeit(lambda: engine(keys, params))
    out = engine(keys, params)
    f_old = jax.jit(lambda o, n: old_summarize_outputs(o, n, edges))
    f_new = jax.jit(lambda o, n: executor.summarize_outputs(o, n, edges))
    res["reduce_only_old"] = timeit(lambda: f_old(out, n))
    res["reduce_only_new"] = timeit(lambda: f_new(out, n))
    a, b = jax.device_get(f_old(out, n)), jax.device_get(f_new(out, n))
    b = {k: tuple(v) for k, v in b.items()}
    res["new_vs_old"] = {
        f"{k}.{name}": ("equal" if np.array_equal(x, y, equal_nan=True) else
                        float(np.nanmax(np.abs(np.asarray(x, np.float64) - y))))
        for k in a for name, x, y in zip(("mean", "m2", "min", "max", "hist"), a[k], b[k])
        if x is not None}
    del out
    g_old = jax.jit(lambda k, p, n: old_summarize_outputs(engine(k, p), n, edges))
    g_new = jax.jit(lambda k, p, n: executor.summarize_outputs(engine(k, p), n, edges))
    for rep in range(2):  # interleaved
        res[f"fused_old_{rep}"] = timeit(lambda: g_old(keys, params, n))
        res[f"fused_new_{rep}"] = timeit(lambda: g_new(keys, params, n))
    res["run_seeds_summary_new"] = timeit(
        lambda: executor.run_seeds(config, params, 0, seeds, summary=True), repeats=5)
    for chunk in (50_000, 25_000):
        eng = jax.jit(fast_softmax.make_batched(config, chunk=chunk))
        res[f"engine_chunk{chunk}"] = timeit(lambda: eng(keys, params))
        del eng
    res["engine_again"] = timeit(lambda: engine(keys, params))
    res["wall_s"] = time.perf_counter() - t_start
    print(json.dumps(res))


if __name__ == "__main__":
    main()
