"""Estimators: update bookkeeping, predictions, and the A3 forms they claim."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from sern_jax.core import estimators as E

ORACLE = E.OracleParams(beta=jnp.asarray(0.5), oracle_eps=jnp.asarray(0.01),
                        flip_q=jnp.asarray(0.5), pinned_arm=jnp.asarray(1, jnp.int32))
MEANS = jnp.array([0.9, 0.6, 0.2])


def _state_after(observations, num_contexts=1):
    state = E.init_state(num_contexts, 3)
    for ctx, arm, reward in observations:
        state = E.update_state(state, jnp.int32(ctx), jnp.int32(arm), jnp.float32(reward),
                               jnp.float32(0.5))
    return state


def test_update_counts_sums_gains():
    state = _state_after([(0, 0, 1), (0, 0, 0), (0, 2, 1)])
    np.testing.assert_array_equal(state.counts, [[2, 0, 1]])
    np.testing.assert_allclose(state.sums, [[1, 0, 1]])
    np.testing.assert_array_equal(state.arm_counts, [2, 0, 1])
    np.testing.assert_allclose(state.gains, [2, 0, 2])  # R / π with π = 0.5


def test_contextual_update_touches_one_cell():
    state = _state_after([(1, 2, 1), (0, 2, 0)], num_contexts=3)
    np.testing.assert_array_equal(state.counts, [[0, 0, 1], [0, 0, 1], [0, 0, 0]])
    np.testing.assert_array_equal(state.arm_counts, [0, 0, 2])


@pytest.mark.parametrize("name,expected", [
    ("exact", [0.9, 0.6, 0.2]),
    ("addhalf", [(1 + 0.5) / 3, 0.5, (1 + 0.5) / 2]),
    ("mean", [0.5, 0.5, 1.0]),
    ("l1median", [0.5, 0.5, 1.0]),
    ("l1argmax", [0.5, 0.5, 0.0]),
    ("pinned", [1.0, 0.0, 1.0]),
])
def test_deterministic_predictions(name, expected):
    state = _state_after([(0, 0, 1), (0, 0, 0), (0, 2, 1)])
    est = E.make_estimator(name)
    r_hat = est.predict(jax.random.key(0), state, jnp.int32(0), MEANS, ORACLE)
    np.testing.assert_allclose(np.asarray(r_hat), expected, rtol=1e-6)


def test_adv_oracle_error_is_exact_and_adversarial():
    state = _state_after([(0, 0, 1)] * 3)
    r_hat = E.make_estimator("adv", clip=False).predict(jax.random.key(0), state, jnp.int32(0),
                                                        MEANS, ORACLE)
    scale = 0.99 * 0.5 / np.sqrt(np.array([4.0, 1.0, 1.0]))
    np.testing.assert_allclose(np.asarray(r_hat), np.asarray(MEANS) + [-scale[0], scale[1], scale[2]],
                               rtol=1e-6)


@pytest.mark.parametrize("name", ["rademacher", "gauss", "flip"])
def test_random_oracles_satisfy_a3_in_mean(name):
    # E|r̂ − r| must be < β/√(n+1) (flip: q_c/√(n+1)·|1 − 2r|): Monte Carlo over 20,000 keys.
    state = _state_after([(0, 1, 0)] * 8)  # n = (0, 8, 0)
    est = E.make_estimator(name, clip=False)
    keys = jax.random.split(jax.random.key(1), 20_000)
    r_hat = jax.vmap(est.predict, (0, None, None, None, None))(keys, state, jnp.int32(0),
                                                               MEANS, ORACLE)
    err = np.abs(np.asarray(r_hat) - np.asarray(MEANS)).mean(0)
    n = np.array([0.0, 8.0, 0.0])
    if name == "flip":
        bound = 0.5 / np.sqrt(n + 1) * np.abs(1 - 2 * np.asarray(MEANS))
        np.testing.assert_allclose(err, bound, rtol=0.05)
    else:
        target = 0.99 * 0.5 / np.sqrt(n + 1)  # E|err| = (1 − ε)β/√(n+1) exactly
        np.testing.assert_allclose(err, target, rtol=0.03)
        assert np.all(err < 0.5 / np.sqrt(n + 1))


def test_clip_keeps_estimates_in_unit_interval():
    state = E.init_state(1, 3)
    big = ORACLE._replace(beta=jnp.asarray(3.0))
    for name in ("adv", "rademacher", "gauss"):
        r = E.make_estimator(name).predict(jax.random.key(2), state, jnp.int32(0), MEANS, big)
        assert np.all((np.asarray(r) >= 0) & (np.asarray(r) <= 1))
        r_raw = E.make_estimator(name, clip=False).predict(jax.random.key(2), state,
                                                           jnp.int32(0), MEANS, big)
        assert np.any((np.asarray(r_raw) < 0) | (np.asarray(r_raw) > 1))


def test_addhalf_fixed_n_a3_constant():
    # audit §2.1: max over p of √(n+1)·E|p̂ − p| is exactly 1/2 (at n = 0), so β = ½ + ε.
    from math import comb
    worst = 0.0
    for n in range(0, 30):
        for p in np.linspace(0, 1, 41):
            e = sum(comb(n, k) * p**k * (1 - p) ** (n - k) * abs((k + 0.5) / (n + 1) - p)
                    for k in range(n + 1))
            worst = max(worst, np.sqrt(n + 1) * e)
    assert worst == pytest.approx(0.5, abs=1e-12)


def test_unknown_estimator_raises():
    with pytest.raises(ValueError, match="'ridge'"):
        E.make_estimator("ridge")


def test_adv_low_pushes_the_worst_arm_down_unclipped():
    state = E.init_state(1, 3)
    r_hat = E.make_estimator("adv_low", clip=False).predict(
        jax.random.key(0), state, jnp.int32(0), MEANS, ORACLE._replace(beta=jnp.asarray(0.9)))
    d = 0.99 * 0.9
    np.testing.assert_allclose(np.asarray(r_hat), [0.9 + d, 0.6 + d, 0.2 - d], rtol=1e-6)
    assert float(r_hat.max() - r_hat.min()) > 1.0  # the range Theorem 1 needs ≤ 1 is exceeded
