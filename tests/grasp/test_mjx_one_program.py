"""One MJX trial program for every object (sern_jax.grasp.world.uniform).

Every MJX check here runs through one compiled program: two different objects on a small
uniform structure (2 parts of at most 12 vertices) and a 28-step trial, in which the jaws
close on the object, squeeze it at the force limit and lift it by 5 mm.
"""

import copy
import dataclasses

import jax
import numpy as np
import pytest

from sern_jax.grasp.model import dataset
from sern_jax.grasp.world import candidates, context, objects, scene, sim, uniform

SHAPE = uniform.UniformShape(parts=2, vertices=12)
SHORT = sim.TrialConfig(approach_height=0.01, approach_steps=2, settle_steps=1,
                        close_steps=10, lift_steps=3, lift_height=0.005, success_lift=0.002,
                        shake_steps=0, hold_steps=12)
NAMES = ("small_box", "tless_part_a")  # a box and two meshes (24 and 8 vertices)
TRIALS = 2


@pytest.fixture(scope="module")
def exact():
    return [scene.build_scene(objects.make_object(n), seed=0) for n in NAMES]


@pytest.fixture(scope="module")
def trials(exact):
    grasps = np.stack([np.stack([scene.centred_grasp(m), scene.centred_grasp(m)
                                 + [0.004, -0.003, 0.0, 0.0]]) for m in exact])
    noise = [sim.sample_noise(jax.random.key(i), TRIALS, SHORT) for i in range(len(exact))]
    return grasps, sim.TrialNoise(*(np.stack([n[k] for n in noise]) for k in range(3)))


@pytest.fixture(scope="module")
def batch(exact):
    return sim.UniformBatch(exact, SHORT, SHAPE, trials=TRIALS)


@pytest.fixture(scope="module")
def batch_results(batch, trials):
    return batch.run_trials(*trials)


def _rows(noise, idx):
    return sim.TrialNoise(*(a[idx] for a in noise))


def test_one_compiled_program_serves_different_objects(exact, batch, batch_results, trials):
    grasps, noise = trials
    swapped = sim.UniformBatch(exact[::-1], SHORT, SHAPE, trials=TRIALS)
    again = swapped.run_trials(grasps[::-1], _rows(noise, slice(None, None, -1)))
    assert swapped.program is batch.program
    assert batch.compiles == 1 and swapped.compiles == 1
    for a, b in zip(batch_results, again[::-1]):
        np.testing.assert_array_equal(a.success, b.success)
        np.testing.assert_allclose(a.rise, b.rise, atol=1e-6)


def test_batched_over_objects_equals_each_object_alone(exact, batch, batch_results, trials):
    """Object i's trials in a batch with another object equal its trials in a batch of
    itself twice (the same compiled program, the same uniform model)."""
    grasps, noise = trials
    for i, model in enumerate(exact):
        alone = sim.UniformBatch([model, model], SHORT, SHAPE, trials=TRIALS)
        out = alone.run_trials(grasps[[i, i]], _rows(noise, [i, i]))
        for res in out:
            np.testing.assert_array_equal(res.success, batch_results[i].success)
            np.testing.assert_allclose(res.rise, batch_results[i].rise, atol=1e-6)
            np.testing.assert_allclose(res.gap, batch_results[i].gap, atol=1e-6)
    assert batch.compiles == 1


def test_native_and_mjx_agree_on_the_uniform_model(batch, batch_results, trials):
    """Short paired trials: the jaws close on the object and squeeze it (the gap is its
    width, not the closed 0); native and MJX end within 3 mm of each other in gap and in
    object height (their contact models differ: MJX's separating-axis manifold against
    MuJoCo's convex collision, soft contacts penetrating by different depths)."""
    grasps, noise = trials
    for i, model in enumerate(batch.uniform):
        native = sim.GraspSimulator(model, "native", SHORT, num_threads=1).run_trials(
            grasps[i], _rows(noise, i))
        mjx = batch_results[i]
        assert not native.nan.any() and not mjx.nan.any()
        assert (native.gap > 0.01).all(), native.gap  # closed on the object
        np.testing.assert_allclose(mjx.gap, native.gap, atol=3e-3)
        np.testing.assert_allclose(mjx.rise, native.rise, atol=3e-3)
        np.testing.assert_array_equal(mjx.success, native.success)


@pytest.mark.slow
def test_per_object_simulator_equals_the_batch(batch, batch_results, trials, exact):
    """GraspSimulator's MJX backend on the uniform model (its own program, over trials
    only) gives each object's batched results."""
    grasps, noise = trials
    for i, model in enumerate(exact):
        one = sim.GraspSimulator(model, "mjx", SHORT, mjx_shape=SHAPE).run_trials(
            grasps[i], _rows(noise, i))
        np.testing.assert_array_equal(one.success, batch_results[i].success)
        np.testing.assert_allclose(one.rise, batch_results[i].rise, atol=1e-5)
        np.testing.assert_allclose(one.gap, batch_results[i].gap, atol=1e-5)


@pytest.mark.slow
def test_full_trials_agree_native_and_mjx_on_uniform_models():
    """The default trial, 8 paired trials on each of two objects: native and MJX agree on
    at least 14 of 16 outcomes (the documented pooled agreement is about 95 %)."""
    models = [scene.build_scene(objects.make_object(n), seed=0) for n in NAMES]
    b = sim.UniformBatch(models, sim.TrialConfig(), trials=8)
    rng = np.random.default_rng(0)
    grasps = np.stack([scene.centred_grasp(m) + np.c_[rng.uniform(-0.01, 0.01, (8, 3)),
                                                       rng.uniform(-0.5, 0.5, 8)]
                       for m in models])
    noise = [sim.sample_noise(jax.random.key(i), 8) for i in range(2)]
    stacked = sim.TrialNoise(*(np.stack([n[k] for n in noise]) for k in range(3)))
    mjx = b.run_trials(grasps, stacked)
    same = 0
    for i, model in enumerate(b.uniform):
        native = sim.GraspSimulator(model, "native", num_threads=1).run_trials(
            grasps[i], noise[i])
        same += int((native.success == mjx[i].success).sum())
    assert same >= 14, same
    assert b.compiles == 1


# ----------------------------------------------------------------------------- no MJX runs


@pytest.mark.parametrize("name", ["sphere", "capsule", "handle", "pipe_tee", "handle_jug",
                                  "tless_part_a", "cylinder", "bracket"])
def test_resampling_keeps_each_hull_within_the_stated_distance(name):
    model = scene.build_scene(objects.make_object(name), seed=0)
    shape = uniform.UniformShape()
    for d, (kind, size, _pos, _quat, pts) in zip(uniform.resample_distances(model, shape),
                                                 uniform._object_parts(model)):
        assert d["relative"] <= uniform.RESAMPLE_TOLERANCE, (name, d)
        verts = uniform.part_vertices(pts, shape.vertices)
        assert len(verts) <= shape.vertices
        if kind in ("box", "mesh") and len(uniform._hull_vertices(pts)) <= shape.vertices:
            assert d["distance_m"] == 0.0, (name, d)  # exact hulls stay exact
        # the resampled hull never reaches outside the exact part
        exact_pts = uniform._surface_samples(kind, size, pts if kind == "mesh" else None)
        assert uniform.hull_distance(verts, exact_pts if kind in ("box", "mesh")
                                     else exact_pts * 1.001) < 1e-9


def test_hull_distance_of_a_shrunk_cube():
    cube = objects.geom_points("box", (1.0, 1.0, 1.0))
    assert uniform.hull_distance(cube, cube) == 0.0
    assert uniform.hull_distance(cube, 0.5 * cube) == pytest.approx(np.sqrt(3) * 0.5)
    assert uniform.hull_distance(cube * [1, 1, 0.5], 0.5 * cube) == pytest.approx(
        np.sqrt(0.5))


def test_uniform_models_share_one_structure_and_stack():
    models = [scene.build_scene(objects.make_object(n), seed=0)
              for n in ("small_box", "sphere", "handle", "tless_part_b")]
    mxs = [uniform.put_uniform(uniform.uniform_scene(m)) for m in models]
    trees = {jax.tree_util.tree_structure(mx) for mx in mxs}
    assert len(trees) == 1
    stacked = uniform.stack_models(mxs)
    assert stacked.body_mass.shape == (4, models[0].nbody)
    # other array values per object: vertices, inertia, start pose
    assert not np.allclose(stacked.body_inertia[0], stacked.body_inertia[1])
    verts = stacked._impl.mesh_convex[0].vert
    assert not np.allclose(verts[0], verts[2])
    other = uniform.put_uniform(uniform.uniform_scene(models[0], SHAPE), SHAPE)
    with pytest.raises(ValueError, match="static structure|shapes"):
        uniform.stack_models([mxs[0], other])


def test_uniform_scene_keeps_inertia_edits_and_the_general_mass_pattern(exact):
    box, tless = exact
    u = uniform.uniform_scene(tless)
    u_ids = scene.scene_ids(u)
    assert len(u_ids.object_geoms) == uniform.UniformShape().parts == u.nmesh
    for field in ("body_mass", "body_inertia", "body_ipos", "qpos0", "dof_invweight0"):
        np.testing.assert_array_equal(getattr(u, field)[..., :],
                                      getattr(tless, field)[..., :], err_msg=field)
    edited = copy.copy(box)
    edited.actuator_gainprm[2, 0] = 123.0
    assert uniform.uniform_scene(edited).actuator_gainprm[2, 0] == 123.0
    # tless_part_a's inertia is off its body frame: MuJoCo's pattern is the general one
    pattern = uniform.general_mass_pattern(u.dof_parentid)
    np.testing.assert_array_equal(pattern["M_rownnz"], u.M_rownnz)
    np.testing.assert_array_equal(pattern["M_colind"], u.M_colind)
    assert pattern["nC"] == u.nC


def test_objects_with_too_many_parts_are_refused(exact):
    with pytest.raises(ValueError, match="parts"):
        uniform.uniform_scene(exact[1], uniform.UniformShape(parts=1))
    assert uniform.shape_for(exact[0]).parts == 4
    with pytest.raises(ValueError, match="vertices"):
        uniform.UniformShape(vertices=4)


def test_bench_objects_flag_refuses_unknown_or_repeated_objects():
    from sern_jax.commands import bench_grasp

    with pytest.raises(ValueError, match="--objects: unknown object 'no_such_object'"):
        bench_grasp.main(["grasp", "--objects", "small_box,no_such_object"])
    with pytest.raises(ValueError, match="--objects must be distinct"):
        bench_grasp.main(["grasp", "--objects", "small_box,small_box"])


# ----------------------------------------------------------------- D0 on the one program
# D0 on the MJX backend (dataset.label_shards_mjx): a shard's trials run in one compiled
# objects x trials program of one fixed shape, padded slots and padded objects never reach the
# saved arrays, and the outcomes agree with the native backend's on the same contexts and
# noise. The calls are 2 objects x 2 trials on SHAPE and SHORT, the program of the checks
# above, so this file compiles it once: 3 objects in shards of 2 (the last one short), 2 poses
# of 8 candidate slots each, each shard's 2 x 16 trials as 8 calls of 2 x 2.

D0_NAMES = ("small_box", "tless_part_a", "small_box")  # object 1: no valid candidate (below)
D0_CONFIG = dataset.DatasetConfig(seed=0, num_objects=3, poses_per_object=2,
                                  objects_per_shard=2, backend="mjx")
D0_SLOTS = 8
D0_CONTEXTS = context.ContextConfig(
    renderer="native", candidates=candidates.CandidateConfig(num_candidates=D0_SLOTS))
D0_CALL_TRIALS = 4  # 2 objects x 2 trials per compiled call


def _d0_patch(mp):
    mp.setattr(dataset.context_lib, "make_contexts",
               _d0_knock_out(dataset.context_lib.make_contexts))
    mp.setattr(dataset, "MJX_CALL_TRIALS", D0_CALL_TRIALS)


def _d0_knock_out(real):
    """Slot 3j of every context invalid; every slot of tless_part_a invalid."""

    def make_contexts(key, spec, *args, **kwargs):
        ctx = real(key, spec, *args, **kwargs)
        valid = np.asarray(ctx.candidates.valid).copy()
        valid[:, ::3] = False
        if spec.name == "tless_part_a":
            valid[:] = False
        return ctx._replace(candidates=ctx.candidates._replace(valid=valid))

    return make_contexts


@pytest.fixture(scope="module")
def d0_labelled():
    """(MJX shards, per-shard stats, native LabelledContexts per object, specs)."""
    specs = [objects.make_object(n) for n in D0_NAMES]
    stats = []
    with pytest.MonkeyPatch.context() as mp:
        _d0_patch(mp)
        shards = list(dataset.label_shards_mjx(D0_CONFIG, [0, 1], [specs[:2], specs[2:]],
                                               trial=SHORT, shape=SHAPE, threads=2,
                                               context_config=D0_CONTEXTS, stats=stats))
        root = jax.random.key(D0_CONFIG.seed)
        native = [dataset.label_contexts(jax.random.fold_in(root, i), spec,
                                         D0_CONFIG.poses_per_object,
                                         context_config=D0_CONTEXTS, trial=SHORT)
                  for i, spec in enumerate(specs)]
    return shards, stats, native, specs


def test_every_shard_runs_the_one_compiled_program(d0_labelled):
    shards, stats, _, _ = d0_labelled
    assert [s for s, _ in shards] == [0, 1]
    assert [[i for i, _ in parts] for _, parts in shards] == [[0, 1], [2]]  # padding dropped
    assert [st["compiles"] for st in stats] == [1, 1]
    # (0 compiled in the first shard where this process already ran the same program)
    assert [st["compiled"] for st in stats] in ([1, 0], [0, 0])
    assert [st["objects"] for st in stats] == [2, 1]
    for st in stats:
        assert st["contexts_s"] > 0 and st["trials_s"] > 0 and st["waited_s"] >= 0


def test_padded_and_invalid_slots_never_reach_the_labels(d0_labelled):
    shards, stats, _, _ = d0_labelled
    by_index = {i: lc for _, parts in shards for i, lc in parts}
    for i, lc in by_index.items():
        assert lc.label.shape == (D0_CONFIG.poses_per_object, D0_SLOTS)
        np.testing.assert_array_equal(lc.label == -1, ~lc.valid)
        np.testing.assert_array_equal(lc.label[lc.valid], lc.successes[lc.valid])
        assert (lc.successes[~lc.valid] == 0).all() and (lc.nan_count[~lc.valid] == 0).all()
    assert not by_index[1].valid.any()  # an object without a valid candidate: all -1
    assert [st["trials"] for st in stats] == [int(by_index[0].valid.sum()),
                                              int(by_index[2].valid.sum())]


def test_contexts_equal_and_outcomes_agree_with_native(d0_labelled):
    """The same contexts bit for bit (the same keys); on the same noise, MJX on the uniform
    scenes and native MuJoCo on the exact ones agree on most outcomes."""
    shards, _, native, _ = d0_labelled
    by_index = {i: lc for _, parts in shards for i, lc in parts}
    same = total = 0
    for i, ref in enumerate(native):
        lc = by_index[i]
        for field in ("pose", "depth", "grasps", "valid", "center_px", "angle_px"):
            np.testing.assert_array_equal(getattr(lc, field), getattr(ref, field), err_msg=field)
        np.testing.assert_array_equal(lc.label == -1, ref.label == -1)
        same += int((lc.label[lc.valid] == ref.label[ref.valid]).sum())
        total += int(lc.valid.sum())
    assert total > 0
    assert same >= 0.8 * total, (same, total)


def test_an_objects_outcomes_do_not_depend_on_the_objects_padding_it(d0_labelled):
    """Object 2 padded with copies of itself (its short shard) and next to object 0: the same
    outcomes (one compiled program; vmapped trials are independent)."""
    shards, _, _, specs = d0_labelled
    alone = dict(shards[1][1])[2]
    root = jax.random.key(D0_CONFIG.seed)
    with pytest.MonkeyPatch.context() as mp:
        _d0_patch(mp)
        prepared = [dataset._prepare_object(root, i, specs[i], D0_CONFIG, SHORT, SHAPE, 1,
                                            D0_CONTEXTS) for i in (2, 0)]
        (paired, _), compiles = dataset._run_mjx_shard(prepared, D0_CONFIG, SHORT, SHAPE)
    assert compiles == (1, 1)
    np.testing.assert_array_equal(paired.label, alone.label)
    np.testing.assert_array_equal(paired.nan_count, alone.nan_count)


def test_the_shard_call_shape_is_fixed_for_the_dataset():
    assert dataset._shard_call_shape(D0_CONFIG, 64) == (2, 128, 128)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(dataset, "MJX_CALL_TRIALS", D0_CALL_TRIALS)
        assert dataset._shard_call_shape(D0_CONFIG, D0_SLOTS) == (2, 16, 2)
    default = dataset.DatasetConfig(backend="mjx")
    assert dataset._shard_call_shape(default, 64) == (10, 1024, 1024)
    many = dataclasses.replace(default, trials_per_grasp=10)  # 102,400 trials: two calls
    assert dataset._shard_call_shape(many, 64) == (10, 10240, 5120)


@pytest.mark.slow
def test_generate_on_mjx_resumes_to_identical_shards(tmp_path):
    """The default trial and shape end to end: generate, drop a shard, resume."""
    config = dataset.DatasetConfig(seed=0, num_objects=3, poses_per_object=1,
                                   objects_per_shard=2, backend="mjx")
    stats = []
    dataset.generate(config, tmp_path / "a", progress=False, log=lambda *_: None, stats=stats)
    assert [st["compiled"] for st in stats] in ([1, 0], [0, 0])
    last = dataset.shard_paths(tmp_path / "a", config)[1]
    with np.load(last) as f:
        kept = {k: f[k] for k in f.files}
    last.unlink()
    dataset.generate(config, tmp_path / "a", progress=False, log=lambda *_: None)
    with np.load(last) as f:
        assert sorted(f.files) == sorted(kept)
        for k in kept:
            np.testing.assert_array_equal(f[k], kept[k], err_msg=k)
    _, data = dataset.load(tmp_path / "a")
    np.testing.assert_array_equal(data["label"] == -1, ~data["valid"])
