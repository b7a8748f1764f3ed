"""The ask/tell loop, driven by the simulator, makes the batched run's choices and updates,
for every registered learner."""

import jax
import numpy as np
import pytest

from sern_jax.grasp.model import artifacts
from sern_jax.grasp.online import asktell, driver
from sern_jax.grasp.online import config as online_config
from sern_jax.grasp.online import keys as keys_lib
from sern_jax.grasp.world import context, objects, sim
from sern_jax.grasp.model import quality_net as qn
from sern_jax.learners import registry


@pytest.fixture(scope="module")
def theta0():
    net = qn.make_quality_network()
    params = net.init(jax.random.key(1))
    rng = np.random.default_rng(0)
    core = {}
    for kind in ("dpp", "random"):
        core[f"{kind}_image"] = rng.normal(0, 0.01, (6, 32, 32)).astype(np.float32)
        core[f"{kind}_depth"] = np.full(6, 0.57, np.float32)
        core[f"{kind}_label"] = (rng.random(6) < 0.5).astype(np.float32)
    return artifacts.Theta0(net, params, core, {}, "asktell-test")


FAST = ("sern", "greedy")  # the softmax and the greedy paths of Algorithm 1's learners


def test_ask_tell_matches_batched_run(tmp_path, theta0):
    """sern and greedy in the default run; every other registered learner below (slow).
    (The batched runs of all four Algorithm 1 learners equal the pre-refactor code:
    tests/grasp/test_runner.py.)"""
    _ask_tell_matches_batched(FAST, tmp_path, theta0)


@pytest.mark.slow  # ~20-30 s of compiles per learner on 2 cores
def test_ask_tell_matches_batched_run_for_every_other_learner(tmp_path, theta0):
    others = tuple(n for n in registry.names() if n not in FAST)
    if not others:
        pytest.skip("no other learner registered")
    _ask_tell_matches_batched(others, tmp_path, theta0)


def _ask_tell_matches_batched(names, tmp_path, theta0):
    config = online_config.OnlineConfig(policies=names, num_seeds=1, rounds=2, explore=3,
                                 evaluate=1, eval_poses=0, eval_trials=0, fit_steps=3,
                                 batch_size=8)
    spec = objects.make_object("triangular_prism")
    res = driver.run(config, [spec], tmp_path / "batched", theta0=theta0, progress=False)
    key_os = keys_lib.object_key(jax.random.key(config.seed), spec.name, 0)
    model = context.scene_model(spec)
    simulator = sim.GraspSimulator(model, "native")
    contexts = {r: context.make_contexts(keys_lib.stream(key_os, keys_lib.EXPLORE_CONTEXT, r),
                                         spec, config.explore, model=model) for r in (1, 2)}
    for q, name in enumerate(names):
        batched = res["results"].explore_action[:, 0, q, 0]  # [R + 1, E]
        learner = asktell.AskTell(config, name, spec.name, 0, theta0)
        state = learner.init()
        for r in (1, 2):
            ctx = contexts[r]
            noise = sim.sample_noise(keys_lib.stream(key_os, keys_lib.EXPLORE_TRIAL, r),
                                     config.explore, simulator.config)
            for j in range(config.explore):
                grasp, state = learner.ask(state, ctx.depth[j])
                slot = state.pending[0]
                assert slot == batched[r, j], (name, r, j)
                np.testing.assert_allclose(grasp, ctx.candidates.grasps[j, slot], atol=1e-5)
                one = sim.TrialNoise(*(np.asarray(a)[j:j + 1] for a in noise))
                reward = simulator.run_trials(grasp[None], one,
                                              object_pose=ctx.poses[j]).success[0]
                state = learner.tell(state, grasp, bool(reward))
                if r == 1 and j == 1:  # save / resume mid-round
                    path = tmp_path / f"state_{name}.npz"
                    learner.save(state, path)
                    state = learner.load(path)
        assert state.round_index == 3
        # the same data and the same parameters as the batched copy
        want = res["states"][q]
        np.testing.assert_array_equal(state.learner.buffer.reward,
                                      np.asarray(want.buffer.reward)[0, 0])
        for a, b in zip(jax.tree.leaves(state.learner.params), jax.tree.leaves(want.params)):
            np.testing.assert_allclose(a, np.asarray(b)[0, 0], rtol=1e-5, atol=1e-6)


def test_ask_tell_bad_use(theta0, tmp_path):
    config = online_config.OnlineConfig(policies=("sern",), num_seeds=1, rounds=1, explore=2,
                                 eval_poses=0, eval_trials=0)
    learner = asktell.AskTell(config, "sern", "x", 0, theta0)
    state = learner.init()
    with pytest.raises(ValueError, match="pending"):
        learner.tell(state, np.zeros(4), 1)
    with pytest.raises(ValueError, match="depth_image"):
        learner.ask(state, np.full((96, 96), np.nan))
    with pytest.raises(ValueError, match="unknown policy 'nope'"):
        asktell.AskTell(config, "nope", "x", 0, theta0)
    learner.save(state, tmp_path / "s.npz")
    other = asktell.AskTell(config, "sern", "y", 0, theta0)
    with pytest.raises(ValueError, match="another config"):
        other.load(tmp_path / "s.npz")
