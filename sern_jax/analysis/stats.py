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

Every interval over seeds takes Student's t with n − 1 degrees of freedom (``t_interval``,
``paired_differences``), never a normal quantile: at n = 5 the normal interval is 29 % too
narrow (t_{0.975, 4} = 2.776). The theory checks (``proofs_check.framework.mean_cell``) use the
same t interval, with the matching one-sided t-test p-value (``t_pvalue``) and power statement
(``t_detectable_excess``), so a check's interval and its verdict agree. ``mean_pvalue`` and
``mean_detectable_excess`` keep the normal form for a bootstrap cell, whose spread is fitted
by a normal, not estimated from n − 1 degrees of freedom.

Estimates of a maximum (the best candidate of a context, the regret oracle's argmax) are
valued on trials independent of those that chose it (``independent_best``,
``oracle_regret``): the maximum of 64 noisy frequencies is biased upward.
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
    "SeedInterval",
    "t_interval",
    "t_half_width",
    "PairedDifference",
    "paired_differences",
    "independent_best",
    "oracle_regret",
    "mean_pvalue",
    "t_pvalue",
    "bootstrap_ci",
    "holm",
    "mean_detectable_excess",
    "t_detectable_excess",
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


class SeedInterval(NamedTuple):
    """A mean over seeds with its Student-t interval (n − 1 degrees of freedom)."""

    mean: float
    sd: float  # sample standard deviation over seeds (ddof = 1)
    se: float  # sd / sqrt(n)
    n: int  # seeds
    half: float  # t_{(1+level)/2, n-1} * se
    lower: float  # mean - half
    upper: float  # mean + half
    level: float  # two-sided confidence level


def t_half_width(sd, n, level: float = 0.95):
    """Half-width t_{(1+level)/2, n−1} · sd / √n of the two-sided Student-t interval
    (elementwise; NaN where n < 2). The one place a seed interval's multiplier comes from."""
    _check_level(level)
    sd = np.asarray(sd, dtype=np.float64)
    n = np.asarray(n, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        q = sps.t.ppf(0.5 + level / 2.0, np.where(n >= 2, n - 1.0, np.nan))
        half = q * sd / np.sqrt(n)
    return half if half.ndim else float(half)


def t_interval(x, level: float = 0.95, axis: int = -1):
    """Student-t interval for the mean of i.i.d. per-seed values.

    Args:
      x: per-seed values; the seed axis is ``axis`` (default last). NaN or inf are an error.
      level: two-sided confidence level (default 0.95).
      axis: the seed axis.

    Returns:
      SeedInterval of floats for 1-D ``x``; of arrays (the other axes) otherwise. With one
      seed the mean is returned and sd, se, half, lower and upper are NaN (no interval).
    """
    _check_level(level)
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == 0:
        raise ValueError("t_interval needs an array of per-seed values")
    if not np.all(np.isfinite(x)):
        raise ValueError("per-seed values contain NaN or inf")
    x = np.moveaxis(x, axis, -1)
    n = x.shape[-1]
    if n < 1:
        raise ValueError("t_interval needs at least one seed")
    mean = x.mean(-1)
    sd = x.std(-1, ddof=1) if n >= 2 else np.full(mean.shape, np.nan)
    se = sd / math.sqrt(n)
    half = np.asarray(t_half_width(sd, n, level))
    out = SeedInterval(mean, sd, se, n, half, mean - half, mean + half, level)
    if x.ndim == 1:
        return SeedInterval(*(float(v) if i not in (3,) else int(v) for i, v in
                              enumerate(out[:-1])), level)
    return out


class PairedDifference(NamedTuple):
    """One paired comparison a − b over seeds (common random numbers pair the seeds)."""

    name: str
    mean: float
    sd: float
    se: float
    n: int
    half: float  # Student-t half-width at ``level`` (per comparison, unadjusted)
    lower: float
    upper: float
    pvalue: float  # two-sided paired t-test of mean 0
    pvalue_holm: float  # Holm-adjusted across the comparisons reported together
    resolved: bool  # pvalue_holm <= 1 - level: the sign is resolved after Holm
    half_family: float  # Bonferroni half-width at level over the m comparisons (simultaneous)


def paired_differences(a, b=None, names=None, level: float = 0.95) -> list[PairedDifference]:
    """Paired differences over seeds with Student-t intervals and Holm across comparisons.

    Args:
      a: [m, S] per-seed values of the m left-hand sides (or the [m, S] differences
        themselves when ``b`` is None).
      b: None or [m, S] (or [S], broadcast) per-seed values of the right-hand sides; seed s of
        a and b must share their random numbers.
      names: m labels (default "0", "1", ...).
      level: confidence level of each interval; Holm controls the family-wise error rate
        at 1 − level for the m sign decisions.

    Returns:
      m PairedDifference. ``half`` is each comparison's own t-interval; ``resolved`` says
      whether 0 is rejected after Holm's correction over the m comparisons; ``half_family``
      widens each interval to Bonferroni's simultaneous level (1 − (1 − level)/m), for
      readers who want intervals that hold together.
    """
    _check_level(level)
    d = np.asarray(a, np.float64)
    if b is not None:
        d = d - np.asarray(b, np.float64)
    d = np.atleast_2d(d)
    if d.ndim != 2:
        raise ValueError(f"need [m, S] per-seed values, got shape {d.shape}")
    m, n = d.shape
    if n < 2:
        raise ValueError(f"paired differences need at least 2 seeds, got {n}")
    if not np.all(np.isfinite(d)):
        raise ValueError("per-seed values contain NaN or inf")
    names = [str(i) for i in range(m)] if names is None else [str(v) for v in names]
    if len(names) != m:
        raise ValueError(f"{len(names)} names for {m} comparisons")
    ci = t_interval(d, level)
    with np.errstate(invalid="ignore", divide="ignore"):
        tstat = np.where(ci.se > 0, ci.mean / ci.se, np.where(ci.mean == 0, 0.0, np.inf))
    p = 2.0 * sps.t.sf(np.abs(tstat), n - 1)
    _, p_holm = holm(p, 1.0 - level)
    half_family = np.asarray(t_half_width(ci.sd, n, 1.0 - (1.0 - level) / m))
    return [PairedDifference(names[i], float(ci.mean[i]), float(ci.sd[i]), float(ci.se[i]),
                             n, float(ci.half[i]), float(ci.lower[i]), float(ci.upper[i]),
                             float(p[i]), float(p_holm[i]), bool(p_holm[i] <= 1.0 - level),
                             float(half_family[i]))
            for i in range(m)]


def _best_of(select, valid):
    """Mask [..., K] of the arms that maximise ``select`` among the valid ones (ties all
    kept), and whether any arm is valid [...]."""
    select = np.asarray(select, np.float64)
    valid = np.ones(select.shape, bool) if valid is None else np.asarray(valid, bool)
    if valid.shape != select.shape:
        valid = np.broadcast_to(valid, select.shape)
    score = np.where(valid, select, -np.inf)
    top = score.max(-1, keepdims=True)
    return (score == top) & valid, valid.any(-1)


def independent_best(select, value, valid=None):
    """The best arm chosen on one set of trials, valued on an independent set.

    ``max_a value_a`` (or the value of the argmax of the same trials) overstates the best
    arm's success: with 64 arms of true success 0.4 and 8 trials each, the largest frequency
    averages about 0.8. Choosing with ``select`` and valuing with ``value`` (trials
    independent of ``select``'s) gives an unbiased estimate of the chosen arm's true value,
    which is at most the true best (a conservative estimate of the best arm's value).

    Args:
      select: [..., K] success frequencies (or counts) from the selection trials.
      value: [..., K] success frequencies from independent trials of the same arms.
      valid: optional [..., K] bool mask (invalid arms are never chosen).

    Returns:
      (best_value [...], chosen [..., K] bool): the mean of ``value`` over the arms tied at
      the top of ``select`` (ties share the choice equally, the expected value of a random
      tie-break), and the tied set. A context with no valid arm gets NaN.
    """
    value = np.asarray(value, np.float64)
    chosen, any_valid = _best_of(select, valid)
    if value.shape != chosen.shape:
        raise ValueError(f"select and value shapes differ: {chosen.shape} vs {value.shape}")
    with np.errstate(invalid="ignore"):
        best = np.where(chosen, value, 0.0).sum(-1) / chosen.sum(-1)
    return np.where(any_valid, best, np.nan), chosen


def oracle_regret(select, value, probs, valid=None):
    """Per-grasp pseudo-regret against an oracle whose argmax and value come from
    independent trials.

    regret = value[argmax select] − Σ_a π(a) value_a, with ``value`` independent of
    ``select``: an unbiased estimate of r(a*) − Σ_a π(a) r_a for the arm a* that the
    selection trials choose. Taking the max and the value from the same trials (the
    previous oracle) adds the upward bias of a maximum of noisy frequencies to every
    policy's regret. (The estimate is conservative with respect to the true best arm: a*
    may not be it, so the regret against the true best is at least this in expectation.)

    Args:
      select: [..., K] success frequencies of the selection trials.
      value: [..., K] success frequencies of independent trials of the same arms.
      probs: [..., K] the policy's distribution over arms (zero on invalid arms), any
        leading shape that broadcasts with ``value`` (e.g. select/value [O, S, 1, E, K],
        probs [O, S, Q, E, K]).
      valid: optional mask broadcastable to ``select``.

    Returns:
      [...] pseudo-regret per grasp (the broadcast leading shape); NaN where no arm is valid.
    """
    value = np.asarray(value, np.float64)
    probs = np.asarray(probs, np.float64)
    best, _ = independent_best(select, value, valid)
    expected = (probs * value).sum(-1)
    return best - expected


def mean_pvalue(mean: float, se: float, bound: float, direction: str = "le") -> float:
    """One-sided CLT p-value for H0: E[X] <= bound ('le') or E[X] >= bound ('ge')."""
    if se <= 0:
        if direction == "le":
            return 0.0 if mean > bound else 1.0
        return 0.0 if mean < bound else 1.0
    z = (mean - bound) / se if direction == "le" else (bound - mean) / se
    return float(sps.norm.sf(z))


def t_pvalue(mean: float, se: float, n: int, bound: float, direction: str = "le") -> float:
    """One-sided Student-t p-value (n − 1 degrees of freedom) for H0: E[X] <= bound ('le') or
    E[X] >= bound ('ge'), from the mean and se = sd/√n of n i.i.d. per-seed values; the test
    whose one-sided interval is ``t_interval(x, 1 − 2·alpha)``'s matching end.

    With se = 0 (every seed equal) the values are treated as exact: 0 when the mean lies on
    the violating side, 1 otherwise.
    """
    n = int(n)
    if n < 2:
        raise ValueError(f"a t-test needs at least 2 seeds, got {n}")
    if direction not in ("le", "ge"):
        raise ValueError(f"direction must be 'le' or 'ge', got {direction!r}")
    if se <= 0:
        return mean_pvalue(mean, 0.0, bound, direction)
    t = (mean - bound) / se if direction == "le" else (bound - mean) / se
    return float(sps.t.sf(t, n - 1))


def t_detectable_excess(se: float, n: int, alpha: float = 0.01, power: float = 0.8) -> float:
    """Smallest true excess E[X] − B that the one-sided t-test at level alpha (n − 1 degrees of
    freedom) detects with the given power: se·δ where the noncentral t with noncentrality δ
    exceeds t_{1−alpha, n−1} with probability ``power`` (exact, ``scipy.stats.nct``; for large
    n it tends to (z_{1−alpha} + z_power)·se, ``mean_detectable_excess``)."""
    from scipy.optimize import brentq

    n = int(n)
    if n < 2:
        raise ValueError(f"a t-test needs at least 2 seeds, got {n}")
    if se <= 0:
        return 0.0
    df = n - 1
    crit = float(sps.t.ppf(1.0 - alpha, df))
    hi = crit + float(sps.t.ppf(power, df)) + 1.0
    while sps.nct.sf(crit, df, hi) < power:
        hi *= 2.0
    delta = brentq(lambda d: sps.nct.sf(crit, df, d) - power, 0.0, hi, xtol=1e-10)
    return float(delta * se)


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
      level, side: as in ``clopper_pearson``; a one-sided bound at ``level`` is the matching end of
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
