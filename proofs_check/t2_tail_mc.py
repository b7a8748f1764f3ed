"""Theorem 2's tail bound under adaptive SERN, by Monte Carlo (audit §2.4 (ii))."""

from __future__ import annotations

import math

import numpy as np

from . import framework as fw
from sern_jax.analysis import theory as th

MEANS = (0.8, 0.3)
TRACK = 1  # the worse arm


def simulate(ctx):
    seeds = ctx.num_seeds(8192, 1024)
    runs = {}
    for alpha in (10.0, 100.0):
        runs[alpha] = fw.engine_run(estimator="rademacher", means=MEANS, horizon=1000,
                                    num_seeds=seeds, alpha0=alpha, num_checkpoints=4, beta=0.5,
                                    seed=ctx.root_seed)
    return {"runs": runs, "seeds": seeds}


def _deltas(t, kappa, c, num=8):
    b = np.geomspace(0.5, 1e-3, num)
    return np.sqrt(t * np.log(1.0 / b) / kappa)


def evaluate(data, ctx):
    cells = []
    fig = []
    n = data["seeds"]
    for alpha, (out, times) in data["runs"].items():
        c = float(th.thm1_c(alpha, 2))
        for t in (100, 1000):
            g = int(np.nonzero(times == t)[0][0])
            N = out.counts[:, g, TRACK]
            forms = {"paper": 1.0 / 8.0, "azuma": 2.0}
            if ctx.mutate:
                forms = {"paper×64 (κ=8)": 8.0}
            for name, kappa in forms.items():
                for d in _deltas(t, kappa, c):
                    b = math.exp(-kappa * d * d / t)
                    k = int((N < c * t - d).sum())
                    cells.append(fw.tail_cell(f"α={alpha:g} t={t} δ={d:.1f} {name}", k, n, b,
                                              ctx.alpha, vacuous=c * t - d <= 0,
                                              note="event impossible (ct − δ ≤ 0)" if c * t - d <= 0 else ""))
            if not ctx.mutate:
                for d in np.sqrt(2.0 * c * t * np.log(1.0 / np.geomspace(0.5, 1e-3, 8))):
                    if d > c * t:  # the Chernoff form needs delta <= ct
                        continue
                    b = math.exp(th.thm2_log_tail_freedman(d, t, c))
                    k = int((N < c * t - d).sum())
                    cells.append(fw.tail_cell(f"α={alpha:g} t={t} δ={d:.1f} freedman", k, n, b,
                                              ctx.alpha))
            ds = np.linspace(0.0, 4.0 * math.sqrt(t), 41)
            fig.append(dict(alpha=alpha, t=t, c=c, delta=ds.tolist(),
                            emp=[float((N < c * t - d).mean()) for d in ds],
                            paper=np.exp(th.thm2_log_tail_paper(ds, t)).tolist(),
                            azuma=np.exp(th.thm2_log_tail_azuma(ds, t)).tolist(),
                            freedman=np.exp(th.thm2_log_tail_freedman(np.maximum(ds, 1e-12), t, c)).tolist()))
    return fw.finish(CHECK, ctx, cells, seeds=n, figure_data={"curves": fig})


CHECK = fw.Check(
    name="t2_tail_mc",
    claim="Thm 2: P(N_a(t) < ct − δ) ≤ exp(−δ²/(8t)); also Azuma exp(−2δ²/t) and the "
          "Freedman/Chernoff form exp(−δ²/(2ct)) (δ ≤ ct)",
    configuration="adaptive SERN, rademacher oracle β = 0.5, K = 2, r = (0.8, 0.3), α ∈ {10,100} "
                  "(π ≈ c), tracked arm = the worse one, t ∈ {100, 1000}; δ grid where each "
                  "bound ∈ [1e−3, 0.5]",
    statistic="fraction of seeds with N_a(t) < ct − δ (Clopper–Pearson, Holm over all cells)",
    bound="each tail form at that δ; UNINFORMATIVE when the bound < 3/S, VACUOUS when the "
          "event is impossible",
    expected=fw.HOLDS,
    simulate=simulate,
    evaluate=evaluate,
    mutation="constant 1/8 replaced by 8 (bound exp(−8δ²/t))",
)
