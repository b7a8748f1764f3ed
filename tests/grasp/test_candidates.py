"""Tests for sern_jax.grasp.world.candidates: antipodal grasps on a box, fixed K, bad input."""

import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from sern_jax.grasp.world import candidates as cd
from sern_jax.grasp.world import depth as dp

_HALF = (0.03, 0.02, 0.015)  # box half-sizes: 6 x 4 x 3 cm
_POS = (0.012, -0.008, _HALF[2])
_YAW = 0.4
_BOX = f"""
<mujoco>
  <compiler angle="radian"/>
  <worldbody>
    <geom type="plane" size="0 0 1"/>
    <body pos="{_POS[0]} {_POS[1]} {_POS[2]}" euler="0 0 {_YAW}">
      <geom name="box" type="box" size="{_HALF[0]} {_HALF[1]} {_HALF[2]}"/>
    </body>
  </worldbody>
</mujoco>
"""
_CAMERA = dp.CameraConfig()  # 96 x 96, fx = 175, 0.6 m above the table
_CONFIG = cd.CandidateConfig()
_BATCH = 3


@pytest.fixture(scope="session")
def box_image():
    mj_model = mujoco.MjModel.from_xml_string(_BOX)
    mj_data = mujoco.MjData(mj_model)
    mujoco.mj_forward(mj_model, mj_data)
    params = dp.overhead_params(_CAMERA)
    image = jax.jit(lambda m, d, p: dp.render(_CAMERA, m, d, p))(
        dp.camera_model(mj_model), dp.geom_poses(mj_data), params
    )
    return np.asarray(image.depth), params


@pytest.fixture(scope="session")
def sampler():
    return cd.make_sampler(_CONFIG, image_shape=_CAMERA.shape)


@pytest.fixture(scope="session")
def batch(box_image, sampler):
    """Image 0 and 1: the box under keys 0 and 1; image 2: an empty, flat table."""
    depth, params = box_image
    images = np.stack([depth, depth, np.full_like(depth, _CAMERA.distance)])
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(7), i))(jnp.arange(3))
    return keys, images, sampler(keys, images, params)


def _box_frame(points):
    """World points [..., 3] in the box frame."""
    c, s = math.cos(_YAW), math.sin(_YAW)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return (np.asarray(points) - np.asarray(_POS)) @ rot


def _exit_faces(centre, direction, tol):
    """Faces through which the line centre + t * direction leaves the box's footprint.

    Returns one set per direction (t > 0, t < 0) of (axis, sign) faces; an exit within
    `tol` of a corner belongs to both faces that meet there.
    """
    out = []
    for forward in (1.0, -1.0):
        d = forward * direction
        t = min(
            (math.copysign(_HALF[a], d[a]) - centre[a]) / d[a]
            for a in (0, 1)
            if abs(d[a]) > 1e-12
        )
        exit_point = centre + t * d
        out.append(
            {
                (a, math.copysign(1.0, exit_point[a]))
                for a in (0, 1)
                if abs(exit_point[a]) >= _HALF[a] - tol
            }
        )
    return out


def test_candidates_are_antipodal_on_a_box(batch, box_image):
    """The jaws close across opposite side faces, within the friction cone, and both
    sampled contacts lie on the box's rim."""
    _, _, out = batch
    _, params = box_image
    valid = np.asarray(out.valid[0])
    assert valid.sum() >= 32, valid.sum()  # a box this size has plenty of pairs
    grasps = np.asarray(out.grasps[0])[valid]
    width = np.asarray(out.width[0])[valid]
    pixel = _CAMERA.distance / _CAMERA.fx  # metres per pixel at the table, ~3.4 mm
    top = 2 * _HALF[2]
    cone = math.atan(_CONFIG.friction_coef)
    for g, w in zip(grasps, width):
        axis = np.array([math.cos(g[3]), math.sin(g[3]), 0.0])
        centre = np.array([g[0], g[1], top])  # the contacts are on the top rim
        local = _box_frame(np.stack([centre - 0.5 * w * axis, centre + 0.5 * w * axis]))
        # Both contacts on the rim: inside the footprint (+1 px) and within 3.5 px of an
        # edge (near a corner the blurred edge band reaches about 3 px inwards).
        slack = np.asarray(_HALF[:2]) - np.abs(local[:, :2])  # [2, 2], >= 0 inside
        assert np.all(slack >= -pixel), (g, local)
        assert np.all(slack.min(axis=1) <= 3.5 * pixel), (g, local)
        # The closing line through the centre leaves the box through opposite faces.
        mid = local.mean(axis=0)[:2]
        assert np.all(np.abs(mid) < np.asarray(_HALF[:2])), (g, mid)
        direction = (local[1] - local[0])[:2] / np.linalg.norm(local[1] - local[0])
        ahead, behind = _exit_faces(mid, direction, pixel)
        axes = [a for (a, sign) in ahead if (a, -sign) in behind]
        assert axes, (g, local, ahead, behind)
        # ... with the jaw axis inside the friction cone of that face normal (+ 0.1 rad
        # for the pixel grid).
        off = min(math.acos(min(1.0, abs(direction[a]))) for a in axes)
        assert off < cone + 0.1, (g, off)
        # Grasp height between the floor the simulator enforces and the box top.
        assert _CONFIG.min_height - 1e-6 <= g[2] <= top, g
        assert -math.pi / 2 <= g[3] < math.pi / 2
    assert np.all(width <= _CONFIG.max_width)
    assert np.all(width >= 2 * _HALF[1] - 7 * pixel)  # about the short side or wider
    # The image-space fields describe the same grasp.
    uv = np.asarray(out.center_px[0])[valid]
    back = np.asarray(dp.deproject(params, jnp.asarray(uv), out.grasp_depth[0][valid]))
    np.testing.assert_allclose(back[:, :2], grasps[:, :2], atol=1e-4)
    np.testing.assert_allclose(back[:, 2], grasps[:, 2], atol=1e-4)


def test_fixed_k_and_validity_mask(batch):
    _, _, out = batch
    k = _CONFIG.num_candidates
    assert out.grasps.shape == (_BATCH, k, 4)
    assert out.valid.shape == (_BATCH, k) and out.valid.dtype == jnp.bool_
    assert out.width.shape == (_BATCH, k)
    assert out.endpoints.shape == (_BATCH, k, 2, 2)
    assert out.center_px.shape == (_BATCH, k, 2)
    assert out.angle_px.shape == (_BATCH, k) and out.grasp_depth.shape == (_BATCH, k)
    assert not np.any(np.asarray(out.valid[2]))  # a flat table has no edges
    invalid = ~np.asarray(out.valid)
    for leaf in out:
        assert np.all(np.isfinite(np.asarray(leaf, np.float64)))
        if leaf.dtype != jnp.bool_:
            assert np.all(np.asarray(leaf)[invalid] == 0)
    # No grasp twice within an image.
    g = np.asarray(out.endpoints[0])[np.asarray(out.valid[0])]
    assert len({tuple(x.ravel()) for x in g}) == len(g)


def test_keyed_and_batched_equals_unbatched(batch, box_image):
    keys, images, out = batch
    _, params = box_image
    assert not np.array_equal(np.asarray(out.grasps[0]), np.asarray(out.grasps[1]))
    one = jax.jit(lambda k, d, p: cd.sample(_CONFIG, k, d, p))
    for i in (0, 1):
        single = one(keys[i], images[i], params)
        for a, b in zip(single, out):
            np.testing.assert_allclose(
                np.asarray(a), np.asarray(b[i]), rtol=1e-6, atol=1e-6
            )
    again = one(keys[0], images[0], params)
    np.testing.assert_array_equal(np.asarray(again.grasps), np.asarray(out.grasps[0]))


def test_mask_restricts_edges(box_image):
    depth, params = box_image
    sampler = cd.make_sampler(_CONFIG)
    keys = jax.random.split(jax.random.key(0), 2)
    images = np.stack([depth, depth])
    mask = np.stack([depth < _CAMERA.distance - 1e-3, np.zeros_like(depth, bool)])
    out = sampler(keys, images, params, mask)
    assert np.asarray(out.valid[0]).sum() >= 32
    assert not np.any(np.asarray(out.valid[1]))


def test_bad_images_raise_before_compiling(sampler, box_image):
    depth, params = box_image
    keys = jax.random.split(jax.random.key(0), 2)
    good = np.stack([depth, depth])
    with pytest.raises(ValueError, match=r"\[B, H, W\].*\(96, 96\)"):
        sampler(keys, depth, params)
    with pytest.raises(ValueError, match=r"\(48, 96\)"):
        sampler(keys, good[:, :48], params)
    with pytest.raises(ValueError, match="floating"):
        sampler(keys, good.astype(np.int32), params)
    with pytest.raises(ValueError, match="one key per image"):
        sampler(keys[:1], good, params)
    with pytest.raises(ValueError, match="mask shape"):
        sampler(keys, good, params, np.ones((2, 96, 95), bool))
    with pytest.raises(ValueError, match=r"\[H, W\]"):
        cd.sample(_CONFIG, keys[0], good, params)
    with pytest.raises(ValueError, match="3x3"):
        cd.sample(_CONFIG, keys[0], np.zeros((2, 5), np.float32), params)


def test_bad_config_raises():
    with pytest.raises(ValueError, match="num_candidates"):
        cd.CandidateConfig(num_candidates=0)
    with pytest.raises(ValueError, match="num_candidates=64 exceeds"):
        cd.CandidateConfig(num_edge_samples=8)
    with pytest.raises(ValueError, match="friction_coef"):
        cd.CandidateConfig(friction_coef=0.0)
    with pytest.raises(ValueError, match="min_width"):
        cd.CandidateConfig(min_width=0.1, max_width=0.05)
    with pytest.raises(ValueError, match="depth_offset_min"):
        cd.CandidateConfig(depth_offset_min=0.05, depth_offset_max=0.01)
