"""Negative control: Theorem 2 with the exponent constant 8 (δ² · 8/t) must be rejected."""

from __future__ import annotations

from . import framework as fw
from sern_jax.analysis import theory as th


def simulate(ctx):
    K, alpha = 2, 100.0
    pi, c = float(th.thm1_pi_min(alpha, K)), float(th.thm1_c(alpha, K))
    ts = (100, 1000, 10_000) if ctx.quick else (100, 1000, 10_000, 100_000)
    return {"rows": [dict(t=t, kappa=th.thm2_exact_kappa(t, pi, c).kappa_min) for t in ts]}


def evaluate(data, ctx):
    k = 2.0 if ctx.mutate else 8.0
    cells = [fw.exact_cell(f"K=2 α=100 t={r['t']}: κ_min vs {k:g}", r["kappa"], k, "ge")
             for r in data["rows"]]
    return fw.finish(CHECK, ctx, cells, seeds=0)


CHECK = fw.Check(
    name="t2_negative_control_8",
    claim="(false on purpose) P(N_a(t) < ct − δ) ≤ exp(−8δ²/t)",
    configuration="pinned, exact binomial, K = 2, α = 100 (π ≈ c ≈ ½), t ∈ {10²,…,10⁵}",
    statistic="κ_min (as in t2_exact_binomial)",
    bound="κ_min ≥ 8",
    expected=fw.FAILS,
    simulate=simulate,
    evaluate=evaluate,
    mutation="constant 8 replaced by Azuma's 2 (then the check must not fail)",
    needs_engine=False,
)
