"""The learner interface (sern_jax.learners) on a synthetic linear-logistic model: every
registered learner never picks a masked candidate, its probabilities sum to 1 over the
valid slots, it is deterministic for a key, vmapped equals one by one, and its update
learns; bad names and hyperparameters are one-line errors naming the flag."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from sern_jax.core import policies as pol
from sern_jax.learners import base, registry

K, D, E, T = 16, 5, 4, 12


def _model() -> base.Model:
    def logits(params, x):
        return x @ params["w"] + params["b"]

    return base.Model(
        init=lambda key: {"w": jax.random.normal(key, (D,)), "b": jnp.zeros(())},
        apply=lambda params, x: jax.nn.sigmoid(logits(params, x)),
        logits=logits,
        features=lambda params, x: x)


MODEL = _model()
TRAIN = base.TrainConfig(horizon=T, fit_steps=5, batch_size=4, learning_rate=0.1)
CORE = base.Data((jnp.asarray(np.random.default_rng(0).normal(size=(3, D)), jnp.float32),),
                 jnp.asarray([1.0, 0.0, 1.0]), jnp.ones(3))
THETA0 = MODEL.init(jax.random.key(0))


def _obs(key, num_valid=9):
    k1, k2, k3 = jax.random.split(key, 3)
    x = jax.random.normal(k1, (K, D))
    valid = jnp.zeros(K, bool).at[jax.random.permutation(k2, K)[:num_valid]].set(True)
    return base.Obs((x,), valid, jax.random.uniform(k3), jnp.int32(0))


@pytest.fixture(scope="module", params=registry.names())
def learner(request):
    values = {"alpha": 0.3}  # a temperature at which softmax is not greedy on this model
    return request.param, registry.make(request.param, MODEL, TRAIN, values)


def test_never_masked_probs_sum_to_one(learner):
    name, lrn = learner
    state = lrn.init(jax.random.key(1), THETA0, CORE)
    act = jax.jit(lrn.act)
    for i in range(40):
        obs = _obs(jax.random.key(100 + i), num_valid=1 + i % K)
        action, probs, _ = act(jax.random.key(i), state, obs)
        valid = np.asarray(obs.valid)
        assert 0 <= int(action) < K and valid[int(action)], (name, i)
        p = np.asarray(probs)
        assert (p[~valid] == 0).all() and (p >= 0).all()
        np.testing.assert_allclose(p[valid].sum(), 1.0, rtol=1e-6)
    # nothing valid: NO_ARM and all-zero probabilities
    obs = _obs(jax.random.key(7))._replace(valid=jnp.zeros(K, bool))
    action, probs, _ = act(jax.random.key(0), state, obs)
    assert int(action) == pol.NO_ARM and (np.asarray(probs) == 0).all()


def test_deterministic_and_batched_equals_unbatched(learner):
    name, lrn = learner
    keys = jax.random.split(jax.random.key(3), 6)
    states = jax.vmap(lrn.init, (0, None, None))(keys, THETA0, CORE)
    obs = jax.vmap(lambda k: _obs(k))(jax.random.split(jax.random.key(4), 6))
    act_keys = jax.random.split(jax.random.key(5), 6)
    batched = jax.jit(jax.vmap(lrn.act))(act_keys, states, obs)
    again = jax.jit(jax.vmap(lrn.act))(act_keys, states, obs)
    jax.tree.map(np.testing.assert_array_equal, batched[:2], again[:2])
    for i in range(6):
        one = jax.tree.map(lambda x, i=i: x[i], (states, obs))
        a, p, _ = jax.jit(lrn.act)(act_keys[i], *one)
        assert int(a) == int(batched[0][i]), (name, i)
        np.testing.assert_allclose(p, batched[1][i], rtol=1e-6, atol=1e-7)
    # update, batched and one by one
    batch = base.Batch((jax.random.normal(jax.random.key(6), (6, E, D)),),
                       jnp.zeros((6, E), jnp.int32), jnp.zeros((6, E)))
    upd_keys = jax.random.split(jax.random.key(8), 6)
    new = jax.jit(jax.vmap(lrn.update))(upd_keys, states, batch)
    for i in range(2):
        one = jax.jit(lrn.update)(upd_keys[i], jax.tree.map(lambda x, i=i: x[i], states),
                                  jax.tree.map(lambda x, i=i: x[i], batch))
        jax.tree.map(lambda a, b, i=i: np.testing.assert_allclose(a, b[i], rtol=1e-5,
                                                                  atol=1e-6), one, new)


def test_update_appends_and_learns_from_failures(learner):
    """Told only failures on some inputs, a learner scores those inputs lower; D grows by
    the phase, NO_ARM rows get weight 0."""
    name, lrn = learner
    state = lrn.init(jax.random.key(0), THETA0, CORE)
    x = jax.random.normal(jax.random.key(9), (E, D))
    action = jnp.asarray([0, 1, pol.NO_ARM, 3], jnp.int32)
    update = jax.jit(lrn.update)
    before = np.asarray(MODEL.apply(state.params, x))
    for r in range(3):
        state = update(jax.random.key(r), state, base.Batch((x,), action, jnp.zeros(E)))
    assert int(state.buffer.count) == 3 * E
    w = np.asarray(state.buffer.weight)
    np.testing.assert_array_equal(w[:3 * E], np.tile([1, 1, 0, 1], 3))
    assert (w[3 * E:T] == 0).all() and (w[T:] == 1).all()  # empty rows, then C
    after = np.asarray(MODEL.apply(state.params, x))
    tried = np.asarray(action) >= 0
    assert (after[tried] < before[tried]).all(), (name, before, after)


def test_a_toy_learner_in_a_few_lines():
    """The interface is small: a learner that picks uniformly among the valid candidates
    (and never learns) is init/act/update in a few lines and runs like the others."""
    def init(key, theta0, core_set):
        return base.LearnerState(theta0, (), base.empty_buffer(core_set, T), ())

    def act(key, state, obs):
        probs = pol.epsilon_greedy_probs(jnp.zeros(K), 1.0, mask=obs.valid)
        return pol.sample_icdf(obs.u, probs, mask=obs.valid), probs, state

    def update(key, state, batch):
        return state._replace(buffer=base.append(state.buffer, batch))

    toy = base.Learner(init, act, update)
    state = toy.init(jax.random.key(0), THETA0, CORE)
    action, probs, state = jax.jit(toy.act)(jax.random.key(1), state, _obs(jax.random.key(2)))
    assert np.asarray(_obs(jax.random.key(2)).valid)[int(action)]
    state = jax.jit(toy.update)(jax.random.key(3), state,
                                base.Batch((jnp.ones((E, D)),), jnp.zeros(E, jnp.int32),
                                           jnp.ones(E)))
    assert int(state.buffer.count) == E


def test_alpha_is_traced_no_recompile():
    """SERN's α lives in the state as a float32 array: a sweep over α is a vmap, one compile."""
    lrn = registry.make("sern", MODEL, TRAIN)
    state = lrn.init(jax.random.key(0), THETA0, CORE)
    act = jax.jit(lrn.act)
    obs = _obs(jax.random.key(1))
    probs = []
    for alpha in (0.05, 0.5, 5.0):
        s = state._replace(extra=state.extra._replace(alpha=jnp.float32(alpha)))
        probs.append(np.asarray(act(jax.random.key(0), s, obs)[1]))
    assert act._cache_size() == 1
    assert probs[0].max() > probs[1].max() > probs[2].max()


# ----------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("name, values, flag", [
    ("sern", {"alpha": 0.0}, "--alpha"), ("sern", {"alpha": -1.0}, "--alpha"),
    ("sern", {"alpha": float("nan")}, "--alpha"), ("sern", {"alpha": float("inf")}, "--alpha"),
    ("sern", {"alpha": 1e-40}, "--alpha"),  # a float32 subnormal: underflows
    ("sern", {"alpha": 1e39}, "--alpha"),  # overflows float32
    ("sern", {"alpha": "0.1"}, "--alpha"),
    ("sern_log", {"alpha0": 0.0}, "--alpha0"), ("sern_log", {"p": 1.0}, "--p"),
    ("sern_log", {"p": 0.0}, "--p"), ("sern_log", {"p": 1e-45}, "--p"),
    ("egreedy", {"epsilon": 1.5}, "--epsilon"), ("egreedy", {"epsilon": -0.1}, "--epsilon"),
    ("egreedy", {"epsilon": 1e-40}, "--epsilon"),
    ("egreedy", {"epsilon": float("nan")}, "--epsilon"),
])
def test_bad_hyperparameter_names_its_flag(name, values, flag):
    with pytest.raises(ValueError) as exc:
        registry.make(name, MODEL, TRAIN, values)
    msg = str(exc.value)
    assert msg.startswith(flag + " ") and "\n" not in msg, msg


def test_good_edge_values_pass():
    registry.make_config("egreedy", {"epsilon": 0.0})
    registry.make_config("egreedy", {"epsilon": 1.0})
    registry.make_config("sern", {"alpha": float(np.finfo(np.float32).tiny)})


def test_bad_names_and_train_config():
    with pytest.raises(ValueError, match=r"^--policies: unknown policy 'foo'; choose from sern"):
        registry.make("foo", MODEL, TRAIN)
    with pytest.raises(ValueError, match="repeat"):
        registry.check_names(("sern", "sern"))
    with pytest.raises(ValueError, match="at least one"):
        registry.check_names(())
    with pytest.raises(ValueError, match="^learning_rate"):
        dataclasses.replace(TRAIN, learning_rate=1e-39)
    with pytest.raises(ValueError, match="^--fit-steps"):
        dataclasses.replace(TRAIN, fit_steps=0)
    with pytest.raises(ValueError, match="sern_log needs a horizon"):
        registry.make("sern_log", MODEL, dataclasses.replace(TRAIN, horizon=1))
    fields = registry.hyperparameters()
    assert {"alpha", "alpha0", "p", "epsilon"} <= set(fields)
    assert all(f.metadata.get("flag", "").startswith("--") for f in fields.values())


def test_core_imports_no_flax_or_mujoco():
    import subprocess
    import sys

    code = ("import sys, sern_jax.learners, sern_jax.learners.registry; "
            "print(any(m.split('.')[0] in ('flax', 'mujoco') for m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "False"
