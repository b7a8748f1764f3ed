"""Theorem 3 on a real neural estimator: SERN's regret over an MLP fine-tuned online against
the paper's decomposition, with β fitted to the network's own errors, and against the
assumption-free pathwise form that a correct proof gives (audit §2.5).

The paper: R_T ≤ β Σ_t E(N_{a*}(t−1)+1)^{−1/2} + β Σ_t E(N_{a_t}(t−1)+1)^{−1/2}
+ Σ_t P(a* ≠ â*_{t−1}) + α ln K·T, a* = argmax_a E_s r_a(s), â* the same for r̂. The audit
finds the inequality probably true but its proof ingredients not implied by the assumptions
(A3 is needed in a conditional, adaptive form; the a_t term suffers selection bias; the
misidentification term is redundant). What a correct proof gives, for any estimator and any
comparator (even the per-context best arm a*_t), since π_t maximises E_π r̂ + αS(π):

    r_{a*_t} − E_{π_t} r ≤ |r̂_{a*_t} − r_{a*_t}| + Σ_a π_t(a)|r̂_a − r_a| + α ln K   (every round)

No new runs: the sern α = 0.1 runs of n1_neural_floor (``NeuralRunConfig(diagnostics=True)``
records Σ|err| at a*_t, Σ π|err|, Σ (N+1)^{−1/2} at a* and at a_t, and the rounds whose
â* ≠ a*). The runner adds the (N+1)^{−1/2} terms once per 20-round phase with the counts at
the phase's start, not N(t−1) each round: each term is at least the paper's, so the bound is
conservative (larger) by at most the phase's 19 extra pulls.

Vacuity: no policy's paper regret can exceed Δ_max·T (Δ_max = max − min of E_s r_a(s)) and no
per-context regret can exceed g·t (g = the largest per-context gap, max_s (max_a − min_a
r_a(s))); the paper's-form cell is VACUOUS when its mean bound is ≥ Δ_max·T, the pathwise
cell when rhs ≥ g·t on every seed and checkpoint. At α = 0.5 the entropy term alone
(α ln K = 0.549) exceeds both gaps of this problem (0.233 and 0.446), which is why the runs
are α = 0.1 (α ln K = 0.110)."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from . import a3_neural_error as a3
from . import framework as fw
from . import neural_runs

ALPHA = 0.1  # α ln K = 0.110 < both gaps; at α = 0.5 (0.549) every cell is vacuous


def simulate(ctx):
    return {"learned": neural_runs.run(ctx, "sern", ALPHA),
            "seeds": neural_runs.sizes(ctx)["seeds"],
            "horizon": neural_runs.sizes(ctx)["horizon"]}


def evaluate(data, ctx):
    out, times, problem = data["learned"]
    horizon = data["horizon"]
    k = problem.num_arms
    d = out.diag
    entropy = ALPHA * math.log(k)  # per round
    keep = 0.0 if ctx.mutate else 1.0  # mutation: the estimator-error terms dropped
    _, betas = a3._per_context(out, times, horizon)
    beta = float(max(betas))
    regret = np.asarray(out.regret_rb_paper[:, -1], np.float64)  # the paper's R_T
    best = beta * np.asarray(d.inv_sqrt_best[:, -1], np.float64)
    chosen = beta * np.asarray(d.inv_sqrt_chosen[:, -1], np.float64)
    misid = np.asarray(d.misid[:, -1], np.float64)
    bound = keep * (best + chosen + misid) + entropy * horizon
    per_ctx_means = np.asarray(jax.vmap(problem.expected_rewards)(
        jnp.asarray(problem.contexts, jnp.float32)), np.float64)  # [M, K]
    delta_max = float(problem.arm_means.max() - problem.arm_means.min())  # paper's R_T ≤ Δ_max·T
    g_max = float((per_ctx_means.max(axis=1) - per_ctx_means.min(axis=1)).max())
    cells = [fw.mean_cell(
        f"paper's form, β fitted: E[R_T − bound], K={k} α={ALPHA:g} T={horizon}",
        regret - bound, 0.0, "le", ctx.alpha,
        vacuous=bool(bound.mean() >= delta_max * horizon),  # then E[R_T − bound] ≤ 0 surely
        note=("mutated: the error terms below are dropped from the bound; " if ctx.mutate
              else "")
        + f"R_T {regret.mean():.4g} vs bound {bound.mean():.4g} (β = {beta:.3f}: "
             f"β Σ(N_a*+1)^-½ {best.mean():.4g} + β Σ(N_at+1)^-½ {chosen.mean():.4g} + "
             f"Σ 1{{â*≠a*}} {misid.mean():.4g} + α ln K·T {entropy * horizon:.4g}); "
             f"trivial bound Δ_max·T = {delta_max * horizon:.4g} (Δ_max {delta_max:.3f})")]
    # the pathwise form, at every checkpoint, with the per-context best arm (standard regret);
    # float32 sums of ≤ T terms of size ≤ 1: allowance 1e-5 per round
    per_ctx = np.asarray(out.regret_rb, np.float64)  # [S, G]
    rhs = (keep * (np.asarray(d.err_best, np.float64) + np.asarray(d.err_rb, np.float64))
           + entropy * times[None, :])
    slack = (rhs + 1e-5 * times[None, :] - per_ctx) / np.maximum(rhs, 1e-12)
    cells.append(fw.exact_cell(
        "pathwise: min over seeds and checkpoints of (Σ|err_{a*_t}| + Σ π|err| + α ln K·t "
        "− R_t(per-context)) / rhs", float(slack.min()), 0.0, "ge",
        vacuous=bool(np.all(rhs >= g_max * times[None, :])),
        note=("mutated: rhs = α ln K·t alone; " if ctx.mutate else "")
        + f"R_T(per-context) {per_ctx[:, -1].mean():.4g} vs rhs {rhs[:, -1].mean():.4g}; "
             f"trivial bound g·T = {g_max * horizon:.4g} (g {g_max:.3f}); rhs < g·t on "
             f"{100 * float(np.mean(rhs < g_max * times[None, :])):.1f}% of seed-checkpoints"))
    # ingredients, reported: the selection-bias ratio of the a_t term, and P(misid)
    ratio = float(np.asarray(d.err_chosen[:, -1]).mean() / chosen.mean())
    cells.append(fw.mean_cell(
        "ingredient (reported): Σ|err_{a_t}| ≤ β Σ (N_{a_t}+1)^{−1/2}",
        np.asarray(d.err_chosen[:, -1], np.float64) - chosen, 0.0, "le", ctx.alpha,
        info_only=True, note=f"ratio {ratio:.3f}; fraction of rounds with â* ≠ a*: "
                             f"{misid.mean() / horizon:.4f}"))
    return fw.finish(CHECK, ctx, cells, seeds=data["seeds"],
                     notes=f"fitted β = {beta:.3f}; R_T/bound = "
                           f"{regret.mean() / bound.mean():.3f}")


CHECK = fw.Check(
    name="t3_neural_inequality",
    claim="Thm 3 with a neural r̂: R_T ≤ β Σ E(N_{a*}+1)^{−1/2} + β Σ E(N_{a_t}+1)^{−1/2} + "
          "Σ P(a* ≠ â*) + α ln K·T (β fitted to the MLP's own errors), and its pathwise core "
          "R_t ≤ Σ|err_{a*_t}| + Σ π|err| + α ln K·t",
    configuration="the sern α = 0.1 runs of n1_neural_floor: finite problem (M = 4, d = 4, "
                  "K = 3, Δ2 = 0.2), MLP [16]; 64 seeds × T = 2000 (quick: 32 × 1000)",
    statistic="per-seed D = R_T − bound (paper's regret, Rao–Blackwellised; a* = argmax_a "
              "E_s r_a(s), â* from the acting network's mean over the 4 contexts); pathwise: "
              "the per-context regret against its assumption-free bound at every checkpoint",
    bound="E[D] ≤ 0 (framework.mean_cell: Student t 99% interval, Holm); pathwise ≥ 0 on "
          "every seed and checkpoint; VACUOUS where the mean bound ≥ Δ_max·T (paper's form) or "
          "rhs ≥ g·t everywhere (pathwise)",
    expected=fw.HOLDS,
    simulate=simulate,
    evaluate=evaluate,
    mutation="the estimator-error terms dropped from both bounds (α ln K·t alone, the bound "
             "of an exact r̂; dropping the entropy term instead still passes on these runs)",
    by_construction="the pathwise cell holds for any estimator under a softmax(r̂/α) policy "
                    "(π_t maximises E_π r̂ + αS(π)); it checks the learner, the runner and "
                    "the diagnostics where its rhs is below the trivial g·t, and the "
                    "mutation shows it can fail. The paper's form uses β fitted over "
                    "this horizon (A3 fails at its rate: a3_neural_error), so it is a check "
                    "of the decomposition at the fitted β, not of A3",
)
