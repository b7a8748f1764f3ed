"""Resting poses settle in threads (sern_jax.grasp.world.context): the same contexts bit for bit."""

import jax
import numpy as np
import pytest

from sern_jax.grasp.world import context, objects


def _arrays(ctx) -> dict[str, np.ndarray]:
    out = {"poses": ctx.poses, "depth": ctx.depth}
    out.update({f"cand.{k}": np.asarray(v) for k, v in ctx.candidates._asdict().items()})
    return out


def test_threaded_contexts_equal_serial_bit_for_bit(monkeypatch):
    spec = objects.sample_population(3, 2)[1]
    config = context.ContextConfig(renderer="native")
    key = jax.random.key(11)
    monkeypatch.setenv("SERN_CONTEXT_THREADS", "1")
    serial = _arrays(context.make_contexts(key, spec, 6, config))
    monkeypatch.setenv("SERN_CONTEXT_THREADS", "3")
    assert context.context_threads() == 3
    threaded = _arrays(context.make_contexts(key, spec, 6, config))
    assert 3 in context._POOLS  # the pool really ran the poses
    assert sorted(serial) == sorted(threaded)
    for k in serial:
        assert serial[k].dtype == threaded[k].dtype and serial[k].shape == threaded[k].shape
        assert serial[k].tobytes() == threaded[k].tobytes(), k
    assert len({tuple(p) for p in serial["poses"]}) == 6  # six different poses


def test_settling_threads_are_an_argument_not_the_calling_threads_name(monkeypatch):
    """make_contexts(threads=...) and resting_poses(threads=...) choose the settling threads:
    1 settles in the calling thread (the pool is never asked), None uses the pool of
    context_threads() whatever the calling thread is named; the contexts are the same bits
    every way."""
    import concurrent.futures

    spec = objects.sample_population(3, 2)[1]
    config = context.ContextConfig(renderer="native")
    model = context.scene_model(spec, config)
    key = jax.random.key(12)
    monkeypatch.setenv("SERN_CONTEXT_THREADS", "2")
    asked = []
    real_pool = context._pool
    monkeypatch.setattr(context, "_pool", lambda n: (asked.append(n), real_pool(n))[1])
    pooled = _arrays(context.make_contexts(key, spec, 4, config, model=model))
    assert asked == [2]
    alone = _arrays(context.make_contexts(key, spec, 4, config, model=model, threads=1))
    poses = context.resting_poses(key, 4, model, config, threads=1)
    assert asked == [2]  # threads=1: in this thread
    with concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="sern-context-x") as ex:
        named = _arrays(ex.submit(context.make_contexts, key, spec, 4, config,
                                  model=model).result())
    assert asked == [2, 2]  # the thread's name changes nothing
    for k in pooled:
        assert pooled[k].tobytes() == alone[k].tobytes() == named[k].tobytes(), k
    assert poses.tobytes() == pooled["poses"].tobytes()
    for bad in (0, -1, True, 1.5):
        with pytest.raises(ValueError, match="threads must be an int >= 1 or None"):
            context.make_contexts(key, spec, 4, config, model=model, threads=bad)
        with pytest.raises(ValueError, match="threads must be an int >= 1 or None"):
            context.resting_poses(key, 4, model, config, threads=bad)


def test_context_threads_follow_the_task_share(monkeypatch):
    monkeypatch.delenv("SERN_CONTEXT_THREADS", raising=False)
    monkeypatch.setenv("SERN_CPU_THREADS", "2")
    assert context.context_threads() == 2


# --- the strong setting on 16 cores: resting poses settled by rollout blocks, their
# uniforms drawn in one call, native trials in a shared pool of workers, the camera model
# kept per scene. Each is checked against the serial computation it replaces, bit for bit.


def _step_by_step_pose(model, seed, max_steps=600):
    """The resting pose as the one-mj_step-per-iteration loop computes it."""
    from sern_jax.grasp.world import scene

    with_loop = scene._settle_in_blocks
    try:
        scene._settle_in_blocks = lambda *a, **k: None  # force the loop
        return scene.resting_pose(model, seed, max_steps=max_steps)
    finally:
        scene._settle_in_blocks = with_loop


def test_rollout_settling_equals_the_step_loop_bit_for_bit(monkeypatch):
    from sern_jax.grasp.world import scene

    specs = [objects.make_object("tless_part_a"), objects.make_object("pipe_tee_steel"),
             objects.sample_population(3, 2)[1]]
    seen = set()
    for spec in specs:
        model = context.scene_model(spec)
        for seed in (3, 104746, 2**31 - 5):
            loop = _step_by_step_pose(model, seed)
            for block in (128, 7):  # 7: many continuations from a block's last state
                monkeypatch.setattr(scene, "SETTLE_BLOCK", block)
                got = scene.resting_pose(model, seed)
                assert got.tobytes() == loop.tobytes(), (spec.name, seed, block)
            seen.add(loop.tobytes())
        for max_steps in (1, 30):  # stopped by max_steps, not by rest
            try:
                want = _step_by_step_pose(model, 5, max_steps)
            except ValueError as e:
                want = str(e)
            try:
                got = scene.resting_pose(model, 5, max_steps=max_steps)
            except ValueError as e:
                got = str(e)
            assert (got == want) if isinstance(want, str) else got.tobytes() == want.tobytes()
    assert len(seen) == 9  # nine different poses: the comparison has teeth


def test_settling_redoes_a_block_that_rollout_stopped_early(monkeypatch):
    """A block whose time stopped advancing (rollout's answer to a MuJoCo warning) is
    refused, and the pose comes from the step loop."""
    from mujoco import rollout as mj_rollout

    from sern_jax.grasp.world import scene

    model = context.scene_model(objects.make_object("tless_part_a"))
    want = _step_by_step_pose(model, 9)
    real = mj_rollout.Rollout.rollout

    def stalls(self, *args, **kwargs):
        state, sensor = real(self, *args, **kwargs)
        state[:, 5:] = state[:, 4:5]  # repeats its state from step 5 on, as after a warning
        return state, sensor

    monkeypatch.setattr(mj_rollout.Rollout, "rollout", stalls)
    data = scene.initial_data(model)
    assert scene._settle_in_blocks(model, data, scene.scene_ids(model), 600) is None
    assert scene.resting_pose(model, 9).tobytes() == want.tobytes()


def test_batched_pose_uniforms_equal_one_seed_at_a_time():
    rng = np.random.default_rng(0)
    seeds = np.concatenate([rng.integers(0, 2**31, 200), [0, 1, 2**31 - 1]])
    batch = np.asarray(context._pose_uniforms(jax.numpy.asarray(seeds, jax.numpy.int32)),
                       np.float64)
    for s, row in zip(seeds, batch):
        one = np.asarray(jax.random.uniform(jax.random.key(int(s)), (5,)), np.float64)
        assert one.tobytes() == row.tobytes(), s
    assert len({r.tobytes() for r in batch}) == len(seeds)


def test_pooled_native_trials_equal_one_thread_bit_for_bit():
    """Trials split into tasks over the shared worker pool (any task size, any thread
    count, objects from several threads at once) give the outcomes of one thread."""
    import concurrent.futures

    from sern_jax.grasp.world import sim

    specs = [objects.make_object("tless_part_a"), objects.make_object("pipe_tee_steel")]
    cases = []
    for i, spec in enumerate(specs):
        ctx = context.make_contexts(jax.random.key(20 + i), spec, 3)
        pi, ki = np.nonzero(np.asarray(ctx.candidates.valid))
        pi, ki = pi[:40], ki[:40]
        grasps = np.asarray(ctx.candidates.grasps, np.float64)[pi, ki]
        noise = sim.sample_noise(jax.random.key(7 + i), len(pi))
        cases.append((ctx.model, grasps, noise, np.asarray(ctx.poses)[pi]))

    def fields(r):
        return [np.asarray(getattr(r, f)).tobytes() for f in ("success", "nan", "rise", "gap")]

    want = [fields(sim.GraspSimulator(m, num_threads=1).run_trials(g, n, object_pose=p))
            for m, g, n, p in cases]
    for threads, chunk in ((3, 256), (2, 5), (4, 1)):
        sims = [sim.GraspSimulator(m, num_threads=threads, chunk=chunk) for m, *_ in cases]
        with concurrent.futures.ThreadPoolExecutor(2) as ex:
            got = list(ex.map(lambda i, sims=sims: fields(sims[i].run_trials(
                cases[i][1], cases[i][2], object_pose=cases[i][3])), range(2)))
        assert got == want, (threads, chunk)
        assert threads in sim._TRIAL_POOLS
    outcomes = [np.frombuffer(w[0], bool) for w in want]
    assert all(0 < o.mean() < 1 for o in outcomes)  # both outcomes occur: teeth


def test_camera_model_is_kept_per_scene_contents():
    from sern_jax.grasp.world import depth

    model = context.scene_model(objects.make_object("tless_part_a"))
    first = context._camera_model(model)
    assert context._camera_model(model) is first
    assert context._camera_model(context.copy_model(model)) is first  # same contents
    for a, b in zip(jax.tree.leaves(first), jax.tree.leaves(depth.camera_model(model))):
        assert np.asarray(a).tobytes() == np.asarray(b).tobytes()
    edited = context.copy_model(model)
    edited.geom_size[edited.ngeom - 1, 0] *= 1.5
    assert context._camera_model(edited) is not first


def test_seed_noise_in_one_call_equals_sample_noise_per_seed():
    """step.seed_noise draws every seed's trial noise in one jitted call: the values of one
    eager ``sim.sample_noise`` per seed key, bit for bit."""
    from sern_jax.grasp.online import step
    from sern_jax.grasp.world import sim

    class _Sim:
        config = sim.TrialConfig()

    for num in (5, 128):
        keys = [jax.random.fold_in(jax.random.key(num), s) for s in range(7)]
        got = step.seed_noise(_Sim(), keys, num)
        for s, key in enumerate(keys):
            want = sim.sample_noise(key, num, _Sim.config)
            for f in range(3):
                assert got[f].dtype == want[f].dtype == np.float64
                assert got[f][s].tobytes() == want[f].tobytes(), (num, s, f)
        assert len({got.friction[s].tobytes() for s in range(7)}) == 7


def test_stream_keys_in_one_call_equal_each_copys_stream():
    """keys.stream_keys derives a stream's [O, S] keys in one jitted call: the keys of one
    eager ``keys.stream`` per (object, seed), for lists of keys and for a key array."""
    from sern_jax.grasp.online import keys as keys_lib

    root = jax.random.key(3)
    keys_os = [[keys_lib.object_key(root, name, s) for s in range(3)] for name in ("a", "bb")]
    arr = jax.numpy.stack([jax.numpy.stack(row) for row in keys_os])
    seen = set()
    for stream, r in ((keys_lib.EXPLORE_CONTEXT, 1), (keys_lib.EVAL_TRIAL, 5),
                      (keys_lib.ACT, 0), (keys_lib.ORACLE_VALUE, 2**20)):
        want = np.asarray(jax.random.key_data(jax.numpy.stack([jax.numpy.stack(
            [keys_lib.stream(k, stream, r) for k in row]) for row in keys_os])))
        for given in (keys_os, arr):
            got = np.asarray(jax.random.key_data(keys_lib.stream_keys(given, stream, r)))
            assert got.tobytes() == want.tobytes(), (stream, r)
        seen.add(want.tobytes())
    assert len(seen) == 4


def test_lower_priority_renices_only_the_calling_thread_on_many_cores(monkeypatch):
    """context.lower_priority: on a host with >= BACKGROUND_NICE_MIN_CORES usable cores it
    sets the calling thread's niceness to BACKGROUND_NICE and leaves the main thread alone;
    on fewer cores (the 2-core machine) it does nothing."""
    import os
    import sys
    import threading

    import pytest

    if not sys.platform.startswith("linux"):
        pytest.skip("per-thread niceness is a Linux feature")
    monkeypatch.delenv("SERN_CPU_THREADS", raising=False)
    main_tid = threading.get_native_id()
    main_before = os.getpriority(os.PRIO_PROCESS, main_tid)

    def niceness_after_call(cores):
        monkeypatch.setattr(os, "sched_getaffinity", lambda _pid: set(range(cores)))
        seen = []

        def body():
            tid = threading.get_native_id()
            before = os.getpriority(os.PRIO_PROCESS, tid)
            context.lower_priority()
            seen.append((before, os.getpriority(os.PRIO_PROCESS, tid)))

        t = threading.Thread(target=body)
        t.start()
        t.join()
        return seen[0]

    before, after = niceness_after_call(context.BACKGROUND_NICE_MIN_CORES - 1)
    assert after == before  # few cores: left off
    before, after = niceness_after_call(context.BACKGROUND_NICE_MIN_CORES)
    assert after == max(before, context.BACKGROUND_NICE)
    assert os.getpriority(os.PRIO_PROCESS, main_tid) == main_before  # main thread untouched


def test_poses_settled_ahead_give_the_same_contexts_bit_for_bit():
    """context.resting_poses is make_contexts' first stage: contexts made from poses settled
    ahead (the online driver's settling threads) equal the ones made in one go; poses of another
    key or shape are refused."""
    spec = objects.sample_population(3, 2)[1]
    config = context.ContextConfig(renderer="native")
    model = context.scene_model(spec, config)
    key = jax.random.key(5)
    whole = _arrays(context.make_contexts(key, spec, 4, config, model=model))
    poses = context.resting_poses(key, 4, model, config)
    staged = _arrays(context.make_contexts(key, spec, 4, config, model=model, poses=poses))
    for k in whole:
        assert whole[k].dtype == staged[k].dtype and whole[k].tobytes() == staged[k].tobytes(), k
    # control: another key's poses give other contexts (the poses are really used)
    other = context.resting_poses(jax.random.key(6), 4, model, config)
    moved = _arrays(context.make_contexts(key, spec, 4, config, model=model, poses=other))
    assert not np.array_equal(moved["poses"], whole["poses"])
    assert not np.array_equal(moved["depth"], whole["depth"])
    for bad in (poses[:3], poses.astype(np.float32)):
        with np.testing.assert_raises_regex(ValueError,
                                            r"poses must be finite float64 with shape \(4, 7\)"):
            context.make_contexts(key, spec, 4, config, model=model, poses=bad)


def test_many_cores_follows_the_usable_cores(monkeypatch):
    import os

    monkeypatch.delenv("SERN_CPU_THREADS", raising=False)
    for cores, want in ((2, False), (context.BACKGROUND_NICE_MIN_CORES, True)):
        monkeypatch.setattr(os, "sched_getaffinity", lambda _pid, n=cores: set(range(n)))
        assert context.many_cores() is want
    monkeypatch.setenv("SERN_CPU_THREADS", "2")  # a 2-CPU Ray task on a many-core node
    assert context.many_cores() is False
