"""proofs_check.framework's mean cells are Student-t (n − 1 dof) intervals over seeds, interval
and p-value alike, checked against scipy.stats.t on small-n cells where t and z differ."""

import math

import numpy as np
import pytest
from scipy import stats as sps

from sern_jax.analysis import stats as st
from sern_jax.commands.scripts import script_module

framework = script_module("proofs_check", "framework")

X5 = np.array([0.0, 1.0, 2.0, 3.0, 4.0])  # mean 2, sd √2.5, se √0.5, 4 dof
SE5 = math.sqrt(2.5 / 5)


def test_mean_cell_interval_is_student_t_at_small_n():
    alpha = 0.01
    le = framework.mean_cell("le", X5, 10.0, "le", alpha)
    ge = framework.mean_cell("ge", X5, -10.0, "ge", alpha)
    t1, t2 = sps.t.ppf(1 - alpha, 4), sps.t.ppf(1 - alpha / 2, 4)  # 3.747, 4.604
    assert le.statistic == pytest.approx(2.0)
    assert le.lower == pytest.approx(2.0 - t1 * SE5, rel=1e-12)  # tested end, one-sided
    assert le.upper == pytest.approx(2.0 + t2 * SE5, rel=1e-12)  # other end, two-sided
    assert ge.upper == pytest.approx(2.0 + t1 * SE5, rel=1e-12)
    assert ge.lower == pytest.approx(2.0 - t2 * SE5, rel=1e-12)
    # not the normal interval: at 4 dof the t end is 61% further out than z's 2.326
    assert le.lower < 2.0 - 1.5 * sps.norm.ppf(1 - alpha) * SE5
    # p-value of "the claim holds" is the one-sided t-test's
    assert le.pvalue == pytest.approx(sps.t.sf((2.0 - 10.0) / SE5, 4), rel=1e-12)
    assert ge.pvalue == pytest.approx(sps.t.sf((-10.0 - 2.0) / SE5, 4), rel=1e-12)
    near = framework.mean_cell("near", X5, 0.5, "le", alpha)
    assert near.pvalue == pytest.approx(sps.t.sf((2.0 - 0.5) / SE5, 4), rel=1e-12)


def test_verdict_between_z_and_t_ends_is_t_s():
    """A bound 3 SE below the mean: a z test (2.326 SE) would reject 'E ≤ bound', the t test
    (3.747 SE at 4 dof) must not; 4 SE below, both reject (the control that fails)."""
    z1, t1 = sps.norm.ppf(0.99), sps.t.ppf(0.99, 4)
    between = 2.0 - 3.0 * SE5
    assert 2.0 - z1 * SE5 > between > 2.0 - t1 * SE5  # z would reject, t does not
    cell = framework.mean_cell("between", X5, between, "le")
    assert framework.decide([cell], 0.01) == framework.PASS
    assert cell.lower < between and cell.pvalue > 0.01
    # the normal-approximation p-value on the same numbers rejects: the cell really moved
    assert st.mean_pvalue(2.0, SE5, between, "le") < 0.01
    control = framework.mean_cell("beyond", X5, 2.0 - 4.0 * SE5, "le")
    assert framework.decide([control], 0.01) == framework.FAIL
    assert control.lower > control.bound and control.pvalue < 0.01
    # mirrored for 'ge'
    up = framework.mean_cell("ge", X5, 2.0 + 3.0 * SE5, "ge")
    assert framework.decide([up], 0.01) == framework.PASS
    assert framework.decide([framework.mean_cell("ge4", X5, 2.0 + 4.0 * SE5, "ge")],
                            0.01) == framework.FAIL


def test_interval_excludes_bound_iff_pvalue_below_alpha():
    rng = np.random.default_rng(3)
    for n in (3, 8, 40):
        x = rng.normal(size=n)
        for bound in np.linspace(-3, 3, 61):
            for direction in ("le", "ge"):
                c = framework.mean_cell("c", x, bound, direction, 0.05)
                excluded = c.lower > bound if direction == "le" else c.upper < bound
                assert excluded == (c.pvalue <= 0.05), (n, bound, direction)


def test_equal_cell_is_two_sided_t():
    cell = framework.equal_cell("eq", X5, 2.0 + 5.0 * SE5, 0.01)
    t2 = sps.t.ppf(0.995, 4)
    assert (cell.lower, cell.upper) == pytest.approx((2.0 - t2 * SE5, 2.0 + t2 * SE5), rel=1e-12)
    assert cell.pvalue == pytest.approx(2 * sps.t.sf(5.0, 4), rel=1e-12)
    # 5 SE away: z (2.576) would reject equality, t at 4 dof (4.604) rejects too;
    # 4 SE away: z rejects, t does not
    assert framework.decide([cell], 0.01) == framework.FAIL
    near = framework.equal_cell("eq4", X5, 2.0 + 4.0 * SE5, 0.01)
    assert framework.decide([near], 0.01) == framework.PASS
    assert 2 * sps.norm.sf(4.0) < 0.01


def test_detectable_excess_has_its_power():
    """At n = 5, a true excess equal to the stated detectable one is rejected by the one-sided
    t-test in 80% of data sets (Monte Carlo, 20,000 normal samples: ±0.009 at 3 SE)."""
    n, alpha, sd = 5, 0.01, 1.0
    det = st.t_detectable_excess(sd / math.sqrt(n), n, alpha)
    assert det > st.mean_detectable_excess(sd / math.sqrt(n), alpha)  # wider than z's
    rng = np.random.default_rng(0)
    x = rng.normal(det, sd, size=(20_000, n))  # true mean = bound 0 + det
    t = x.mean(1) / (x.std(1, ddof=1) / math.sqrt(n))
    rate = np.mean(t > sps.t.ppf(1 - alpha, n - 1))
    assert abs(rate - 0.8) < 0.009
    # the cell reports it (bound + excess, 'le')
    c = framework.mean_cell("d", X5, 0.0, "le", alpha)
    assert c.detectable == pytest.approx(st.t_detectable_excess(SE5, 5, alpha), rel=1e-12)


def test_zero_variance_and_too_few_seeds():
    c = framework.mean_cell("z", [0.0] * 64, 0.5, "ge", value_range=(0.0, 10.0))
    assert "exact zero-variance test" in c.note
    assert c.pvalue == pytest.approx((1 - 0.5 / 10.0) ** 64)
    with pytest.raises(ValueError, match="at least 2"):
        framework.mean_cell("one", [1.0], 0.0)


def test_cells_record_seeds_and_se():
    c = framework.mean_cell("c", X5, 0.0)
    assert c.n == 5 and c.se == pytest.approx(SE5, rel=1e-12)
    e = framework.equal_cell("e", X5, 2.0)
    assert e.n == 5 and e.se == pytest.approx(SE5, rel=1e-12)
    assert framework.tail_cell("t", 3, 100, 0.5).n == 0


def test_bootstrap_cell_pvalue_is_student_t_on_the_bca_spread():
    """bootstrap_cell (ratios, slopes of means over seeds) keeps its BCa interval; its p-value
    and detectable excess are Student t with n − 1 dof on the SE that the two-sided BCa
    interval implies, se = half-width / t_{1−α/2, n−1} (the mean cells' rule), not a normal
    fit: at 8 seeds a bound 1.5 half-widths from the estimate gets the t tail, about 10 times
    the normal fit's p-value."""
    rng = np.random.default_rng(3)
    x = np.stack([1.0 + 0.3 * rng.standard_normal(8), 2.0 + 0.3 * rng.standard_normal(8)],
                 axis=1)  # [S = 8, 2]

    def ratio(m):
        return m[..., 0] / m[..., 1]

    alpha, n = 0.01, 8
    est, lo, hi = st.bootstrap_ci(x, ratio, seed=0, num_resamples=2000, level=1 - alpha,
                                  side="two", method="bca")
    half = (hi - lo) / 2.0
    se = half / sps.t.ppf(1 - alpha / 2, n - 1)
    for k in (0.3, 1.0, 1.5, 3.0):
        for direction, bound in (("le", est - k * half), ("ge", est + k * half),
                                 ("le", est + k * half)):
            c = framework.bootstrap_cell("r", x, ratio, bound, direction, alpha)
            t = (est - bound) / se if direction == "le" else (bound - est) / se
            assert c.pvalue == pytest.approx(sps.t.sf(t, n - 1), rel=1e-9), (k, direction)
            excess = st.t_detectable_excess(se, n, alpha)
            assert c.detectable == pytest.approx(
                bound + excess if direction == "le" else bound - excess, rel=1e-9)
            assert c.statistic == pytest.approx(est)
            # the seeds and SE behind the p-value are recorded (reports: n 0, se nan before)
            assert c.n == n and c.se == pytest.approx(se, rel=1e-12)
            # the interval is the BCa one, as before: two-sided end beside the tested one
            assert (c.upper if direction == "le" else c.lower) == pytest.approx(
                hi if direction == "le" else lo, rel=1e-12)
    far = framework.bootstrap_cell("r", x, ratio, est - 1.5 * half, "le", alpha)
    z_fit = sps.norm.sf(1.5 * sps.norm.ppf(1 - alpha / 2))  # the normal fit's p-value
    assert far.pvalue > 5 * z_fit
