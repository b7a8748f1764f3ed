"""The ask/tell learner, driven by the simulator, makes the batched run's choices."""

import jax
import numpy as np
import pytest

from sern_jax.grasp import artifacts, context, objects, online, sim
from sern_jax.grasp import quality_net as qn


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


def test_ask_tell_matches_batched_run(tmp_path, theta0):
    config = online.OnlineConfig(policies=("sern",), num_seeds=1, rounds=2, explore=3,
                                 evaluate=1, eval_poses=0, eval_trials=0, fit_steps=3,
                                 batch_size=8)
    spec = objects.make_object("triangular_prism")
    res = online.run(config, [spec], tmp_path / "batched", theta0=theta0, progress=False)
    batched = res["results"].explore_action[:, 0, 0, 0]  # [R + 1, E]

    learner = online.AskTell(config, "sern", spec.name, 0, theta0)
    state = learner.init()
    key_os = online.object_key(jax.random.key(config.seed), spec.name, 0)
    model = context.scene_model(spec)
    simulator = sim.GraspSimulator(model, "native")
    for r in (1, 2):
        ctx = context.make_contexts(online._stream(key_os, online.EXPLORE_CONTEXT, r), spec,
                                    config.explore, model=model)
        noise = sim.sample_noise(online._stream(key_os, online.EXPLORE_TRIAL, r),
                                 config.explore, simulator.config)
        for j in range(config.explore):
            grasp, state = learner.ask(state, ctx.depth[j])
            slot = state.pending[0]
            assert slot == batched[r, j], (r, j)
            np.testing.assert_allclose(grasp, ctx.candidates.grasps[j, slot], atol=1e-5)
            one = sim.TrialNoise(*(np.asarray(a)[j:j + 1] for a in noise))
            reward = simulator.run_trials(grasp[None], one, object_pose=ctx.poses[j]).success[0]
            state = learner.tell(state, grasp, bool(reward))
            if r == 1 and j == 1:  # save / resume mid-round
                path = tmp_path / "state.npz"
                learner.save(state, path)
                state = learner.load(path)
    assert state.round_index == 3


def test_ask_tell_bad_use(theta0):
    config = online.OnlineConfig(policies=("sern",), num_seeds=1, rounds=1, explore=2,
                                 eval_poses=0, eval_trials=0)
    learner = online.AskTell(config, "sern", "x", 0, theta0)
    state = learner.init()
    with pytest.raises(ValueError, match="pending"):
        learner.tell(state, np.zeros(4), 1)
    with pytest.raises(ValueError, match="depth_image"):
        learner.ask(state, np.full((96, 96), np.nan))
    with pytest.raises(ValueError, match="policy"):
        online.AskTell(config, "nope", "x", 0, theta0)
