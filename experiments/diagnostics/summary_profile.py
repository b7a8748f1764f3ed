"""Where the time between the fast engine and run_seeds(summary=True) goes.

Times, in one process, the engine alone, the summary reduction alone (on materialised
outputs), its parts, the fused summary call, the key derivation, the host statistics, and
run_seeds(summary=True) end to end; then variants of the compensated sum (barriers every L
halving levels) that must give bit-identical sums. Prints one JSON line.

Written against the summary code of commit 959f9af (``executor.*`` names; since the layout by
role the driver is sern_jax.engine.drive and the reduction sern_jax.engine.summary).
Run from the repository root:
    python experiments/diagnostics/summary_profile.py [SEEDS]
Record: experiments/results/bench/profile_summary_h100.json (SEEDS 200000).
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
    jax.block_until_ready(fn())  # warm-up (compile)
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        ts.append(time.perf_counter() - t0)
    return {"median_ms": 1e3 * float(np.median(ts)), "times_ms": [round(1e3 * t, 3) for t in ts]}


def compensated_sum_every(x, every):
    """executor.compensated_sum with an optimization barrier every ``every`` levels."""
    s, c = x, jnp.zeros_like(x)
    rest = []
    level = 0
    while s.shape[0] > 1:
        if s.shape[0] % 2:
            rest.append((s[-1], c[-1]))
            s, c = s[:-1], c[:-1]
        h = s.shape[0] // 2
        s, e = summary._two_sum(s[:h], s[h:])
        c = c[:h] + c[h:] + e
        level += 1
        if level % every == 0:
            s, c = jax.lax.optimization_barrier((s, c))
    total, comp = s[0], c[0]
    for s_r, c_r in rest:
        total, e = summary._two_sum(total, s_r)
        comp = comp + c_r + e
    return total + comp


def main():
    seeds = int(sys.argv[1]) if len(sys.argv) > 1 else 200_000
    res = {"command": " ".join(sys.argv), "machine": io.machine(devices=True),
           "jax": jax.__version__, "seeds": seeds}
    t_start = time.perf_counter()
    w = benchmarks.BanditWorkload(seeds=seeds)
    s = benchmarks.bandit_setup(w)
    config, params = s.config, s.params
    keys = sim.seed_keys(s.root, seeds)
    engine = jax.jit(fast_softmax.make_batched(config, chunk=None))
    res["engine"] = timeit(lambda: engine(keys, params))
    out = engine(keys, params)
    edges = executor.summary_edges(config)
    n = jnp.asarray(seeds, jnp.int32)
    summ = jax.jit(lambda o, n: executor.summarize_outputs(o, n, edges))
    res["reduce_only"] = timeit(lambda: summ(out, n))
    # parts, on the counts field ([S, G, K])
    x = out.counts.astype(jnp.float32)
    valid = jnp.arange(seeds) < n
    f_cs = jax.jit(lambda x: executor.compensated_sum(jnp.where(valid[:, None, None], x, 0.0)))
    res["counts_compsum"] = timeit(lambda: f_cs(x))
    f_mm = jax.jit(lambda x: (jnp.min(x, 0), jnp.max(x, 0)))
    res["counts_minmax"] = timeit(lambda: f_mm(x))
    f_ps = jax.jit(lambda x: jnp.sum(x, 0))
    res["counts_plainsum"] = timeit(lambda: f_ps(x))
    e = jnp.asarray(edges["counts"], jnp.float32)

    def hist(x):
        x3 = x.reshape(seeds, x.shape[1], -1)
        idx = summary._bin_index(x3, e, jnp.float32)
        bins = e.shape[1] - 1
        cols = jnp.arange(x3.shape[1] * x3.shape[2], dtype=jnp.int32).reshape(x3.shape[1:])
        flat = cols[None] * bins + idx
        return jnp.zeros(x3.shape[1] * x3.shape[2] * bins, jnp.int32).at[flat.reshape(-1)].add(1)
    f_h = jax.jit(hist)
    res["counts_hist"] = timeit(lambda: f_h(x))
    for every in (1, 2, 3, 4, 6):
        f = jax.jit(lambda x, every=every: compensated_sum_every(
            jnp.where(valid[:, None, None], x, 0.0), every))
        t0 = time.perf_counter()
        jax.block_until_ready(f(x))
        comp_s = time.perf_counter() - t0
        ref = jax.jit(lambda x: executor.compensated_sum(jnp.where(valid[:, None, None], x, 0.0)))(x)
        same = bool(jnp.all(f(x) == ref))
        xc = out.compensator
        fc = jax.jit(lambda x, every=every: compensated_sum_every(x, every))
        same_c = bool(jnp.all(fc(xc) == jax.jit(executor.compensated_sum)(xc)))
        res[f"compsum_every{every}"] = {**timeit(lambda: f(x)), "first_call_s": comp_s,
                                         "bit_identical_counts": same,
                                         "bit_identical_compensator": same_c}
    del out, x
    plan = executor.plan_run(config, params, seeds, summary=True)
    res["plan"] = {"chunk": plan.chunk, "workers": plan.workers, "fast": plan.fast}
    res["fused_summary_call"] = timeit(lambda: plan.fn(keys, params, n))
    res["seed_keys_eager"] = timeit(lambda: sim.seed_keys(s.root, seeds))
    sk = jax.jit(lambda r, st: jax.vmap(lambda i: jax.random.fold_in(r, i))(jnp.arange(seeds, dtype=jnp.uint32) + st))
    res["seed_keys_jit"] = timeit(lambda: sk(s.root, jnp.uint32(0)))
    dev = plan.fn(keys, params, n)
    jax.block_until_ready(dev)
    res["host_stats"] = timeit(lambda: summary.host_stats(dev, seeds, edges))
    res["run_seeds_summary"] = timeit(
        lambda: executor.run_seeds(config, params, 0, seeds, summary=True), repeats=3)
    # the fused summary with barriers every 4 levels (executor.compensated_sum swapped)
    orig = executor.compensated_sum
    for every in (3, 6):
        executor.compensated_sum = lambda x, every=every: compensated_sum_every(x, every)
        f_var = jax.jit(lambda k, p, n: executor.summarize_outputs(engine(k, p), n, edges))
        res[f"fused_summary_every{every}"] = timeit(lambda: f_var(keys, params, n))
        new = jax.device_get(f_var(keys, params, n))
        executor.compensated_sum = orig
        ref = jax.device_get(dev)
        res[f"fused_summary_every{every}_identical"] = all(
            bool(np.array_equal(a, b, equal_nan=True)) for a, b in
            zip(jax.tree.leaves(new), jax.tree.leaves(ref)))
    res["wall_s"] = time.perf_counter() - t_start
    print(json.dumps(res))


if __name__ == "__main__":
    main()
