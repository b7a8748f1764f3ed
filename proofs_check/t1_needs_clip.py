"""Negative control: Theorem 1 fails without r̂ ∈ [0,1] (audit §2.3 (iv), §3.5).

Workaround (engine_requests.md #1): the engine has no 'track-low' oracle (its ``adv`` pushes the
best arm down and the others up, and rejects β < 0), so this module runs its own float64 K = 2
scan: r̂_1 = r_1 + s(n_1), r̂_2 = r_2 − s(n_2), s(n) = (1−ε)β/√(n+1), optionally clipped, softmax,
one float64 uniform per round by inverse CDF (the engine's conventions).
"""

from __future__ import annotations

import numpy as np

from . import framework as fw
from sern_jax.analysis import theory as th

R = (1.0, 0.0)
ALPHA, BETA, EPS, HORIZON = 1.0, 0.99, 0.01, 113


def _run(num_seeds, seed, clip):
    import jax
    import jax.numpy as jnp

    with jax.enable_x64(True):
        r = jnp.asarray(R, jnp.float64)

        def one(key):
            def body(carry, t):
                n, low_min = carry
                s = (1.0 - EPS) * BETA / jnp.sqrt(n + 1.0)
                r_hat = r + jnp.array([1.0, -1.0]) * s
                r_hat = jnp.clip(r_hat, 0.0, 1.0) if clip else r_hat
                logits = r_hat / ALPHA
                pi = jax.nn.softmax(logits - logits.max())
                u = jax.random.uniform(jax.random.fold_in(key, t), (), jnp.float64)
                arm = jnp.minimum(jnp.sum(jnp.cumsum(pi) <= u), 1)
                n = n + jax.nn.one_hot(arm, 2, dtype=jnp.float64)
                return (n, jnp.minimum(low_min, pi[1])), n[1]

            (_, pmin), n2 = jax.lax.scan(body, (jnp.zeros(2, jnp.float64), jnp.float64(1.0)),
                                         jnp.arange(HORIZON))
            return n2, pmin

        keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(seed), i))(
            jnp.arange(num_seeds))
        n2, pmin = jax.jit(jax.vmap(one))(keys)
        return np.asarray(n2), np.asarray(pmin)


def simulate(ctx):
    seeds = ctx.num_seeds(4096, 2048)
    return {"unclipped": _run(seeds, ctx.root_seed, False), "clipped": _run(seeds, ctx.root_seed, True),
            "seeds": seeds}


def evaluate(data, ctx):
    n2, pmin = data["clipped" if ctx.mutate else "unclipped"]
    c = float(th.thm1_c(ALPHA, 2))
    cells = [fw.exact_cell("min_t π_t(2) vs c (pathwise)", float(pmin.min()), c, "ge")]
    for t in (10, 20, 40, 60, 80, 100, 113):
        cells.append(fw.mean_cell(f"t={t}: E N_2(t)", n2[:, t - 1], c * t, "ge", ctx.alpha))
    fig = {"t": list(range(1, HORIZON + 1)), "mean_n2": n2.mean(axis=0).tolist(), "c": c}
    return fw.finish(CHECK, ctx, cells, seeds=data["seeds"], figure_data=fig)


CHECK = fw.Check(
    name="t1_needs_clip",
    claim="Thm 1 without its unstated hypothesis r̂ ∈ [0,1]: E N_a(t) ≥ ct for any estimator",
    configuration="unclipped 'track-low' adversarial oracle, K = 2, r = (1, 0), α = 1, β = 0.99, "
                  "ε = 0.01, t ∈ [10, 113] (own scan, see module docstring)",
    statistic="mean N_2(t) (Student t, Holm), and min_t π_t(2)",
    bound="ct, c = e^{−1}/2 = 0.184",
    expected=fw.FAILS,
    simulate=simulate,
    evaluate=evaluate,
    mutation="estimates clipped to [0,1] (the theorem's hypothesis restored: nothing may fail)",
)
