"""Theorem 4's exploration constant c0 T^{-p}/K against Theorem 1's exact floor (audit §3.1)."""

from __future__ import annotations

import math

import numpy as np

from . import framework as fw
from sern_jax.core import schedules
from sern_jax.analysis import theory as th

ALPHA0 = (0.1, 0.5, 0.9, 1.0, 2.0)
PS = (0.1, 0.2, 0.3)
KS = (2, 10, 64)


def simulate(ctx):
    log_t = np.linspace(1e-3, 80.0, 40_001) * th.LN10  # T up to 10^80
    rows = []
    for a0 in ALPHA0:
        for p in PS:
            for K in KS:
                lr = th.thm4_c_log_ratio(log_t, K, a0, p)
                # mutation: Theorem 1's own c = T^{-p/alpha0}/K in place of c0 T^{-p}/K
                alpha = schedules.alpha_of_log_horizon("log", log_t, a0, p)
                lr_t1 = th.thm1_log_pi_min(alpha, K) - th.thm1_log_c(alpha, K)
                i = int(np.argmin(lr))
                neg = np.nonzero(lr < 0)[0]
                rows.append(dict(alpha0=a0, p=p, K=K, min_log10=float(lr[i] / th.LN10),
                                 at_log10_t=float(log_t[i] / th.LN10),
                                 first_violation_log10_t=float(log_t[neg[0]] / th.LN10) if neg.size else math.inf,
                                 predicted_log10_t=th.thm4_c_violation_log_t(a0, p) / th.LN10,
                                 min_log10_t1=float(lr_t1.min() / th.LN10)))
    return {"rows": rows}


def evaluate(data, ctx):
    cells = []
    for r in data["rows"]:
        stat = r["min_log10_t1"] if ctx.mutate else r["min_log10"]
        cells.append(fw.exact_cell(
            f"α0={r['alpha0']:g} p={r['p']:g} K={r['K']}: min log10 ratio", stat, 0.0, "ge",
            expect=None if ctx.mutate else (fw.PASS if r["alpha0"] >= 1 else fw.FAIL),
            note=(f"first violation at T = 10^{r['first_violation_log10_t']:.1f} "
                  f"(≈ e^(1/(p(1−α0))) = 10^{r['predicted_log10_t']:.1f})"
                  if math.isfinite(r["first_violation_log10_t"]) else "")))
    return fw.finish(CHECK, ctx, cells, seeds=0, figure_data={"rows": data["rows"]})


CHECK = fw.Check(
    name="t4_c_consistency",
    claim="Thm 4 uses c = c0·T^{−p}/K (c0 = e^{−1/α0}) as the exploration floor under "
          "α = α0/ln(T^p), for every α0 > 0",
    configuration="deterministic; α0 ∈ {0.1,0.5,0.9,1,2}, p ∈ {0.1,0.2,0.3}, K ∈ {2,10,64}, "
                  "ln T on a grid up to T = 10^80",
    statistic="min over T of log10[π_min(T) / (c0 T^{−p}/K)], π_min = Theorem 1's exact floor",
    bound="≥ 0 (expected to hold for α0 ≥ 1, to fail for α0 < 1 beyond T = e^{1/(p(1−α0))})",
    expected=fw.FAILS,
    simulate=simulate,
    evaluate=evaluate,
    mutation="Theorem 4's c replaced by Theorem 1's c = T^{−p/α0}/K (then nothing may fail)",
    needs_engine=False,
)
