"""The optional RealSense-like depth noise: σ grows with range as stated, holes
appear at the stated rates (more beside depth jumps), holes are filled, and it is off by
default."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from sern_jax.grasp.world import context, depth, objects

RS = depth.CameraConfig(noise_model="realsense")


def _apply(config, image, num, seed=0):
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(seed), i))(jnp.arange(num))
    params = depth.overhead_params(config)
    fn = jax.jit(jax.vmap(lambda k, d: depth._noise(config, k, params, d), (0, None)))
    return np.asarray(fn(keys, jnp.asarray(image, jnp.float32)))


@pytest.mark.parametrize("z", [0.4, 0.8])
def test_sigma_grows_with_range_as_stated(z):
    config = depth.CameraConfig(noise_model="realsense", rs_dropout=0.0, rs_edge_dropout=0.0)
    out = _apply(config, np.full((32, 32), z), 64)
    sigma = config.rs_sigma0 + config.rs_sigma2 * z**2  # 0.78 mm at 0.4 m, 2.5 mm at 0.8 m
    n = out.size
    sd = out.std()
    # the sample sd of n normal values has sd ~ sigma / sqrt(2 n)
    assert abs(sd - sigma) < 5 * sigma / np.sqrt(2 * n)
    assert abs(out.mean() - z) < 5 * sigma / np.sqrt(n)


def test_holes_at_stated_rates_more_beside_jumps():
    # a 5 cm step between columns 15 and 16; no inpainting: holes take the background (the
    # farthest valid depth), which is how they are counted here
    config = depth.CameraConfig(noise_model="realsense", rs_sigma0=0.0, rs_sigma2=0.0,
                                rs_dropout=0.02, rs_edge_dropout=0.3, rs_inpaint_steps=0)
    image = np.full((32, 32), 0.60)
    image[:, 16:] = 0.55
    out = _apply(config, image, 200)
    hole = np.isclose(out, 0.60) & (image == 0.55)[None]  # a near pixel shown as far
    edge = np.zeros((32, 32), bool)
    edge[:, 16] = True  # near side of the jump
    flat = (image == 0.55) & ~edge
    r_edge = hole[:, edge].mean()
    r_flat = hole[:, flat].mean()
    n_edge = hole[:, edge].size
    n_flat = hole[:, flat].size
    assert abs(r_edge - 0.3) < 5 * np.sqrt(0.3 * 0.7 / n_edge)
    assert abs(r_flat - 0.02) < 5 * np.sqrt(0.02 * 0.98 / n_flat)


def test_inpaint_fills_from_neighbours_and_background():
    image = jnp.asarray(np.arange(25.0).reshape(5, 5))
    missing = np.zeros((5, 5), bool)
    missing[2, 2] = True
    out = np.asarray(depth.inpaint(image, jnp.asarray(missing), 1))
    assert out[2, 2] == pytest.approx(np.mean([6, 7, 8, 11, 13, 16, 17, 18]))
    np.testing.assert_array_equal(np.delete(out.ravel(), 12), np.delete(np.arange(25.0), 12))
    # with no fill pass, a hole takes the farthest valid depth
    out0 = np.asarray(depth.inpaint(image, jnp.asarray(missing), 0))
    assert out0[2, 2] == 24.0


def test_off_by_default_and_reaches_contexts():
    assert context.ContextConfig().noise is False
    assert depth.CameraConfig().noise_model == "dexnet"
    spec = objects.make_object("small_box")
    key = jax.random.key(3)
    clean = context.make_contexts(key, spec, 2, context.ContextConfig(renderer="native"))
    noisy_cfg = context.ContextConfig(renderer="native", noise=True, camera=RS)
    noisy = context.make_contexts(key, spec, 2, noisy_cfg)
    again = context.make_contexts(key, spec, 2, noisy_cfg)
    np.testing.assert_array_equal(noisy.depth, again.depth)  # keyed, deterministic
    np.testing.assert_array_equal(clean.poses, noisy.poses)  # same poses: noise only
    diff = np.abs(noisy.depth - clean.depth)
    assert diff.max() > 0
    assert np.median(diff) < 0.005  # mm-scale noise at ~0.6 m, not a different image


def test_bad_noise_settings_are_refused():
    with pytest.raises(ValueError, match="noise_model"):
        depth.CameraConfig(noise_model="kinect")
    with pytest.raises(ValueError, match="dropout"):
        depth.CameraConfig(rs_dropout=1.5)
