"""Tests for sern_jax.grasp.world.context: batched equals unbatched, streams, no recompile, trials."""

import jax
import numpy as np
import pytest

from sern_jax.grasp.world import context, objects, scene, sim

NUM_POSES = 3


@pytest.fixture(scope="module")
def spec():
    return objects.make_object("small_box")


@pytest.fixture(scope="module")
def contexts(spec):
    return context.make_contexts(jax.random.key(7), spec, NUM_POSES)


def test_shapes_and_numpy_leaves(contexts):
    config = context.ContextConfig()
    h, w = config.camera.shape
    k = config.candidates.num_candidates
    assert contexts.poses.shape == (NUM_POSES, 7)
    assert contexts.depth.shape == (NUM_POSES, h, w)
    assert contexts.candidates.grasps.shape == (NUM_POSES, k, 4)
    assert contexts.candidates.valid.shape == (NUM_POSES, k)
    assert contexts.camera.rot.shape == (3, 3)
    for leaf in jax.tree.leaves((contexts.depth, contexts.candidates, contexts.camera)):
        assert isinstance(leaf, np.ndarray)
    assert contexts.candidates.valid.any(axis=1).all()
    np.testing.assert_allclose(np.linalg.norm(contexts.poses[:, 3:], axis=1), 1, atol=1e-9)


@pytest.mark.parametrize("i", [0, 2])
def test_batched_equals_unbatched(spec, contexts, i):
    one = context.make_context(jax.random.fold_in(jax.random.key(7), i), spec)
    np.testing.assert_array_equal(one.pose, contexts.poses[i])
    np.testing.assert_array_equal(scene.object_pose(one.model), one.pose)
    np.testing.assert_allclose(one.depth, contexts.depth[i], rtol=0, atol=1e-6)
    np.testing.assert_array_equal(one.candidates.valid, contexts.candidates.valid[i])
    for a, b in zip(one.candidates, jax.tree.map(lambda x: x[i], contexts.candidates)):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6)
    alone = contexts.context(i)
    np.testing.assert_array_equal(scene.object_pose(alone.model), contexts.poses[i])


def test_contexts_differ_and_keys_repeat(spec, contexts):
    # Seed diversity: each pose has its own resting pose and its own candidates.
    assert len({tuple(p) for p in np.round(contexts.poses, 6)}) == NUM_POSES
    grasps = contexts.candidates.grasps
    assert not np.array_equal(grasps[0], grasps[1])
    again = context.make_contexts(jax.random.key(7), spec, NUM_POSES, model=contexts.model)
    np.testing.assert_array_equal(again.poses, contexts.poses)
    np.testing.assert_array_equal(again.candidates.valid, contexts.candidates.valid)


def test_streams_are_named_fold_ins():
    key = jax.random.key(3)
    seeds = context.pose_seeds(jax.random.fold_in(key, 0)[None])
    bits = jax.random.bits(jax.random.fold_in(jax.random.fold_in(key, 0),
                                              context.POSE_STREAM), (), "uint32")
    assert seeds[0] == int(bits) >> 1
    assert len({context.POSE_STREAM, context.DEPTH_NOISE_STREAM,
                context.CANDIDATE_STREAM}) == 3


def test_no_recompile_across_keys_and_models(spec, contexts):
    config = context.ContextConfig()
    fn = context._pipeline(config.camera, config.candidates, config.noise)
    before = fn._cache_size()
    context.make_contexts(jax.random.key(99), spec, NUM_POSES, model=contexts.model)
    context.make_contexts(jax.random.key(100), spec, NUM_POSES)  # a fresh model
    assert fn._cache_size() == before


def test_noise_changes_depth_only_on_the_object(spec):
    key = jax.random.key(5)
    clean = context.make_contexts(key, spec, 1)
    noisy = context.make_contexts(
        key, spec, 1, context.ContextConfig(noise=True), model=clean.model)
    np.testing.assert_array_equal(noisy.poses, clean.poses)
    diff = noisy.depth != clean.depth
    assert diff.any()
    far = context.ContextConfig().camera.far
    assert not diff[clean.depth >= far].any()


@pytest.mark.parametrize("kwargs, match", [
    (dict(num_poses=0), "num_poses"),
    (dict(num_poses=2.0), "num_poses"),
    (dict(key=0), "key"),
    (dict(config="x"), "config"),
    (dict(spec="small_box"), "spec"),
    (dict(model="m"), "model"),
])
def test_bad_input_raises(spec, kwargs, match):
    args = dict(key=jax.random.key(0), spec=spec, num_poses=2)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        context.make_contexts(**args)


def test_trials_with_per_trial_poses_equal_per_context_models(contexts):
    """run_trials(object_pose=[N, 7]) on the shared model = each context's own model."""
    grasps = np.stack([scene.centred_grasp(contexts.model, p) for p in contexts.poses])
    noise = sim.sample_noise(jax.random.key(4), NUM_POSES)
    shared = sim.GraspSimulator(contexts.model, "native", num_threads=1)
    batch = shared.run_trials(grasps, noise, object_pose=contexts.poses)
    for i in range(NUM_POSES):
        own = sim.GraspSimulator(contexts.context(i).model, "native", num_threads=1)
        one = own.run_trials(grasps[i : i + 1], sim.TrialNoise(*(a[i : i + 1] for a in noise)))
        assert one.success[0] == batch.success[i]
        np.testing.assert_allclose(one.rise[0], batch.rise[i], atol=1e-9)
    assert batch.success.any()  # centred grasps on a small box mostly hold
