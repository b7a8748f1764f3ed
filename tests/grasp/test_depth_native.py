"""The native (mj_multiRay) renderer gives depth.render's image, and contexts agree."""

import jax
import numpy as np

from sern_jax.grasp.world import context, depth, depth_native, objects, scene


def test_native_renderer_matches_jax_renderer():
    for name in ("handle", "triangular_prism"):
        spec = objects.make_object(name)
        model = context.scene_model(spec)
        jax_cfg = context.ContextConfig(renderer="jax")
        ctx = context.make_contexts(jax.random.key(3), spec, 2, jax_cfg, model=model)
        params = depth.overhead_params(jax_cfg.camera)
        d, g = depth_native.render_native(
            jax_cfg.camera, model, scene.initial_data(model), params, ctx.poses,
            scene.scene_ids(model).object_qpos)
        assert d.shape == ctx.depth.shape
        # 1e-4 m: the float32 ray tests of depth.render against MuJoCo's float64 ones.
        np.testing.assert_allclose(d, ctx.depth, atol=1e-4)
        assert (g >= 0).any()


def test_native_and_jax_contexts_agree():
    spec = objects.make_object("t_shape")
    a = context.make_contexts(jax.random.key(5), spec, 3, context.ContextConfig(renderer="native"))
    b = context.make_contexts(jax.random.key(5), spec, 3, context.ContextConfig(renderer="jax"))
    np.testing.assert_allclose(a.depth, b.depth, atol=1e-4)
    np.testing.assert_array_equal(a.candidates.valid, b.candidates.valid)
    np.testing.assert_allclose(a.candidates.grasps, b.candidates.grasps, atol=1e-4)
