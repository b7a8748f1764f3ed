"""Neural-Linear's per-arm posteriors (the synthetic MLP's ArmFeatures): each arm's posterior
is the shared-β closed form fitted on that arm's rows alone; the learner's chunked refit over
the written rows equals that closed form on the whole buffer; the cached U = L⁻ᵀ gives the
same UCB index and draws of the right law."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from sern_jax.core import contextual_problems as cp
from sern_jax.engine import networks
from sern_jax.engine import neural as nr
from sern_jax.learners import base, registry
from sern_jax.learners import neural_linear as nl


@pytest.mark.parametrize("n, g, empty_arm", [(37, 3, None), (64, 5, 2)])
def test_arm_posteriors_equal_one_fit_per_arm(n, g, empty_arm):
    rng = np.random.default_rng(n)
    d = 6
    phi = rng.normal(size=(n, d)).astype(np.float32)
    arms = rng.integers(0, g, n)
    if empty_arm is not None:
        arms[arms == empty_arm] = (empty_arm + 1) % g
    arm = np.eye(g, dtype=np.float32)[arms]
    y = rng.normal(size=n).astype(np.float32)
    w = (rng.random(n) < 0.8).astype(np.float32)  # some empty rows
    got = nl.fit_arm_posteriors(phi, arm, y, w, 0.25, 6.0, 6.0)
    assert got.mean.shape == (g, d) and got.chol_inv_t.shape == (g, d, d)
    for k in range(g):  # each arm: the shared-β closed form on its own rows
        ref = nl.fit_posterior(phi, y, w * arm[:, k], 0.25, 6.0, 6.0)
        for field in nl.Posterior._fields:
            np.testing.assert_allclose(getattr(got, field)[k], getattr(ref, field),
                                       rtol=2e-4, atol=2e-5, err_msg=f"{field}, arm {k}")
    if empty_arm is not None:  # no rows: the prior
        np.testing.assert_allclose(got.mean[empty_arm], 0.0)
        assert float(got.a[empty_arm]) == 6.0 and float(got.b[empty_arm]) == 6.0


@pytest.mark.parametrize("name, chunk", [("neural_lints", 4), ("neural_linucb", 256)])
def test_learner_refit_over_its_arm_rows_equals_the_closed_form(name, chunk, monkeypatch):
    """Each arm's rows of D in chunks (partial last chunks, a core set C beside), none of
    D's empty rows: the same posterior as fit_arm_posteriors on the whole buffer with the
    current θ, phase after phase (a NO_ARM row is not filed)."""
    monkeypatch.setattr(nl, "_CHUNK", chunk)
    horizon, e = 30, 6
    model = networks.mlp_model(3, 2, (5,))
    train = base.TrainConfig(horizon=horizon, fit_steps=2, batch_size=4, learning_rate=0.05)
    lrn = registry.make(name, model, train, registry.make_config(name, {"nl_sigma2": "arm"}))
    core = base.Data((networks.candidate_inputs(jnp.asarray([0.2, -0.1]), 3),),
                     jnp.asarray([1.0, 0.0, 0.5]), jnp.ones(3))  # a core set C too
    state = lrn.init(jax.random.key(0), model.init(jax.random.key(1)), core)
    rng = np.random.default_rng(0)
    update = jax.jit(lrn.update)
    for r in range(4):
        assert int(state.extra.arm_counts.sum()) == r * (e - 1)
        post = state.extra.posterior
        buf = state.buffer
        f = model.features(state.params, *buf.inputs)
        phi = nl.design(f.phi)
        y = buf.reward - model.apply(state.params, *buf.inputs)  # prior mean: the network
        ref = nl.fit_arm_posteriors(phi, f.arm, y, buf.weight, 0.25, 6.0, 6.0)
        for field in nl.Posterior._fields:
            np.testing.assert_allclose(getattr(post, field), getattr(ref, field),
                                       rtol=5e-4, atol=5e-5, err_msg=f"{field}, phase {r}")
        x = rng.normal(size=(e, 2)).astype(np.float32)
        arms = rng.integers(0, 3, e)
        z = jnp.asarray(np.concatenate([x, np.eye(3, dtype=np.float32)[arms]], 1))
        action = np.where(np.arange(e) == r, -1, arms)  # one NO_ARM row per phase
        batch = base.Batch((z,), jnp.asarray(action, jnp.int32),
                           jnp.asarray(rng.random(e), jnp.float32))
        state = update(jax.random.key(r), state, batch)


def test_cached_inverse_factor_and_per_arm_scores():
    rng = np.random.default_rng(3)
    g, d, n = 3, 4, 60
    phi = rng.normal(size=(n, d)).astype(np.float32)
    arm = np.eye(g, dtype=np.float32)[rng.integers(0, g, n)]
    post = nl.fit_arm_posteriors(phi, arm, rng.normal(size=n), np.ones(n), 0.25, 6.0, 6.0)
    for k in range(g):  # U Uᵀ = Λ⁻¹
        u = np.asarray(post.chol_inv_t[k], np.float64)
        np.testing.assert_allclose(u @ u.T, np.linalg.inv(np.asarray(post.precision[k],
                                                                    np.float64)),
                                   rtol=1e-4, atol=1e-6)
    q = rng.normal(size=(g, d)).astype(np.float32)  # candidate k belongs to arm k
    qa = np.eye(g, dtype=np.float32)
    cov = np.linalg.inv(np.asarray(post.precision, np.float64))  # [g, d, d]
    m = np.einsum("kd,kd->k", q, np.asarray(post.mean, np.float64))
    var = np.asarray(post.b / post.a) * np.einsum("kd,kde,ke->k", q, cov, q)
    np.testing.assert_allclose(nl.ucb_index(post, q, 2.0, qa), m + 2 * np.sqrt(var),
                               rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(nl.posterior_mean(post, q, qa), m, rtol=1e-5, atol=1e-6)
    draws = np.asarray(jax.vmap(lambda key: nl.thompson_scores(key, post, q, qa))(
        jax.random.split(jax.random.key(0), 4000)), np.float64)
    pred_var = np.asarray(post.b / (post.a - 1)) * np.einsum("kd,kde,ke->k", q, cov, q)
    assert (np.abs(draws.mean(0) - m) < 5 * np.sqrt(pred_var / 4000)).all()
    np.testing.assert_allclose(draws.var(0), pred_var, rtol=0.15)
    # independent draws per arm: the arms' scores are uncorrelated
    c = np.corrcoef(draws.T)
    assert np.all(np.abs(c[np.triu_indices(g, 1)]) < 0.1)


def test_neural_lints_batched_equals_unbatched_on_the_wheel():
    """The per-arm learner in the runner: seed i alone (unbatched jit) = seed i among 4."""
    horizon = 40
    problem = cp.wheel(0.7)
    model = networks.mlp_model(5, 2, (6,))
    train = base.TrainConfig(horizon=horizon, fit_steps=2, batch_size=8, learning_rate=1e-2)
    run = nr.make_run(nr.NeuralRunConfig(horizon=horizon, update_every=10, num_checkpoints=2),
                      problem, registry.make("neural_lints", model, train), model)
    many = nr.run_seeds(run, seed=3, num_seeds=4, chunk_size=4)
    # the learner contract's checks (tests/learners/test_engine_contract.py leaves this learner
    # to this test in the default run): counts and compensator sum to T, all fields finite
    np.testing.assert_array_equal(many.counts[:, -1].sum(axis=1), horizon)
    np.testing.assert_allclose(many.compensator[:, -1].sum(axis=1), horizon, rtol=1e-5)
    for field in ("regret", "regret_paper", "regret_rb", "regret_rb_paper", "compensator",
                  "min_prob"):
        assert np.isfinite(getattr(many, field)).all(), field
    from sern_jax.engine import simulate as sim
    one = jax.jit(run)(sim.seed_keys(jax.random.key(3), 1, 2)[0])
    np.testing.assert_array_equal(np.asarray(one.counts), many.counts[2])
    np.testing.assert_allclose(np.asarray(one.regret_rb), many.regret_rb[2], rtol=1e-5)
    assert len({tuple(c[-1]) for c in many.counts}) > 1  # seeds differ


def test_pooled_sigma2_equals_the_block_closed_form():
    """--nl-sigma2 pooled: the per-arm means and precisions are unchanged, and (a, b) is the
    Normal-inverse-Gamma closed form of ONE regression on the block features onehot(arm) ⊗ φ
    (σ² shared, β_g | σ² ~ N(0, σ²/λ I)): fit_posterior on the [N, G d] block design."""
    rng = np.random.default_rng(11)
    n, g, d = 50, 4, 5
    phi = rng.normal(size=(n, d)).astype(np.float32)
    arms = rng.integers(0, g - 1, n)  # arm g - 1 has no rows
    arm = np.eye(g, dtype=np.float32)[arms]
    y = rng.normal(size=n).astype(np.float32)
    w = (rng.random(n) < 0.8).astype(np.float32)
    pooled = nl.fit_arm_posteriors(phi, arm, y, w, 0.25, 6.0, 6.0, pooled=True)
    own = nl.fit_arm_posteriors(phi, arm, y, w, 0.25, 6.0, 6.0)
    block = (arm[:, :, None] * phi[:, None, :]).reshape(n, g * d)
    ref = nl.fit_posterior(block, y, w, 0.25, 6.0, 6.0)
    for k in range(g):
        sl = slice(k * d, (k + 1) * d)
        np.testing.assert_allclose(pooled.mean[k], ref.mean[sl], rtol=2e-4, atol=2e-5)
        np.testing.assert_allclose(pooled.precision[k], ref.precision[sl, sl], rtol=1e-5)
        np.testing.assert_allclose(pooled.mean[k], own.mean[k], rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(pooled.a, np.full(g, float(ref.a)), rtol=1e-6)
    np.testing.assert_allclose(pooled.b, np.full(g, float(ref.b)), rtol=2e-4)
    # and it is not the per-arm σ² (the arms' a differ with their row counts)
    assert len(set(np.asarray(own.a).tolist())) > 1


def test_pooled_thompson_draws_share_one_sigma2():
    """Pooled: one σ² draw for all arms; mean and variance of the scores are those of the
    block posterior's predictive (Student-t with 2a dof), and the arms' scores are
    positively correlated through the shared σ² (uncorrelated with per-arm σ²)."""
    rng = np.random.default_rng(5)
    g, d, n = 3, 4, 6  # few rows, a0 = 1: σ²'s posterior is wide (a = 4)
    phi = rng.normal(size=(n, d)).astype(np.float32)
    arm = np.eye(g, dtype=np.float32)[np.arange(n) % g]
    post = nl.fit_arm_posteriors(phi, arm, rng.normal(size=n), np.ones(n), 0.25, 1.0, 1.0,
                                 pooled=True)
    q = rng.normal(size=(g, d)).astype(np.float32)
    qa = np.eye(g, dtype=np.float32)
    draws = np.asarray(jax.vmap(lambda key: nl.thompson_scores(key, post, q, qa, True))(
        jax.random.split(jax.random.key(1), 20000)), np.float64)
    cov = np.linalg.inv(np.asarray(post.precision, np.float64))
    m = np.einsum("kd,kd->k", q, np.asarray(post.mean, np.float64))
    pred_var = np.asarray(post.b / (post.a - 1)) * np.einsum("kd,kde,ke->k", q, cov, q)
    assert (np.abs(draws.mean(0) - m) < 5 * np.sqrt(pred_var / 20000)).all()
    np.testing.assert_allclose(draws.var(0), pred_var, rtol=0.15)
    # (β_g − μ_g)² share σ²: corr = Var σ² / Var(σ² χ²_1) = (1/18)/(1/2 − 1/9) ≈ 0.14 at
    # a = 4 (IG moments), against 0 for independent σ² (SE ≈ 0.007 with 20,000 draws)
    dev = (draws - m) ** 2
    c = np.corrcoef(dev.T)[np.triu_indices(g, 1)]
    assert np.all(c > 0.08), c
    indep = np.asarray(jax.vmap(lambda key: nl.thompson_scores(key, post, q, qa, False))(
        jax.random.split(jax.random.key(1), 20000)), np.float64)
    ci = np.corrcoef(((indep - m) ** 2).T)[np.triu_indices(g, 1)]
    assert np.all(np.abs(ci) < 0.04), ci


@pytest.mark.parametrize("name", ["neural_lints", "neural_linucb"])
def test_learner_pooled_refit_equals_the_block_closed_form(name):
    """The learner with --nl-sigma2 pooled: after an update, its posterior is the pooled
    closed form on the whole buffer (the chunked per-arm sums, then one σ²)."""
    horizon, e = 24, 8
    model = networks.mlp_model(3, 2, (5,))
    train = base.TrainConfig(horizon=horizon, fit_steps=2, batch_size=4, learning_rate=0.05)
    lrn = registry.make(name, model, train, registry.make_config(name, {"nl_sigma2": "pooled"}))
    state = lrn.init(jax.random.key(0), model.init(jax.random.key(1)),
                     nr._empty_core_set(cp.wheel(0.5)._replace(context_dim=2, num_arms=3)))
    rng = np.random.default_rng(1)
    for r in range(2):
        x = rng.normal(size=(e, 2)).astype(np.float32)
        arms = rng.integers(0, 3, e)
        z = jnp.asarray(np.concatenate([x, np.eye(3, dtype=np.float32)[arms]], 1))
        batch = base.Batch((z,), jnp.asarray(arms, jnp.int32),
                           jnp.asarray(rng.random(e), jnp.float32))
        state = lrn.update(jax.random.key(r), state, batch)
    buf = state.buffer
    f = model.features(state.params, *buf.inputs)
    y = buf.reward - model.apply(state.params, *buf.inputs)
    ref = nl.fit_arm_posteriors(nl.design(f.phi), f.arm, y, buf.weight, 0.25, 6.0, 6.0,
                                pooled=True)
    for field in nl.Posterior._fields:
        np.testing.assert_allclose(getattr(state.extra.posterior, field), getattr(ref, field),
                                   rtol=5e-4, atol=5e-5, err_msg=field)
    assert len(set(np.asarray(state.extra.posterior.a).tolist())) == 1


def test_nl_sigma2_bad_value_names_the_flag():
    with pytest.raises(ValueError, match="^--nl-sigma2 must be one of arm, pooled"):
        nl.NeuralLinTSConfig(nl_sigma2="shared")
