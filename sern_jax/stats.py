"""Confidence intervals, multiple-testing correction and power for the theory checks.

Host-side numpy (float64) over ``scipy.stats``: Clopper–Pearson is
``binomtest(...).proportion_ci(method="exact")``, the bootstrap is ``scipy.stats.bootstrap``
(BCa or percentile, seeded ``numpy`` generator), normal and beta quantiles / tails are
``norm`` and ``beta``/``binom``. What scipy lacks stays here: Holm's step-down correction and
the power statements (smallest detectable excess / probability). The methodology is audit §2.2
(``reference/theory-audit.md``):

* mean inequalities "E[X] <= B" fail iff the lower one-sided CI of E[X] exceeds B (CLT, or a
  BCa/percentile bootstrap for skewed per-seed values);
* tail probabilities "P(E) <= b" fail iff the Clopper–Pearson lower bound exceeds b;
* a family of cells is corrected with Holm;
* every test reports the smallest violation it could detect.
"""

from __future__ import annotations

import math
import warnings
from typing import Callable, NamedTuple

import numpy as np
from scipy import stats as sps

__all__ = [
    "clopper_pearson",
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


def _check_level(level: float) -> None:
    if not 0.0 < level < 1.0:
        raise ValueError(f"confidence level must be in (0, 1), got {level!r}")


def _check_side(side: str) -> None:
    if side not in ("two", "lower", "upper"):
        raise ValueError(f"side must be 'two', 'lower' or 'upper', got {side!r}")


def clopper_pearson(k, n, level: float = 0.99, side: str = "two"):
    """Clopper–Pearson (exact binomial) confidence interval for a proportion, elementwise
    ``scipy.stats.binomtest(k, n).proportion_ci(level, method="exact")``.

    Args:
      k: successes (int array), 0 <= k <= n.
      n: trials (int array) >= 1.
      level: confidence level.
      side: 'two' (each tail (1-level)/2), 'lower' (only the lower bound at 1-level; upper
        = 1) or 'upper' (only the upper bound; lower = 0).

    Returns:
      (lower, upper) float64 arrays of the broadcast shape of k and n.
    """
    _check_level(level)
    _check_side(side)
    k, n = np.broadcast_arrays(np.asarray(k), np.asarray(n))
    kf, nf = k.astype(np.float64), n.astype(np.float64)
    if (np.any(nf < 1) or np.any(kf < 0) or np.any(kf > nf) or np.any(kf != np.round(kf))
            or np.any(nf != np.round(nf))):
        raise ValueError(f"need integers 0 <= k <= n, n >= 1; got k={k!r}, n={n!r}")
    alternative = {"two": "two-sided", "lower": "greater", "upper": "less"}[side]
    lower = np.empty(k.shape)
    upper = np.empty(k.shape)
    for i in np.ndindex(k.shape):
        ci = sps.binomtest(int(kf[i]), int(nf[i]), alternative=alternative).proportion_ci(
            confidence_level=level, method="exact")
        lower[i], upper[i] = ci.low, ci.high
    return lower, upper


def tail_pvalue(k, n, bound) -> np.ndarray:
    """One-sided exact p-value for H0: P(E) <= bound, given k events in n trials:
    P(Bin(n, bound) >= k) (``binom.sf(k - 1, n, bound)``; 1 for k <= 0, 0 for k > n)."""
    k, n, bound = np.broadcast_arrays(*(np.asarray(v, np.float64) for v in (k, n, bound)))
    return np.asarray(sps.binom.sf(k - 1.0, n, np.clip(bound, 0.0, 1.0)), dtype=np.float64)


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
    z = float(sps.norm.ppf(1.0 - (1.0 - level) / (2.0 if side == "two" else 1.0)))
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
    return float(sps.norm.sf(z))


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
    """Seeded bootstrap CI for a smooth function of column means, fn(mean over seeds)
    (``scipy.stats.bootstrap``, rows resampled together: ``paired=True``).

    Args:
      data: [S] or [S, d] per-seed values.
      fn: maps [..., d] column means to [...] statistics (default: the first column).
      seed: bootstrap seed (``numpy.random.default_rng(seed)``; no global RNG).
      num_resamples: B.
      level, side: as in ``mean_ci``; a one-sided bound at ``level`` is the matching end of
        the two-sided interval at ``2 level - 1`` (BCa adjusts each end on its own).
      method: 'bca' or 'percentile'. BCa falls back to the percentile interval where scipy
        cannot form it (a bootstrap distribution without spread on one side of the estimate).

    Returns:
      (estimate, lower, upper) floats.
    """
    _check_level(level)
    _check_side(side)
    x = np.asarray(data, dtype=np.float64)
    if x.ndim == 1:
        x = x[:, None]
    n, d = x.shape
    if n < 2 or not np.all(np.isfinite(x)):
        raise ValueError(f"bootstrap needs >= 2 finite rows, got shape {x.shape}")
    if method not in ("bca", "percentile"):
        raise ValueError(f"method must be 'bca' or 'percentile', got {method!r}")
    fn = fn if fn is not None else (lambda m: m[..., 0])

    def statistic(*columns, axis=-1):
        return fn(np.stack([c.mean(axis=axis) for c in columns], axis=-1))

    two_sided_level = level if side == "two" else 2.0 * level - 1.0
    kwargs = dict(n_resamples=num_resamples, vectorized=True, paired=True,
                  confidence_level=two_sided_level,
                  batch=max(1, int(2e6 // (n * d))))  # bounds the resampled arrays' memory

    def interval(kind):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", sps.DegenerateDataWarning)
            res = sps.bootstrap(tuple(x.T), statistic, method=kind,
                                rng=np.random.default_rng(seed), **kwargs)
        return float(res.confidence_interval.low), float(res.confidence_interval.high)

    lo, hi = interval("BCa" if method == "bca" else "percentile")
    if not (np.isfinite(lo) and np.isfinite(hi)):
        lo, hi = interval("percentile")
    theta = float(fn(x.mean(axis=0)))
    lo = lo if side in ("two", "lower") else -math.inf
    hi = hi if side in ("two", "upper") else math.inf
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
    return float((sps.norm.ppf(1.0 - alpha) + sps.norm.ppf(power)) * se)


def tail_critical_count(n: int, bound: float, alpha: float = 0.01) -> int:
    """Smallest event count k whose one-sided CP lower bound exceeds ``bound`` (n + 1 if none:
    the test cannot reject). Exact search over k (``binom.isf`` rounds at the boundary)."""
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
    one-sided Clopper–Pearson test with n seeds; 1.0 if the test cannot reject at all.

    With k the critical count, P(Bin(n, q) >= k) = I_q(k, n - k + 1) = power, so q is a beta
    quantile: ``beta.ppf(power, k, n - k + 1)``.
    """
    k = tail_critical_count(n, bound, alpha)
    if k > n:
        return 1.0
    return float(sps.beta.ppf(power, k, n - k + 1))
