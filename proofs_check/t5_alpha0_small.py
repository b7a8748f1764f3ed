"""Theorem 5 fails for α0 < p·g (audit §3.9): the best arm is never found."""

from __future__ import annotations

import math

import numpy as np

from . import common
from . import framework as fw
from sern_jax.analysis import theory as th

MEANS = (1.0, 0.9)
P, EPS = 0.3, 0.01
DELTA = MEANS[0] - MEANS[1]


def simulate(ctx):
    seeds = ctx.num_seeds(512, 128)
    ts = (100, 1000, 10_000) if ctx.quick else (100, 1000, 10_000, 100_000)
    curves = {}
    for a0 in (0.1, 1.0):
        res = common.runs_over_horizons(ts, lambda t: fw.alpha_log(a0, P, t), estimator="adv",
                                        means=MEANS, num_seeds=seeds, beta=1.0, oracle_eps=EPS,
                                        seed=ctx.root_seed, share=ctx.quick)
        curves[a0] = {t: (np.asarray(res[t].regret_rb_paper) / t, np.asarray(res[t].counts[:, 0]))
                      for t in ts}
    return {"curves": curves, "ts": ts, "seeds": seeds}


def evaluate(data, ctx):
    cells = []
    g = (1.0 - EPS) - DELTA
    a0 = 0.1
    # analytic: lim inf R_T/T >= Delta (certified lower bound / T -> Delta as T -> inf)
    lim = DELTA if g * P / a0 > 1 else 0.0
    cells.append(fw.exact_cell("α0=0.1: lim_T certified lower bound of R_T/T", lim,
                               DELTA if ctx.mutate else 0.0, "le",
                               note=f"g·p/α0 = {g * P / a0:.3f} > 1"))
    for t in data["ts"]:
        ratio, n1 = data["curves"][a0][t]
        lower = math.exp(th.certified_log_regret_lower(math.log(t), DELTA, a0, P, EPS)) / t
        cells.append(fw.mean_cell(f"α0=0.1 T={t}: R_T/T ≥ certified lower bound", ratio, lower,
                                  "ge", ctx.alpha, info_only=True, expect=fw.PASS,
                                  note=f"best arm pulled in {int((n1 > 0).sum())} of "
                                       f"{len(n1)} seeds"))
    fig = {str(a): {"ts": list(data["ts"]),
                    "ratio": [float(data["curves"][a][t][0].mean()) for t in data["ts"]]}
           for a in data["curves"]}
    return fw.finish(CHECK, ctx, cells, seeds=data["seeds"], figure_data={"curves": fig},
                     notes="α0 = 1 on the same instance is recorded for the figure")


CHECK = fw.Check(
    name="t5_alpha0_small",
    claim="Thm 5 for every α0 > 0: R_T/T → 0",
    configuration="K = 2, r = (1, 0.9), adv oracle β = 1, α0 = 0.1 < p·g = 0.267, p = 0.3; MC "
                  "at T ∈ {10²,…,10⁴(10⁵)} (α0 = 1 alongside for the figure)",
    statistic="lim_T of the certified lower bound on R_T/T (analytic); MC R_T/T vs that bound",
    bound="0",
    expected=fw.FAILS,
    simulate=simulate,
    evaluate=evaluate,
    mutation="limit compared with Δ instead of 0 (nothing may fail)",
)
