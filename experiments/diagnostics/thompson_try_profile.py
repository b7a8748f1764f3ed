"""Where a Beta try of the fast Thompson runner spends its time on XLA:CPU.

Per lane and try, [256 seeds, 64 arms] in a 400-step fori_loop, one compiled call per
variant: a cheap LCG alone, the unrolled threefry alone, threefry + open_unit + prng.hold, the
BB/closed-form math on LCG uniforms, and the full prng.beta_try. Prints one line per variant
(ns per lane, minimum and median of 5 runs).

Run from the repository root:
    python experiments/diagnostics/thompson_try_profile.py
Record: experiments/results/bench/profile_thompson_try_2core.txt.
"""
import time, jax, jax.numpy as jnp, numpy as np
from sern_jax.core import prng
C, K, N = 256, 64, 400
lane = jnp.arange(K, dtype=jnp.uint32)[None, :]
k1 = jnp.arange(C, dtype=jnp.uint32)[:, None] * np.uint32(2654435761)
k2 = k1 ^ np.uint32(12345)
key = jax.random.key(0)
a = 1.0 + jnp.floor(jax.random.uniform(key, (C, K)) * 30)
b = 1.0 + jnp.floor(jax.random.uniform(jax.random.fold_in(key, 1), (C, K)) * 60)
def loop(body):
    def f(a, b):
        def it(i, acc):
            return acc + body(i.astype(jnp.uint32), a, b)
        return jax.lax.fori_loop(0, N, it, jnp.zeros((C, K), jnp.float32))
    return jax.jit(f)
def hash_only(i, a, b):
    w1, w2 = prng.threefry2x32(k1, k2, i, lane)
    return (w1 ^ w2).astype(jnp.float32)
def hash_held(i, a, b):
    w1, w2 = prng.threefry2x32(k1, k2, i, lane)
    return prng.hold(prng.open_unit(w1, jnp.float32)) + prng.hold(prng.open_unit(w2, jnp.float32))
def full(i, a, b):
    th, ok = prng.beta_try(k1, k2, a, b, i + jnp.zeros_like(lane), lane)
    return jnp.where(ok, th, 0.0)
def math_only(i, a, b):
    # uniforms from a cheap LCG instead of threefry
    x = (lane * np.uint32(747796405) + i * np.uint32(2891336453) + k1)
    w1 = x * np.uint32(277803737); w2 = w1 * np.uint32(747796405) + np.uint32(1)
    u1, u2 = prng.open_unit(w1, jnp.float32), prng.open_unit(w2, jnp.float32)
    # copy of beta_try's math on u1, u2
    lo, hi = jnp.minimum(a, b), jnp.maximum(a, b)
    log_u = jnp.log(u1)
    theta_one = jnp.where(a == 1.0, -jnp.expm1(log_u / b), jnp.exp(log_u / a))
    bb = lo > 1.0
    lo_s = jnp.where(bb, lo, 2.0); hi_s = jnp.where(bb, hi, 2.0)
    alpha = lo_s + hi_s
    beta = jnp.sqrt((alpha - 2.0) / (2.0 * lo_s * hi_s - alpha))
    gamma = lo_s + 1.0 / beta
    v = beta * jnp.log(u1 / (1.0 - u1)); w = lo_s * jnp.exp(v)
    z = u1 * u1 * u2; r = gamma * v - 1.3862944; s = lo_s + r - w; t = jnp.log(z)
    accept = ((s + 2.609438 >= 5.0 * z) | (s > t) | (r + alpha * jnp.log(alpha / (hi_s + w)) >= t))
    theta_bb = jnp.where(a == lo_s, w, hi_s) / (hi_s + w)
    theta = jnp.where(bb, theta_bb, theta_one)
    return jnp.where(accept | ~bb, theta, 0.0)
def lcg_only(i, a, b):
    x = (lane * np.uint32(747796405) + i * np.uint32(2891336453) + k1)
    w1 = x * np.uint32(277803737); w2 = w1 * np.uint32(747796405) + np.uint32(1)
    return prng.open_unit(w1, jnp.float32) + prng.open_unit(w2, jnp.float32)
for name, body in [("lcg_only", lcg_only), ("hash_only", hash_only), ("hash_held", hash_held), ("math_only", math_only), ("full_try", full)]:
    f = loop(body); jax.block_until_ready(f(a, b))
    ts = []
    for _ in range(5):
        t0 = time.perf_counter(); jax.block_until_ready(f(a, b)); ts.append(time.perf_counter() - t0)
    print(f"{name:10s} ns/lane min {min(ts)/(N*C*K)*1e9:6.2f} med {np.median(ts)/(N*C*K)*1e9:6.2f}")
