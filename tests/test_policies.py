"""Policy identities (property tests), sampler frequencies, and the textbook-softmax check."""

import hypothesis.extra.numpy as hnp
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from sern_jax.core import policies

K = 6
estimates = hnp.arrays(np.float32, (K,), elements=st.floats(0, 1, width=32))
alphas = st.floats(0.02, 5.0)

softmax = jax.jit(policies.softmax_probs)
entropy = jax.jit(policies.entropy)


@given(r=estimates, alpha=alphas)
def test_softmax_attains_gibbs_value(r, alpha):
    # max_π E_π r + α S(π) = α logsumexp(r / α), attained by softmax(r / α).
    pi = softmax(r, alpha)
    value = float(jnp.dot(pi, r) + alpha * entropy(pi))
    optimum = float(alpha * jax.scipy.special.logsumexp(r / alpha))
    assert value == pytest.approx(optimum, rel=1e-5, abs=1e-5)


@given(r=estimates, alpha=alphas, q_raw=hnp.arrays(np.float32, (K,), elements=st.floats(0.01, 1)))
def test_softmax_maximises_regularised_objective(r, alpha, q_raw):
    pi = softmax(r, alpha)
    q = q_raw / q_raw.sum()
    objective = lambda p: float(jnp.dot(p, r) + alpha * entropy(p))
    assert objective(pi) >= objective(jnp.asarray(q)) - 1e-5


@given(r=estimates, alpha=alphas, eps=st.floats(0, 1), t=st.integers(1, 10_000))
def test_all_closed_form_policies_are_distributions(r, alpha, eps, t):
    counts = jnp.arange(K, dtype=jnp.int32)
    outs = [
        softmax(r, alpha),
        policies.greedy_probs(r),
        policies.epsilon_greedy_probs(r, eps),
        policies.ucb1_probs(r, counts, jnp.asarray(t), 1.0),
        policies.exp3_probs(r * 10, 0.1),
    ]
    for pi in outs:
        assert np.all(np.asarray(pi) >= 0)
        assert float(jnp.sum(pi)) == pytest.approx(1.0, abs=1e-5)


@given(r=hnp.arrays(np.float32, (K,), elements=st.floats(0, 1, width=32), unique=True))
def test_softmax_tends_to_greedy(r):
    gap = np.sort(r)[-1] - np.sort(r)[-2]
    if gap < 1e-3:
        return
    pi = softmax(r, gap / 50.0)  # e^{-50} suppression of every non-argmax arm
    np.testing.assert_allclose(np.asarray(pi), np.asarray(policies.greedy_probs(r)), atol=1e-6)


def test_softmax_tiny_alpha_is_finite():
    r = jnp.array([0.3, 0.9, 0.9, 0.1])
    pi = softmax(r, 1e-30)
    assert np.all(np.isfinite(np.asarray(pi)))
    np.testing.assert_allclose(np.asarray(pi), [0, 0.5, 0.5, 0], atol=1e-7)


def _frequencies(probs, n, seed=0):
    u = jax.random.uniform(jax.random.key(seed), (n,))
    arms = jax.jit(jax.vmap(policies.sample_icdf, (0, None)))(u, probs)
    return np.bincount(np.asarray(arms), minlength=probs.shape[0]) / n


def test_icdf_sampler_chi_square():
    # Pearson chi-square with 5 d.o.f.; the 0.999 quantile is 20.515, so this test has a
    # false-alarm rate of 1e-3 for a correct sampler (fixed key: deterministic in CI).
    probs = jnp.array([0.05, 0.1, 0.15, 0.2, 0.2, 0.3])
    n = 200_000
    freq = _frequencies(probs, n)
    chi2 = n * np.sum((freq - np.asarray(probs)) ** 2 / np.asarray(probs))
    assert chi2 < 20.515


def test_icdf_sampler_detects_a_wrong_distribution():
    # The same statistic must reject a sampler of a different π: the test can fail.
    probs = jnp.array([0.05, 0.1, 0.15, 0.2, 0.2, 0.3])
    wrong = jnp.array([0.06, 0.1, 0.14, 0.2, 0.2, 0.3])
    n = 200_000
    freq = _frequencies(wrong, n)
    chi2 = n * np.sum((freq - np.asarray(probs)) ** 2 / np.asarray(probs))
    assert chi2 > 20.515


def test_zero_weight_arm_is_never_sampled():
    probs = jnp.array([0.0, 0.5, 0.0, 0.5, 0.0])
    freq = _frequencies(probs, 50_000)
    assert freq[0] == freq[2] == freq[4] == 0.0


def test_textbook_softmax_total_variation():
    # The semantics check of bandit-anchors.md §5: 4 arms with empirical means
    # (0.50, 0.45, 0.40, 0.30) and τ = 0.05 must be sampled as softmax(μ̂/τ) =
    # (0.657, 0.242, 0.089, 0.012). Peers measured TV 0.015 (SMPyBandits), 0.040 (mabwiser),
    # 0.34 (contextualbandits); with 200k draws the sampling TV of a correct sampler is ~0.002.
    mu = jnp.array([0.50, 0.45, 0.40, 0.30])
    pi = softmax(mu, 0.05)
    np.testing.assert_allclose(np.asarray(pi), [0.657, 0.242, 0.089, 0.012], atol=1e-3)
    freq = _frequencies(pi, 200_000, seed=3)
    tv = 0.5 * np.abs(freq - np.asarray(pi)).sum()
    assert tv < 0.005
    smpy = np.asarray(softmax(mu / (1 + 1 / 20), 0.05))  # X/(τ(1+N)) with N = 20
    assert 0.5 * np.abs(freq - smpy).sum() > 0.01  # the check separates the peer's policy


def test_thompson_and_boltzmann_gumbel_frequencies():
    counts = jnp.array([100, 100, 100], jnp.int32)
    sums = jnp.array([70.0, 50.0, 30.0])
    keys = jax.random.split(jax.random.key(0), 4000)
    ts = jax.jit(jax.vmap(policies.thompson_probs, (0, None, None)))(keys, counts, sums)
    assert np.allclose(np.asarray(ts).sum(-1), 1.0)
    freq = np.asarray(ts).mean(0)
    assert freq[0] > 0.99  # P(Beta(71,31) < Beta(51,51)) is about 2e-3
    bg = jax.jit(jax.vmap(policies.boltzmann_gumbel_probs, (0, None, None, None)))(
        keys, sums / 100.0, counts, 1.0)
    freq_bg = np.asarray(bg).mean(0)
    assert freq_bg[0] > freq_bg[1] > freq_bg[2] > 0
    unpulled = policies.boltzmann_gumbel_probs(keys[0], sums, jnp.array([3, 0, 0]), 1.0)
    np.testing.assert_allclose(np.asarray(unpulled), [0, 0.5, 0.5])


def test_unknown_policy_raises():
    with pytest.raises(ValueError, match="nope"):
        policies.policy_probs("nope", jax.random.key(0), None, 1.0, None)


# ---------------------------------------------------------------- validity masks

masks = hnp.arrays(np.bool_, (K,))
nonempty_masks = masks.filter(lambda m: m.any())
masked_softmax = jax.jit(policies.softmax_probs)
masked_greedy = jax.jit(policies.greedy_probs)
masked_eps = jax.jit(policies.epsilon_greedy_probs)
masked_sample = jax.jit(policies.sample_icdf)
# What a padded slot may hold: the masked policies must ignore it.
garbage = st.sampled_from([np.nan, np.inf, -np.inf, 1e30, -1e30, 0.5])


def _masked_outputs(r, alpha, eps, mask):
    return {
        "softmax": masked_softmax(r, alpha, mask),
        "greedy": masked_greedy(r, mask),
        "epsilon_greedy": masked_eps(r, eps, mask),
        "ucb1": policies.ucb1_probs(r, jnp.arange(K, dtype=jnp.int32) % 3, jnp.asarray(7), 1.0,
                                    mask),
    }


def _with_garbage(r, mask, fill):
    return np.where(mask, r, np.float32(fill)).astype(np.float32)


@given(r=estimates, alpha=alphas, eps=st.floats(0, 1), mask=masks, fill=garbage)
def test_masked_policies_zero_on_invalid_and_sum_to_one(r, alpha, eps, mask, fill):
    r = _with_garbage(r, mask, fill)
    for name, pi in _masked_outputs(r, alpha, eps, mask).items():
        pi = np.asarray(pi)
        assert not np.any(np.isnan(pi)), name
        assert np.all(pi >= 0), name
        assert np.all(pi[~mask] == 0.0), name
        if mask.any():
            assert pi.sum() == pytest.approx(1.0, abs=1e-5), name
        else:
            assert np.all(pi == 0.0), name


@given(r=estimates, alpha=alphas, eps=st.floats(0, 1), mask=nonempty_masks, fill=garbage)
def test_masked_policies_equal_unmasked_on_valid_subvector(r, alpha, eps, mask, fill):
    sub = r[mask]
    expected = {
        "softmax": policies.softmax_probs(sub, alpha),
        "greedy": policies.greedy_probs(sub),
        "epsilon_greedy": policies.epsilon_greedy_probs(sub, eps),
    }
    got = _masked_outputs(_with_garbage(r, mask, fill), alpha, eps, mask)
    for name, want in expected.items():
        np.testing.assert_allclose(np.asarray(got[name])[mask], np.asarray(want),
                                   rtol=1e-5, atol=1e-7, err_msg=name)


@given(r=estimates, alpha=alphas, eps=st.floats(0, 1))
def test_all_true_mask_equals_no_mask(r, alpha, eps):
    everything = np.ones(K, bool)
    got = _masked_outputs(r, alpha, eps, everything)
    np.testing.assert_allclose(np.asarray(got["softmax"]), np.asarray(softmax(r, alpha)),
                               rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(np.asarray(got["greedy"]), np.asarray(policies.greedy_probs(r)))
    np.testing.assert_allclose(np.asarray(got["epsilon_greedy"]),
                               np.asarray(policies.epsilon_greedy_probs(r, eps)), atol=1e-7)


@given(r=estimates, mask=nonempty_masks, fill=garbage)
def test_masked_softmax_tiny_alpha_is_greedy_and_finite(r, mask, fill):
    pi = np.asarray(masked_softmax(_with_garbage(r, mask, fill), 1e-30, mask))
    assert np.all(np.isfinite(pi))
    np.testing.assert_allclose(pi, np.asarray(policies.greedy_probs(r, mask)), atol=1e-6)


def test_no_valid_arm_is_defined_not_nan():
    r = jnp.array([0.3, 0.9, np.nan, 0.1])
    none = jnp.zeros(4, bool)
    for pi in (policies.softmax_probs(r, 0.1, none), policies.softmax_probs(r, 1e-30, none),
               policies.greedy_probs(r, none), policies.epsilon_greedy_probs(r, 0.2, none)):
        np.testing.assert_array_equal(np.asarray(pi), np.zeros(4))
        assert int(policies.sample_icdf(0.5, pi)) == policies.NO_ARM
    assert int(policies.sample_icdf(0.5, jnp.ones(4), none)) == policies.NO_ARM


def test_all_minus_inf_softmax_is_uniform_not_nan():
    # Today's bug: softmax over all -inf estimates was all-NaN and sample_icdf then silently
    # picked arm 0. Every arm ties at -inf: the limit is uniform, the same as greedy_probs.
    r = jnp.full(4, -jnp.inf)
    for alpha in (0.1, 1e-30):
        pi = np.asarray(jax.jit(policies.softmax_probs)(r, alpha))
        np.testing.assert_array_equal(pi, np.full(4, 0.25))
    mask = jnp.array([False, True, True, False])
    np.testing.assert_array_equal(np.asarray(policies.softmax_probs(r, 0.1, mask)),
                                  [0, 0.5, 0.5, 0])
    # +inf estimates: uniform over the +inf arms (the limit), not NaN.
    r = jnp.array([0.1, jnp.inf, 0.3, jnp.inf])
    np.testing.assert_array_equal(np.asarray(policies.softmax_probs(r, 0.1)), [0, 0.5, 0, 0.5])


def test_nan_probs_are_not_sampled_as_arm_zero():
    assert int(policies.sample_icdf(0.3, jnp.full(4, jnp.nan))) == policies.NO_ARM
    assert int(policies.sample_icdf(0.3, jnp.zeros(4))) == policies.NO_ARM


# u values a float32 uniform can take, including the last ones below 1.
U_EDGE = np.array([0.0, 1e-30, 0.5, 1 - 2**-23, np.nextafter(np.float32(1), np.float32(0))],
                  np.float32)
unit_floats = st.one_of(st.sampled_from(list(U_EDGE)),
                        st.floats(0, 1, exclude_max=True, width=32))


@given(w=hnp.arrays(np.float32, (K,), elements=st.floats(0, 1, width=32)), mask=masks,
       u=unit_floats)
def test_sample_icdf_never_returns_an_invalid_arm(w, mask, u):
    arm = int(masked_sample(u, w, mask))
    usable = mask & (w > 0)
    if usable.any():
        assert 0 <= arm < K and usable[arm]
    else:
        assert arm == policies.NO_ARM


@given(mask=nonempty_masks, u=unit_floats, r=estimates, alpha=st.floats(1e-30, 5.0))
def test_sample_icdf_on_masked_policy_output(mask, u, r, alpha):
    pi = masked_softmax(r, alpha, mask)
    for m in (mask, None):  # the probs alone must already be enough
        arm = int(masked_sample(u, pi, m))
        assert 0 <= arm < K and mask[arm]


_exact_cumsum = jnp.cumsum


def _rounding_cumsum(x, axis=None):
    # A cumsum as a tree-ordered (accelerator) scan may round it: each entry off by a few ulps,
    # so zero-weight entries no longer repeat their predecessor and the last entry can exceed
    # the last positive arm's (CPU's sequential cumsum is monotone and cannot show this).
    exact = _exact_cumsum(x, axis=axis)
    wobble = jnp.where(jnp.arange(x.shape[-1]) % 2 == 0, 1.0 + 3e-7, 1.0 - 3e-7)
    return exact * wobble.astype(exact.dtype)


def _old_sample_icdf(u, probs):  # the formula before masks, kept to show the test can fail
    cdf = jnp.cumsum(probs)
    return jnp.minimum(jnp.sum(cdf <= u * cdf[-1]), probs.shape[-1] - 1)


def test_sample_icdf_survives_cumsum_rounding(monkeypatch):
    monkeypatch.setattr(jnp, "cumsum", _rounding_cumsum)
    # Masked arms between and after the valid ones; u up to the last float32 below 1.
    probs = jnp.asarray([0.2, 0.3, 0.1, 0.15, 0.0, 0.25, 0.0, 0.4, 0.1], jnp.float32)
    mask = jnp.array([True, True, False, True, False, True, False, False, False])
    u = jnp.asarray(np.concatenate([U_EDGE, np.linspace(0, 1, 4001, dtype=np.float32)[:-1]]))
    new = jax.jit(jax.vmap(lambda u, p, m: policies.sample_icdf(u, p, m), (0, None, None)))
    arms = np.asarray(new(u, probs, mask))
    assert np.all(np.asarray(mask)[arms])
    assert arms[list(U_EDGE).index(U_EDGE[-1])] == 5  # u -> 1: the last valid arm
    old = jax.jit(jax.vmap(_old_sample_icdf, (0, None)))
    old_arms = np.asarray(old(u, jnp.where(mask, probs, 0.0)))
    assert not np.all(np.asarray(mask)[old_arms])  # the count formula leaks here


def test_masked_sampler_chi_square():
    # Same test as the unmasked one, on a K = 64 vector with invalid slots everywhere.
    mask = np.zeros(64, bool)
    mask[[0, 5, 17, 40, 62]] = True
    probs = jnp.asarray(np.linspace(1.0, 2.0, 64), jnp.float32)
    n = 200_000
    u = jax.random.uniform(jax.random.key(7), (n,))
    arms = np.asarray(jax.jit(jax.vmap(policies.sample_icdf, (0, None, None)))(u, probs, mask))
    assert np.all(mask[arms])
    freq = np.bincount(arms, minlength=64)[mask] / n
    target = np.asarray(probs)[mask] / np.asarray(probs)[mask].sum()
    chi2 = n * np.sum((freq - target) ** 2 / target)
    assert chi2 < 18.467  # chi-square(4) 0.999 quantile


def test_grasp_sized_masked_policies_under_vmap():
    # What the grasp learner does: K = 64 candidates, a `valid` mask, batched.
    keys = jax.random.split(jax.random.key(0), 3)
    r = jax.random.uniform(keys[0], (32, 64))
    valid = jax.random.uniform(keys[1], (32, 64)) < 0.3
    valid = valid.at[0].set(False)  # one object with no valid candidate
    u = jax.random.uniform(keys[2], (32,))
    pi = jax.jit(jax.vmap(policies.softmax_probs, (0, None, 0)))(r, 0.05, valid)
    arms = jax.jit(jax.vmap(policies.sample_icdf))(u, pi, valid)
    pi, arms, valid = np.asarray(pi), np.asarray(arms), np.asarray(valid)
    assert not np.isnan(pi).any() and np.all(pi[~valid] == 0)
    np.testing.assert_allclose(pi[1:].sum(-1), 1.0, atol=1e-5)
    assert arms[0] == policies.NO_ARM and np.all(valid[np.arange(1, 32), arms[1:]])


def test_policy_probs_passes_the_mask():
    inputs = policies.PolicyInputs(r_hat=jnp.array([0.9, 0.1, 0.5]), counts=jnp.ones(3, jnp.int32),
                                   sums=jnp.ones(3), gains=jnp.zeros(3), t=jnp.asarray(5))
    params = type("P", (), {"epsilon": 0.3, "ucb_c": 1.0})()
    mask = jnp.array([False, True, True])
    key = jax.random.key(0)
    for name in policies.MASKABLE_POLICIES:
        pi = np.asarray(policies.policy_probs(name, key, inputs, 0.1, params, mask))
        assert pi[0] == 0 and pi.sum() == pytest.approx(1.0)
    np.testing.assert_array_equal(
        np.asarray(policies.policy_probs("greedy", key, inputs, 0.1, params, mask)), [0, 0, 1])
    with pytest.raises(ValueError, match="thompson.*mask"):
        policies.policy_probs("thompson", key, inputs, 0.1, params, mask)


def test_check_mask_names_the_problem():
    assert policies.check_mask(np.array([True, False])).dtype == np.bool_
    with pytest.raises(ValueError, match="no valid arm"):
        policies.check_mask(np.zeros(4, bool))
    with pytest.raises(ValueError, match=r"row \(1,\)"):
        policies.check_mask(np.array([[True, False], [False, False]]))
    with pytest.raises(ValueError, match="boolean"):
        policies.check_mask(np.array([1, 0, 1]))
    with pytest.raises(ValueError, match="K=3 arms but 64"):
        policies.check_mask(np.ones(3, bool), num_arms=64)
