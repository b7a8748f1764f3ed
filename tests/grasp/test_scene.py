"""Tests for sern_jax.grasp.world.scene: build, resting pose, solver settings, indices."""

import mujoco
import numpy as np
import pytest

from sern_jax.grasp.world import objects, scene


def _lowest_z(model):
    data = scene.initial_data(model)
    return scene._lowest_point(model, data, scene.scene_ids(model))


@pytest.mark.parametrize("name", objects.object_names())
def test_every_named_object_rests_on_the_table(name):
    model = scene.build_scene(objects.make_object(name), seed=3)
    pose = scene.object_pose(model)
    assert np.all(np.isfinite(pose))
    assert abs(np.linalg.norm(pose[3:]) - 1) < 1e-6
    assert np.abs(pose[:2]).max() <= scene.SceneConfig().xy_jitter + 1e-9
    # Resting on the table: lowest point within 3 mm of z = 0 (contact penetration).
    assert -0.003 < _lowest_z(model) < 0.003


def test_population_objects_build_and_rest():
    for i, spec in enumerate(objects.sample_population(0, 12)):
        model = scene.build_scene(spec, seed=i)
        assert -0.003 < _lowest_z(model) < 0.003, spec.name


def test_solver_settings_materials_and_types():
    model = scene.build_scene(objects.make_object("slim_bottle"))
    assert model.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
    assert model.opt.impratio == pytest.approx(10.0)
    assert model.opt.iterations >= 5
    assert model.opt.solver == mujoco.mjtSolver.mjSOL_NEWTON
    assert model.nmat >= 1 and np.all(model.geom_matid >= 0)  # mjx.ray needs materials
    ids = scene.scene_ids(model)
    types = set(model.geom_type[list(ids.object_geoms)])
    assert mujoco.mjtGeom.mjGEOM_CYLINDER not in types  # no cylinders for mjx.ray
    assert mujoco.mjtGeom.mjGEOM_ELLIPSOID not in types
    assert np.all(model.geom_group[list(ids.object_geoms)] == scene.GROUP_OBJECT)
    assert np.all(model.geom_group[list(ids.gripper_geoms)] == scene.GROUP_GRIPPER)
    assert set(ids.pad_geoms) <= set(ids.gripper_geoms)


def test_resting_pose_is_seeded():
    spec = objects.make_object("t_shape")
    a = scene.object_pose(scene.build_scene(spec, seed=5))
    b = scene.object_pose(scene.build_scene(spec, seed=5))
    c = scene.object_pose(scene.build_scene(spec, seed=6))
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_mjx_accepts_the_scene():
    from sern_jax.grasp.world._mjx import mjx

    model = scene.build_scene(objects.make_object("triangular_prism"))
    mx = mjx.put_model(model)
    assert mx.nq == model.nq and mx.ngeom == model.ngeom


def test_bad_inputs_raise():
    with pytest.raises(ValueError, match="ObjectSpec"):
        scene.build_scene("small_box")
    with pytest.raises(ValueError, match="timestep"):
        scene.SceneConfig(timestep=0.5)
    model = scene.build_scene(objects.make_object("cube"))
    with pytest.raises(ValueError, match="pose"):
        scene.set_object_pose(model, [0, 0, np.nan, 1, 0, 0, 0])


def test_scene_config_reads_back_the_build_settings():
    config = scene.SceneConfig(timestep=0.004, iterations=7, ls_iterations=9, impratio=5.0,
                               opening=0.07, finger_force=12.5, finger_kp=900.0,
                               finger_damping=15.0, palm_kp=3000.0, palm_damping=150.0,
                               yaw_kp=40.0, yaw_damping=4.0, friction=0.7, pad_friction=0.4)
    model = mujoco.MjModel.from_xml_string(
        scene.scene_xml(objects.make_object("small_box"), config))
    assert scene.scene_config(model) == config
    assert scene.scene_config(scene.build_scene(objects.make_object("sphere"))) == \
        scene.SceneConfig()


def test_scene_xml_inertial_overrides_the_geoms_inertia():
    spec = objects.make_object("small_box")
    inertial = ((0.001, -0.002, 0.003), (1.0, 0.0, 0.0, 0.0), 0.25, (1e-4, 2e-4, 3e-4))
    assert scene.scene_xml(spec) == scene.scene_xml(spec, inertial=None)
    model = mujoco.MjModel.from_xml_string(scene.scene_xml(spec, inertial=inertial))
    body = scene.scene_ids(model).object_body
    np.testing.assert_allclose(model.body_ipos[body], inertial[0])
    assert model.body_mass[body] == 0.25
    np.testing.assert_allclose(model.body_inertia[body], inertial[3])
