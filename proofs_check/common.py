"""Instances and shared engine runs used by several checks (cached in framework)."""

from __future__ import annotations

import math

import numpy as np

from . import framework as fw


def linear_means(num_arms: int, hi: float = 0.9, lo: float = 0.1) -> np.ndarray:
    """Evenly spaced means, best arm first."""
    return np.linspace(hi, lo, num_arms)


def gap_means(num_arms: int, family: str, delta2: float = 0.2) -> np.ndarray:
    """Gap families of audit §6 t3_inequality: linear, one-good, many-near-optimal."""
    if family == "linear":
        return linear_means(num_arms)
    if family == "one_good":
        return np.r_[0.8, np.full(num_arms - 1, 0.8 - delta2)]
    if family == "near_opt":
        return np.r_[0.8, np.linspace(0.8 - delta2, 0.8 - 2 * delta2, num_arms - 1)]
    raise ValueError(f"unknown gap family {family!r}")


def delta2_means(num_arms: int, delta2: float) -> np.ndarray:
    """Best 0.9, second 0.9 - Delta2, the rest evenly spread below (Assumption 1 gap Delta2)."""
    second = 0.9 - delta2
    rest = np.linspace(second, 0.0, num_arms - 1)[1:] if num_arms > 2 else np.zeros(0)
    return np.r_[0.9, second, rest]


def powers_of_ten(ts) -> list[int]:
    out = []
    for t in ts:
        k = round(math.log10(t))
        if 10**k != t:
            raise ValueError(f"horizon grid must be powers of ten, got {t}")
        out.append(int(t))
    return out


def runs_over_horizons(ts, alpha_of_t, *, estimator, means, num_seeds, share=True,
                       horizon=None, **kw):
    """One run per horizon T with alpha = alpha_of_t(T) (a separate run per T, as Theorems 4–5
    need, since alpha depends on T). The rounds 1..T of a longer run with the same constant
    alpha are exactly the horizon-T run, so for T_max <= 1e4 one compiled horizon-T_max
    program serves every T (read at the checkpoint t = T); larger T get their own horizon.
    ``horizon`` (a power of ten >= max(ts), at most 1e4, with ``share``): the program's
    horizon instead of T_max, so that calls with different ``ts`` share one program.

    Returns:
      dict T -> (RunOutput sliced at t = T, i.e. fields [S] / [S, K]).
    """
    ts = powers_of_ten(ts)
    out = {}
    t_max = max(ts) if horizon is None else powers_of_ten([horizon])[0]
    if t_max < max(ts):
        raise ValueError(f"horizon {horizon} is below the largest T {max(ts)}")
    for t in ts:
        run_horizon = t_max if (share and t_max <= 10_000) else t
        ncp = int(round(math.log10(run_horizon))) + 1
        res, times = fw.engine_run(estimator=estimator, means=means, horizon=run_horizon,
                                   num_seeds=num_seeds, alpha0=alpha_of_t(t),
                                   num_checkpoints=ncp, **kw)
        idx = int(np.nonzero(times == t)[0][0])
        out[t] = _slice(res, idx)
    return out


def _slice(res, idx):
    import jax

    return jax.tree.map(lambda x: x[:, idx], res)


# ---------------------------------------------------------------------------------------
# Theorem 1–2 family: SERN with clipped estimators, constant alpha (shared by t1/t2 checks)
# ---------------------------------------------------------------------------------------


def t1_grid(ctx):
    if ctx.quick:
        return dict(estimators=("adv", "addhalf"), ks=(2, 10), alphas=(0.2, 1.0),
                    horizon=500, seeds=ctx.num_seeds(1024, 128))
    return dict(estimators=("adv", "rademacher", "gauss", "addhalf", "exact"), ks=(2, 10, 64),
                alphas=(0.05, 0.2, 1.0, 5.0), horizon=2000, seeds=ctx.num_seeds(1024, 128))


def t1_runs(ctx):
    """Runs of the Theorem 1 grid: dict (estimator, K, alpha) -> (RunOutput, times)."""
    g = t1_grid(ctx)
    out = {}
    for est in g["estimators"]:
        for K in g["ks"]:
            for alpha in g["alphas"]:
                ctx.note(f"t1 runs: {est} K={K} α={alpha}")
                out[(est, K, alpha)] = fw.engine_run(
                    estimator=est, means=linear_means(K), horizon=g["horizon"],
                    num_seeds=g["seeds"], alpha0=alpha, num_checkpoints=12, beta=0.5,
                    seed=ctx.root_seed)
    return {"runs": out, "grid": g}


# ---------------------------------------------------------------------------------------
# Theorem 3 family: diagnostics runs (shared by t3_inequality and t3_no_misid_term)
# ---------------------------------------------------------------------------------------

ORACLE_BETA = 0.3
ADDHALF_BETA = 0.5 + 1e-3  # fixed-n A3 constant of (S+1/2)/(n+1) (audit §2.1), strict
FLIP_Q = 0.49


def a3_beta(estimator: str, means) -> float:
    """The Assumption 3 constant each estimator satisfies on these means (audit §2.1)."""
    if estimator in ("adv", "rademacher", "gauss"):
        return ORACLE_BETA
    if estimator == "addhalf":
        return ADDHALF_BETA
    if estimator == "flip":
        return float(np.max(np.abs(1.0 - 2.0 * np.asarray(means)))) * FLIP_Q * 1.001
    if estimator == "exact":
        return 0.0
    raise ValueError(f"no A3 constant for estimator {estimator!r}")


def t3_grid(ctx):
    if ctx.quick:
        combos = [("adv", 10, "linear"), ("gauss", 2, "linear"), ("addhalf", 2, "linear"),
                  ("flip", 2, "linear")]
        return dict(combos=combos, alphas=(0.02, 0.2, 1.0), horizon=2000,
                    seeds=ctx.num_seeds(512, 256))
    combos = [(e, K, f) for e in ("adv", "rademacher", "gauss", "addhalf", "flip")
              for K in (2, 10) for f in ("linear", "one_good", "near_opt")]
    return dict(combos=combos, alphas=(0.02, 0.2, 1.0), horizon=5000,
                seeds=ctx.num_seeds(512, 256))


def t3_runs(ctx):
    g = t3_grid(ctx)
    runs = {}
    for est, K, fam in g["combos"]:
        means = gap_means(K, fam)
        for alpha in g["alphas"]:
            ctx.note(f"t3 runs: {est} K={K} {fam} α={alpha}")
            oracle = {"beta": ORACLE_BETA} if est in ("adv", "rademacher", "gauss") else {}
            if est == "flip":
                oracle = {"flip_q": FLIP_Q}
            runs[(est, K, fam, alpha)] = (fw.engine_run(
                estimator=est, means=means, horizon=g["horizon"], num_seeds=g["seeds"],
                alpha0=alpha, num_checkpoints=8, diagnostics=True, seed=ctx.root_seed, **oracle),
                means)
    return {"runs": runs, "grid": g}


def t3_per_seed(out, means, est, alpha, horizon, with_entropy=True):
    """Per-seed regret and the four Theorem 3 terms at T (Rao–Blackwellised a_t term)."""
    from sern_jax.analysis import theory as th

    d = out.diag
    terms = th.thm3_terms(a3_beta(est, means), d.inv_sqrt_best[:, -1], d.inv_sqrt_rb[:, -1],
                          d.misid[:, -1], alpha, horizon, len(means))
    if not with_entropy:
        terms = terms._replace(entropy=np.zeros_like(terms.entropy))
    return np.asarray(out.regret_rb_paper[:, -1]), terms
