"""Exact fast Thompson sampling: the Beta sampler against scipy's Beta (KS, with a
wrong-parameter control that must fail), the batched runner against the general one."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats as st

from sern_jax.engine import drive as executor, fast_thompson
from sern_jax.core import prng, problems
from sern_jax.engine import simulate as sim

N = 20_000  # draws per parameter pair


def _draws(a, b, seed=0):
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(seed), i))(jnp.arange(10))
    fn = jax.jit(jax.vmap(lambda k: prng.sample_beta(k, jnp.full(N // 10, a, jnp.float32),
                                                     jnp.full(N // 10, b, jnp.float32))))
    return np.asarray(fn(keys), np.float64).ravel()


# order statistics (min(a, b) = 1 or 2, also with a real other parameter; with a large one
# most draws take the expm1 polynomial), and Cheng's BB (min > 2, or between 1 and 2),
# symmetric, skewed and large
PAIRS = [(1.0, 1.0), (1.0, 9.0), (6.0, 1.0), (1.0, 3000.0), (2000.0, 1.0), (2.0, 2.0),
         (2.0, 160.0), (9.0, 2.0), (2.0, 7.5), (1500.0, 2.0), (1.5, 4.0), (3.0, 3.0),
         (35.0, 4.0), (300.0, 700.0)]


@pytest.mark.parametrize("a,b", PAIRS)
def test_beta_draws_match_scipy_and_a_wrong_parameter_fails(a, b):
    x = _draws(a, b)
    # Beta's support in float32 is [0, 1]: a draw within half an ulp of 1 rounds to 1.0 (the
    # H100's exp does so for Beta(2000, 1); about 2000 * 2^-25 of the true draws lie there),
    # so the ends are allowed, but only as often as that rounding explains
    assert np.all((x >= 0) & (x <= 1))
    near = max(a, b) * 2.0 ** -24  # generous: the mass within one ulp of either end
    assert np.mean((x == 0) | (x == 1)) <= 10 * near + 3 / x.size
    assert st.kstest(x, st.beta(a, b).cdf).pvalue > 1e-3
    # control: a 10% larger first parameter is detected by the same test on the same draws
    assert st.kstest(x, st.beta(a * 1.1, b).cdf).pvalue < 1e-3


@pytest.mark.parametrize("a,b", [(1.0, 3000.0), (2.0, 500.0), (5.0, 9.0)])
def test_float64_beta_draws_match_scipy(a, b):
    """In float64 the order-statistics forms use jnp.expm1 (the float32 Taylor branch would
    carry ~1e-9 relative error): KS against scipy with the wrong-parameter control."""
    with jax.enable_x64():
        keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(3), i))(jnp.arange(10))
        x = np.asarray(jax.jit(jax.vmap(lambda k: prng.sample_beta(
            k, jnp.full(N // 10, a, jnp.float64), jnp.full(N // 10, b, jnp.float64))))(keys))
    assert x.dtype == np.float64 and np.all((x > 0) & (x < 1))
    assert st.kstest(x.ravel(), st.beta(a, b).cdf).pvalue > 1e-3
    assert st.kstest(x.ravel(), st.beta(a * 1.1, b).cdf).pvalue < 1e-3


def test_beta_below_one_is_nan_not_a_wrong_draw():
    x = jax.jit(prng.sample_beta)(jax.random.key(0), jnp.array([0.5, 2.0]),
                                  jnp.array([2.0, 0.9]))
    assert np.all(np.isnan(np.asarray(x)))


CFG = sim.RunConfig(policy="thompson", num_arms=8, horizon=300, num_checkpoints=8,
                    random_means=True)
PARAMS = sim.default_params(CFG, problems.bernoulli([0.5] * 8))


def test_fast_thompson_equals_the_general_runner():
    assert executor.plan_run(CFG, PARAMS, 40).fast
    fast = executor.run_seeds(CFG, PARAMS, seed=1, num_seeds=40, runner="fast")
    general = executor.run_seeds(CFG, PARAMS, seed=1, num_seeds=40, runner="general")
    # same draws lane by lane: the same arms, the same Kahan-summed regret
    np.testing.assert_array_equal(fast.counts, general.counts)
    for field in ("regret", "regret_paper", "regret_rb", "regret_rb_paper", "compensator",
                  "min_prob"):
        np.testing.assert_allclose(getattr(fast, field), getattr(general, field), rtol=1e-6,
                                   atol=1e-6, err_msg=field)
    # seeds differ from each other, and Thompson learns: the best arm is pulled most
    assert len({tuple(c) for c in fast.counts[:, -1]}) == 40
    assert fast.counts[:, -1].sum(-1).tolist() == [300] * 40


@pytest.mark.parametrize("lookahead,pulled_tries", [(1, 0), (3, 1), (4, 3)])
def test_fast_thompson_lookahead_keeps_the_draws(lookahead, pulled_tries):
    """Drawing ahead (any depth, any number of immediate tries for the pulled lane) changes
    only the loop, not the draws: the same arms as the general runner, seed by seed."""
    general = executor.run_seeds(CFG, PARAMS, seed=2, num_seeds=16, runner="general")
    fn = jax.jit(fast_thompson.make_batched(CFG, lookahead=lookahead,
                                            pulled_tries=pulled_tries, with_steps=True))
    out, steps = fn(sim.seed_keys(jax.random.key(2), 16), PARAMS)
    np.testing.assert_array_equal(np.asarray(out.counts), general.counts)
    # every round costs at least one loop step, and rejections cost a few more
    assert CFG.horizon <= int(np.max(steps)) < 4 * CFG.horizon
    with pytest.raises(ValueError, match="lookahead"):
        fast_thompson.make_batched(CFG, lookahead=0)


def test_hold_is_the_identity_on_every_uniform_and_key_word():
    """prng.hold / hold_bits only stop XLA from recomputing a hash in every fusion; they must
    return their argument bit for bit: all 2^23 float32 uniforms of open_unit, 0 and 1, and
    key words with every 16-bit half."""
    m = np.arange(2**23, dtype=np.float32)
    u = np.concatenate([(m + np.float32(0.5)) * np.float32(2.0**-23), [0.0, 1.0]]).astype(
        np.float32)
    np.testing.assert_array_equal(np.asarray(jax.jit(prng.hold)(jnp.asarray(u))), u)
    half = np.arange(2**16, dtype=np.uint32)
    words = np.concatenate([half, half << np.uint32(16), (half << np.uint32(16)) | half[::-1]])
    np.testing.assert_array_equal(np.asarray(jax.jit(prng.hold_bits)(jnp.asarray(words))),
                                  words)


def test_packed_try_is_the_try_held_exactly():
    """beta_try_packed is beta_try's draw where accepted and REJECTED elsewhere, bit for bit
    (prng.hold is exact on every value a draw can take: all float32 from 2^-60 to 1, sampled,
    and REJECTED), so the fast runner's held values are the general runner's draws."""
    rng = np.random.default_rng(0)
    bits = rng.integers(np.float32(2.0**-60).view(np.uint32), np.float32(1.0).view(np.uint32),
                        2**22, dtype=np.uint32, endpoint=True)
    x = np.concatenate([bits.view(np.float32), [1.0, prng.REJECTED]]).astype(np.float32)
    np.testing.assert_array_equal(np.asarray(jax.jit(prng.hold)(jnp.asarray(x))), x)
    a = jnp.asarray(rng.integers(1, 40, (64, 64)), jnp.float32)
    b = jnp.asarray(rng.integers(1, 400, (64, 64)), jnp.float32)
    lane = jnp.arange(64, dtype=jnp.uint32)[None, :]
    tries = jnp.asarray(rng.integers(0, 3, (64, 64)), jnp.uint32)
    k1, k2 = jnp.uint32(12345), jnp.uint32(678)
    theta, acc = jax.jit(prng.beta_try)(k1, k2, a, b, tries, lane)
    packed = jax.jit(prng.beta_try_packed)(k1, k2, a, b, tries, lane)
    assert 0.7 < float(jnp.mean(acc)) < 1.0  # some rejections, or the test is hollow
    np.testing.assert_array_equal(np.asarray(packed),
                                  np.where(np.asarray(acc), np.asarray(theta), prng.REJECTED))


def test_fast_thompson_refuses_what_it_does_not_reproduce():
    for bad in (dataclasses.replace(CFG, policy="softmax"),
                dataclasses.replace(CFG, diagnostics=True),
                dataclasses.replace(CFG, num_contexts=2)):
        assert not fast_thompson.supports(bad)
    with pytest.raises(ValueError, match="fast_thompson supports"):
        fast_thompson.make_batched(dataclasses.replace(CFG, diagnostics=True))


def test_expm1_is_exact_enough_in_float64_and_float32():
    """prng._expm1: in float64 it must be jnp.expm1 (the float32 Taylor branch truncates at
    ~1e-9 relative, which the KS tests cannot see); in float32 within its documented error."""
    y64 = np.concatenate([-np.logspace(-12, 1, 200), np.logspace(-12, -1.3, 50)])
    with jax.enable_x64():
        y = jnp.asarray(y64, jnp.float64)
        got = np.asarray(prng._expm1(y, jnp.exp(y)))
    assert got.dtype == np.float64 and np.max(np.abs(got / np.expm1(y64) - 1)) < 1e-14
    y32 = y64.astype(np.float32)
    got = np.asarray(prng._expm1(jnp.asarray(y32), jnp.exp(jnp.asarray(y32))), np.float64)
    assert np.max(np.abs(got / np.expm1(y32.astype(np.float64)) - 1)) < 2e-6
