"""Assumption 3 at a random, adaptively chosen count fails for empirical means (audit §3.3)."""

from __future__ import annotations

import math

import numpy as np

from . import framework as fw

BETA = 0.5 + 1e-3
INSTANCES = ((0.9, 0.5), (0.6, 0.4))


def fixed_n_max(n_max=200, num_p=401):
    """max over n <= n_max and p of sqrt(n+1) E|(S+1/2)/(n+1) - p|, S ~ Bin(n, p), exactly."""
    from sern_jax.analysis import theory as th

    best = 0.0
    ps = np.linspace(0.0, 1.0, num_p)
    for n in range(0, n_max + 1):
        s = np.arange(n + 1)
        for p in ps:
            if p in (0.0, 1.0):
                pmf = (s == (n if p == 1.0 else 0)).astype(float)
            else:
                lc = th.log_binom_cdf_all(n, p) if n > 0 else np.zeros(1)
                pmf = np.diff(np.exp(np.concatenate([[-np.inf], lc])))
            err = float(np.sum(pmf * np.abs((s + 0.5) / (n + 1) - p)))
            best = max(best, math.sqrt(n + 1) * err)
    return best


def simulate(ctx):
    seeds = ctx.num_seeds(4096, 4096)
    runs = {r: fw.engine_run(estimator="addhalf", means=r, horizon=2000, num_seeds=seeds,
                             alpha0=0.02, num_checkpoints=8, diagnostics=True,
                             seed=ctx.root_seed)
            for r in INSTANCES}
    return {"runs": runs, "seeds": seeds,
            "fixed_n_max": fixed_n_max(60 if ctx.quick else 200, 101 if ctx.quick else 401)}


def evaluate(data, ctx):
    beta = 2.0 if ctx.mutate else BETA
    cells = []
    for r, (out, _) in data["runs"].items():
        d = out.diag
        D = np.asarray(d.err_best[:, -1]) - beta * np.asarray(d.inv_sqrt_best[:, -1])
        cells.append(fw.mean_cell(f"r={r}: E[Σ|err_a*| − β Σ(N_a*+1)^(−1/2)]", D, 0.0, "le",
                                  ctx.alpha))
    cells.append(fw.exact_cell("fixed n: max_n,p √(n+1)·E|p̂ − p|", data["fixed_n_max"], 0.5,
                               "le", expect=fw.PASS, info_only=True,
                               note="A3 holds for every fixed n with β = ½ (attained at n = 0)"))
    return fw.finish(CHECK, ctx, cells, seeds=data["seeds"])


CHECK = fw.Check(
    name="a3_adaptive_addhalf",
    claim="A3 as Thm 3 uses it: E|r̂_{a*} − r_{a*}| ≤ β (N_{a*}(t−1)+1)^{−1/2} at the random "
          "count, for the add-half mean with its fixed-n constant β = ½ + 10⁻³",
    configuration="addhalf, SERN α = 0.02 (lock-in), K = 2, r ∈ {(0.9,0.5), (0.6,0.4)}, "
                  "T = 2000; plus the exact fixed-n maximum",
    statistic="per-seed Σ_t |err_{a*}| − β Σ_t (N_{a*}(t−1)+1)^{−1/2}",
    bound="E ≤ 0 (Student t, n − 1 dof, Holm over the two instances)",
    expected=fw.FAILS,
    simulate=simulate,
    evaluate=evaluate,
    mutation="β = 2 in place of ½ + 10⁻³",
)
