"""The simulated world of an online run (scene physics, trial randomisation, depth noise)
is a choice of the caller, reaches the contexts and the trials, and is part of the run's
identity."""

import numpy as np
import pytest

from sern_jax.grasp.world import context, objects, scene, sim
from sern_jax.grasp.online import config as online_config
from sern_jax.grasp.online import driver

CONFIG = online_config.OnlineConfig(policies=("greedy",), num_seeds=2, rounds=1, explore=3,
                             evaluate=2, eval_poses=0, fit_steps=1, batch_size=4)


def _quiet(*_):
    pass


@pytest.mark.slow  # two tiny learning runs, ~35 s on 2 cores; the fast test below is its core
def test_world_reaches_the_trials_and_the_fingerprint(tiny_theta0, tmp_path):
    spec = objects.make_object("small_box")
    # 0.05 N per finger cannot lift a box of ~0.1 kg (friction <= 0.8): every trial fails.
    weak = context.ContextConfig(scene=scene.SceneConfig(finger_force=0.05))
    res = driver.run(CONFIG, [spec], tmp_path / "weak", theta0=tiny_theta0, progress=False,
                     log=_quiet, context_config=weak)
    assert np.all(res["results"].paper_eval[1:] == 0.0)
    assert np.all(res["results"].explore_success[1:] == 0.0)
    # control: the same run in the default world lifts the box some of the time
    base = driver.run(CONFIG, [spec], tmp_path / "default", theta0=tiny_theta0,
                      progress=False, log=_quiet)
    assert base["results"].explore_success[1:].sum() + base["results"].paper_eval[1:].sum() > 0
    # the same directory with the default world is another run
    with pytest.raises(ValueError, match="different learning run"):
        driver.run(CONFIG, [spec], tmp_path / "weak", theta0=tiny_theta0, progress=False,
                   log=_quiet)
    # and a trial config differing only in its friction range is another run too
    other = sim.TrialConfig(friction_range=(0.2, 0.4))
    with pytest.raises(ValueError, match="different learning run"):
        driver.run(CONFIG, [spec], tmp_path / "weak", theta0=tiny_theta0, progress=False,
                   log=_quiet, context_config=weak, trial_config=other)



def test_weak_grip_fails_where_the_default_lifts(centred_grasp):
    """The fast core of the test above: the scene config decides the trial's outcome."""
    spec = objects.make_object("small_box")
    grasp = np.asarray(centred_grasp, np.float64)[None]
    outcomes = []
    for force in (scene.SceneConfig().finger_force, 0.05):
        model = scene.build_scene(spec, seed=0, config=scene.SceneConfig(finger_force=force))
        simulator = sim.GraspSimulator(model, "native", num_threads=1)
        outcomes.append(bool(simulator.run_trials(grasp, sim.zero_noise(1)).success[0]))
    assert outcomes == [True, False]
