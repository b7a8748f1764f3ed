"""Theorem 3's regret decomposition, per seed, paired (audit §2.5)."""

from __future__ import annotations


from . import common
from . import framework as fw


def simulate(ctx):
    return common.t3_runs(ctx)


def evaluate(data, ctx):
    cells = []
    ratios = []
    T = data["grid"]["horizon"]
    for (est, K, fam, alpha), ((out, _), means) in data["runs"].items():
        regret, terms = common.t3_per_seed(out, means, est, alpha, T, with_entropy=not ctx.mutate)
        bound = terms.total
        cells.append(fw.mean_cell(f"{est} K={K} {fam} α={alpha:g}: E[R_T − bound]",
                                  regret - bound, 0.0, "le", ctx.alpha,
                                  note=f"regret {regret.mean():.4g} vs bound {bound.mean():.4g}"))
        ratios.append(dict(est=est, K=K, fam=fam, alpha=alpha, regret=float(regret.mean()),
                           best=float(terms.best.mean()), chosen=float(terms.chosen.mean()),
                           misid=float(terms.misid.mean()), entropy=float(terms.entropy.mean())))
    r = [x["regret"] / (x["best"] + x["chosen"] + x["misid"] + x["entropy"]) for x in ratios]
    return fw.finish(CHECK, ctx, cells, seeds=data["grid"]["seeds"],
                     notes=f"regret/bound ranges over [{min(r):.3g}, {max(r):.3g}]",
                     figure_data={"terms": ratios, "horizon": T})


CHECK = fw.Check(
    name="t3_inequality",
    claim="Thm 3: R_T ≤ β Σ E(N_{a*}(t−1)+1)^{−1/2} + β Σ E(N_{a_t}(t−1)+1)^{−1/2} + "
          "Σ P(a* ≠ â*_{t−1}) + α ln K·T",
    configuration="SERN, constant α ∈ {0.02,0.2,1}; full: {adv,rademacher,gauss,addhalf,flip} × "
                  "K ∈ {2,10} × gaps {linear, one-good, near-optimal}, T = 5000; quick: "
                  "(adv,K=10), (gauss|addhalf|flip, K=2), linear gaps, T = 2000; β = 0.3 for the "
                  "oracles, ½+10⁻³ for addhalf (fixed-n A3), max|1−2r|·q_c for flip (q_c = 0.49)",
    statistic="per-seed D = R_T − bound_i (paper's regret, Rao–Blackwellised; the a_t term "
              "as Σ_τ Σ_a π_τ(a)(N_a+1)^{−1/2}, same expectation; ties count as misidentified)",
    bound="E[D] ≤ 0 (Student t upper 99%, Holm over configurations)",
    expected=fw.HOLDS,
    simulate=simulate,
    evaluate=evaluate,
    mutation="entropy term α ln K·T dropped from the bound",
    by_construction="for adv and rademacher (|err| ≤ β/√(n+1) almost surely) the inequality "
                    "without even the misidentification term holds on every path (audit "
                    "§2.5), so only the gauss, flip and addhalf cells are genuinely "
                    "statistical",
)
