"""Tests for sern_jax.analysis.theory: closed forms against brute force and the audit's tables."""

import math

import numpy as np
import pytest
from scipy import stats as sps

from sern_jax.analysis import theory as th


def test_pi_min_is_softmax_minimum_and_c_is_below():
    # Brute force: softmax of r_hat with one arm at 0 and the rest at 1 (range 1).
    for K in (2, 10, 64):
        for alpha in (0.05, 0.3, 1.0, 10.0):
            logits = np.r_[0.0, np.ones(K - 1)] / alpha
            pi = np.exp(logits - logits.max())
            pi /= pi.sum()
            assert th.thm1_pi_min(alpha, K) == pytest.approx(pi[0], rel=1e-12)
            ratio = th.thm1_looseness(alpha, K)
            assert 1.0 <= ratio <= K / (K - 1) + 1e-12


def test_thm1_c_experiment_value():
    # audit §0: c = 3.2e-11 at alpha = 0.05, K = 64.
    assert th.thm1_c(0.05, 64) == pytest.approx(math.exp(-20) / 64, rel=1e-12)
    assert 3.2e-11 < th.thm1_c(0.05, 64) < 3.3e-11


def test_bad_input_raises():
    with pytest.raises(ValueError, match="alpha"):
        th.thm1_c(0.0, 2)
    with pytest.raises(ValueError, match="num_arms"):
        th.thm1_c(1.0, 1)
    with pytest.raises(ValueError, match="log_t"):
        th.thm4_log_bound(0.0, 2, 0.1, 0.2, 1.0, 0.1)


def test_log_binom_cdf_matches_scipy():
    for n, p in ((10, 0.3), (1000, 0.01), (5000, 0.5)):
        ks = np.arange(n + 1)
        ref = sps.binom.logcdf(ks, n, p)
        got = th.log_binom_cdf_all(n, p)
        sel = ref > -700
        np.testing.assert_allclose(got[sel], ref[sel], rtol=1e-9, atol=1e-9)


def test_kappa_audit_table():
    # audit §2.4 (i): kappa_min in [2.1, 2.4] for K = 2, alpha = 100 (pi ~ c ~ 1/2).
    for t in (100, 1000, 10_000):
        r = th.thm2_exact_kappa(t, float(th.thm1_pi_min(100.0, 2)), float(th.thm1_c(100.0, 2)))
        assert 2.05 < r.kappa_min < 2.45
        assert r.kappa_min < 8.0  # the false constant 8 is rejected


def test_kappa_is_min_over_all_deltas_bruteforce():
    # Brute force over a fine delta grid: kappa_min is a lower envelope.
    t, K, alpha = 200, 2, 10.0
    pi, c = float(th.thm1_pi_min(alpha, K)), float(th.thm1_c(alpha, K))
    r = th.thm2_exact_kappa(t, pi, c)
    deltas = np.linspace(1e-3, c * t, 20_000)
    m = np.ceil(c * t - deltas) - 1
    p = sps.binom.cdf(m, t, pi)
    ok = (p <= 0.1) & (p > 0)
    kap = -np.log(p[ok]) * t / deltas[ok] ** 2
    assert r.kappa_min <= kap.min() + 1e-9
    assert r.kappa_min >= kap.min() * (1 - 1e-2)


def test_tail_bound_ordering():
    d, t, c = 30.0, 1000.0, 0.1
    assert th.thm2_log_tail_azuma(d, t) < th.thm2_log_tail_paper(d, t)
    assert th.thm2_log_tail_freedman(d, t, c) < th.thm2_log_tail_azuma(d, t)


def test_neg_log1mexp_all_regimes():
    for log_x in (-60.0, -35.0, -29.0, -5.0, 0.0, 0.5, 3.0):
        x = math.exp(log_x)
        ref = -math.log(-math.expm1(-x))
        assert th.neg_log1mexp(log_x) == pytest.approx(ref, rel=1e-12)


# audit §4 table: (K, beta, Delta2, alpha0, p) -> (log10 T*, log10 T_Delta, corrected, dominant)
AUDIT_ROWS = [
    ((2, 0.1, 0.2, 1.0, 0.1), 4.9, 15.1, 3.1, 4),
    ((2, 0.1, 0.2, 1.0, 0.2), 6.6, 11.6, 1.7, 1),
    ((2, 1.0, 0.05, 0.1, 0.3), 460.3, 463.5, math.inf, 3),
    ((10, 0.1, 0.05, 1.0, 0.1), 10.5, 200.0, 10.0, 4),
    ((64, 1.0, 0.05, 0.1, 0.3), 472.3, 475.6, math.inf, 3),
    ((64, 0.1, 0.2, 1.0, 0.3), 69.1, 86.0, 6.1, 1),
]


@pytest.mark.parametrize("row,t_star,t_delta,corr,dominant", AUDIT_ROWS)
def test_thm4_crossings_match_audit(row, t_star, t_delta, corr, dominant):
    K, beta, d2, a0, p = row
    got = th.thm4_crossing(*row)
    assert got == pytest.approx(t_star, abs=0.06)
    assert th.thm4_crossing(*row, fraction=d2) == pytest.approx(t_delta, abs=0.06)
    c = th.corrected_crossing(K, beta, a0, p)
    assert c == pytest.approx(corr, abs=0.06) if math.isfinite(corr) else c == math.inf
    terms = th.thm4_log_terms(got * th.LN10, *row)
    assert int(np.argmax(terms)) + 1 == dominant


def test_thm4_log_bound_matches_naive_where_naive_is_finite():
    K, beta, d2, a0, p = 2, 0.1, 0.2, 1.0, 0.1
    for T in (1e2, 1e4, 1e6):
        c0 = math.exp(-1 / a0)
        naive = (
            2**3.5 * K**1.5 * beta * c0**-1.5 * T ** ((3 * p + 1) / 2)
            + 2 * beta * K / (1 - math.exp(-(c0**2) / (32 * K**2) * T ** (-2 * p)))
            + 2 * (K - 1) * math.exp((beta / d2) ** 2 - 0.25)
            / (1 - math.exp(-(c0**2) / (8 * K**2) * T ** (-2 * p)))
            + a0 * math.log(K) * T / math.log(T**p)
        )
        got = math.exp(th.thm4_log_bound(math.log(T), K, beta, d2, a0, p))
        assert got == pytest.approx(naive, rel=1e-8)


def test_thm4_bound_finite_where_float_overflows():
    # beta/Delta2 = 33 overflows exp() in float64; alpha0 = 0.1, K = 64 cancels 1 - e^{-x}.
    v = th.thm4_log_bound(math.log(1e6), 64, 1.0, 0.03, 0.1, 0.3)
    assert np.isfinite(v) and v / th.LN10 > 300


def test_flip_term3_violated_analytically():
    # audit §3.7: claimed term 3 = 918.5 at T = 1e6, p = 0.02; floor 979.
    t3 = math.exp(th.thm4_log_terms(math.log(1e6), 2, 0.3, 0.5, 1.0, 0.02)[2])
    assert t3 == pytest.approx(918.5, abs=0.1)
    assert th.flip_misid_floor(1e6, 0.49) == pytest.approx(979.0, abs=0.1)


def test_c_consistency():
    L = np.linspace(0.1, 200.0, 2000)
    for a0 in (1.0, 2.0):
        for p in (0.1, 0.3):
            assert np.all(th.thm4_c_log_ratio(L, 10, a0, p) >= -1e-12)
    r = th.thm4_c_log_ratio(L, 2, 0.1, 0.3)
    assert np.any(r < 0)
    assert th.thm4_c_violation_log_t(0.1, 0.3) == pytest.approx(1 / 0.27)


def test_certified_crossings():
    assert th.certified_crossing(0.2, 0.1, 0.15) == pytest.approx(32.2, abs=0.06)
    assert th.certified_crossing(0.1, 0.1, 0.3) == pytest.approx(180.4, abs=0.1)
    # No certificate when alpha0 >= g p.
    assert th.certified_crossing(0.2, 1.0, 0.15) == math.inf


def test_exact_oracle_regret_and_worst_case():
    T, d, a0, p = 1000.0, 0.2, 1.0, 0.3
    alpha = a0 / (p * math.log(T))
    pi2 = 1.0 / (1.0 + math.exp(d / alpha))
    assert th.exact_oracle_regret_k2(T, d, a0, p) == pytest.approx(d * pi2 * T, rel=1e-12)
    assert th.worst_case_x() == pytest.approx(1.278464542761074, rel=1e-12)
    T = 1e6
    m, dstar = th.max_regret_over_delta(T, 1.0, 0.3)
    grid = np.linspace(1e-4, 1.0, 200_001)
    assert m == pytest.approx(th.exact_oracle_regret_k2(T, grid, 1.0, 0.3).max(), rel=1e-6)
    assert m / T == pytest.approx(0.067, abs=5e-4)  # audit §3.10


def test_host_alpha_is_the_traced_schedule_and_feeds_theorem1():
    # one α(T) (schedules), evaluated on the host and in traced code, gives the same float64
    import jax
    import jax.numpy as jnp

    from sern_jax.core import schedules

    with jax.enable_x64():
        for kind in schedules.SCHEDULE_NAMES:
            for horizon, a0, p in ((10, 1.0, 0.3), (1000, 0.5, 0.2), (10**6, 2.0, 0.1)):
                traced = schedules.alpha_t(kind, 0, horizon, jnp.float64(a0), jnp.float64(p))
                host = schedules.alpha_of_horizon(kind, horizon, a0, p)
                assert float(host) == pytest.approx(float(traced), rel=1e-15), (kind, horizon)
    assert float(schedules.alpha_of_horizon("log", 1000, 1.0, 0.3)) == 1.0 / (0.3 * math.log(1000))
    log_t = np.array([2.0, 50.0, 180.0])  # T up to e^180: beyond float range as a horizon
    np.testing.assert_allclose(schedules.alpha_of_log_horizon("theorem4", log_t, 0.5, 0.3),
                               0.5 / (1 + 0.5 * 0.3 * log_t), rtol=1e-15)
    with pytest.raises(ValueError, match="cosine"):
        schedules.alpha_of_horizon("cosine", 10, 1.0, 0.3)
