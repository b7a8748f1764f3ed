"""The engine (make_run through executor.run_seeds): closed-form regret, seed conventions, bad
input. Planning, chunking, sharding and memory are tests/test_executor.py."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from sern_jax.engine import drive as executor
from sern_jax.core import problems
from sern_jax.engine import simulate as sim

CFG = sim.RunConfig(policy="softmax", estimator="addhalf", num_arms=5, horizon=300,
                    num_checkpoints=12)
PROB = problems.bernoulli([0.9, 0.8, 0.5, 0.3, 0.1])


@pytest.fixture(scope="module")
def thousand_seeds():
    params = sim.default_params(CFG, PROB, alpha0=0.1)
    return params, executor.run_seeds(CFG, params, seed=7, num_seeds=1000)


def test_k2_exact_oracle_closed_form_float64():
    # audit §3.10: with r̂ = r, K = 2 and α = α0/ln(T^p), π(worse) = 1/(1 + T^{pΔ/α0}), so the
    # Rao–Blackwellised regret is exactly ΔT/(1 + T^{pΔ/α0}).
    with jax.enable_x64():
        for horizon, delta, alpha0, p in [(100, 0.3, 1.0, 0.3), (1000, 0.5, 0.5, 0.2),
                                          (5000, 0.1, 2.0, 0.3)]:
            cfg = sim.RunConfig(policy="softmax", estimator="exact", schedule="log",
                                num_arms=2, horizon=horizon, num_checkpoints=4,
                                dtype="float64")
            prob = problems.bernoulli([0.7, 0.7 - delta], dtype=jnp.float64)
            params = sim.default_params(cfg, prob, alpha0=alpha0, p=p)
            out = executor.run_seeds(cfg, params, num_seeds=3)
            closed = delta * horizon / (1.0 + horizon ** (p * delta / alpha0))
            np.testing.assert_allclose(out.regret_rb[:, -1], closed, rtol=1e-9)
            np.testing.assert_allclose(out.regret_rb_paper[:, -1], closed, rtol=1e-9)


def test_bookkeeping(thousand_seeds):
    params, out = thousand_seeds
    t = sim.checkpoint_times(CFG)
    assert t[-1] == CFG.horizon and np.all(np.diff(t) > 0)
    np.testing.assert_array_equal(out.counts.sum(-1), np.broadcast_to(t, (1000, t.size)))
    np.testing.assert_allclose(out.compensator.sum(-1), np.broadcast_to(t, (1000, t.size)),
                               rtol=1e-5)
    assert np.all(np.diff(out.regret, axis=1) >= -1e-5)  # one context: regret is non-decreasing
    # Theorem 1 pathwise with clipped r̂: π_t(a) ≥ π_min = 1/(1 + (K−1)e^{1/α}).
    pi_min = 1.0 / (1.0 + 4 * np.exp(1 / 0.1))
    assert out.min_prob.min() >= pi_min * (1 - 1e-5)


def test_rao_blackwell_agrees_with_realised_regret(thousand_seeds):
    _, out = thousand_seeds
    diff = out.regret[:, -1] - out.regret_rb[:, -1]
    se = diff.std(ddof=1) / np.sqrt(diff.size)
    assert abs(diff.mean()) < 5 * se + 1e-9


def test_seed_diversity(thousand_seeds):
    _, out = thousand_seeds
    rows = {out.counts[i].tobytes() for i in range(200)}
    assert len(rows) == 200


def test_seed_alone_equals_seed_in_batch(thousand_seeds):
    params, out = thousand_seeds
    run = jax.jit(sim.make_run(CFG))
    root = jax.random.key(7)
    for i in (0, 417, 999):
        alone = run(jax.random.fold_in(root, i), params)
        np.testing.assert_array_equal(np.asarray(alone.counts), out.counts[i])
        np.testing.assert_allclose(np.asarray(alone.regret_rb), out.regret_rb[i], rtol=1e-6,
                                   atol=1e-4)


def test_chunked_equals_unchunked(thousand_seeds):
    params, out = thousand_seeds
    chunked = executor.run_seeds(CFG, params, seed=7, num_seeds=1000, chunk_size=300)
    np.testing.assert_array_equal(chunked.counts, out.counts)


_POLICIES = ("softmax", "greedy", "epsilon_greedy", "ucb1", "thompson", "boltzmann_gumbel",
             "exp3")
# every policy with one estimator (the two alternate; softmax with both) in the default run,
# the other pairs slow: each pair is a compile of its own (~4 s each on the 2 cores)
_DEFAULT_PAIRS = {(p, ("addhalf", "gauss")[i % 2]) for i, p in enumerate(_POLICIES)} | {
    ("softmax", "gauss")}


@pytest.mark.parametrize("policy,estimator", [
    (p, e) if (p, e) in _DEFAULT_PAIRS else pytest.param(p, e, marks=pytest.mark.slow)
    for p in _POLICIES for e in ("addhalf", "gauss")])
def test_policies_and_estimators_run_finite(policy, estimator):
    prob = problems.contextual_with_gap(jax.random.key(3), 3, 4, gap=0.2)
    cfg = sim.RunConfig(policy=policy, estimator=estimator, num_arms=4, num_contexts=3,
                        horizon=40, num_checkpoints=4, diagnostics=True)
    out = executor.run_seeds(cfg, sim.default_params(cfg, prob, alpha0=0.2), num_seeds=8)
    for leaf in jax.tree.leaves(out):
        assert np.all(np.isfinite(leaf)), (policy, estimator)
    assert np.all(out.counts[:, -1].sum(-1) == 40)
    assert np.all(out.regret_rb[:, -1] >= -1e-5)


def test_greedy_with_exact_oracle_has_zero_regret():
    cfg = sim.RunConfig(policy="greedy", estimator="exact", num_arms=3, num_contexts=2,
                        horizon=100, num_checkpoints=3)
    prob = problems.contextual([[0.1, 0.9, 0.5], [0.8, 0.2, 0.3]])
    out = executor.run_seeds(cfg, sim.default_params(cfg, prob), num_seeds=16)
    np.testing.assert_allclose(out.regret[:, -1], 0.0, atol=1e-6)
    # The paper's comparator (best arm on average: arm 1, mean 0.55) can be beaten per context.
    assert np.all(out.regret_paper[:, -1] < 0)


def test_random_means_differ_per_seed():
    cfg = sim.RunConfig(num_arms=4, horizon=20, num_checkpoints=2, random_means=True,
                        policy="greedy", estimator="exact")
    out = executor.run_seeds(cfg, sim.default_params(cfg, problems.bernoulli([0.5] * 4)),
                        num_seeds=50)
    assert len({out.counts[i, -1].tobytes() for i in range(50)}) > 1


BAD = [
    (dict(num_arms=1), {}, "num_arms"),
    (dict(horizon=0), {}, "horizon"),
    (dict(policy="softmaxx"), {}, "softmaxx"),
    (dict(estimator="ridge"), {}, "ridge"),
    (dict(schedule="cosine"), {}, "cosine"),
    ({}, dict(alpha0=0.0), "alpha0"),
    ({}, dict(alpha0=-1.0), "alpha0"),
    ({}, dict(epsilon=1.5), "epsilon"),
    ({}, dict(epsilon=-0.1), "epsilon"),
]


@pytest.mark.parametrize("cfg_kw,param_kw,match", BAD)
def test_bad_input_raises_before_compile(cfg_kw, param_kw, match):
    cfg = sim.RunConfig(**{**dict(num_arms=3, horizon=10), **cfg_kw})
    prob = problems.bernoulli([0.1, 0.2, 0.3])
    with pytest.raises(ValueError, match=match):
        params = sim.default_params(cfg, prob, **param_kw)
        executor.run_seeds(cfg, params, num_seeds=2)


def test_bad_problems_and_seeds_raise():
    cfg = sim.RunConfig(num_arms=3, horizon=10)
    with pytest.raises(ValueError, match="NaN"):
        problems.bernoulli([0.1, float("nan"), 0.3])
    with pytest.raises(ValueError, match="1.2"):
        problems.bernoulli([0.1, 1.2, 0.3])
    with pytest.raises(ValueError, match="num_arms=3"):
        executor.run_seeds(cfg, sim.default_params(cfg, problems.bernoulli([0.1, 0.2])), num_seeds=2)
    with pytest.raises(ValueError, match="num_seeds"):
        executor.run_seeds(cfg, sim.default_params(cfg, problems.bernoulli([0.1, 0.2, 0.3])),
                      num_seeds=0)
    with pytest.raises(ValueError, match="T >= 2"):
        c = sim.RunConfig(num_arms=3, horizon=1, schedule="log")
        executor.run_seeds(c, sim.default_params(c, problems.bernoulli([0.1, 0.2, 0.3])), num_seeds=1)
    with pytest.raises(ValueError, match="x64"):
        sim.validate(sim.RunConfig(dtype="float64"))


def test_diagnostics_exact_oracle_identities():
    # With r̂ = r every error sum is 0, misidentification never happens (distinct means), the
    # entropy sum equals T·S(π) for the constant π, and inv_sqrt_all ≥ inv_sqrt_rb.
    cfg = sim.RunConfig(policy="softmax", estimator="exact", num_arms=3, horizon=64,
                        num_checkpoints=4, diagnostics=True)
    prob = problems.bernoulli([0.2, 0.5, 0.9])
    out = executor.run_seeds(cfg, sim.default_params(cfg, prob, alpha0=0.5), num_seeds=4)
    d = out.diag
    for f in ("err_best", "err_rb", "err_chosen", "misid", "misid_strict"):
        np.testing.assert_allclose(getattr(d, f), 0.0, atol=1e-6)
    pi = np.exp(np.array([0.2, 0.5, 0.9]) / 0.5)
    pi /= pi.sum()
    np.testing.assert_allclose(d.entropy[:, -1], 64 * -(pi * np.log(pi)).sum(), rtol=1e-5)
    assert np.all(d.inv_sqrt_all >= d.inv_sqrt_rb - 1e-6)
    np.testing.assert_allclose(d.inv_sqrt_all[:, 0], 3.0, rtol=1e-6)  # t = 1: all counts 0
