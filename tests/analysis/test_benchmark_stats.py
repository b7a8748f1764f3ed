"""The benchmark's statistics (sern_jax.analysis.benchmark_stats): metrics, the object-level
t interval, Holm, TOST and the power statement, each against a hand computation or a seeded
simulation, with controls that must fail."""

import numpy as np
import pytest
from scipy import stats as sps

from sern_jax.analysis import benchmark_stats as bs


def test_metrics_by_hand():
    # [R + 1 = 4, 2 copies]: copy 0 reaches 0.8 in round 2, copy 1 never does
    lv = np.array([[0.5, 0.5], [0.7, 0.6], [0.8, 0.7], [0.9, 0.75]])
    ex = np.array([[np.nan, np.nan], [0.5, 0.2], [0.6, 0.4], [0.7, 0.6]])
    m = bs.run_metrics(lv, ex, explore=20)
    np.testing.assert_allclose(m["curve_area"], [80.0, 68.333333333333], rtol=1e-12)
    np.testing.assert_allclose(m["explore_success"], [60.0, 40.0], rtol=1e-12)
    np.testing.assert_allclose(m["round5"], [90.0, 75.0])
    np.testing.assert_array_equal(m["grasps_to_80"], [40.0, 80.0])  # censored: (R + 1) x 20
    with pytest.raises(ValueError, match="not finished"):
        bs.run_metrics(np.where(np.arange(4)[:, None] == 3, np.nan, lv), ex, 20)


def test_object_level_is_the_t_interval_over_object_means():
    rng = np.random.default_rng(0)
    d = rng.normal(1.0, 2.0, (6, 10))
    ol = bs.object_level(d)
    m = d.mean(1)
    se = m.std(ddof=1) / np.sqrt(6)
    q = sps.t.ppf(0.975, 5)
    assert ol.df == 5 and ol.n_objects == 6 and ol.n_seeds == 10
    np.testing.assert_allclose([ol.diff, ol.se, ol.ci_low, ol.ci_high],
                               [m.mean(), se, m.mean() - q * se, m.mean() + q * se],
                               rtol=1e-12)
    np.testing.assert_allclose(ol.p, sps.ttest_1samp(m, 0.0).pvalue, rtol=1e-10)
    # batched over leading axes equals one at a time
    both = bs.object_level(np.stack([d, -d]))
    np.testing.assert_allclose(both.diff, [ol.diff, -ol.diff])
    np.testing.assert_allclose(both.p, [ol.p, ol.p])
    with pytest.raises(ValueError, match=">= 2 objects"):
        bs.object_level(d[:1])


def test_per_object_uses_seeds():
    d = np.array([[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]])
    po = bs.per_object(d)
    q = sps.t.ppf(0.975, 2)
    np.testing.assert_allclose(po.upper, [2.0 + q * 1.0 / np.sqrt(3), 0.0])


def test_holm_matches_a_hand_computation():
    from sern_jax.analysis import stats

    # sorted: 0.005 x 4 = 0.02, 0.01 x 3 = 0.03, 0.03 x 2 = 0.06, 0.04 x 1 = 0.04 -> 0.06
    _, adj = stats.holm([0.01, 0.04, 0.03, 0.005], 0.05)
    np.testing.assert_allclose(adj, [0.03, 0.06, 0.06, 0.02])
    # and compare() applies it within each family
    rng = np.random.default_rng(1)
    metrics = {k: rng.normal(0, 1, (4, 3, 5)) for k in bs.METRICS}
    comps, _ = bs.compare(metrics, ["sern", "b", "c"], ["o1", "o2", "o3", "o4"])
    for fam in ("primary", "secondary"):
        cs = [c for c in comps if c["family"] == fam]
        assert len(cs) == 4
        np.testing.assert_allclose([c["holm_p"] for c in cs],
                                   stats.holm([c["p"] for c in cs], 0.05)[1])


def test_tost_by_hand_and_its_controls():
    # diff 0.5, se 0.5, df 11: t_lower = (0.5 + 2)/0.5 = 5, t_upper = (0.5 − 2)/0.5 = −3
    t = bs.tost(0.5, 0.5, 11, 2.0)
    assert t.p_lower == pytest.approx(sps.t.sf(5.0, 11))
    assert t.p_upper == pytest.approx(sps.t.cdf(-3.0, 11))
    assert t.p == max(t.p_lower, t.p_upper) and t.equivalent
    # control that must fail: a true difference of 3 points is never equivalent at ± 2,
    # however precise the estimate
    for se in (0.01, 0.3, 1.0):
        assert not bs.tost(3.0, se, 11, 2.0).equivalent
    # at the margin itself the rejection rate is at most alpha (seeded simulation)
    rng = np.random.default_rng(2)
    d = 2.0 + rng.normal(0.0, 1.0, (4000, 12, 1)) + rng.normal(0.0, 2.0, (4000, 12, 40))
    ol = bs.object_level(d)
    rate = bs.tost(ol.diff, ol.se, ol.df, 2.0).equivalent.mean()
    assert rate <= 0.05 + 5 * np.sqrt(0.05 * 0.95 / 4000)
    # and a true difference of 3: essentially never
    ol3 = bs.object_level(d + 1.0)
    assert bs.tost(ol3.diff, ol3.se, ol3.df, 2.0).equivalent.mean() < 0.005
    # power control: a null difference with a precise estimate is declared equivalent
    assert bs.tost(0.1, 0.3, 11, 2.0).equivalent


def test_intervals_cover_zero_at_the_nominal_rate():
    """a = b + noise of mean 0 (objects and seeds both random): the object-level 95 %
    interval covers 0 in 95 % of seeded simulations (within 5 SE); a real difference of 3
    points is not covered (control)."""
    rng = np.random.default_rng(3)
    n = 4000
    b = rng.normal(60.0, 10.0, (n, 12, 1)) + rng.normal(0.0, 5.0, (n, 12, 40))
    a = b + rng.normal(0.0, 1.5, (n, 12, 1)) + rng.normal(0.0, 3.0, (n, 12, 40))
    ol = bs.object_level(a - b)
    cover = ((ol.ci_low <= 0) & (ol.ci_high >= 0)).mean()
    assert abs(cover - 0.95) <= 5 * np.sqrt(0.95 * 0.05 / n), cover
    assert abs((ol.p < 0.05).mean() - 0.05) <= 5 * np.sqrt(0.95 * 0.05 / n)
    ol3 = bs.object_level(a - b + 3.0)
    assert ((ol3.ci_low <= 0) & (ol3.ci_high >= 0)).mean() < 0.05


def test_detectable_difference_has_the_power_it_claims():
    rng = np.random.default_rng(4)
    det = bs.detectable_difference(3.0, 1.0, 12, 40, alpha=0.05, family_size=8)
    assert det.df == 11 and det.alpha == pytest.approx(0.05 / 8)
    assert det.se == pytest.approx(np.sqrt((1.0 + 9.0 / 40) / 12))
    assert bs.power(det.diff, 3.0, 1.0, 12, 40, 0.05, 8) == pytest.approx(0.8, abs=1e-8)
    n = 4000
    d = det.diff + rng.normal(0.0, 1.0, (n, 12, 1)) + rng.normal(0.0, 3.0, (n, 12, 40))
    ol = bs.object_level(d)
    rate = (ol.p < det.alpha).mean()
    assert abs(rate - 0.8) <= 5 * np.sqrt(0.8 * 0.2 / n), rate
    # more objects or seeds detect less; one object is the test over seeds
    assert bs.detectable_difference(3.0, 1.0, 24, 40, 0.05, 8).diff < det.diff
    one = bs.detectable_difference(2.0, 0.0, 1, 40, 0.05, 8)
    assert one.df == 39 and one.se == pytest.approx(2.0 / np.sqrt(40))
    # against the normal approximation (z_{1-a/2} + z_power) se: close at 39 df, above it
    z = (sps.norm.ppf(1 - 0.05 / 16) + sps.norm.ppf(0.8)) * one.se
    assert z < one.diff < 1.1 * z


def test_compare_fields_and_per_object_rows():
    rng = np.random.default_rng(5)
    objects, learners = ["o1", "o2", "o3"], ["greedy", "sern"]
    metrics = {k: rng.normal(50, 5, (3, 2, 4)) for k in bs.METRICS}
    metrics["curve_area"][:, 1] = metrics["curve_area"][:, 0] + 1.0  # sern exactly +1
    comps, rows = bs.compare(metrics, learners, objects, reference="sern")
    c = next(c for c in comps if c["metric"] == "curve_area")
    assert (c["a"], c["b"], c["level"], c["family"]) == ("sern", "greedy", "objects", "primary")
    assert c["diff"] == pytest.approx(1.0) and c["ci_low"] == pytest.approx(1.0)
    assert c["p"] == 0.0 and c["tost"]["equivalent"] is True
    g = next(c for c in comps if c["metric"] == "grasps_to_80")
    assert g["tost"]["margin"] is None and g["family"] == "secondary"
    assert len(rows) == 4 * 3 and {r["object"] for r in rows} == set(objects)
    assert all(r["n"] == 4 for r in rows)
    with pytest.raises(ValueError, match="reference"):
        bs.compare(metrics, ["a", "b"], objects)


def test_means_and_curves():
    lv = np.zeros((3, 2, 2, 4))
    lv[:, 0] = 0.5
    lv[:, 1] = 0.7
    cur = bs.curves(lv, ["x", "y"])
    assert cur["x"]["2"]["mean"] == pytest.approx(60.0)
    assert cur["x"]["0"]["se"] == pytest.approx(10.0)
    means = bs.learner_means({"round5": 100 * lv[-1]}, ["x", "y"])
    assert means["y"]["round5"]["mean"] == pytest.approx(60.0)
