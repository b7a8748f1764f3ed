"""Tests for sern_jax.stats against scipy and by simulated coverage."""

import numpy as np
import pytest
from scipy import stats as sps

from sern_jax import stats as st


def test_beta_quantile_matches_scipy():
    q = np.array([1e-6, 0.005, 0.3, 0.99, 0.999999])
    for a, b in ((0.5, 0.5), (2.5, 7.0), (1.0, 4096.0), (3000.0, 1097.0)):
        np.testing.assert_allclose(st.beta_quantile(q, a, b), sps.beta.ppf(q, a, b), rtol=1e-9, atol=1e-15)


def test_clopper_pearson_matches_scipy():
    n = 500
    ks = np.array([0, 1, 7, 250, 499, 500])
    lo, hi = st.clopper_pearson(ks, n, 0.99)
    for k, l, h in zip(ks, lo, hi):
        ci = sps.binomtest(int(k), n).proportion_ci(0.99, "exact")
        assert l == pytest.approx(ci.low, abs=1e-12)
        assert h == pytest.approx(ci.high, abs=1e-12)
    lo1, hi1 = st.clopper_pearson(7, n, 0.99, side="lower")
    assert hi1 == 1.0 and lo1 == pytest.approx(sps.beta.ppf(0.01, 7, n - 6), rel=1e-9)


def test_binom_sf_matches_scipy():
    for k, n, p in ((5, 100, 0.02), (0, 10, 0.5), (60, 100, 0.5)):
        assert st.binom_sf(k, n, p) == pytest.approx(sps.binom.sf(k - 1, n, p), rel=1e-9, abs=1e-300)


def test_holm_matches_definition():
    p = np.array([0.01, 0.04, 0.03, 0.005])
    reject, adj = st.holm(p, 0.05)
    # sorted: .005*4=.02, .01*3=.03, .03*2=.06, .04*1=.04 -> max-accumulate .02 .03 .06 .06
    np.testing.assert_allclose(adj, [0.03, 0.06, 0.06, 0.02])
    assert reject.tolist() == [True, False, False, True]


def test_mean_ci_and_pvalue():
    x = np.arange(100.0)
    ci = st.mean_ci(x, 0.99, side="lower")
    assert ci.upper == np.inf
    z = sps.norm.ppf(0.99)
    assert ci.lower == pytest.approx(49.5 - z * x.std(ddof=1) / 10, rel=1e-12)
    assert st.mean_pvalue(1.0, 0.5, 0.0) == pytest.approx(sps.norm.sf(2.0), rel=1e-12)
    with pytest.raises(ValueError, match="level"):
        st.mean_ci(x, 1.5)


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
