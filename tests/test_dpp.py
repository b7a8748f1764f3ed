"""Tests for sern_jax.core.dpp: exact k-DPP sampling, greedy MAP, RFF lift, core-set selection.

Statistical tests run at a stated false-alarm rate ALPHA = 1e-3 per test (Bonferroni over
items); the keys are fixed (fold_in of key(0)), so each run is deterministic, and the rate
says how unlikely a pass/fail flip is under a change of keys.
"""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from sern_jax.core import dpp

ALPHA = 1e-3
NUM_SAMPLES = 4000


def _keys(num, root=0):
    return jax.vmap(lambda i: jax.random.fold_in(jax.random.key(root), i))(
        jnp.arange(num)
    )


def _features(seed, num, dim):
    return np.random.default_rng(seed).normal(size=(num, dim))


def _exact_marginals(features, k):
    """P(i in S) for the k-DPP P(S) ∝ det L_S, L = F F^T, by enumerating all k-subsets."""
    kernel = features @ features.T
    num = kernel.shape[0]
    subsets = list(itertools.combinations(range(num), k))
    weights = np.array([np.linalg.det(kernel[np.ix_(s, s)]) for s in subsets])
    weights = np.maximum(weights, 0.0) / np.maximum(weights, 0.0).sum()
    marginals = np.zeros(num)
    for w, s in zip(weights, subsets):
        marginals[list(s)] += w
    return marginals


def _binomial_rejects(counts, num_samples, marginals, alpha=ALPHA):
    """Two-sided exact binomial test per item, Bonferroni over items: True = reject."""
    pvals = [
        stats.binomtest(int(c), num_samples, float(p)).pvalue
        for c, p in zip(counts, marginals)
    ]
    return min(pvals) < alpha / len(marginals)


# (N, d, k): d < N generic; d == k (rank exactly k: one eigenvector set); d > N (full rank).
@pytest.mark.parametrize("num,dim,k", [(6, 5, 2), (7, 3, 3), (8, 10, 3)])
def test_sampler_inclusion_frequencies_match_enumeration(num, dim, k):
    features = _features(10 + num, num, dim)
    samples = np.asarray(dpp.sample_kdpp_batch(_keys(NUM_SAMPLES), features, k))
    assert samples.shape == (NUM_SAMPLES, k)
    assert all(len(set(row)) == k for row in samples.tolist())
    counts = np.bincount(samples.ravel(), minlength=num)
    exact = _exact_marginals(features, k)
    assert not _binomial_rejects(counts, NUM_SAMPLES, exact)
    # Negative controls: the same test rejects uniform k-subsets and another kernel's DPP.
    assert _binomial_rejects(counts, NUM_SAMPLES, np.full(num, k / num))
    other = _exact_marginals(_features(99, num, dim), k)
    assert _binomial_rejects(counts, NUM_SAMPLES, other)


def test_sampler_subset_histogram_chi_square():
    """Whole-distribution check: chi-square over all 15 subsets of size 2 of 6 items."""
    num, k = 6, 2
    features = _features(3, num, 5)  # same shapes as a case above: no new compile
    kernel = features @ features.T
    subsets = list(itertools.combinations(range(num), k))
    probs = np.array([np.linalg.det(kernel[np.ix_(s, s)]) for s in subsets])
    probs /= probs.sum()
    samples = np.sort(
        np.asarray(dpp.sample_kdpp_batch(_keys(NUM_SAMPLES, 1), features, k))
    )
    index = {s: i for i, s in enumerate(subsets)}
    observed = np.bincount(
        [index[tuple(r)] for r in samples.tolist()], minlength=len(subsets)
    )
    assert NUM_SAMPLES * probs.min() >= 5  # chi-square approximation valid
    assert stats.chisquare(observed, NUM_SAMPLES * probs).pvalue > ALPHA
    uniform = np.full(len(subsets), NUM_SAMPLES / len(subsets))
    assert (
        stats.chisquare(observed, uniform).pvalue < ALPHA
    )  # wrong-distribution control


def test_sample_seed_diversity_same_key_and_batch_equals_unbatched():
    features = _features(1, 60, 20)
    keys = _keys(32, root=7)
    samples = np.asarray(dpp.sample_kdpp_batch(keys, features, 6))
    distinct = {frozenset(r) for r in samples.tolist()}
    assert len(distinct) >= 30  # C(60, 6) = 5e7 subsets: collisions are rare
    for i in (0, 17):
        single = np.asarray(dpp.sample_kdpp(keys[i], features, 6))
        np.testing.assert_array_equal(single, samples[i])
        np.testing.assert_array_equal(
            single, np.asarray(dpp.sample_kdpp(keys[i], features, 6))
        )


def _brute_force_greedy(kernel, k):
    chosen = []
    for _ in range(k):
        rest = [i for i in range(kernel.shape[0]) if i not in chosen]
        dets = [np.linalg.det(kernel[np.ix_(chosen + [i], chosen + [i])]) for i in rest]
        chosen.append(rest[int(np.argmax(dets))])
    return chosen


@pytest.mark.parametrize("seed", range(5))
def test_greedy_equals_brute_force_greedy(seed):
    num, dim, k = 8, 6, 4
    features = _features(100 + seed, num, dim)
    kernel = features @ features.T
    result = dpp.greedy_map(features, k)
    np.testing.assert_array_equal(
        np.asarray(result.indices), _brute_force_greedy(kernel, k)
    )
    gains = np.asarray(result.log_det_gains)
    for t in range(1, k + 1):  # every prefix: sum of gains = log det L_{S_t}
        sub = np.asarray(result.indices)[:t]
        logdet = np.linalg.slogdet(kernel[np.ix_(sub, sub)])[1]
        np.testing.assert_allclose(gains[:t].sum(), logdet, rtol=1e-9)


def test_greedy_log_det_gains_exact_on_larger_set():
    features = _features(5, 400, 48)
    result = dpp.greedy_map(features, 40)
    idx = np.asarray(result.indices)
    assert len(set(idx.tolist())) == 40
    sign, logdet = np.linalg.slogdet(features[idx] @ features[idx].T)
    assert sign > 0
    np.testing.assert_allclose(
        np.asarray(result.log_det_gains).sum(), logdet, rtol=1e-9
    )
    assert np.all(
        np.diff(np.asarray(result.log_det_gains)) <= 1e-12
    )  # gains never grow


def test_no_recompile_for_same_shapes():
    dpp.greedy_map(_features(0, 50, 10), 4)
    dpp.sample_kdpp(jax.random.key(0), _features(0, 50, 10), 4)
    greedy_cache = dpp._greedy_map_core._cache_size()
    sample_cache = dpp._sample_kdpp_core._cache_size()
    for seed in range(1, 4):
        dpp.greedy_map(_features(seed, 50, 10), 4)
        dpp.sample_kdpp(jax.random.key(seed), _features(seed, 50, 10), 4)
    assert dpp._greedy_map_core._cache_size() == greedy_cache
    assert dpp._sample_kdpp_core._cache_size() == sample_cache


def test_rank_errors():
    features = _features(0, 20, 4)
    for call in (
        lambda: dpp.greedy_map(features, 5),
        lambda: dpp.sample_kdpp(jax.random.key(0), features, 5),
    ):
        with pytest.raises(ValueError, match=r"k=5 .*rank.*d=4"):
            call()
    # Numerically rank 2 in 6 dims: only caught after the dual eigendecomposition / pivots.
    rng = np.random.default_rng(1)
    low_rank = rng.normal(size=(20, 2)) @ rng.normal(size=(2, 6))
    for call in (
        lambda: dpp.greedy_map(low_rank, 3),
        lambda: dpp.sample_kdpp(jax.random.key(0), low_rank, 3),
    ):
        with pytest.raises(ValueError, match=r"k=3 exceeds the numerical rank 2"):
            call()
    assert np.asarray(dpp.greedy_map(low_rank, 2).indices).shape == (2,)


def test_bad_input_is_value_error_before_compile():
    good = _features(0, 10, 5)
    nan = good.copy()
    nan[3, 2] = np.nan
    cache = dpp._greedy_map_core._cache_size()
    cases = [
        (good, 0, "k must be >= 1"),
        (good, 11, "exceeds the ground-set size"),
        (good, 2.0, "k must be an int"),
        (nan, 2, "NaN"),
        (good[0], 2, "2-D"),
        (good[None], 2, "2-D"),
        (np.zeros((0, 5)), 1, "non-empty"),
    ]
    for features, k, message in cases:
        with pytest.raises(ValueError, match=message):
            dpp.greedy_map(features, k)
        with pytest.raises(ValueError, match=message):
            dpp.sample_kdpp(jax.random.key(0), features, k)
    assert dpp._greedy_map_core._cache_size() == cache
    with pytest.raises(ValueError, match="keys must be a 1-D"):
        dpp.sample_kdpp_batch(jax.random.key(0), good, 2)
    with pytest.raises(ValueError, match="method"):
        dpp.select_core_set(jax.random.key(0), good, 2, method="map")
    with pytest.raises(ValueError, match="num_rff"):
        dpp.select_core_set(jax.random.key(0), good, 8, num_rff=None)
    with pytest.raises(ValueError, match="even"):
        dpp.random_fourier_features(jax.random.key(0), good, 7)
    with pytest.raises(ValueError, match="lengthscale"):
        dpp.random_fourier_features(jax.random.key(0), good, 8, lengthscale=0.0)


def test_random_fourier_features_approximate_rbf():
    x = _features(2, 6, 3)
    ell = 1.5
    phi = np.asarray(dpp.random_fourier_features(jax.random.key(3), x, 8192, ell))
    assert phi.shape == (6, 8192) and phi.dtype == np.float64
    np.testing.assert_allclose(np.sum(phi**2, axis=1), 1.0, rtol=1e-12)
    dist2 = np.sum((x[:, None] - x[None]) ** 2, axis=-1)
    # Each entry averages 4096 terms of variance <= 1/2: SE <= 0.011, tolerance 5 SE.
    np.testing.assert_allclose(phi @ phi.T, np.exp(-dist2 / (2 * ell**2)), atol=0.055)
    ell_med = dpp.median_lengthscale(jax.random.key(0), x)
    iu = np.triu_indices(6, 1)
    np.testing.assert_allclose(ell_med, np.median(np.sqrt(dist2[iu])), rtol=1e-9)


@pytest.mark.parametrize("method", ["greedy", "sample"])
def test_select_core_set(method):
    rng = np.random.default_rng(4)
    x = rng.normal(size=(500, 3)) * np.array(
        [1.0, 100.0, 0.01]
    )  # scales differ: standardised
    idx = np.asarray(
        dpp.select_core_set(jax.random.key(1), x, 24, method=method, num_rff=64)
    )
    assert idx.shape == (24,) and idx.dtype == np.int32
    assert len(set(idx.tolist())) == 24 and idx.min() >= 0 and idx.max() < 500


def test_greedy_core_set_covers_clusters():
    """Five tight, well-separated clusters of unequal size: greedy picks one from each."""
    rng = np.random.default_rng(6)
    centres = 20.0 * np.eye(5, 4)
    sizes = [300, 100, 40, 10, 3]
    x = np.concatenate(
        [c + 0.1 * rng.normal(size=(n, 4)) for c, n in zip(centres, sizes)]
    )
    labels = np.repeat(np.arange(5), sizes)
    idx = np.asarray(
        dpp.select_core_set(jax.random.key(2), x, 5, num_rff=128, lengthscale=2.0)
    )
    assert sorted(labels[idx].tolist()) == [0, 1, 2, 3, 4]
