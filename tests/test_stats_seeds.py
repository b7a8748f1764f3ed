"""Seed intervals (Student t), paired differences with Holm, and the independent-trials
oracle / best-arm estimate."""

import math

import numpy as np
import pytest
from scipy import stats as sps

from sern_jax.analysis import stats as st


@pytest.mark.parametrize("n", [2, 5, 20])
def test_t_interval_matches_scipy_t_quantiles(n):
    rng = np.random.default_rng(n)
    x = rng.normal(3.0, 2.0, n)
    ci = st.t_interval(x, 0.95)
    sd = x.std(ddof=1)
    q = sps.t.ppf(0.975, n - 1)  # scipy's quantile: 12.706 (n=2), 2.776 (5), 2.093 (20)
    assert ci.n == n
    assert ci.mean == pytest.approx(x.mean(), rel=1e-12)
    assert ci.sd == pytest.approx(sd, rel=1e-12)
    assert ci.se == pytest.approx(sd / math.sqrt(n), rel=1e-12)
    assert ci.half == pytest.approx(q * sd / math.sqrt(n), rel=1e-12)
    assert ci.lower == pytest.approx(x.mean() - ci.half, rel=1e-12)
    assert ci.upper == pytest.approx(x.mean() + ci.half, rel=1e-12)
    # scipy's own t interval agrees
    lo, hi = sps.t.interval(0.95, n - 1, loc=x.mean(), scale=sd / math.sqrt(n))
    assert (ci.lower, ci.upper) == pytest.approx((lo, hi), rel=1e-10)
    # control: the normal 1.96 interval is narrower and does not pass the same check
    half_z = 1.96 * sd / math.sqrt(n)
    assert half_z < ci.half and half_z != pytest.approx(ci.half, rel=1e-3)


def test_t_interval_covers_at_its_level_where_196_undercovers():
    # 20,000 samples of n = 5 normal values: the t interval covers ~95 %, the 1.96 one ~88 %.
    rng = np.random.default_rng(0)
    x = rng.normal(0.0, 1.0, (20_000, 5))
    ci = st.t_interval(x, 0.95)
    cover_t = np.mean((ci.lower <= 0) & (0 <= ci.upper))
    half_z = 1.96 * ci.se
    cover_z = np.mean(np.abs(ci.mean) <= half_z)
    assert abs(cover_t - 0.95) < 5 * math.sqrt(0.95 * 0.05 / 20_000)
    assert cover_z < 0.90


def test_t_interval_axis_one_seed_and_bad_input():
    x = np.arange(12.0).reshape(3, 4)
    ci = st.t_interval(x, 0.9, axis=0)
    np.testing.assert_allclose(ci.mean, x.mean(0))
    np.testing.assert_allclose(ci.half, sps.t.ppf(0.95, 2) * x.std(0, ddof=1) / math.sqrt(3))
    one = st.t_interval([0.7])
    assert one.mean == 0.7 and one.n == 1 and math.isnan(one.half)
    with pytest.raises(ValueError, match="NaN"):
        st.t_interval([1.0, np.nan])
    with pytest.raises(ValueError, match="level"):
        st.t_interval([1.0, 2.0], 1.0)
    assert math.isnan(st.t_half_width(1.0, 1))
    assert st.t_half_width(2.0, 5) == pytest.approx(sps.t.ppf(0.975, 4) * 2 / math.sqrt(5))


def test_holm_hand_worked():
    # p = (0.012, 0.030, 0.004), m = 3, alpha = 0.05. Sorted: 0.004 (x3 = 0.012 <= 0.05,
    # reject), 0.012 (x2 = 0.024 <= 0.05, reject), 0.030 (x1 = 0.030 <= 0.05, reject).
    reject, adj = st.holm([0.012, 0.030, 0.004], 0.05)
    np.testing.assert_allclose(adj, [0.024, 0.030, 0.012])
    assert reject.tolist() == [True, True, True]
    # p = (0.020, 0.030, 0.010): 0.010 x3 = 0.030 reject; 0.020 x2 = 0.040 reject;
    # 0.030 x1 = 0.030 but monotone: max(0.040, 0.030) = 0.040 <= 0.05 reject.
    # At alpha = 0.035: 0.030 rejects, then 0.040 > 0.035 stops: only the smallest.
    reject, adj = st.holm([0.020, 0.030, 0.010], 0.035)
    np.testing.assert_allclose(adj, [0.040, 0.040, 0.030])
    assert reject.tolist() == [False, False, True]
    # Bonferroni would reject none of these at 0.035 except 0.010 (0.030); unadjusted all.


def test_paired_differences_t_and_holm():
    rng = np.random.default_rng(1)
    n = 10
    base = rng.normal(0.7, 0.1, n)
    a = np.stack([base + 0.05 + rng.normal(0, 0.02, n),   # clear positive difference
                  base + rng.normal(0, 0.02, n)])          # no difference
    rows = st.paired_differences(a, base, names=["big", "none"], level=0.95)
    d = a - base
    for row, di in zip(rows, d):
        se = di.std(ddof=1) / math.sqrt(n)
        assert row.mean == pytest.approx(di.mean())
        assert row.half == pytest.approx(sps.t.ppf(0.975, n - 1) * se)
        assert row.pvalue == pytest.approx(sps.ttest_1samp(di, 0.0).pvalue, rel=1e-9)
        assert row.half_family == pytest.approx(sps.t.ppf(1 - 0.025 / 2, n - 1) * se)
    _, adj = st.holm([r.pvalue for r in rows], 0.05)
    assert [r.pvalue_holm for r in rows] == pytest.approx(adj.tolist())
    assert rows[0].resolved and rows[0].name == "big"
    assert not rows[1].resolved
    with pytest.raises(ValueError, match="2 seeds"):
        st.paired_differences([[1.0]], [[0.0]])


def test_independent_best_is_unbiased_where_the_max_is_not():
    # 64 arms that all succeed with probability 0.4, 8 trials each: the largest frequency
    # averages ~0.8; the argmax valued on 8 independent trials averages 0.4.
    rng = np.random.default_rng(2)
    reps, k, m = 4000, 64, 8
    sel = rng.binomial(m, 0.4, (reps, k)) / m
    val = rng.binomial(m, 0.4, (reps, k)) / m
    naive = sel.max(-1)
    best, chosen = st.independent_best(sel, val)
    assert naive.mean() > 0.75
    se = best.std() / math.sqrt(reps)
    assert abs(best.mean() - 0.4) < 5 * se
    assert chosen.any(-1).all()
    # invalid arms are never chosen; no valid arm gives NaN
    valid = np.zeros((2, 4), bool)
    valid[0, 1] = True
    b, c = st.independent_best(np.array([[1.0, 0.1, 0.9, 0.9]] * 2),
                               np.array([[0.0, 0.5, 0.0, 0.0]] * 2), valid)
    assert b[0] == 0.5 and math.isnan(b[1]) and c[0].tolist() == [False, True, False, False]


def test_oracle_regret_recovers_a_known_regret():
    # Synthetic table: C contexts x K arms with true success r; policy "uniform over valid"
    # and policy "always arm 0". The true best arm (r = 0.9) is unique with a large gap, so
    # the selection trials find it w.h.p. and the true regret is known exactly:
    #   uniform: 0.9 - mean(r);  arm 0: 0.9 - 0.5.
    rng = np.random.default_rng(3)
    reps, k, m = 3000, 16, 32
    r = np.full(k, 0.3)
    r[0], r[5] = 0.5, 0.9
    probs = np.stack([np.full(k, 1 / k), np.eye(k)[0]])  # [Q=2, K]
    true = np.array([0.9 - r.mean(), 0.9 - 0.5])
    sel = rng.binomial(m, r, (reps, 1, k)) / m
    val = rng.binomial(m, r, (reps, 1, k)) / m
    reg = st.oracle_regret(sel, val, probs[None])  # [reps, 2]
    assert reg.shape == (reps, 2)
    se = reg.std(0) / math.sqrt(reps)
    assert np.all(np.abs(reg.mean(0) - true) < 5 * se)
    # all arms equal (r = 0.4): every policy's true regret is 0; the same-trials oracle
    # (max and value from one set) reports a clearly positive regret, the independent one 0.
    r2 = np.full(64, 0.4)
    sel = rng.binomial(8, r2, (reps, 1, 64)) / 8
    val = rng.binomial(8, r2, (reps, 1, 64)) / 8
    p2 = np.full((1, 1, 64), 1 / 64)
    same = (sel.max(-1) - (p2 * sel).sum(-1)).mean()
    indep = st.oracle_regret(sel, val, p2)
    assert same > 0.3
    assert abs(indep.mean()) < 5 * indep.std() / math.sqrt(indep.size)
