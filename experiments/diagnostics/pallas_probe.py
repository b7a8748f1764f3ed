"""The fused Pallas kernel (sern_jax.engine.pallas_softmax) against the fast engine on a GPU.

In one process:

1. the order of XLA's cumsum on this GPU vs a left-to-right float32 prefix sum (what decides
   whether the kernel's rebase can equal the engine's bit for bit);
2. small-size validation (K = 64, T = 2,000, 4,096 seeds): each kernel variant against
   ``fast_softmax.make_batched`` (same keys): fraction of seeds whose counts equal at every
   checkpoint, max |diff| of the float outputs;
3. timing at the benchmark's workload (K = 64, T = 10^4, 200,000 seeds, α = 0.05, add-half,
   U[0,1] means per seed, 30 checkpoints): the engine's fast path (one jitted call, as
   ``sern bench bandit``'s ``fast``) and each kernel variant, compile excluded, one warm-up
   run, then ``repeats`` timed runs (median), outputs blocked on; plus the full-size agreement.

Needs an NVIDIA GPU. Run from the repository root:
    python experiments/diagnostics/pallas_probe.py OUT.json [configs]
Records: experiments/results/bench/pallas_probe_h100_{1,2,3}.json (see pallas_README.md there).
"""

from __future__ import annotations

import json
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from sern_jax.engine import fast_softmax, pallas_softmax
from sern_jax.infra import io, timing
from sern_jax.core import problems
from sern_jax.engine import simulate as sim


def log(*a):
    print(f"[{time.strftime('%H:%M:%S')}]", *a, flush=True)


def setup(horizon, seeds, arms=64, alpha=0.05):
    config = sim.RunConfig(policy="softmax", estimator="addhalf", schedule="constant",
                           num_arms=arms, horizon=horizon, random_means=True)
    params = sim.default_params(config, problems.bernoulli(np.full(arms, 0.5)), alpha0=alpha)
    keys = sim.seed_keys(jax.random.key(0), seeds)
    return config, params, keys


def compare(a, b):
    a = jax.tree.map(np.asarray, a)
    b = jax.tree.map(np.asarray, b)
    same = np.all(a.counts == b.counts, axis=(1, 2))
    d = {"seeds": int(same.size), "counts_equal_fraction": float(same.mean()),
         "final_counts_equal_fraction": float(np.mean(np.all(a.counts[:, -1] == b.counts[:, -1],
                                                             axis=-1)))}
    for f in ("regret", "regret_rb", "compensator", "min_prob"):
        x, y = getattr(a, f), getattr(b, f)
        d[f"{f}_max_abs_diff"] = float(np.max(np.abs(x.astype(np.float64) - y)))
        d[f"{f}_max_abs_diff_equal_counts"] = (float(np.max(np.abs(
            x[same].astype(np.float64) - y[same]))) if same.any() else None)
    d["mean_regret_T"] = [float(a.regret[:, -1].mean()), float(b.regret[:, -1].mean())]
    return d


def tiled_numpy(x, tile):
    """Left-to-right float32 prefix sums within tiles, plus the left-to-right exclusive
    prefix of the tile totals (XLA's ReduceWindowRewriter order; tile = K: plain)."""
    n, k = x.shape
    inner = np.zeros_like(x)
    for c in range(0, k, tile):
        acc = np.zeros(n, np.float32)
        for j in range(c, min(c + tile, k)):
            acc = (acc + x[:, j]).astype(np.float32)
            inner[:, j] = acc
    out = inner.copy()
    carry = np.zeros(n, np.float32)
    for c in range(tile, k, tile):
        carry = (carry + inner[:, c - 1]).astype(np.float32)
        out[:, c:c + tile] = (inner[:, c:c + tile] + carry[:, None]).astype(np.float32)
    return out


def cumsum_probe():
    x = jax.random.uniform(jax.random.key(5), (65536, 64), jnp.float32) + 1e-3
    xla = np.asarray(jax.jit(lambda v: jnp.cumsum(v, axis=1))(x))
    xn = np.asarray(x)
    res = {}
    for tile in (64, 32, 16, 8):
        cand = tiled_numpy(xn, tile)
        res[f"xla_cumsum_equals_tiled{tile}_fraction"] = float(np.mean(xla == cand))
    return res


def main():
    out_path = sys.argv[1]
    variants = [tuple(v.split(":")) for v in (sys.argv[2].split(",") if len(sys.argv) > 2
                                             else ["32:4:scan"])]
    repeats = int(sys.argv[3]) if len(sys.argv) > 3 else 3
    result = {"script": "experiments/diagnostics/pallas_probe.py",
              "argv": sys.argv[1:], "jax_version": jax.__version__,
              "device": str(jax.devices()[0].device_kind), "machine": io.machine()}
    log("devices", jax.devices())
    result["cumsum_probe"] = cumsum_probe()
    log("cumsum", result["cumsum_probe"])

    # ---- small validation
    config, params, keys = setup(2000, 4096)
    eng = jax.jit(fast_softmax.make_batched(config))(keys, params)
    val = {}
    for b, nw, mode in variants:
        name = f"B{b}_w{nw}_{mode}"
        try:
            fn = jax.jit(pallas_softmax.make_pallas_run(
                config, seeds_per_program=int(b), num_warps=int(nw), rebase=mode))
            t0 = time.perf_counter()
            got = jax.block_until_ready(fn(keys, params))
            val[name] = {"first_call_s": time.perf_counter() - t0, **compare(got, eng)}
        except Exception as e:  # record the exact error, go on with the others
            val[name] = {"error": f"{type(e).__name__}: {str(e)[:2000]}"}
        log("validate", name, val[name])
    result["validate_T2000_S4096"] = val
    del eng

    # ---- timing at the benchmark workload
    horizon, seeds = 10_000, 200_000
    config, params, keys = setup(horizon, seeds)
    work = horizon * seeds
    timed = {}
    fast = jax.jit(fast_softmax.make_batched(config))
    t0 = time.perf_counter()
    comp = fast.lower(keys, params).compile()
    compile_s = time.perf_counter() - t0
    t = timing.time_calls(lambda: comp(keys, params), repeats, warmup=1)
    eng_out = jax.tree.map(np.asarray, t.result)
    timed["engine_fast"] = {"compile_s": compile_s, "seed_rounds_per_s": work / t.median_s,
                            **t.stats()}
    log("engine", timed["engine_fast"])
    for b, nw, mode in variants:
        name = f"B{b}_w{nw}_{mode}"
        if "error" in val.get(name, {}):
            continue
        fn = jax.jit(pallas_softmax.make_pallas_run(
            config, seeds_per_program=int(b), num_warps=int(nw), rebase=mode))
        t0 = time.perf_counter()
        comp = fn.lower(keys, params).compile()
        compile_s = time.perf_counter() - t0
        t = timing.time_calls(lambda: comp(keys, params), repeats, warmup=1)
        timed[name] = {"compile_s": compile_s, "seed_rounds_per_s": work / t.median_s,
                       **t.stats(), "agreement": compare(t.result, eng_out)}
        log("kernel", name, timed[name])
        with open(out_path, "w") as fh:
            json.dump({**result, "timed_K64_T10000_S200000": timed}, fh, indent=1)
    result["timed_K64_T10000_S200000"] = timed
    with open(out_path, "w") as fh:
        json.dump(result, fh, indent=1)
    log("done")


if __name__ == "__main__":
    main()
