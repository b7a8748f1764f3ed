"""The paper's experiments use a fixed α = 0.05; no theorem covers them (audit §3.1).

With a constant α the exact-oracle policy is the fixed distribution π = softmax(r/α), so
R_T/T = Σ_a π_a Δ_a for every T: linear regret, not the R_T/T → 0 of Theorem 5 (whose
schedule α = α0/ln(T^p) needs T = e^{20/p} ≥ 10²⁶ to reach 0.05 for p < 1/3). Theorem 1's
exploration floor at α = 0.05 and K = 64 is c = e^{−20}/64 = 3.2·10⁻¹¹: c·T < 1 for any
feasible T, so it says nothing.
"""

from __future__ import annotations

import numpy as np

from . import common
from . import framework as fw
from sern_jax.analysis import theory as th

ALPHA = 0.05
NUM_ARMS = 64


def means() -> np.ndarray:
    return common.linear_means(NUM_ARMS)


def exact_limit(r: np.ndarray, alpha: float) -> float:
    """Σ_a softmax(r/α)_a (max r − r_a), in float64."""
    z = (r - r.max()) / alpha
    pi = np.exp(z) / np.exp(z).sum()
    return float(pi @ (r.max() - r))


def simulate(ctx):
    seeds = ctx.num_seeds(512, 128)
    ts = (100, 10_000) if ctx.quick else (100, 100_000)
    out = {}
    for est in ("exact", "addhalf"):
        res = common.runs_over_horizons(ts, lambda t: ALPHA, estimator=est, means=means(),
                                        num_seeds=seeds, seed=ctx.root_seed)
        out[est] = {t: (np.asarray(res[t].regret_rb_paper) / t, np.asarray(res[t].counts))
                    for t in ts}
    return {"runs": out, "ts": ts, "seeds": seeds}


def evaluate(data, ctx):
    r = means()
    limit = exact_limit(r, ALPHA)
    c = float(th.thm1_c(ALPHA, NUM_ARMS))
    ts = data["ts"]
    cells = [fw.exact_cell("exact oracle: lim_T R_T/T = Σ_a π_a Δ_a vs 0 (Thm 5)", limit,
                           limit if ctx.mutate else 0.0, "le",
                           note=f"π = softmax(r/{ALPHA}) is the same every round")]
    for t in ts:
        ratio, _ = data["runs"]["exact"][t]
        farthest = ratio[np.argmax(np.abs(ratio - limit))]
        cells.append(fw.exact_cell(f"exact oracle, T={t}: R_T/T = Σ_a π_a Δ_a (seed farthest "
                                   "from it)", farthest, limit, "eq", info_only=True,
                                   expect=fw.PASS))
        ratio, counts = data["runs"]["addhalf"][t]
        cells.append(fw.equal_cell(f"addhalf, T={t}: R_T/T vs the exact-oracle limit", ratio,
                                   limit, ctx.alpha, info_only=True,
                                   note=f"arms never pulled per seed (mean): "
                                        f"{float((counts == 0).sum(axis=1).mean()):.1f} of "
                                        f"{NUM_ARMS}"))
    t = ts[-1]
    cells.append(fw.exact_cell(f"Thm 1 at α={ALPHA}, K={NUM_ARMS}: c·T at T={t}", c * t, 1.0,
                               "le", vacuous=True, info_only=True,
                               note=f"c = e^(−1/α)/K = {c:.3g}: E N_a(T) ≥ c·T < 1 says nothing"))
    fig = {est: {"ts": list(ts), "ratio": [float(data["runs"][est][t][0].mean()) for t in ts]}
           for est in data["runs"]}
    return fw.finish(CHECK, ctx, cells, seeds=data["seeds"],
                     figure_data={"curves": fig, "limit": limit, "c": c})


CHECK = fw.Check(
    name="exp_fixed_alpha",
    claim="The paper's experimental setting (fixed α = 0.05, Section VI) has the no-regret "
          "guarantee of Theorems 4–5: R_T/T → 0",
    configuration=f"K = {NUM_ARMS}, means evenly spaced 0.9 … 0.1, constant α = {ALPHA}; exact "
                  "oracle (deterministic) and add-half estimator; T ∈ {10², 10⁴ (quick) or 10⁵}",
    statistic="lim_T R_T/T of the exact-oracle policy, Σ_a softmax(r/α)_a Δ_a (closed form, "
              "matched by the engine at each T)",
    bound="0",
    expected=fw.FAILS,
    simulate=simulate,
    evaluate=evaluate,
    mutation="the limit compared with itself instead of 0 (nothing may fail)",
)
