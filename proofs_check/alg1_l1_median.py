"""Negative control: Algorithm 1's L1 loss estimates the median, so R_T/T stays linear (§3.2)."""

from __future__ import annotations

import numpy as np

from . import common
from . import framework as fw

MEANS = (0.9, 0.6)
CONTROL = "addhalf"  # the squared-loss mean: R_T/T decreases (the mutation tests it instead)


def ratios_over_horizons(ctx, means, estimator):
    """R_T/T per seed for ``estimator`` and the add-half control, α = 1/ln(T^0.3), per T."""
    seeds = ctx.num_seeds(512, 128)
    ts = (1000, 10_000) if ctx.quick else (1000, 10_000, 100_000)
    out = {}
    for est in (estimator, CONTROL):
        res = common.runs_over_horizons(ts, lambda t: fw.alpha_log(1.0, 0.3, t), estimator=est,
                                        means=means, num_seeds=seeds, seed=ctx.root_seed,
                                        share=ctx.quick)
        out[est] = {t: np.asarray(res[t].regret_rb_paper) / t for t in ts}
    return {"runs": out, "ts": ts, "seeds": seeds}


def ratio_cells(data, ctx, estimator):
    """Paired per-seed increments of R_T/T between consecutive T, bound ≤ 0 (Theorem 5)."""
    ts = data["ts"]
    cells = []
    primary = CONTROL if ctx.mutate else estimator
    for est in (estimator, CONTROL):
        r = data["runs"][est]
        for a, b in zip(ts[:-1], ts[1:]):
            cells.append(fw.mean_cell(f"{est}: R/T at T={b} − at T={a}", r[b] - r[a], 0.0, "le",
                                      ctx.alpha, info_only=est != primary,
                                      expect=fw.PASS if est == CONTROL else None,
                                      note=f"R/T = {r[a].mean():.4f} → {r[b].mean():.4f}"))
    return cells


def figure_data(data):
    return {"curves": {est: {"ts": list(data["ts"]),
                             "ratio": [float(data["runs"][est][t].mean()) for t in data["ts"]]}
                       for est in data["runs"]}}


def simulate(ctx):
    return ratios_over_horizons(ctx, MEANS, "l1median")


def evaluate(data, ctx):
    return fw.finish(CHECK, ctx, ratio_cells(data, ctx, "l1median"), seeds=data["seeds"],
                     figure_data=figure_data(data))


CHECK = fw.Check(
    name="alg1_l1_median",
    claim="Thm 5 for Algorithm 1 as written (θ fitted with the L1 loss Σ|R − r̂|): R_T/T "
          "decreases to 0",
    configuration="l1median estimator (the L1 minimiser on 0/1 rewards = sample median), "
                  "K = 2, r = (0.9, 0.6), α = 1/ln(T^0.3), separate run per T ∈ {10³,10⁴(,10⁵)}; "
                  "addhalf (squared-loss mean) as control",
    statistic="paired per-seed difference of R_T/T between consecutive T",
    bound="≤ 0",
    expected=fw.FAILS,
    simulate=simulate,
    evaluate=evaluate,
    mutation="the add-half (squared-loss) estimator tested in place of L1 (nothing may fail)",
)
