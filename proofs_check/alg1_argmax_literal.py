"""Negative control: Algorithm 1's update read literally, θ = argmax Σ|R − r̂| (audit §3.2).

On 0/1 rewards Σ|R_i − x| = n₁ + (n₀ − n₁)x is linear in x ∈ [0, 1], so its maximiser is
1 − median: the fit scores an arm 1 when it mostly fails and 0 when it mostly succeeds
(estimator ``l1argmax``). SERN then prefers the worse arm, and R_T/T grows towards Δ.
"""

from __future__ import annotations

from . import alg1_l1_median as l1
from . import framework as fw

MEANS = (0.9, 0.3)
ESTIMATOR = "l1argmax"


def simulate(ctx):
    return l1.ratios_over_horizons(ctx, MEANS, ESTIMATOR)


def evaluate(data, ctx):
    cells = l1.ratio_cells(data, ctx, ESTIMATOR)
    # Worse than choosing uniformly at random (R/T = Δ/2), recorded beside the verdict.
    t = data["ts"][-1]
    delta = MEANS[0] - MEANS[1]
    cells.append(fw.mean_cell(f"{ESTIMATOR}: R/T at T={t} vs uniform play Δ/2",
                              data["runs"][ESTIMATOR][t], delta / 2, "ge", ctx.alpha,
                              info_only=True))
    return fw.finish(CHECK, ctx, cells, seeds=data["seeds"], figure_data=l1.figure_data(data))


CHECK = fw.Check(
    name="alg1_argmax_literal",
    claim="Thm 5 for Algorithm 1 exactly as printed (θ_t = argmax_θ Σ|R − r̂|): R_T/T "
          "decreases to 0",
    configuration="l1argmax estimator (the maximiser of the L1 loss on 0/1 rewards = 1 − median), "
                  "K = 2, r = (0.9, 0.3), α = 1/ln(T^0.3), separate run per T ∈ {10³,10⁴(,10⁵)}; "
                  "addhalf (squared-loss mean) as control",
    statistic="paired per-seed difference of R_T/T between consecutive T",
    bound="≤ 0",
    expected=fw.FAILS,
    simulate=simulate,
    evaluate=evaluate,
    mutation="the add-half (squared-loss) estimator tested in place of the argmax (nothing may "
             "fail)",
)
