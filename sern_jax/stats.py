"""Confidence intervals, multiple-testing correction and power for the theory checks.

Host-side numpy (float64) plus two JAX calls (``betainc`` for beta quantiles, ``random`` for
seeded bootstrap resampling), both evaluated inside ``jax.enable_x64()``; no scipy. The
methodology is audit §2.2 (``reference/theory-audit.md``):

* mean inequalities "E[X] <= B" fail iff the lower one-sided CI of E[X] exceeds B (CLT, or a
  BCa/percentile bootstrap for skewed per-seed values);
* tail probabilities "P(E) <= b" fail iff the Clopper–Pearson lower bound exceeds b;
* a family of cells is corrected with Holm;
* every test reports the smallest violation it could detect.
"""

from __future__ import annotations

import math
from statistics import NormalDist
from typing import Callable, NamedTuple

import numpy as np

__all__ = [
    "normal_quantile",
    "normal_sf",
    "betainc",
    "beta_quantile",
    "clopper_pearson",
    "binom_sf",
    "tail_pvalue",
    "MeanCI",
    "mean_ci",
    "mean_pvalue",
    "bootstrap_ci",
    "holm",
    "mean_detectable_excess",
    "tail_critical_count",
    "tail_detectable_prob",
]

_NORMAL = NormalDist()


def _check_level(level: float) -> None:
    if not 0.0 < level < 1.0:
        raise ValueError(f"confidence level must be in (0, 1), got {level!r}")


def normal_quantile(q) -> np.ndarray:
    """Standard-normal quantile Phi^{-1}(q), q in (0, 1) (stdlib NormalDist)."""
    q = np.asarray(q, dtype=np.float64)
    if np.any((q <= 0) | (q >= 1)):
        raise ValueError(f"normal quantile needs q in (0, 1), got {q!r}")
    return np.vectorize(_NORMAL.inv_cdf, otypes=[np.float64])(q)


def normal_sf(z) -> np.ndarray:
    """1 - Phi(z), accurate in the upper tail (erfc)."""
    z = np.asarray(z, dtype=np.float64)
    return 0.5 * np.vectorize(math.erfc, otypes=[np.float64])(z / math.sqrt(2.0))


def betainc(a, b, x) -> np.ndarray:
    """Regularized incomplete beta I_x(a, b) in float64 (jax.scipy.special.betainc, x64)."""
    import jax
    import jax.numpy as jnp

    with jax.enable_x64(True):
        out = jax.scipy.special.betainc(
            jnp.asarray(a, jnp.float64), jnp.asarray(b, jnp.float64), jnp.asarray(x, jnp.float64)
        )
        return np.asarray(out, dtype=np.float64)


def beta_quantile(q, a, b, iters: int = 80) -> np.ndarray:
    """Quantile of Beta(a, b): the x with I_x(a, b) = q, by bisection (vectorised).

    Args:
      q: probabilities in [0, 1].
      a, b: shape parameters > 0 (broadcast with q).
      iters: bisection steps (80 gives ~1e-24 absolute width, i.e. float64 resolution).

    Returns:
      float64 array of quantiles in [0, 1].
    """
    q, a, b = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (q, a, b)))
    if np.any((a <= 0) | (b <= 0)):
        raise ValueError(f"beta shape parameters must be > 0, got a={a!r}, b={b!r}")
    lo = np.zeros_like(q)
    hi = np.ones_like(q)
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        below = betainc(a, b, mid) < q
        lo = np.where(below, mid, lo)
        hi = np.where(below, hi, mid)
    return 0.5 * (lo + hi)


def clopper_pearson(k, n, level: float = 0.99, side: str = "two"):
    """Clopper–Pearson (exact binomial) confidence interval for a proportion.

    Args:
      k: successes (int array), 0 <= k <= n.
      n: trials (int array) >= 1.
      level: confidence level.
      side: 'two' (each tail (1-level)/2), 'lower' (only the lower bound at 1-level; upper
        = 1) or 'upper' (only the upper bound; lower = 0).

    Returns:
      (lower, upper) float64 arrays.
    """
    _check_level(level)
    k, n = np.broadcast_arrays(np.asarray(k, np.float64), np.asarray(n, np.float64))
    if np.any(n < 1) or np.any(k < 0) or np.any(k > n):
        raise ValueError(f"need 0 <= k <= n, n >= 1; got k={k!r}, n={n!r}")
    if side not in ("two", "lower", "upper"):
        raise ValueError(f"side must be 'two', 'lower' or 'upper', got {side!r}")
    tail = (1.0 - level) / 2.0 if side == "two" else 1.0 - level
    lower = np.zeros_like(k)
    upper = np.ones_like(k)
    if side in ("two", "lower"):
        m = k > 0
        if np.any(m):
            lower[m] = beta_quantile(tail, k[m], n[m] - k[m] + 1.0)
    if side in ("two", "upper"):
        m = k < n
        if np.any(m):
            upper[m] = beta_quantile(1.0 - tail, k[m] + 1.0, n[m] - k[m])
    return lower, upper


def binom_sf(k, n, prob) -> np.ndarray:
    """P(Bin(n, prob) >= k) = I_prob(k, n-k+1) for k >= 1 (1 for k <= 0, 0 for k > n)."""
    k, n, prob = np.broadcast_arrays(*(np.asarray(v, np.float64) for v in (k, n, prob)))
    out = np.where(k <= 0, 1.0, 0.0)
    m = (k >= 1) & (k <= n)
    if np.any(m):
        out[m] = betainc(k[m], n[m] - k[m] + 1.0, np.clip(prob[m], 0.0, 1.0))
    return out


def tail_pvalue(k, n, bound) -> np.ndarray:
    """One-sided exact p-value for H0: P(E) <= bound, given k events in n trials."""
    return binom_sf(k, n, bound)


class MeanCI(NamedTuple):
    mean: float
    lower: float
    upper: float
    se: float
    n: int


def mean_ci(x, level: float = 0.99, side: str = "two") -> MeanCI:
    """CLT confidence interval for E[X] from i.i.d. per-seed values.

    Args:
      x: [S] per-seed values, S >= 2.
      level: confidence level.
      side: 'two', 'lower' (one-sided lower bound; upper = +inf) or 'upper'.

    Returns:
      MeanCI.
    """
    _check_level(level)
    x = np.asarray(x, dtype=np.float64).ravel()
    if x.size < 2:
        raise ValueError(f"need at least 2 values for a CLT interval, got {x.size}")
    if not np.all(np.isfinite(x)):
        raise ValueError("per-seed values contain NaN or inf")
    mean = float(x.mean())
    se = float(x.std(ddof=1) / math.sqrt(x.size))
    z = float(normal_quantile(1.0 - (1.0 - level) / (2.0 if side == "two" else 1.0)))
    lo = mean - z * se if side in ("two", "lower") else -math.inf
    hi = mean + z * se if side in ("two", "upper") else math.inf
    return MeanCI(mean, lo, hi, se, x.size)


def mean_pvalue(mean: float, se: float, bound: float, direction: str = "le") -> float:
    """One-sided CLT p-value for H0: E[X] <= bound ('le') or E[X] >= bound ('ge')."""
    if se <= 0:
        if direction == "le":
            return 0.0 if mean > bound else 1.0
        return 0.0 if mean < bound else 1.0
    z = (mean - bound) / se if direction == "le" else (bound - mean) / se
    return float(normal_sf(z))


def bootstrap_ci(
    data,
    fn: Callable[[np.ndarray], np.ndarray] | None = None,
    *,
    seed: int = 0,
    num_resamples: int = 2000,
    level: float = 0.99,
    side: str = "two",
    method: str = "bca",
):
    """Seeded bootstrap CI for a smooth function of column means, fn(mean over seeds).

    Resampling seeds with replacement multiplies the data by multinomial counts, so every
    resample's column means are one matrix product. BCa uses the closed-form jackknife of
    column means (leave-one-out mean = (sum - x_i)/(n-1)).

    Args:
      data: [S] or [S, d] per-seed values.
      fn: maps [..., d] column means to [...] statistics (default: the first column).
      seed: bootstrap seed (jax.random.key(seed); no global RNG).
      num_resamples: B.
      level, side: as in ``mean_ci``.
      method: 'bca' or 'percentile'.

    Returns:
      (estimate, lower, upper) floats.
    """
    import jax

    _check_level(level)
    x = np.asarray(data, dtype=np.float64)
    if x.ndim == 1:
        x = x[:, None]
    n = x.shape[0]
    if n < 2 or not np.all(np.isfinite(x)):
        raise ValueError(f"bootstrap needs >= 2 finite rows, got shape {x.shape}")
    if method not in ("bca", "percentile"):
        raise ValueError(f"method must be 'bca' or 'percentile', got {method!r}")
    fn = fn if fn is not None else (lambda m: m[..., 0])
    idx = np.asarray(
        jax.random.randint(jax.random.key(seed), (num_resamples, n), 0, n), dtype=np.int64
    )
    chunk = max(1, int(2e6 // (n * x.shape[1])))
    boot_means = np.concatenate(
        [x[idx[i : i + chunk]].mean(axis=1) for i in range(0, num_resamples, chunk)]
    )
    theta_b = np.asarray(fn(boot_means), dtype=np.float64)
    theta = float(fn(x.mean(axis=0)))
    tail = (1.0 - level) / (2.0 if side == "two" else 1.0)
    q_lo, q_hi = tail, 1.0 - tail
    if method == "bca":
        frac = np.clip(np.mean(theta_b < theta) + 0.5 * np.mean(theta_b == theta), 1e-6, 1 - 1e-6)
        z0 = float(normal_quantile(frac))
        jack = np.asarray(fn((x.sum(axis=0) - x) / (n - 1)), dtype=np.float64)
        dj = jack.mean() - jack
        denom = 6.0 * (np.sum(dj**2) ** 1.5)
        acc = float(np.sum(dj**3) / denom) if denom > 0 else 0.0

        def adj(q):
            zq = float(normal_quantile(q))
            return float(_NORMAL.cdf(z0 + (z0 + zq) / (1.0 - acc * (z0 + zq))))

        q_lo, q_hi = adj(q_lo), adj(q_hi)
    lo = float(np.quantile(theta_b, q_lo)) if side in ("two", "lower") else -math.inf
    hi = float(np.quantile(theta_b, q_hi)) if side in ("two", "upper") else math.inf
    return theta, lo, hi


def holm(pvalues, alpha: float = 0.01):
    """Holm step-down correction.

    Args:
      pvalues: [m] one-sided p-values.
      alpha: family-wise error rate.

    Returns:
      (reject [m] bool, adjusted [m] p-values).
    """
    p = np.asarray(pvalues, dtype=np.float64).ravel()
    m = p.size
    if m == 0:
        return np.zeros(0, bool), np.zeros(0)
    order = np.argsort(p)
    adj_sorted = np.maximum.accumulate(np.minimum(1.0, (m - np.arange(m)) * p[order]))
    adjusted = np.empty(m)
    adjusted[order] = adj_sorted
    return adjusted <= alpha, adjusted


def mean_detectable_excess(se: float, alpha: float = 0.01, power: float = 0.8) -> float:
    """Smallest true excess E[X] - B that a one-sided CLT test at level alpha detects with the
    given power: (z_{1-alpha} + z_{power}) * SE."""
    return float((normal_quantile(1.0 - alpha) + normal_quantile(power)) * se)


def tail_critical_count(n: int, bound: float, alpha: float = 0.01) -> int:
    """Smallest event count k whose one-sided CP lower bound exceeds ``bound`` (n + 1 if none:
    the test cannot reject)."""
    if bound >= 1.0:
        return n + 1
    lo, hi = 0, n + 1  # invariant: p-value(lo) > alpha (or lo == 0), hi rejects or == n+1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if tail_pvalue(mid, n, bound) <= alpha:
            hi = mid
        else:
            lo = mid
    return hi


def tail_detectable_prob(n: int, bound: float, alpha: float = 0.01, power: float = 0.8):
    """Smallest true event probability detected (with ``power``) as exceeding ``bound`` by the
    one-sided Clopper–Pearson test with n seeds; 1.0 if the test cannot reject at all."""
    k = tail_critical_count(n, bound, alpha)
    if k > n:
        return 1.0
    lo, hi = float(bound), 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if binom_sf(k, n, mid) >= power:
            hi = mid
        else:
            lo = mid
    return hi
