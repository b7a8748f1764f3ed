"""Closed forms of the SERN paper's Theorems 1–5 and of the audit's corrections.

Everything here is deterministic float64 numpy (no randomness, no JAX flags touched), and
every quantity that can overflow is computed in log-space. Equation references:

* "paper Thm k" — Section V of ``paper/SERN-paper.txt``.
* "audit §x" — ``reference/theory-audit.md``.

Notation: ``K`` arms, horizon ``T`` (``log_t = ln T``), temperature ``alpha``; for the horizon
schedule of Theorem 4, ``alpha = alpha0 / ln(T^p)`` (computed by ``schedules.alpha_of_horizon``:
α(T) is written once, there). This module owns Theorem 1's constant c = e^{-1/α}/K
(:func:`thm1_c`) and the exact floor π_min (:func:`thm1_pi_min`); everything else uses these.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from sern_jax.core import schedules

__all__ = [
    "thm1_c",
    "thm1_log_c",
    "thm1_pi_min",
    "thm1_log_pi_min",
    "thm1_looseness",
    "thm2_log_tail_paper",
    "thm2_log_tail_azuma",
    "thm2_log_tail_freedman",
    "thm2_log_tail",
    "log_binom_cdf_all",
    "thm2_exact_kappa",
    "Thm3Terms",
    "thm3_terms",
    "neg_log1mexp",
    "logsumexp",
    "Thm4Params",
    "thm4_log_terms",
    "thm4_log_bound",
    "thm4_c_log_ratio",
    "thm4_c_violation_log_t",
    "corrected_log_terms",
    "corrected_log_bound",
    "crossing_log10_t",
    "thm4_crossing",
    "corrected_crossing",
    "certified_log_regret_lower",
    "certified_crossing",
    "certified_ever_pulled_log_bound",
    "exact_oracle_regret_k2",
    "worst_case_x",
    "max_regret_over_delta",
    "flip_misid_floor",
    "LN10",
]

LN10 = math.log(10.0)


def _f64(x) -> np.ndarray:
    return np.asarray(x, dtype=np.float64)


def _check_arms(num_arms) -> None:
    if np.any(np.asarray(num_arms) < 2):
        raise ValueError(f"num_arms must be >= 2, got {num_arms!r}")


def _check_positive(name: str, value) -> None:
    v = np.asarray(value, dtype=np.float64)
    if np.any(~np.isfinite(v)) or np.any(v <= 0):
        raise ValueError(f"{name} must be finite and > 0, got {value!r}")


# --------------------------------------------------------------------------------------
# Theorem 1: E[N_a(t)] >= c t,  c = exp(-1/alpha) / K.
# --------------------------------------------------------------------------------------


def thm1_log_c(alpha, num_arms, value_range=1.0) -> np.ndarray:
    """ln c with c = exp(-range/alpha)/K (paper Thm 1 has range = 1; audit §2.3 general).

    Args:
      alpha: temperature(s) > 0, any shape.
      num_arms: K >= 2 (broadcasts).
      value_range: max r_hat - min r_hat that the estimator can produce (1 for r_hat in [0,1]).

    Returns:
      float64 array of ln c.
    """
    _check_positive("alpha", alpha)
    _check_arms(num_arms)
    return -_f64(value_range) / _f64(alpha) - np.log(_f64(num_arms))


def thm1_c(alpha, num_arms, value_range=1.0) -> np.ndarray:
    """Theorem 1's constant c = exp(-1/alpha)/K (paper Thm 1). May underflow to 0; use
    ``thm1_log_c`` when alpha is small."""
    return np.exp(thm1_log_c(alpha, num_arms, value_range))


def thm1_log_pi_min(alpha, num_arms, value_range=1.0) -> np.ndarray:
    """ln pi_min, pi_min = 1/(1 + (K-1) e^{range/alpha}), the exact pathwise minimum of a
    softmax over K estimates whose range is <= ``value_range`` (audit §2.3)."""
    _check_positive("alpha", alpha)
    _check_arms(num_arms)
    return -np.logaddexp(0.0, np.log(_f64(num_arms) - 1.0) + _f64(value_range) / _f64(alpha))


def thm1_pi_min(alpha, num_arms, value_range=1.0) -> np.ndarray:
    """Exact softmax minimum probability pi_min (audit §2.3); >= c, and pi_min/c <= K/(K-1)."""
    return np.exp(thm1_log_pi_min(alpha, num_arms, value_range))


def thm1_looseness(alpha, num_arms) -> np.ndarray:
    """pi_min / c, in [1, K/(K-1)] (audit §2.3: the constant is loose by at most K/(K-1))."""
    return np.exp(thm1_log_pi_min(alpha, num_arms) - thm1_log_c(alpha, num_arms))


# --------------------------------------------------------------------------------------
# Theorem 2: P(N_a(t) < ct - delta) <= exp(-delta^2/(8t)).
# --------------------------------------------------------------------------------------


def thm2_log_tail_paper(delta, t, constant=1.0 / 8.0) -> np.ndarray:
    """ln of the paper's bound exp(-delta^2/(8t)) (paper Thm 2). ``constant`` is the
    exponent's factor kappa in exp(-kappa delta^2/t); the paper's is 1/8."""
    return -_f64(constant) * _f64(delta) ** 2 / _f64(t)


def thm2_log_tail_azuma(delta, t) -> np.ndarray:
    """ln of the Hoeffding–Azuma bound exp(-2 delta^2/t): the martingale
    M_t = N_a(t) - sum pi has increments in a predictable interval of length 1 (audit §2.4)."""
    return thm2_log_tail_paper(delta, t, constant=2.0)


def thm2_log_tail_freedman(delta, t, c) -> np.ndarray:
    """ln of the Freedman / multiplicative-Chernoff form exp(-delta^2/(2ct)) (audit §2.4).

    Valid for 0 < delta <= ct whenever pi_tau(a) >= c pathwise: N_a(t) then stochastically
    dominates Bin(t, c) (coupling), and the Chernoff lower tail of Bin(t, c) gives this.
    With delta = ct/2 it is the audit's exp(-ct/8).
    """
    return -_f64(delta) ** 2 / (2.0 * _f64(c) * _f64(t))


def thm2_log_tail(kind: str, delta, t, c=None) -> np.ndarray:
    """Dispatch: kind in {'paper', 'azuma', 'freedman'}."""
    if kind == "paper":
        return thm2_log_tail_paper(delta, t)
    if kind == "azuma":
        return thm2_log_tail_azuma(delta, t)
    if kind == "freedman":
        if c is None:
            raise ValueError("freedman bound needs c")
        return thm2_log_tail_freedman(delta, t, c)
    raise ValueError(f"unknown Theorem 2 bound kind {kind!r}")


def log_binom_cdf_all(n: int, prob: float) -> np.ndarray:
    """ln P(Bin(n, prob) <= k) for k = 0..n, exact in float64 (pmf recursion + log-cumsum).

    Args:
      n: number of trials >= 1.
      prob: success probability in (0, 1).

    Returns:
      [n+1] float64 log-CDF.
    """
    n = int(n)
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    if not 0.0 < prob < 1.0:
        raise ValueError(f"prob must be in (0, 1), got {prob!r}")
    k = np.arange(n, dtype=np.float64)
    steps = np.log((n - k) / (k + 1.0)) + (math.log(prob) - math.log1p(-prob))
    log_pmf = np.concatenate([[n * math.log1p(-prob)], n * math.log1p(-prob) + np.cumsum(steps)])
    return np.logaddexp.accumulate(log_pmf)


class KappaResult(NamedTuple):
    kappa_min: float  # min over delta of -ln P / (delta^2/t) among deltas with P <= p_max
    delta_at_min: float  # the delta (supremum of its interval) where the min is reached
    log_p_at_min: float  # ln P at that delta
    num_deltas: int  # how many distinct events (integer thresholds) entered the min


def thm2_exact_kappa(t: int, pi: float, c: float, p_max: float = 0.1) -> KappaResult:
    """Effective exponent constant of the exact binomial tail (audit §2.4 check (i)).

    For N ~ Bin(t, pi) (the ``pinned`` estimator makes N_a(t) exactly this), the event
    {N < ct - delta} equals {N <= m} for the integer m = ceil(ct - delta) - 1, so
    kappa(delta) = -ln P / (delta^2/t) is minimised at the supremum delta = ct - m of each
    interval. A bound exp(-k delta^2/t) holds for every delta > 0 iff kappa_min >= k.

    Args:
      t: rounds.
      pi: per-round probability of the tracked arm (pi_min for ``pinned``).
      c: Theorem 1's c.
      p_max: only deltas with P <= p_max enter the minimum (the audit's convention).

    Returns:
      KappaResult; kappa_min is +inf when no threshold has P <= p_max.
    """
    log_cdf = log_binom_cdf_all(t, pi)
    m = np.arange(t + 1, dtype=np.float64)
    delta = c * t - m
    ok = (delta > 0) & (log_cdf <= math.log(p_max))
    if not np.any(ok):
        return KappaResult(math.inf, math.nan, math.nan, 0)
    kappa = -log_cdf[ok] * t / delta[ok] ** 2
    i = int(np.argmin(kappa))
    return KappaResult(float(kappa[i]), float(delta[ok][i]), float(log_cdf[ok][i]), int(ok.sum()))


# --------------------------------------------------------------------------------------
# Theorem 3: R_T <= beta sum E(N_a*+1)^-1/2 + beta sum E(N_at+1)^-1/2 + sum P(misid)
#                  + alpha ln K T.
# --------------------------------------------------------------------------------------


class Thm3Terms(NamedTuple):
    best: np.ndarray  # beta * sum_t (N_{a*}(t-1)+1)^{-1/2}
    chosen: np.ndarray  # beta * sum_t (N_{a_t}(t-1)+1)^{-1/2}  (or its RB form)
    misid: np.ndarray  # sum_t 1{a* != hat a*_{t-1}}
    entropy: np.ndarray  # alpha ln K * T (or sum_t alpha_t ln K)

    @property
    def total(self) -> np.ndarray:
        return self.best + self.chosen + self.misid + self.entropy

    @property
    def total_without_misid(self) -> np.ndarray:
        return self.best + self.chosen + self.entropy


def thm3_terms(
    beta, inv_sqrt_best, inv_sqrt_chosen, misid, alpha, horizon, num_arms
) -> Thm3Terms:
    """The four terms of Theorem 3 from per-seed sums (paper Thm 3; audit §2.5).

    Pass per-seed sums (the engine's Diagnostics at a checkpoint); their seed means are the
    expectations in the theorem, so per-seed ``regret - terms.total`` is the paired statistic.

    Args:
      beta: Assumption 3 constant.
      inv_sqrt_best: [S] sum_t (N_{a*}(t-1)+1)^{-1/2}.
      inv_sqrt_chosen: [S] sum_t (N_{a_t}(t-1)+1)^{-1/2} (or sum_t sum_a pi_t(a)(...), the
        Rao–Blackwellised version with the same expectation).
      misid: [S] sum_t 1{hat a*_{t-1} != a*}.
      alpha: constant temperature.
      horizon: T.
      num_arms: K.

    Returns:
      Thm3Terms of float64 arrays.
    """
    _check_positive("alpha", alpha)
    _check_arms(num_arms)
    ent = _f64(alpha) * math.log(num_arms) * _f64(horizon)
    return Thm3Terms(
        best=_f64(beta) * _f64(inv_sqrt_best),
        chosen=_f64(beta) * _f64(inv_sqrt_chosen),
        misid=_f64(misid),
        entropy=ent + np.zeros_like(_f64(misid)),
    )


# --------------------------------------------------------------------------------------
# Theorem 4 in log-space (audit §2.6, §4).
# --------------------------------------------------------------------------------------


def neg_log1mexp(log_x) -> np.ndarray:
    """-ln(1 - e^{-x}) for x > 0 given as ln x, without cancellation (audit §4 item 3).

    ln x < -30: -ln x + x/2 (series); x <= ln 2: -ln(-expm1(-x)); else -log1p(-e^{-x}).
    """
    log_x = _f64(log_x)
    x = np.exp(np.minimum(log_x, 700.0))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        small = -log_x + 0.5 * x
        mid = -np.log(-np.expm1(-x))
        large = -np.log1p(-np.exp(-x))
    return np.where(log_x < -30.0, small, np.where(x <= math.log(2.0), mid, large))


def logsumexp(a, axis=-1) -> np.ndarray:
    """Stable ln sum exp along ``axis`` (float64 numpy)."""
    a = _f64(a)
    m = np.max(a, axis=axis, keepdims=True)
    m = np.where(np.isfinite(m), m, 0.0)
    return np.squeeze(m, axis=axis) + np.log(np.sum(np.exp(a - m), axis=axis))


class Thm4Params(NamedTuple):
    num_arms: int
    beta: float
    delta2: float
    alpha0: float
    p: float


def _check_thm4(num_arms, beta, delta2, alpha0, p) -> None:
    _check_arms(num_arms)
    _check_positive("beta", beta)
    _check_positive("delta2", delta2)
    _check_positive("alpha0", alpha0)
    _check_positive("p", p)


def thm4_log_terms(log_t, num_arms, beta, delta2, alpha0, p, d_scale=1.0) -> np.ndarray:
    """ln of Theorem 4's four terms at ln T (paper Thm 4; audit §2.6, §4).

    T1 = C0 c0^{-3/2} T^{(3p+1)/2},  T2 = C1 / (1 - exp(-c0^2 d1 T^{-2p})),
    T3 = C2 / (1 - exp(-c0^2 d2 T^{-2p})),  T4 = alpha0 ln K T / ln(T^p),
    c0 = e^{-1/alpha0}, C0 = 2^{7/2} K^{3/2} beta, C1 = 2 beta K,
    C2 = 2 (K-1) exp((beta/Delta2)^2 - 1/4), d1 = 1/(32 K^2), d2 = 1/(8 K^2).

    Args:
      log_t: ln T > 0 (any shape).
      num_arms, beta, delta2, alpha0, p: scalars or broadcasting arrays.
      d_scale: multiplies d1 and d2 (1 for the paper; 16 gives Azuma's constant 2 in place of
        1/8, audit §3.4).

    Returns:
      [..., 4] float64 log-terms.
    """
    _check_thm4(num_arms, beta, delta2, alpha0, p)
    L = _f64(log_t)
    if np.any(L <= 0):
        raise ValueError(f"log_t must be > 0 (T > 1), got {log_t!r}")
    K = _f64(num_arms)
    beta, delta2, alpha0, p = map(_f64, (beta, delta2, alpha0, p))
    log_c0 = -1.0 / alpha0
    log_C0 = 3.5 * math.log(2.0) + 1.5 * np.log(K) + np.log(beta)
    log_C1 = math.log(2.0) + np.log(beta) + np.log(K)
    log_C2 = math.log(2.0) + np.log(K - 1.0) + (beta / delta2) ** 2 - 0.25
    log_d1 = np.log(d_scale / 32.0) - 2.0 * np.log(K)
    log_d2 = np.log(d_scale / 8.0) - 2.0 * np.log(K)
    t1 = log_C0 - 1.5 * log_c0 + 0.5 * (3.0 * p + 1.0) * L
    t2 = log_C1 + neg_log1mexp(2.0 * log_c0 + log_d1 - 2.0 * p * L)
    t3 = log_C2 + neg_log1mexp(2.0 * log_c0 + log_d2 - 2.0 * p * L)
    t4 = np.log(alpha0 * np.log(K)) + L - np.log(p * L)
    return np.stack(np.broadcast_arrays(t1, t2, t3, t4), axis=-1)


def thm4_log_bound(log_t, num_arms, beta, delta2, alpha0, p, d_scale=1.0) -> np.ndarray:
    """ln B(T), Theorem 4's bound, as the logsumexp of ``thm4_log_terms`` (audit §4)."""
    return logsumexp(thm4_log_terms(log_t, num_arms, beta, delta2, alpha0, p, d_scale))


def thm4_c_log_ratio(log_t, num_arms, alpha0, p) -> np.ndarray:
    """ln [pi_min(T) / (c0 T^{-p} / K)]: Theorem 1's exact exploration floor under
    alpha = alpha0/ln(T^p) over the c that Theorem 4's constants use (audit §3.1).

    >= 0 for all T > 1 iff alpha0 >= 1; for alpha0 < 1 it turns negative once
    ln T > 1/(p (1 - alpha0)) (approximately; exactly where this function crosses 0).
    """
    _check_arms(num_arms)
    _check_positive("alpha0", alpha0)
    _check_positive("p", p)
    L = _f64(log_t)
    alpha = schedules.alpha_of_log_horizon("log", L, alpha0, p)
    log_pi = thm1_log_pi_min(alpha, num_arms)
    log_c4 = -1.0 / _f64(alpha0) - _f64(p) * L - np.log(_f64(num_arms))
    return log_pi - log_c4


def thm4_c_violation_log_t(alpha0, p) -> float:
    """ln T beyond which c0 T^{-p} > T^{-p/alpha0} (audit §3.1): 1/(p(1-alpha0)); inf if
    alpha0 >= 1."""
    _check_positive("alpha0", alpha0)
    _check_positive("p", p)
    return math.inf if alpha0 >= 1.0 else 1.0 / (p * (1.0 - alpha0))


def corrected_log_terms(log_t, num_arms, beta, alpha0, p, conditional_only=False):
    """ln of the corrected bound's three terms (audit §3.8):

    R_T <= 2 beta sqrt(K) T^{(1+p/alpha0)/2} + 2 beta sqrt(K T) + alpha0 ln K T / (p ln T),
    using c = T^{-p/alpha0}/K from Theorem 1 and E[1/(1+Bin(t-1,c))] <= 1/(ct).
    ``conditional_only``: the a_t term becomes 2 beta K sqrt(K) T^{(1+p/alpha0)/2} (only the
    conditional form of A3 holds, so the K-factor bound is needed).

    Returns:
      [..., 3] float64 log-terms.
    """
    _check_arms(num_arms)
    _check_positive("beta", beta)
    _check_positive("alpha0", alpha0)
    _check_positive("p", p)
    L = _f64(log_t)
    K = _f64(num_arms)
    beta, alpha0, p = map(_f64, (beta, alpha0, p))
    t1 = np.log(2.0 * beta) + 0.5 * np.log(K) + 0.5 * (1.0 + p / alpha0) * L
    if conditional_only:
        t2 = np.log(2.0 * beta) + 1.5 * np.log(K) + 0.5 * (1.0 + p / alpha0) * L
    else:
        t2 = np.log(2.0 * beta) + 0.5 * np.log(K) + 0.5 * L
    t3 = np.log(alpha0 * np.log(K)) + L - np.log(p * L)
    return np.stack(np.broadcast_arrays(t1, t2, t3), axis=-1)


def corrected_log_bound(log_t, num_arms, beta, alpha0, p, conditional_only=False):
    """ln of the corrected bound of audit §3.8 (logsumexp of ``corrected_log_terms``)."""
    return logsumexp(corrected_log_terms(log_t, num_arms, beta, alpha0, p, conditional_only))


def crossing_log10_t(
    log_gap_fn, log10_t_max: float = 5000.0, num_grid: int = 20001, iters: int = 100
) -> float:
    """First log10 T at which ``log_gap_fn(ln T) < 0``, solved in ln T (audit §4 item 2).

    Scans a grid of log10 T in (0, log10_t_max], then bisects inside the first bracket. The
    result is the first crossing on that grid resolution (for the monotone ratios here it is
    the unique crossing). Returns inf when there is none below 10^{log10_t_max}.
    """
    log10_grid = np.linspace(log10_t_max / (num_grid - 1), log10_t_max, num_grid)
    gap = log_gap_fn(log10_grid * LN10)
    neg = np.nonzero(gap < 0)[0]
    if neg.size == 0:
        return math.inf
    i = int(neg[0])
    lo, hi = (log10_grid[i - 1] if i > 0 else 1e-9), log10_grid[i]
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        if log_gap_fn(np.array(mid * LN10)) < 0:
            hi = mid
        else:
            lo = mid
    return float(hi)


def thm4_crossing(
    num_arms, beta, delta2, alpha0, p, fraction=1.0, d_scale=1.0, num_grid=20001
) -> float:
    """log10 T* = first T with B(T) < fraction * T (audit §4: fraction=1 gives T*, fraction
    = Delta2 gives T_Delta). B(T)/T is decreasing for p < 1/3, so a coarse grid suffices there."""
    lf = math.log(fraction)
    return crossing_log10_t(
        lambda L: thm4_log_bound(L, num_arms, beta, delta2, alpha0, p, d_scale) - L - lf,
        num_grid=num_grid,
    )


def corrected_crossing(num_arms, beta, alpha0, p, fraction=1.0) -> float:
    """log10 T* for the corrected bound of audit §3.8 (inf when p/alpha0 >= 1)."""
    if p / alpha0 >= 1.0:
        return math.inf
    lf = math.log(fraction)
    return crossing_log10_t(
        lambda L: corrected_log_bound(L, num_arms, beta, alpha0, p) - L - lf
    )


# --------------------------------------------------------------------------------------
# Certified counterexample for alpha0 < 1 (audit §3.9).
# --------------------------------------------------------------------------------------


def _log1mexp_neg(log_y):
    """ln(1 - y) for y = e^{log_y} < 1."""
    log_y = np.minimum(_f64(log_y), 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(
            log_y > -math.log(2.0), np.log(-np.expm1(log_y)), np.log1p(-np.exp(log_y))
        )


def certified_ever_pulled_log_bound(log_t, delta, alpha0, p, oracle_eps=0.01):
    """ln of T^{1 - g p/alpha0}, g = (1 - oracle_eps) - delta: upper bound on
    P(best arm ever pulled by T) for K = 2, r = (1, 1 - delta), ``adv`` oracle with beta = 1
    (audit §3.9). The best arm's estimate sits at oracle_eps until it is first pulled, the
    other arm's at >= 1 - delta, so each round pulls arm 1 with prob <= e^{-g/alpha}."""
    g = (1.0 - oracle_eps) - _f64(delta)
    return (1.0 - g * _f64(p) / _f64(alpha0)) * _f64(log_t)


def certified_log_regret_lower(log_t, delta, alpha0, p, oracle_eps=0.01):
    """ln of the certified lower bound on R_T (audit §3.9):

    R_T >= Delta T (1 - T^{1 - g p/alpha0}) (1 - T^{-g p/alpha0}),  g = 1 - eps - Delta.

    Meaningful (finite) only when g p/alpha0 > 1 and T > 1; returns -inf elsewhere.
    """
    L = _f64(log_t)
    g = (1.0 - oracle_eps) - _f64(delta)
    r = g * _f64(p) / _f64(alpha0)
    log_a = (1.0 - r) * L
    log_b = -r * L
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.log(_f64(delta)) + L + _log1mexp_neg(log_a) + _log1mexp_neg(log_b)
    return np.where((log_a < 0) & (L > 0), out, -np.inf)


def certified_crossing(delta, alpha0, p, beta=1.0, oracle_eps=0.01) -> float:
    """log10 T from which the certified lower bound exceeds Theorem 4's B(T) (K = 2,
    Delta2 = delta), i.e. Theorem 4 is violated analytically (audit §3.9)."""
    return crossing_log10_t(
        lambda L: thm4_log_bound(L, 2, beta, delta, alpha0, p)
        - certified_log_regret_lower(L, delta, alpha0, p, oracle_eps)
    )


# --------------------------------------------------------------------------------------
# The rate the schedule actually achieves (audit §3.10).
# --------------------------------------------------------------------------------------


def exact_oracle_regret_k2(horizon, delta, alpha0, p) -> np.ndarray:
    """R_T = Delta T / (1 + T^{p Delta/alpha0}): K = 2, exact oracle, alpha = alpha0/ln(T^p)
    (audit §3.10). Per-round regret is Delta pi(2) = Delta / (1 + e^{Delta/alpha})."""
    T = _f64(horizon)
    x = _f64(p) * _f64(delta) / _f64(alpha0) * np.log(T)
    return _f64(delta) * T * np.exp(-np.logaddexp(0.0, x))


def worst_case_x() -> float:
    """Root of 1 + e^x = x e^x (x = 1.27846...): maximiser of x/(1+e^x) (audit §3.10)."""
    lo, hi = 1.0, 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if 1.0 + math.exp(mid) - mid * math.exp(mid) > 0:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def max_regret_over_delta(horizon, alpha0, p):
    """max over Delta in (0, 1] of the K = 2 exact-oracle regret (audit §3.10).

    Unconstrained maximiser Delta* = x* alpha0/(p ln T) with value e^{-x*} alpha0 T/(p ln T)
    = 0.2785 alpha0 T/(p ln T); if Delta* > 1 the maximum is at Delta = 1.

    Returns:
      (max_regret, argmax_delta) float64 arrays.
    """
    T = _f64(horizon)
    xs = worst_case_x()
    d_star = xs * _f64(alpha0) / (_f64(p) * np.log(T))
    d = np.minimum(d_star, 1.0)
    return exact_oracle_regret_k2(T, d, alpha0, p), d


def flip_misid_floor(horizon, flip_q) -> np.ndarray:
    """Analytic floor sum_t P(misid) >= sum_{t<=T} q_c/sqrt(t) >= 2 q_c (sqrt(T+1) - 1) for the
    ``flip`` oracle on an instance where a flip of a* is a strict misidentification
    (audit §3.7; q_n = q_c/sqrt(n+1) and N_{a*}(t-1) <= t-1)."""
    return 2.0 * _f64(flip_q) * (np.sqrt(_f64(horizon) + 1.0) - 1.0)
