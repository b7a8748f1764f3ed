"""The simulated world (gripper, trial) is part of every run directory's fingerprint: D0
made under the 6 N trial, θ0 pretrained on it and learn runs with it can
never be mixed with those of the 20 N trial in one directory."""

import dataclasses
import json

import pytest

from sern_jax.infra import io
from sern_jax.grasp.model import dataset, pretrain
from sern_jax.grasp.online import config as online_config
from sern_jax.grasp.world import scene, sim


def _weak():
    """physics_settings() as it read before 2026-11-24 (6 N, 6 / 8 Newton iterations)."""
    old = scene.SceneConfig(finger_force=scene.WEAK_FINGER_FORCE, iterations=6,
                            ls_iterations=8)
    value = sim.physics_settings(old)
    return lambda *a, **k: value


def test_default_trial_is_the_named_gripper():
    c = scene.SceneConfig()
    assert c.finger_force == 20.0 and "2F-85" in scene.GRIPPER
    assert scene.WEAK_FINGER_FORCE == 6.0  # still reachable, as a non-default setting
    assert scene.SceneConfig(finger_force=scene.WEAK_FINGER_FORCE).finger_force == 6.0
    p = sim.physics_settings()
    assert p["scene"]["finger_force"] == 20.0 and p["trial"]["friction_range"] == [0.3, 0.8]
    json.dumps(p)  # plain data
    weak = sim.physics_settings(dataclasses.replace(c, finger_force=6.0))
    assert weak != p


def test_dataset_fingerprint_sees_the_trial(monkeypatch):
    cfg = dataset.DatasetConfig(num_objects=2, poses_per_object=1)
    new = cfg.fingerprint()
    monkeypatch.setattr(dataset.sim_lib, "physics_settings", _weak())
    assert cfg.fingerprint() != new
    # and so does pretraining on it
    pc = pretrain.PretrainConfig()
    assert pc.fingerprint(cfg.fingerprint()) != pc.fingerprint(new)


def test_load_refuses_a_d0_of_another_trial(tmp_path, monkeypatch):
    cfg = dataset.DatasetConfig(num_objects=2, poses_per_object=1)
    with monkeypatch.context() as m:
        m.setattr(dataset.sim_lib, "physics_settings", _weak())
        old = cfg.fingerprint()
    io.save_json(tmp_path / "config.json", {"config": cfg, "fingerprint": old})
    with pytest.raises(ValueError, match="another simulated world"):
        dataset.load(tmp_path)
    # generating into it is refused too (another dataset), before any simulation
    with pytest.raises(ValueError, match="different dataset"):
        dataset.generate(cfg, tmp_path, progress=False)


def test_learn_fingerprint_sees_the_default_trial(monkeypatch, tiny_theta0):
    from sern_jax.grasp.world import objects

    config = online_config.OnlineConfig(rounds=1, explore=1, num_seeds=1)
    specs = [objects.make_object("small_box")]
    new = online_config.run_fingerprint(config, specs, tiny_theta0)
    monkeypatch.setattr(online_config.sim_lib, "physics_settings", _weak())
    assert online_config.run_fingerprint(config, specs, tiny_theta0) != new
