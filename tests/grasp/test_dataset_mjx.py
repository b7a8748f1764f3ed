"""D0 on the MJX backend (dataset.label_shards_mjx): a shard's trials run in one compiled
objects x trials program of one fixed shape, padded slots and padded objects never reach the
saved arrays, and the outcomes agree with the native backend's on the same contexts and noise.

The default run compiles one small program, the one of tests/grasp/test_mjx_one_program.py
(its short trial, its 2-part uniform shape, 2 objects x 2 trials per call; a run's compilation
cache serves it to both files): 3 objects in shards of 2 (the last one short), 2 poses of 8
candidate slots each, so each shard's 2 x 16 trials run as 8 calls of 2 x 2.
"""

import dataclasses

import jax
import numpy as np
import pytest

from sern_jax.grasp.model import dataset
from sern_jax.grasp.world import candidates, context, objects, sim, uniform

SHAPE = uniform.UniformShape(parts=2, vertices=12)
SHORT = sim.TrialConfig(approach_height=0.01, approach_steps=2, settle_steps=1,
                        close_steps=10, lift_steps=3, lift_height=0.005, success_lift=0.002,
                        shake_steps=0, hold_steps=12)
NAMES = ("small_box", "tless_part_a", "small_box")  # object 1: no valid candidate (below)
CONFIG = dataset.DatasetConfig(seed=0, num_objects=3, poses_per_object=2, objects_per_shard=2,
                               backend="mjx")
SLOTS = 8
CONTEXTS = context.ContextConfig(renderer="native",
                                 candidates=candidates.CandidateConfig(num_candidates=SLOTS))
CALL_TRIALS = 4  # 2 objects x 2 trials per compiled call


def _patch(mp):
    mp.setattr(dataset.context_lib, "make_contexts",
               _knock_out(dataset.context_lib.make_contexts))
    mp.setattr(dataset, "MJX_CALL_TRIALS", CALL_TRIALS)


def _knock_out(real):
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
def labelled():
    """(MJX shards, per-shard stats, native LabelledContexts per object, specs)."""
    specs = [objects.make_object(n) for n in NAMES]
    stats = []
    with pytest.MonkeyPatch.context() as mp:
        _patch(mp)
        shards = list(dataset.label_shards_mjx(CONFIG, [0, 1], [specs[:2], specs[2:]],
                                               trial=SHORT, shape=SHAPE, threads=2,
                                               context_config=CONTEXTS, stats=stats))
        root = jax.random.key(CONFIG.seed)
        native = [dataset.label_contexts(jax.random.fold_in(root, i), spec,
                                         CONFIG.poses_per_object, context_config=CONTEXTS,
                                         trial=SHORT)
                  for i, spec in enumerate(specs)]
    return shards, stats, native, specs


def test_every_shard_runs_the_one_compiled_program(labelled):
    shards, stats, _, _ = labelled
    assert [s for s, _ in shards] == [0, 1]
    assert [[i for i, _ in parts] for _, parts in shards] == [[0, 1], [2]]  # padding dropped
    assert [st["compiles"] for st in stats] == [1, 1]
    # (0 compiled in the first shard where this process already ran the same program)
    assert [st["compiled"] for st in stats] in ([1, 0], [0, 0])
    assert [st["objects"] for st in stats] == [2, 1]
    for st in stats:
        assert st["contexts_s"] > 0 and st["trials_s"] > 0 and st["waited_s"] >= 0


def test_padded_and_invalid_slots_never_reach_the_labels(labelled):
    shards, stats, _, _ = labelled
    by_index = {i: lc for _, parts in shards for i, lc in parts}
    for i, lc in by_index.items():
        assert lc.label.shape == (CONFIG.poses_per_object, SLOTS)
        np.testing.assert_array_equal(lc.label == -1, ~lc.valid)
        np.testing.assert_array_equal(lc.label[lc.valid], lc.successes[lc.valid])
        assert (lc.successes[~lc.valid] == 0).all() and (lc.nan_count[~lc.valid] == 0).all()
    assert not by_index[1].valid.any()  # an object without a valid candidate: all -1
    assert [st["trials"] for st in stats] == [int(by_index[0].valid.sum()),
                                              int(by_index[2].valid.sum())]


def test_contexts_equal_and_outcomes_agree_with_native(labelled):
    """The same contexts bit for bit (the same keys); on the same noise, MJX on the uniform
    scenes and native MuJoCo on the exact ones agree on most outcomes."""
    shards, _, native, _ = labelled
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


def test_an_objects_outcomes_do_not_depend_on_the_objects_padding_it(labelled):
    """Object 2 padded with copies of itself (its short shard) and next to object 0: the same
    outcomes (one compiled program; vmapped trials are independent)."""
    shards, _, _, specs = labelled
    alone = dict(shards[1][1])[2]
    root = jax.random.key(CONFIG.seed)
    with pytest.MonkeyPatch.context() as mp:
        _patch(mp)
        prepared = [dataset._prepare_object(root, i, specs[i], CONFIG, SHORT, SHAPE, 1,
                                            CONTEXTS) for i in (2, 0)]
        (paired, _), compiles = dataset._run_mjx_shard(prepared, CONFIG, SHORT, SHAPE)
    assert compiles == (1, 1)
    np.testing.assert_array_equal(paired.label, alone.label)
    np.testing.assert_array_equal(paired.nan_count, alone.nan_count)


def test_the_shard_call_shape_is_fixed_for_the_dataset():
    assert dataset._shard_call_shape(CONFIG, 64) == (2, 128, 128)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(dataset, "MJX_CALL_TRIALS", CALL_TRIALS)
        assert dataset._shard_call_shape(CONFIG, SLOTS) == (2, 16, 2)
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
