"""The baseline learners: neural_linucb, neural_lints, ensemble_ts, neural_ucb,
normalized, egreedy_decay, sern_decay, on a tiny MLP (fast; not the grasp net).

Each never picks a masked candidate, its probabilities sum to 1 over the valid slots, it is
deterministic for a key and vmapped equals one by one; Neural-Linear's posterior equals a
closed-form ridge regression (numpy, float64) on the same features; ensemble TS plays each
member's argmax with frequency 1/M (chi-square, with a wrong-frequency control that must
fail); told only failures, a learner ranks those grasps lower."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from sern_jax.core import policies as pol
from sern_jax.learners import (
    base,
    decaying,
    ensemble,
    neural_linear,
    neural_ucb,
    normalized,
)

K, D, H, E, T = 16, 5, 8, 4, 12
NAMES = ("neural_linucb", "neural_lints", "ensemble_ts", "neural_ucb", "normalized",
         "egreedy_decay", "sern_decay")


def _mlp() -> base.Model:
    """x [..., D] -> relu(x W1 + b1) [..., H] (features) -> logit."""

    def features(params, x):
        b1 = jnp.reshape(params["b1"], (1,) * (x.ndim - 1) + (H,))
        return jax.nn.relu(x @ params["w1"] + b1)

    def logits(params, x):
        return features(params, x) @ params["w2"] + params["b2"]

    def init(key):
        k1, k2 = jax.random.split(key)
        return {"w1": jax.random.normal(k1, (D, H)) / np.sqrt(D), "b1": jnp.full((H,), 0.1),
                "w2": jax.random.normal(k2, (H,)) / np.sqrt(H), "b2": jnp.zeros(())}

    return base.Model(init=init, apply=lambda p, x: jax.nn.sigmoid(logits(p, x)),
                      logits=logits, features=features)


MODEL = _mlp()
TRAIN = base.TrainConfig(horizon=T, fit_steps=8, batch_size=4, learning_rate=0.05)
_rng = np.random.default_rng(0)
CORE = base.Data((jnp.asarray(_rng.normal(size=(6, D)), jnp.float32),),
                 jnp.asarray([1.0, 0.0, 1.0, 1.0, 0.0, 1.0]), jnp.ones(6))
THETA0 = MODEL.init(jax.random.key(0))
# ensemble_ts's default layout is shared heads (covered by tests/learners/test_learners.py's
# contract on every registered learner's defaults and by the shared-heads tests below); the
# tests here that take NETWORKS keep the whole-network layout (--ensemble-heads networks)
# covered: contract (slow), told only failures, 1/M frequency, drawn-member act.
NETWORKS = ensemble.EnsembleConfig(ensemble_size=3, ensemble_heads="networks")

def FACTORIES_OF(model):
    return (("neural_linucb", neural_linear.neural_linucb(model, TRAIN)),
            ("neural_lints", neural_linear.neural_lints(model, TRAIN)),
            ("ensemble_ts", ensemble.ensemble_ts(model, TRAIN, NETWORKS)),
            ("neural_ucb", neural_ucb.neural_ucb(model, TRAIN)),
            ("normalized", normalized.normalized(model, TRAIN)),
            ("egreedy_decay", decaying.egreedy_decay(model, TRAIN)),
            ("sern_decay", decaying.sern_decay(model, TRAIN)))


FACTORIES = {
    "neural_linucb": lambda: neural_linear.neural_linucb(MODEL, TRAIN),
    "neural_lints": lambda: neural_linear.neural_lints(MODEL, TRAIN),
    "ensemble_ts": lambda: ensemble.ensemble_ts(MODEL, TRAIN, NETWORKS),
    "neural_ucb": lambda: neural_ucb.neural_ucb(MODEL, TRAIN),
    "normalized": lambda: normalized.normalized(MODEL, TRAIN),
    "egreedy_decay": lambda: decaying.egreedy_decay(MODEL, TRAIN),
    "sern_decay": lambda: decaying.sern_decay(MODEL, TRAIN),
}


def _obs(key, num_valid=9, t=0):
    k1, k2, k3 = jax.random.split(key, 3)
    x = jax.random.normal(k1, (K, D))
    valid = jnp.zeros(K, bool).at[jax.random.permutation(k2, K)[:num_valid]].set(True)
    return base.Obs((x,), valid, jax.random.uniform(k3), jnp.int32(t))


def _batch(key, fail=False):
    x = jax.random.normal(key, (E, D))
    action = jnp.asarray([0, 1, pol.NO_ARM, 3], jnp.int32)
    reward = jnp.zeros(E) if fail else (action >= 0).astype(jnp.float32)
    return base.Batch((x,), action, reward)


# The per-learner contract tests compile each learner 2-4 times (~10-25 s each on the shared
# 2 cores): slow. tests/learners/test_learners.py runs the same contract on every registered
# learner (these included) in the default run, on a linear model.
@pytest.fixture(scope="module", params=[pytest.param(n, marks=pytest.mark.slow)
                                        for n in NAMES])
def learner(request):
    return request.param, FACTORIES[request.param]()


# Told only failures: the two learners whose estimate is not the network's r̂ run by
# default (the others' is the network, which test_learners.py checks); all with -m slow.
FAILURE_CASES = [n if n in ("neural_lints", "ensemble_ts")
                 else pytest.param(n, marks=pytest.mark.slow) for n in NAMES]


def _linear_model() -> base.Model:
    def logits(params, x):
        return x @ params["w"] + params["b"]

    return base.Model(init=lambda key: {"w": jax.random.normal(key, (D,)), "b": jnp.zeros(())},
                      apply=lambda p, x: jax.nn.sigmoid(logits(p, x)), logits=logits,
                      features=lambda p, x: x)


def test_never_masked_probs_sum_to_one(learner):
    name, lrn = learner
    state = lrn.init(jax.random.key(1), THETA0, CORE)
    state = jax.jit(lrn.update)(jax.random.key(2), state, _batch(jax.random.key(3)))
    act = jax.jit(lrn.act)
    for i in range(32):
        obs = _obs(jax.random.key(100 + i), num_valid=1 + i % K, t=i)
        action, probs, _ = act(jax.random.key(i), state, obs)
        valid = np.asarray(obs.valid)
        assert 0 <= int(action) < K and valid[int(action)], (name, i)
        p = np.asarray(probs)
        assert (p[~valid] == 0).all() and (p >= 0).all() and p[int(action)] > 0, (name, i)
        np.testing.assert_allclose(p[valid].sum(), 1.0, rtol=1e-6)
    obs = _obs(jax.random.key(7))._replace(valid=jnp.zeros(K, bool))
    action, probs, _ = act(jax.random.key(0), state, obs)
    assert int(action) == pol.NO_ARM and (np.asarray(probs) == 0).all(), name


def test_deterministic_and_batched_equals_unbatched(learner):
    name, lrn = learner
    n = 5
    states = jax.vmap(lrn.init, (0, None, None))(jax.random.split(jax.random.key(3), n),
                                                 THETA0, CORE)
    batch = jax.vmap(lambda k: _batch(k))(jax.random.split(jax.random.key(6), n))
    upd_keys = jax.random.split(jax.random.key(8), n)
    vupdate, vact = jax.jit(jax.vmap(lrn.update)), jax.jit(jax.vmap(lrn.act))
    states = vupdate(upd_keys, states, batch)
    again = vupdate(upd_keys, states, batch)
    jax.tree.map(np.testing.assert_array_equal, again, vupdate(upd_keys, states, batch))
    obs = jax.vmap(lambda k: _obs(k, t=7))(jax.random.split(jax.random.key(4), n))
    act_keys = jax.random.split(jax.random.key(5), n)
    batched = vact(act_keys, states, obs)
    jax.tree.map(np.testing.assert_array_equal, batched[:2], vact(act_keys, states, obs)[:2])
    one_act = jax.jit(lrn.act)
    for i in range(n):
        one = jax.tree.map(lambda x, i=i: x[i], (states, obs))
        a, p, _ = one_act(act_keys[i], *one)
        assert int(a) == int(batched[0][i]), (name, i)
        np.testing.assert_allclose(p, batched[1][i], rtol=1e-6, atol=1e-7)
    one_update = jax.jit(lrn.update)
    for i in range(n):
        one = jax.tree.map(lambda x, i=i: x[i], (states, obs))
        a, p, _ = jax.jit(lrn.act)(act_keys[i], *one)
        assert int(a) == int(batched[0][i]), (name, i)
        np.testing.assert_allclose(p, batched[1][i], rtol=1e-6, atol=1e-7)
    for i in range(2):
        pick = lambda x, i=i: x[i]
        one = one_update(upd_keys[i], jax.tree.map(pick, states), jax.tree.map(pick, batch))
        jax.tree.map(lambda a, b, i=i: np.testing.assert_allclose(a, b[i], rtol=1e-4,
                                                                  atol=1e-5), one, again)


def test_seeds_differ_for_randomised_learners():
    """Different act keys give different Thompson draws (the seed-diversity check)."""
    for name in ("neural_lints", "ensemble_ts"):
        lrn = FACTORIES[name]()
        state = lrn.init(jax.random.key(1), THETA0, CORE)
        for r in range(2):
            state = jax.jit(lrn.update)(jax.random.key(r), state, _batch(jax.random.key(r)))
        obs = _obs(jax.random.key(11), num_valid=K)
        keys = jax.random.split(jax.random.key(12), 200)
        actions = np.asarray(jax.jit(jax.vmap(lrn.act, (0, None, None)))(keys, state, obs)[0])
        assert len(np.unique(actions)) > 1, name


@pytest.mark.parametrize("name", FAILURE_CASES)
def test_told_only_failures_ranks_those_lower(name):
    """After phases of failures on some grasps, the learner's estimate of those grasps falls,
    and by more than its estimate of candidates it was told nothing about."""
    model = _linear_model()
    lrn = dict(FACTORIES_OF(model))[name]
    # Neural-Linear (prior mean: the network's r̂): from an empty core set, so its estimate
    # starts at r̂ in (0, 1); a ridge fit to this 6-row C on 6 features overshoots below 0,
    # where failures (label 0) pull it up, not down.
    core = CORE._replace(weight=jnp.zeros(6)) if name.startswith("neural_lin") else CORE
    state = lrn.init(jax.random.key(0), model.init(jax.random.key(0)), core)
    x_fail = jax.random.normal(jax.random.key(9), (E, D))
    action = jnp.asarray([0, 1, pol.NO_ARM, 3], jnp.int32)
    others = jax.random.normal(jax.random.key(10), (K - E, D))
    x_all = jnp.concatenate([x_fail, others])
    obs = base.Obs((x_all,), jnp.ones(K, bool), jnp.float32(0.5), jnp.int32(0))
    predict = jax.jit(lrn.predict)
    before = np.asarray(predict(state, obs))
    update = jax.jit(lrn.update)
    for r in range(3):
        state = update(jax.random.key(r), state, base.Batch((x_fail,), action, jnp.zeros(E)))
    after = np.asarray(predict(state, obs))
    tried = np.r_[np.asarray(action) >= 0, np.zeros(K - E, bool)]
    assert (after[tried] < before[tried]).all(), (name, before, after)
    drop = before - after  # relative to the candidates it was told nothing about:
    assert drop[tried].mean() > drop[E:].mean(), (name, before, after)


# ----------------------------------------------------------------------------- Neural-Linear


def _ridge(phi, y, w, lam, a0, b0):
    phi, y, w = (np.asarray(v, np.float64) for v in (phi, y, w))
    prec = lam * np.eye(phi.shape[1]) + phi.T @ (w[:, None] * phi)
    mean = np.linalg.solve(prec, phi.T @ (w * y))
    a = a0 + w.sum() / 2
    b = b0 + 0.5 * (np.sum(w * y * y) - mean @ prec @ mean)  # the textbook NIG form
    return mean, prec, a, b


@pytest.mark.parametrize("prior_mean", neural_linear.PRIOR_MEANS)
@pytest.mark.parametrize("name", ["neural_lints", "neural_linucb"])
def test_neural_linear_posterior_is_ridge_on_current_features(name, prior_mean):
    """The posterior is the closed-form ridge/NIG fit on D ∪ C with the current θ's
    features, to the residuals y − r̂_θ (prior mean ``network``) or to y (``zero``)."""
    config = (neural_linear.NeuralLinTSConfig if name == "neural_lints"
              else neural_linear.NeuralLinUCBConfig)(nl_prior_mean=prior_mean)
    lrn = getattr(neural_linear, name)(MODEL, TRAIN, config)
    state = lrn.init(jax.random.key(0), THETA0, CORE)
    for r in range(3):  # init (C, θ0 features), then after each update (new θ's features)
        buf = state.buffer
        phi = np.asarray(neural_linear.design(MODEL.features(state.params, *buf.inputs)))
        y = np.asarray(buf.reward, np.float64)
        if prior_mean == "network":
            y = y - np.asarray(MODEL.apply(state.params, *buf.inputs), np.float64)
        mean, prec, a, b = _ridge(phi, y, buf.weight, 0.25, 6.0, 6.0)
        post = state.extra.posterior
        np.testing.assert_allclose(post.mean, mean, rtol=1e-4, atol=1e-5)
        np.testing.assert_allclose(post.precision, prec, rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(post.a, a, rtol=1e-6)
        np.testing.assert_allclose(post.b, b, rtol=1e-4)
        state = jax.jit(lrn.update)(jax.random.key(r), state, _batch(jax.random.key(r)))
    assert int(state.buffer.count) == 3 * E


@pytest.mark.parametrize("name", ["neural_lints", "neural_linucb"])
def test_neural_linear_centred_on_the_network_without_data(name):
    """Prior mean ``network``: with no data (an empty core set) the greedy estimate is the
    network's r̂ exactly and the scores are r̂ plus the prior's spread; ``zero`` starts at
    0. After data, predict = r̂ + φ·μ."""
    empty = CORE._replace(weight=jnp.zeros(6))
    obs = _obs(jax.random.key(3), num_valid=K)
    r_hat = np.asarray(MODEL.apply(THETA0, *obs.inputs))
    for prior_mean, want in (("network", r_hat), ("zero", np.zeros(K))):
        config = (neural_linear.NeuralLinTSConfig if name == "neural_lints"
                  else neural_linear.NeuralLinUCBConfig)(nl_prior_mean=prior_mean)
        lrn = getattr(neural_linear, name)(MODEL, TRAIN, config)
        state = lrn.init(jax.random.key(0), THETA0, empty)
        np.testing.assert_allclose(lrn.predict(state, obs), want, rtol=1e-6, atol=1e-7)
        state = lrn.update(jax.random.key(1), state, _batch(jax.random.key(2)))
        phi = neural_linear.design(MODEL.features(state.params, *obs.inputs))
        mean = np.asarray(phi) @ np.asarray(state.extra.posterior.mean)
        offset = (np.asarray(MODEL.apply(state.params, *obs.inputs)) if prior_mean ==
                  "network" else 0.0)
        np.testing.assert_allclose(lrn.predict(state, obs), mean + offset, rtol=1e-5,
                                   atol=1e-6)


def test_fit_posterior_weights_and_prior():
    """Weighted rows count w times; a zero-weight row is ignored; no data gives the prior."""
    rng = np.random.default_rng(1)
    phi = rng.normal(size=(7, 3))
    y = rng.integers(0, 2, 7).astype(float)
    w = np.array([1, 2, 0, 1, 1, 3, 0], float)
    got = neural_linear.fit_posterior(phi, y, w, 0.5, 2.0, 3.0)
    rep = np.repeat(np.arange(7), w.astype(int))
    mean, prec, a, b = _ridge(phi[rep], y[rep], np.ones(len(rep)), 0.5, 2.0, 3.0)
    np.testing.assert_allclose(got.mean, mean, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(got.precision, prec, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(got.a, a, rtol=1e-6)
    np.testing.assert_allclose(got.b, b, rtol=1e-4)
    empty = neural_linear.fit_posterior(phi, y, np.zeros(7), 0.5, 2.0, 3.0)
    np.testing.assert_array_equal(empty.mean, 0.0)
    assert float(empty.a) == 2.0 and float(empty.b) == 3.0


def test_neural_linear_ucb_and_thompson_match_the_posterior():
    """UCB: φ·μ + c sqrt(b/a φᵀΛ⁻¹φ) (numpy); Thompson: the mean over draws of φ·β tends to
    φ·μ and its covariance to b/(a-1) φΛ⁻¹φᵀ (Monte Carlo, 4000 draws, 5 SE)."""
    rng = np.random.default_rng(2)
    phi = rng.normal(size=(40, 4))
    y = rng.normal(size=40)
    post = neural_linear.fit_posterior(phi, y, np.ones(40), 0.25, 6.0, 6.0)
    q = rng.normal(size=(5, 4)).astype(np.float32)
    cov = np.linalg.inv(np.asarray(post.precision, np.float64))
    m = q @ np.asarray(post.mean, np.float64)
    var = float(post.b) / float(post.a) * np.einsum("kd,de,ke->k", q, cov, q)
    np.testing.assert_allclose(neural_linear.ucb_index(post, q, 2.0), m + 2 * np.sqrt(var),
                               rtol=1e-4, atol=1e-5)
    draws = np.asarray(jax.vmap(lambda k: neural_linear.thompson_scores(k, post, q))(
        jax.random.split(jax.random.key(0), 4000)), np.float64)
    pred_var = float(post.b) / (float(post.a) - 1) * np.einsum("kd,de,ke->k", q, cov, q)
    se = np.sqrt(pred_var / 4000)
    assert (np.abs(draws.mean(0) - m) < 5 * se).all()
    np.testing.assert_allclose(draws.var(0), pred_var, rtol=0.15)


# ----------------------------------------------------------------------------- ensemble


def _linear_members(num_m):
    """A linear model whose member m scores candidate m highest (one-hot inputs)."""
    model = base.Model(init=lambda key: {"w": jnp.zeros(D), "b": jnp.zeros(())},
                       apply=lambda p, x: jax.nn.sigmoid(x @ p["w"] + p["b"]),
                       logits=lambda p, x: x @ p["w"] + p["b"],
                       features=lambda p, x: x)
    return model, {"w": 3.0 * jnp.eye(num_m, D), "b": jnp.zeros(num_m)}


def test_ensemble_ts_plays_each_members_argmax_with_frequency_one_over_m():
    num_m, n = 3, 3000
    model, members = _linear_members(num_m)
    lrn = ensemble.ensemble_ts(model, TRAIN, dataclasses.replace(NETWORKS,
                                                                 ensemble_size=num_m))
    state = lrn.init(jax.random.key(0), model.init(None), CORE._replace(
        inputs=(jnp.zeros((6, D)),)))
    state = state._replace(params=jax.tree.map(lambda x: x[0], members),
                           extra=state.extra._replace(
                               params=jax.tree.map(lambda x: x[1:], members)))
    x = jnp.eye(K, D)  # candidate k < D is e_k: member m's r̂ is highest at k = m
    obs = base.Obs((x,), jnp.ones(K, bool), jnp.float32(0.3), jnp.int32(0))
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(42), i))(jnp.arange(n))
    actions, probs, _ = jax.jit(jax.vmap(lrn.act, (0, None, None)))(keys, state, obs)
    actions = np.asarray(actions)
    assert set(np.unique(actions)) <= set(range(num_m))
    counts = np.bincount(actions, minlength=num_m)
    assert stats.chisquare(counts, np.full(num_m, n / num_m)).pvalue > 1e-3, counts
    # Control: a wrong frequency (0.4, 0.3, 0.3) must be rejected by the same test.
    assert stats.chisquare(counts, n * np.array([0.4, 0.3, 0.3])).pvalue < 1e-6, counts
    # π is the exact mixture: 1/M on each member's argmax.
    np.testing.assert_allclose(np.asarray(probs[0])[:num_m], 1.0 / num_m, rtol=1e-6)


def test_ensemble_act_plays_the_drawn_members_argmax_with_or_without_probs():
    """act computes the action from the drawn member's forward alone (so a caller that
    drops probs skips the other M - 1 forwards); it must equal the action the learner took
    before, the argmax of member m among all M members' forwards, on every decision, and
    be the same whether or not the jitted caller outputs probs (the runner's two paths)."""
    num_m, n = 4, 64
    lrn = ensemble.ensemble_ts(MODEL, TRAIN, dataclasses.replace(NETWORKS,
                                                                 ensemble_size=num_m))
    state = lrn.init(jax.random.key(0), THETA0, CORE)
    for i in range(2):  # members part
        state = jax.jit(lrn.update)(jax.random.key(10 + i), state, _batch(jax.random.key(i)))

    def before(key, st, obs):  # the formula of the committed comparison's run
        params = jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), st.params,
                              st.extra.params)
        r_hat = jax.vmap(lambda p: MODEL.apply(p, *obs.inputs))(params)
        greedy = jax.vmap(lambda r: pol.greedy_probs(r, mask=obs.valid))(r_hat)
        m = jax.random.randint(key, (), 0, num_m)
        return pol.sample_icdf(obs.u, greedy[m], mask=obs.valid), jnp.mean(greedy, 0)

    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(3), i))(jnp.arange(n))
    obs = jax.vmap(lambda k: _obs(k, num_valid=12))(keys)
    full = jax.jit(jax.vmap(lrn.act, (0, None, 0)))(keys, state, obs)
    only = jax.jit(lambda *a: jax.vmap(lrn.act, (0, None, 0))(*a)[0])(keys, state, obs)
    ref = jax.jit(jax.vmap(before, (0, None, 0)))(keys, state, obs)
    np.testing.assert_array_equal(full[0], ref[0])
    np.testing.assert_array_equal(only, ref[0])
    np.testing.assert_array_equal(full[1], ref[1])
    assert len(np.unique(np.asarray(ref[0]))) > 1  # not a degenerate all-equal case
    # Control: drawing the member from another key changes some actions.
    other = jax.jit(jax.vmap(before, (0, None, 0)))(keys[::-1], state, obs)[0]
    assert (np.asarray(other) != np.asarray(ref[0])).any()


@pytest.mark.parametrize("kind", ["bernoulli", "poisson"])
def test_ensemble_bootstrap_weights_and_members_part(kind):
    config = ensemble.EnsembleConfig(ensemble_size=4, bootstrap=kind, bootstrap_p=0.5,
                                     ensemble_heads="networks")
    lrn = ensemble.ensemble_ts(MODEL, TRAIN, config)
    state = lrn.init(jax.random.key(0), THETA0, CORE)
    w = np.asarray(state.extra.weights)
    assert w.shape == (4, T + 6) and (w >= 0).all() and (w == np.round(w)).all()
    if kind == "bernoulli":
        assert set(np.unique(w)) <= {0.0, 1.0}
    big = np.asarray(ensemble.bootstrap_weights(jax.random.key(1), 8, 5000, kind, 0.5))
    assert abs(big.mean() - (0.5 if kind == "bernoulli" else 1.0)) < 0.02
    # members start equal (θ0) and part after an update
    def member(st, m):  # member 0 is state.params, the others extra.params [M - 1]
        return st.params if m == 0 else jax.tree.map(lambda x: x[m - 1], st.extra.params)

    same = lambda a, b: all(np.array_equal(x, y) for x, y in
                            zip(jax.tree.leaves(a), jax.tree.leaves(b)))
    assert all(same(member(state, 0), member(state, m)) for m in range(1, 4))
    state = jax.jit(lrn.update)(jax.random.key(1), state, _batch(jax.random.key(2)))
    assert not any(same(member(state, 0), member(state, m)) for m in range(1, 4))


# ----------------------------------------------------------------------------- NeuralUCB


def test_neural_ucb_gradients_and_width():
    """g = r̂(1 − r̂) x for a logistic model (closed form); Z grows by the played rows' g²,
    and the width of a played candidate shrinks."""
    model, _ = _linear_members(1)
    params = {"w": jnp.asarray([0.5, -1.0, 0.2, 0.0, 0.3]), "b": jnp.float32(0.1)}
    x = jax.random.normal(jax.random.key(0), (K, D))
    g = np.asarray(neural_ucb.candidate_gradients(model, params, (x,)))
    r = np.asarray(model.apply(params, x))
    # ravel order of {"b", "w"}: b first, then w
    want = np.concatenate([(r * (1 - r))[:, None], (r * (1 - r))[:, None] * np.asarray(x)], 1)
    np.testing.assert_allclose(g, want, rtol=1e-5, atol=1e-6)
    lrn = neural_ucb.neural_ucb(model, TRAIN)
    state = lrn.init(jax.random.key(0), params, CORE._replace(inputs=(jnp.zeros((6, D)),)))
    np.testing.assert_allclose(state.extra.z_diag, 0.001)
    batch = base.Batch((x[:E],), jnp.asarray([0, 1, pol.NO_ARM, 3], jnp.int32), jnp.ones(E))
    new = jax.jit(lrn.update)(jax.random.key(1), state, batch)
    played = np.asarray([1, 1, 0, 1], float)
    np.testing.assert_allclose(new.extra.z_diag,
                               0.001 + (played[:, None] * g[:E] ** 2).sum(0), rtol=1e-5)

    def width(st):
        ex = st.extra
        gg = np.asarray(neural_ucb.candidate_gradients(model, st.params, (x,)))
        return np.sqrt(float(ex.ucb_lambda) * float(ex.nu) * (gg ** 2 / np.asarray(ex.z_diag)[None]).sum(1))

    before, after = width(state), width(new._replace(params=state.params))
    assert (after[[0, 1, 3]] < before[[0, 1, 3]]).all()


# ----------------------------------------------------------------------------- schedules


def test_decaying_schedules_and_normalized_probs():
    state_e = FACTORIES["egreedy_decay"]().init(jax.random.key(0), THETA0, CORE)
    state_s = FACTORIES["sern_decay"]().init(jax.random.key(0), THETA0, CORE)
    obs = _obs(jax.random.key(1))
    r_hat = MODEL.apply(THETA0, *obs.inputs)
    for t in (0, 1, 9, 99):
        o = obs._replace(t=jnp.int32(t))
        _, p, _ = FACTORIES["egreedy_decay"]().act(jax.random.key(0), state_e, o)
        eps = min(1.0, 1.0 / (t + 1))
        np.testing.assert_allclose(p, pol.epsilon_greedy_probs(r_hat, eps, obs.valid),
                                   rtol=1e-6)
        _, p, _ = FACTORIES["sern_decay"]().act(jax.random.key(0), state_s, o)
        alpha = 0.1 / np.log2(t + 2)
        np.testing.assert_allclose(p, pol.softmax_probs(r_hat, alpha, obs.valid), rtol=1e-5)
    _, p, _ = FACTORIES["normalized"]().act(jax.random.key(0), state_e, obs)
    want = np.where(obs.valid, r_hat, 0.0)
    np.testing.assert_allclose(p, want / want.sum(), rtol=1e-6)


# ----------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("config, values, flag", [
    (neural_linear.NeuralLinTSConfig, {"lambda_prior": 0.0}, "--lambda-prior"),
    (neural_linear.NeuralLinTSConfig, {"a0": float("nan")}, "--a0"),
    (neural_linear.NeuralLinTSConfig, {"b0": -1.0}, "--b0"),
    (neural_linear.NeuralLinUCBConfig, {"ucb_width": float("inf")}, "--ucb-width"),
    (neural_linear.NeuralLinUCBConfig, {"nl_prior_mean": "one"}, "--nl-prior-mean"),
    (neural_linear.NeuralLinTSConfig, {"nl_prior_mean": 0.0}, "--nl-prior-mean"),
    (ensemble.EnsembleConfig, {"ensemble_size": 0}, "--ensemble-size"),
    (ensemble.EnsembleConfig, {"ensemble_size": 2.5}, "--ensemble-size"),
    (ensemble.EnsembleConfig, {"bootstrap": "jackknife"}, "--bootstrap"),
    (ensemble.EnsembleConfig, {"bootstrap_p": 0.0}, "--bootstrap-p"),
    (ensemble.EnsembleConfig, {"bootstrap_p": 1.5}, "--bootstrap-p"),
    (ensemble.EnsembleConfig, {"ensemble_heads": "torso"}, "--ensemble-heads"),
    (neural_ucb.NeuralUCBConfig, {"ucb_lambda": 0.0}, "--ucb-lambda"),
    (neural_ucb.NeuralUCBConfig, {"nu": float("nan")}, "--nu"),
    (decaying.EGreedyDecayConfig, {"decay_epsilon0": -1.0}, "--decay-epsilon0"),
    (decaying.SernDecayConfig, {"decay_alpha0": 1e-40}, "--decay-alpha0"),
])
def test_bad_hyperparameter_names_its_flag(config, values, flag):
    with pytest.raises(ValueError) as exc:
        config(**values)
    msg = str(exc.value)
    assert msg.startswith(flag + " ") and "\n" not in msg, msg


def test_configs_are_frozen_and_flags_documented():
    for cfg in (neural_linear.NeuralLinTSConfig(), neural_linear.NeuralLinUCBConfig(),
                ensemble.EnsembleConfig(), neural_ucb.NeuralUCBConfig(),
                decaying.EGreedyDecayConfig(), decaying.SernDecayConfig()):
        for f in dataclasses.fields(cfg):
            assert f.metadata["flag"] == "--" + f.name.replace("_", "-")
            assert f.metadata["help"]
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(cfg, dataclasses.fields(cfg)[0].name, 1)


# ----------------------------------------------------------------------------- shared heads


SHARED = ensemble.EnsembleConfig(ensemble_size=3, ensemble_heads="shared")


def test_ensemble_default_layout_is_shared_heads():
    """The default since the comparison's rerun; whole networks stay selectable
    under the flag's existing value."""
    assert ensemble.EnsembleConfig() == dataclasses.replace(SHARED, ensemble_size=3)
    lrn = ensemble.ensemble_ts(MODEL, TRAIN)
    assert isinstance(lrn.init(jax.random.key(0), THETA0, CORE).extra,
                      ensemble.SharedHeadsExtra)
    lrn = ensemble.ensemble_ts(MODEL, TRAIN, NETWORKS)
    assert isinstance(lrn.init(jax.random.key(0), THETA0, CORE).extra,
                      ensemble.EnsembleExtra)


def test_ensemble_shared_heads_contract():
    """--ensemble-heads shared: starts at θ0 (heads 0: predict = the network's r̂), never
    picks a masked slot, π sums to 1 and is the mixture of the heads' argmaxes, the heads
    part after an update, deterministic for a key, and vmapped equals one by one."""
    lrn = ensemble.ensemble_ts(MODEL, TRAIN, SHARED)
    state = lrn.init(jax.random.key(1), THETA0, CORE)
    obs = _obs(jax.random.key(2))
    np.testing.assert_allclose(lrn.predict(state, obs), MODEL.apply(THETA0, *obs.inputs),
                               rtol=1e-6)
    assert np.asarray(state.extra.heads.w).shape == (3, H)
    update, act = jax.jit(lrn.update), jax.jit(lrn.act)
    new = update(jax.random.key(3), state, _batch(jax.random.key(4)))
    again = update(jax.random.key(3), state, _batch(jax.random.key(4)))
    jax.tree.map(np.testing.assert_array_equal, new, again)
    w = np.asarray(new.extra.heads.w)
    assert not np.allclose(w[0], w[1]) and not np.allclose(w[1], w[2])  # members part
    assert not np.array_equal(np.asarray(new.params["w1"]), np.asarray(THETA0["w1"]))
    for i in range(24):
        obs = _obs(jax.random.key(100 + i), num_valid=1 + i % K, t=i)
        action, probs, _ = act(jax.random.key(i), new, obs)
        valid, p = np.asarray(obs.valid), np.asarray(probs)
        assert valid[int(action)] and (p[~valid] == 0).all() and p[int(action)] > 0
        np.testing.assert_allclose(p[valid].sum(), 1.0, rtol=1e-6)
    obs = _obs(jax.random.key(7))._replace(valid=jnp.zeros(K, bool))
    assert int(act(jax.random.key(0), new, obs)[0]) == pol.NO_ARM
    n = 4
    keys = jax.random.split(jax.random.key(9), n)
    states = jax.vmap(lrn.init, (0, None, None))(keys, THETA0, CORE)
    batch = jax.vmap(_batch)(jax.random.split(jax.random.key(6), n))
    states = jax.jit(jax.vmap(lrn.update))(keys, states, batch)
    obs = jax.vmap(lambda k: _obs(k, t=3))(jax.random.split(jax.random.key(5), n))
    a, p, _ = jax.jit(jax.vmap(lrn.act))(keys, states, obs)
    for i in range(n):
        one = jax.tree.map(lambda x, i=i: x[i], (states, obs))
        ai, pi, _ = act(keys[i], *one)
        assert int(ai) == int(a[i])
        np.testing.assert_allclose(pi, p[i], rtol=1e-6, atol=1e-7)
        st = update(keys[i], lrn.init(keys[i], THETA0, CORE),
                    jax.tree.map(lambda x, i=i: x[i], batch))
        jax.tree.map(lambda x, y, i=i: np.testing.assert_allclose(x, y[i], rtol=1e-4,
                                                                  atol=1e-5), st, states)


def test_ensemble_shared_heads_plays_each_heads_argmax_with_frequency_one_over_m():
    num_m, n = 3, 3000
    model, _ = _linear_members(num_m)
    lrn = ensemble.ensemble_ts(model, TRAIN, dataclasses.replace(SHARED, ensemble_size=num_m))
    state = lrn.init(jax.random.key(0), model.init(None), CORE._replace(
        inputs=(jnp.zeros((6, D)),)))
    # head m scores candidate m highest (features = the one-hot input)
    state = state._replace(extra=state.extra._replace(heads=ensemble.Heads(
        3.0 * jnp.eye(num_m, D), jnp.zeros(num_m))))
    obs = base.Obs((jnp.eye(K, D),), jnp.ones(K, bool), jnp.float32(0.3), jnp.int32(0))
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(42), i))(jnp.arange(n))
    actions, probs, _ = jax.jit(jax.vmap(lrn.act, (0, None, None)))(keys, state, obs)
    counts = np.bincount(np.asarray(actions), minlength=num_m)
    assert counts.sum() == n and len(counts) == num_m, counts
    assert stats.chisquare(counts, np.full(num_m, n / num_m)).pvalue > 1e-3, counts
    assert stats.chisquare(counts, n * np.array([0.4, 0.3, 0.3])).pvalue < 1e-6, counts
    np.testing.assert_allclose(np.asarray(probs[0])[:num_m], 1.0 / num_m, rtol=1e-6)


def test_ensemble_shared_heads_told_only_failures_ranks_them_lower():
    lrn = ensemble.ensemble_ts(MODEL, TRAIN, SHARED)
    state = lrn.init(jax.random.key(1), THETA0, CORE)
    batch = _batch(jax.random.key(2), fail=True)
    obs = base.Obs((batch.inputs[0],), jnp.ones(E, bool), jnp.float32(0.5), jnp.int32(0))
    before = np.asarray(lrn.predict(state, obs))
    for i in range(3):
        state = jax.jit(lrn.update)(jax.random.key(10 + i), state, batch)
    after = np.asarray(lrn.predict(state, obs))
    played = np.asarray(batch.action) >= 0
    assert (after[played] < before[played]).all(), (before, after)
