"""Tests for sern_jax.grasp.world.depth: parity with native mj_ray, cylinders, no materials."""

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from sern_jax.grasp.world._mjx import mjx

from sern_jax.grasp.world import depth as dp

# A scene without any <material>, with every geom type the camera must see, a cylinder,
# a mesh, and a "gripper" body in geom group 3 hovering over the objects.
_SCENE = """
<mujoco>
  <compiler angle="radian"/>
  <asset>
    <mesh name="wedge" vertex="0 0 0  0.04 0 0  0 0.03 0  0 0 0.03  0.04 0 0.03  0 0.03 0.03"/>
    <!-- a cube with one top corner pushed in: not convex, so mjx.ray's triangles see it -->
    <mesh name="dent"
          vertex="0 0 0  .05 0 0  .05 .05 0  0 .05 0  0 0 .05  .05 0 .05  .035 .035 .015
                  0 .05 .05"
          face="0 2 1  0 3 2  4 5 6  4 6 7  0 1 5  0 5 4  3 7 6  3 6 2  0 4 7  0 7 3
                1 2 6  1 6 5"/>
  </asset>
  <worldbody>
    <geom name="table" type="plane" size="0 0 1"/>
    <body name="box" pos="0.03 0.02 0.03" euler="0.3 0.2 0.5">
      <freejoint/>
      <geom type="box" size="0.02 0.03 0.025"/>
    </body>
    <body name="cyl" pos="-0.05 -0.04 0.035" euler="0.5 0.1 0.3">
      <geom name="cylinder" type="cylinder" size="0.02 0.035" contype="0" conaffinity="0"/>
    </body>
    <body name="round" pos="0.0 -0.09 0.03">
      <geom type="sphere" size="0.025"/>
      <geom type="capsule" size="0.012 0.02" pos="0.06 0 0" euler="0 1.2 0"/>
      <geom type="ellipsoid" size="0.015 0.02 0.03" pos="-0.06 0 0"/>
    </body>
    <body name="wedge" pos="-0.08 0.06 0">
      <geom name="wedge" type="mesh" mesh="wedge"/>
    </body>
    <body name="dent" pos="0.07 -0.04 0">
      <geom name="dent" type="mesh" mesh="dent" contype="0" conaffinity="0"/>
    </body>
    <body name="gripper" pos="0.03 0.02 0.12">
      <geom name="palm" type="box" size="0.05 0.01 0.01" group="3" contype="0"
            conaffinity="0"/>
    </body>
  </worldbody>
</mujoco>
"""

_SMALL = dp.CameraConfig(
    height=16, width=16, fx=22.0, fy=22.0, distance=0.5, geomgroup=()
)
_NO_GRIPPER = (1, 1, 1, 0, 1, 1)


@pytest.fixture(scope="session")
def scene():
    mj_model = mujoco.MjModel.from_xml_string(_SCENE)
    mj_data = mujoco.MjData(mj_model)
    mujoco.mj_forward(mj_model, mj_data)
    return mj_model, mj_data


@pytest.fixture(scope="session")
def small_render():
    return jax.jit(lambda m, d, p: dp.render(_SMALL, m, d, p))


@pytest.fixture(scope="session")
def batched_render():
    return dp.make_renderer(_SMALL)


def _native(mj_model, mj_data, params, config, geomgroup=None, bodyexclude=-1):
    rays = np.asarray(dp.pixel_rays(config, params), np.float64).reshape(-1, 3)
    pos = np.asarray(params.pos, np.float64)
    dist = np.empty(len(rays))
    geom = np.empty(len(rays), np.int64)
    gid = np.zeros(1, np.int32)
    group = None if geomgroup is None else np.asarray(geomgroup, np.uint8)
    for i, ray in enumerate(rays):
        dist[i] = mujoco.mj_ray(mj_model, mj_data, pos, ray, group, 1, bodyexclude, gid)
        geom[i] = gid[0]
    return dist.reshape(config.shape), geom.reshape(config.shape)


@pytest.mark.parametrize("fast_convex_mesh", [True, False])
def test_parity_with_native_mj_ray(scene, small_render, fast_convex_mesh):
    """16x16 depth equals MuJoCo's own mj_ray within 1e-4 m, over every geom type, with
    convex meshes cast as polyhedra (default) or by mjx.ray's triangle test."""
    mj_model, mj_data = scene
    assert mj_model.nmat == 0  # the no-material case that crashes raw mjx.ray
    params = dp.overhead_params(_SMALL, target=(-0.01, -0.01, 0.0))
    if fast_convex_mesh:
        render = small_render
    else:
        config = dataclasses.replace(_SMALL, fast_convex_mesh=False)
        render = jax.jit(lambda m, d, p: dp.render(config, m, d, p))
    image = render(dp.camera_model(mj_model), dp.geom_poses(mj_data), params)
    ref_dist, ref_geom = _native(mj_model, mj_data, params, _SMALL)
    assert np.all(ref_dist > 0)  # the table is everywhere
    np.testing.assert_allclose(np.asarray(image.depth), ref_dist, rtol=1e-4, atol=1e-4)
    # Geom ids can differ only at grazing ties; demand near-total agreement, and that
    # several object types are actually in view.
    same = np.asarray(image.geom) == ref_geom
    assert same.mean() >= 0.98, same.mean()
    types_seen = set(mj_model.geom_type[ref_geom[ref_geom >= 0]].tolist())
    assert len(types_seen) >= 4 and int(mujoco.mjtGeom.mjGEOM_MESH) in types_seen
    seen = set(ref_geom.ravel().tolist())
    for name in (
        "wedge",
        "dent",
    ):  # the convex and the non-convex mesh are both in view
        assert mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_GEOM, name) in seen, name


def test_convexity_check_picks_the_fast_mesh_path(scene):
    mj_model, _ = scene
    m = dp.camera_model(mj_model)

    def gid(name):
        return mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_GEOM, name)

    wedge = dp._convex_planes(m, gid("wedge"))
    assert wedge is not None and len(wedge[0]) == 5  # a triangular prism has 5 faces
    assert dp._convex_planes(m, gid("dent")) is None


def test_cylinder_is_seen_although_mjx_ray_misses_it(scene):
    """Rays at the cylinder hit it (exact analytic test); raw mjx.ray sees through it."""
    mj_model, mj_data = scene
    cyl = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_GEOM, "cylinder")
    m = dp.camera_model(mj_model)
    poses = dp.geom_poses(mj_data)
    centre = mj_data.geom_xpos[cyl]
    config = dp.CameraConfig(
        height=5, width=5, fx=400.0, fy=400.0, distance=0.5, geomgroup=()
    )
    params = dp.overhead_params(config, target=(centre[0], centre[1], 0.0))
    image = jax.jit(lambda m, d, p: dp.render(config, m, d, p))(m, poses, params)
    ref_dist, ref_geom = _native(mj_model, mj_data, params, config)
    assert np.all(ref_geom == cyl)  # the small view is filled by the cylinder
    assert np.all(np.asarray(image.geom) == cyl)
    np.testing.assert_allclose(np.asarray(image.depth), ref_dist, rtol=1e-4, atol=1e-4)
    # Raw mjx.ray on the same ray reports something farther (the table), not the cylinder.
    ray = dp.pixel_rays(config, params)[2, 2]
    with jax.numpy_rank_promotion("allow"):  # MJX's mesh ray broadcasts implicitly
        raw_dist, raw_geom = jax.jit(mjx.ray)(m, poses, params.pos, ray)
    assert int(raw_geom) != cyl
    assert float(raw_dist) > ref_dist[2, 2] + 0.01


def test_no_material_model_needs_and_gets_a_default_material(scene):
    mj_model, _ = scene
    m = dp.camera_model(mj_model)
    assert m.mat_rgba.shape == (1, 4)
    assert np.all(np.asarray(m.geom_matid) == -1)  # nothing references the default row
    with_mat = mujoco.MjModel.from_xml_string(
        _SCENE.replace("<asset>", '<asset><material name="grey" rgba=".5 .5 .5 1"/>')
    )
    assert dp.camera_model(with_mat).mat_rgba.shape == (1, 4)  # left as it was


def test_gripper_excluded_by_geomgroup_and_bodyexclude(scene, small_render):
    mj_model, mj_data = scene
    palm = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_GEOM, "palm")
    gripper = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_BODY, "gripper")
    m = dp.camera_model(mj_model)
    poses = dp.geom_poses(mj_data)
    configs = {
        "group": dataclasses.replace(_SMALL, geomgroup=_NO_GRIPPER),
        "body": dataclasses.replace(_SMALL, bodyexclude=(gripper,)),
    }
    params = dp.overhead_params(_SMALL, target=(0.03, 0.02, 0.0))
    images = {
        k: jax.jit(lambda m, d, p, c=c: dp.render(c, m, d, p))(m, poses, params)
        for k, c in configs.items()
    }
    images["all"] = small_render(m, poses, params)
    assert dp.CameraConfig().geomgroup == _NO_GRIPPER  # the default hides the gripper
    assert np.any(np.asarray(images["all"].geom) == palm)
    for key in ("group", "body"):
        assert not np.any(np.asarray(images[key].geom) == palm), key
    np.testing.assert_array_equal(
        np.asarray(images["group"].depth), np.asarray(images["body"].depth)
    )
    ref_dist, _ = _native(mj_model, mj_data, params, _SMALL, geomgroup=_NO_GRIPPER)
    np.testing.assert_allclose(np.asarray(images["group"].depth), ref_dist, atol=1e-4)


def _poses(mj_model, mj_data, shifts):
    """Geom poses of the scene with the free box moved by each (dx, dy)."""
    data = mujoco.MjData(mj_model)
    out = []
    for dx, dy in shifts:
        data.qpos[:] = mj_data.qpos
        data.qpos[0] += dx
        data.qpos[1] += dy
        mujoco.mj_kinematics(mj_model, data)
        out.append(dp.geom_poses(data))
    return jax.tree.map(lambda *x: jnp.stack(x), *out)


def test_batched_equals_unbatched(scene, small_render, batched_render):
    mj_model, mj_data = scene
    m = dp.camera_model(mj_model)
    poses = _poses(mj_model, mj_data, [(0.0, 0.0), (0.02, -0.01), (-0.03, 0.02)])
    params = jax.tree.map(lambda x: jnp.stack([x] * 3), dp.overhead_params(_SMALL))
    params = params._replace(pos=params.pos.at[2, 0].add(0.01))  # one camera moved
    batch = batched_render(m, poses, params)
    assert batch.depth.shape == (3, 16, 16)
    assert not np.allclose(batch.depth[0], batch.depth[1])  # the scenes differ
    for i in range(3):
        one = small_render(
            m, jax.tree.map(lambda x: x[i], poses), jax.tree.map(lambda x: x[i], params)
        )
        np.testing.assert_allclose(
            np.asarray(batch.depth[i]), np.asarray(one.depth), rtol=1e-6, atol=1e-6
        )
        np.testing.assert_array_equal(np.asarray(batch.geom[i]), np.asarray(one.geom))


def test_noise_is_keyed(scene, batched_render):
    mj_model, mj_data = scene
    m = dp.camera_model(mj_model)
    poses = jax.tree.map(lambda x: jnp.stack([x] * 4), dp.geom_poses(mj_data))
    params = jax.tree.map(lambda x: jnp.stack([x] * 4), dp.overhead_params(_SMALL))
    keys = jax.random.split(jax.random.key(0), 4)
    keys = keys.at[1].set(keys[0])  # images 0 and 1 share a key
    noisy = dp.make_renderer(_SMALL, noise=True)(keys, m, poses, params)
    clean = batched_render(m, poses, params)
    depth = np.asarray(noisy.depth)
    np.testing.assert_array_equal(depth[0], depth[1])
    assert not np.array_equal(depth[0], depth[2])
    assert not np.array_equal(depth[2], depth[3])
    diff = depth - np.asarray(clean.depth)
    # Dex-Net magnitudes: gamma(1000) ~ 3% of 0.5 m, plus 5 mm correlated noise.
    assert 0.002 < diff.std() < 0.05, diff.std()
    np.testing.assert_array_equal(np.asarray(noisy.geom), np.asarray(clean.geom))


def test_bad_config_and_model_raise():
    with pytest.raises(ValueError, match="height"):
        dp.CameraConfig(height=0)
    with pytest.raises(ValueError, match="fx"):
        dp.CameraConfig(fx=-1.0)
    with pytest.raises(ValueError, match="geomgroup"):
        dp.CameraConfig(geomgroup=(1, 0))
    with pytest.raises(ValueError, match="MjModel"):
        dp.camera_model("not a model")
    with pytest.raises(ValueError, match="target"):
        dp.overhead_params(_SMALL, target=(0.0, np.nan, 0.0))


def test_project_inverts_deproject():
    params = dp.overhead_params(_SMALL, target=(0.1, -0.2, 0.0))
    uv = jnp.array([[0.0, 0.0], [3.5, 11.0], [15.0, 15.0]])
    points = dp.deproject(params, uv, jnp.array([0.3, 0.45, 0.5]))
    back, z = dp.project(params, points)
    np.testing.assert_allclose(np.asarray(back), np.asarray(uv), atol=1e-4)
    np.testing.assert_allclose(np.asarray(z), [0.3, 0.45, 0.5], atol=1e-6)
    # Overhead: image right is world +x, image down is world -y.
    assert points[2, 0] > points[0, 0] and points[2, 1] < points[0, 1]
