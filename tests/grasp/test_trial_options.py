"""Trial options for the defensibility checks: ``sim.refine`` keeps the trial's
physical schedule at a smaller step, and a refined trial on a simple grasp agrees with the
default one."""

import dataclasses

import numpy as np
import pytest

from sern_jax.grasp.world import scene, sim


def test_refine_keeps_physical_time():
    base = sim.TrialConfig()
    dt = scene.SceneConfig().timestep
    for k in (2, 4):
        fine = sim.refine(base, k)
        assert fine.num_steps == k * base.num_steps
        assert fine.num_steps * (dt / k) == pytest.approx(base.num_steps * dt)
        assert dataclasses.replace(fine, **{f: getattr(base, f) for f in (
            "approach_steps", "settle_steps", "close_steps", "lift_steps", "shake_steps",
            "hold_steps")}) == base  # nothing but the step counts changes
    with pytest.raises(ValueError, match="factor"):
        sim.refine(base, 0)


def test_refined_trial_lifts_the_centred_box(box_model, centred_grasp):
    # the centred grasp of the small box succeeds at 5 ms and at 2.5 ms (same start pose)
    from sern_jax.grasp.world import context, objects

    spec = objects.make_object("small_box")
    pose = scene.object_pose(box_model)
    grasp = np.asarray(centred_grasp, np.float64)[None]
    ok = []
    for k in (1, 2):
        cfg = context.ContextConfig(scene=scene.SceneConfig(timestep=0.005 / k))
        model = context.scene_model(spec, cfg)
        simulator = sim.GraspSimulator(model, "native", config=sim.refine(sim.TrialConfig(), k),
                                       num_threads=1)
        ok.append(bool(simulator.run_trials(grasp, sim.zero_noise(1), object_pose=pose)
                       .success[0]))
    assert ok == [True, True]
