"""Tests for sern_jax.analysis.stats against exact sums, definitions and simulated coverage."""

import math
from fractions import Fraction

import numpy as np
import pytest
from scipy import stats as sps

from sern_jax.analysis import stats as st


def _binom_sf_exact(k, n, p):
    """P(Bin(n, p) >= k) in exact rational arithmetic from the float p (independent of scipy)."""
    q = Fraction(p)
    return float(sum(math.comb(n, j) * q**j * (1 - q) ** (n - j) for j in range(k, n + 1)))


def test_clopper_pearson_solves_its_defining_equations():
    # lower: P(Bin(n, lo) >= k) = tail; upper: P(Bin(n, hi) <= k) = tail (exact sums), and the
    # beta-quantile form lo = B^{-1}(tail; k, n-k+1), hi = B^{-1}(1-tail; k+1, n-k).
    n = 500
    ks = np.array([0, 1, 7, 250, 499, 500])
    lo, hi = st.clopper_pearson(ks, n, 0.99)
    assert lo[0] == 0.0 and hi[-1] == 1.0
    for k, l, h in zip(ks, lo, hi):
        if k > 0:
            assert _binom_sf_exact(int(k), n, l) == pytest.approx(0.005, rel=1e-8)
            assert l == pytest.approx(sps.beta.ppf(0.005, k, n - k + 1), abs=1e-12)
        if k < n:
            assert 1.0 - _binom_sf_exact(int(k) + 1, n, h) == pytest.approx(0.005, rel=1e-8)
            assert h == pytest.approx(sps.beta.ppf(0.995, k + 1, n - k), abs=1e-12)
    lo1, hi1 = st.clopper_pearson(7, n, 0.99, side="lower")
    assert hi1 == 1.0 and lo1 == pytest.approx(sps.beta.ppf(0.01, 7, n - 6), rel=1e-9)
    lo2, hi2 = st.clopper_pearson([[3, 9]], [[40, 40]], 0.9, side="upper")
    assert lo2.shape == (1, 2) and np.all(lo2 == 0.0)
    assert hi2[0, 0] == pytest.approx(sps.beta.ppf(0.9, 4, 37), rel=1e-9)
    with pytest.raises(ValueError, match="k <= n"):
        st.clopper_pearson(5, 4)
    with pytest.raises(ValueError, match="side"):
        st.clopper_pearson(1, 4, side="both")


def test_tail_pvalue_is_the_exact_binomial_tail():
    for k, n, p in ((5, 100, 0.02), (1, 10, 0.5), (60, 100, 0.5), (30, 40, 0.3)):
        assert st.tail_pvalue(k, n, p) == pytest.approx(_binom_sf_exact(k, n, p), rel=1e-9)
    assert st.tail_pvalue(0, 10, 0.5) == 1.0 and st.tail_pvalue(11, 10, 0.5) == 0.0


def test_holm_matches_definition():
    p = np.array([0.01, 0.04, 0.03, 0.005])
    reject, adj = st.holm(p, 0.05)
    # sorted: .005*4=.02, .01*3=.03, .03*2=.06, .04*1=.04 -> max-accumulate .02 .03 .06 .06
    np.testing.assert_allclose(adj, [0.03, 0.06, 0.06, 0.02])
    assert reject.tolist() == [True, False, False, True]


def test_t_and_normal_pvalues():
    # one-sided t-test of "E ≤ 0" with mean 1, se 0.5 (t = 2) at 99 seeds: 98 dof
    assert st.t_pvalue(1.0, 0.5, 99, 0.0) == pytest.approx(sps.t.sf(2.0, 98), rel=1e-12)
    assert st.t_pvalue(1.0, 0.5, 5, 2.0, "ge") == pytest.approx(sps.t.sf(2.0, 4), rel=1e-12)
    assert st.t_pvalue(1.0, 0.5, 5, 0.0) > st.mean_pvalue(1.0, 0.5, 0.0)  # t's heavier tail
    assert st.t_pvalue(1.0, 0.0, 5, 0.0) == 0.0 and st.t_pvalue(1.0, 0.0, 5, 2.0) == 1.0
    with pytest.raises(ValueError, match="2 seeds"):
        st.t_pvalue(1.0, 0.5, 1, 0.0)
    assert st.mean_pvalue(1.0, 0.5, 0.0) == pytest.approx(sps.norm.sf(2.0), rel=1e-12)


def test_bootstrap_coverage_and_determinism():
    # Exponential means: 90% two-sided BCa CI should cover the true mean ~90% of the time.
    rng = np.random.default_rng(1)
    cover = 0
    trials = 60
    for i in range(trials):
        x = rng.exponential(size=200)
        _, lo, hi = st.bootstrap_ci(x, seed=i, num_resamples=400, level=0.9)
        cover += lo <= 1.0 <= hi
    assert 0.75 <= cover / trials <= 0.98
    a = st.bootstrap_ci(x, seed=3, num_resamples=300)
    b = st.bootstrap_ci(x, seed=3, num_resamples=300)
    assert a == b


def test_bootstrap_ratio_of_means():
    rng = np.random.default_rng(0)
    x = np.stack([rng.normal(3.0, 1.0, 1000), rng.normal(2.0, 0.1, 1000)], axis=1)
    est, lo, hi = st.bootstrap_ci(x, lambda m: m[..., 0] / m[..., 1], seed=0, num_resamples=500)
    assert lo < 1.5 < hi and est == pytest.approx(x[:, 0].mean() / x[:, 1].mean())


def test_power_statements():
    n, b = 4096, 0.01
    k = st.tail_critical_count(n, b)
    assert st.tail_pvalue(k, n, b) <= 0.01 < st.tail_pvalue(k - 1, n, b)
    p = st.tail_detectable_prob(n, b)
    assert b < p < 2 * b
    assert sps.binom.sf(k - 1, n, p) == pytest.approx(0.8, abs=1e-6)
    # bound < 3/S: can only reject with many events relative to the bound.
    assert st.tail_detectable_prob(100, 1e-4) > 10 * 1e-4
    assert st.mean_detectable_excess(1.0) == pytest.approx(sps.norm.ppf(0.99) + sps.norm.ppf(0.8))
    # the t-test's: noncentral t with 80% above t_{0.99, n-1}; tends to the normal form
    d = st.t_detectable_excess(1.0, 5)
    assert sps.nct.sf(sps.t.ppf(0.99, 4), 4, d) == pytest.approx(0.8, abs=1e-8)
    assert st.t_detectable_excess(1.0, 10_000) == pytest.approx(
        st.mean_detectable_excess(1.0), rel=1e-3)
