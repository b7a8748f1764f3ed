"""Negative control on a real neural estimator: Algorithm 1's update exactly as printed,
θ_t = argmax_θ Σ|R − r̂| (Adam steps ascending the L1 loss), fine-tuning an MLP online under
SERN. On 0/1 rewards the argmax pushes r̂ towards 1 where an arm mostly fails and towards 0
where it mostly succeeds (1 − median, audit §3.2), so SERN comes to prefer the worse arms and
R_t/t grows instead of decreasing (Theorem 5's claim). The problem has each context's best
arm at 0.8 and the others at 0.2 / 0.3 (``neural_runs`` "split"): on the gap problem of the
other neural checks every mean is below ½, the printed update sends every r̂ to 1 and SERN
merely plays uniformly. Control: the same network with the learners' own cross-entropy
update."""

from __future__ import annotations

import numpy as np

from . import framework as fw
from . import neural_runs

ALPHA = 0.1


def simulate(ctx):
    return {"printed": neural_runs.run(ctx, "sern", ALPHA, loss="l1argmax", problem="split"),
            "control": neural_runs.run(ctx, "sern", ALPHA, problem="split"),
            "seeds": neural_runs.sizes(ctx)["seeds"],
            "horizon": neural_runs.sizes(ctx)["horizon"]}


def _ratio_cell(label, run, horizon, ctx, **kw):
    out, times, _ = run
    first = 0  # the first checkpoint: one phase, decided by θ0's r̂
    r = np.asarray(out.regret_rb, np.float64)  # per-context pseudo-regret [S, G]
    early, late = r[:, first] / times[first], r[:, -1] / times[-1]
    return fw.mean_cell(f"{label}: R/t at t={int(times[-1])} − at t={int(times[first])}",
                        late - early, 0.0, "le", ctx.alpha,
                        note=f"R/t = {early.mean():.4f} → {late.mean():.4f}", **kw)


def evaluate(data, ctx):
    horizon = data["horizon"]
    primary, other = ("control", "printed") if ctx.mutate else ("printed", "control")
    names = {"printed": "printed argmax-L1 update", "control": "cross-entropy update"}
    cells = [_ratio_cell(names[primary], data[primary], horizon, ctx),
             _ratio_cell(names[other], data[other], horizon, ctx, info_only=True,
                         expect=fw.PASS if other == "control" else None)]
    return fw.finish(CHECK, ctx, cells, seeds=data["seeds"])


CHECK = fw.Check(
    name="alg1_neural_argmax",
    claim="Thm 5 for Algorithm 1 exactly as printed (θ = argmax Σ|R − r̂|) on an MLP "
          "fine-tuned online: R_t/t decreases",
    configuration="finite problem, M = 4 contexts (d = 4), K = 3, each context's best arm "
                  "0.8, the others 0.2 and 0.3; MLP [16], sern α = 0.1, 10 Adam steps (lr "
                  "1e-2) ascending the L1 loss every 20 rounds; 64 seeds × T = 2000 (quick: "
                  "32 × 1000); control: the same learner with the cross-entropy update",
    statistic="paired per-seed difference of the per-context regret R_t/t between the last "
              "checkpoint (t = T) and the first (t = 20, one phase on θ0)",
    bound="≤ 0",
    expected=fw.FAILS,
    simulate=simulate,
    evaluate=evaluate,
    mutation="the cross-entropy control tested in place of the printed update",
)
