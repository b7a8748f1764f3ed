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


def test_context_threads_follow_the_task_share(monkeypatch):
    monkeypatch.delenv("SERN_CONTEXT_THREADS", raising=False)
    monkeypatch.setenv("SERN_CPU_THREADS", "2")
    assert context.context_threads() == 2


# --- issue 20 (strong setting on 16 cores): resting poses settled by rollout blocks, their
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
    """The runner draws every seed's trial noise in one jitted call: the values of one
    eager ``sim.sample_noise`` per seed key, bit for bit."""
    from sern_jax.grasp.online import runner
    from sern_jax.grasp.world import sim

    class _Sim:
        config = sim.TrialConfig()

    for num in (5, 128):
        keys = [jax.random.fold_in(jax.random.key(num), s) for s in range(7)]
        got = runner._seed_noise(_Sim(), keys, num)
        for s, key in enumerate(keys):
            want = sim.sample_noise(key, num, _Sim.config)
            for f in range(3):
                assert got[f].dtype == want[f].dtype == np.float64
                assert got[f][s].tobytes() == want[f].tobytes(), (num, s, f)
        assert len({got.friction[s].tobytes() for s in range(7)}) == 7


def test_readme_quotes_the_parallel_strong_run():
    """The README's row and paragraph for the one-command strong run after these changes
    (issue 20, still over 4 minutes), recomputed from the committed record."""
    import json
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    folder = root / "experiments" / "results" / "strong" / "single_command_h100_dbe31c2"
    readme = " ".join((root / "README.md").read_text().split())
    timing = json.loads((folder / "timing.json").read_text())
    run = json.loads((folder / "strong.json").read_text())
    mid = json.loads((folder / "intermediate_e9ccbf7_strong.json").read_text())
    old = json.loads((folder.parent / "single_command_h100" / "strong.json").read_text())
    context_txt = (folder / "context.txt").read_text()
    assert timing["exit_code"] == 0 and "rc 0" in context_txt
    assert f"wall {timing['wall_seconds_command']}" in context_txt
    assert run["seeds"] == 20 and run["rounds_done"] == 5 and " strong --seeds 20" in run["command"]
    assert run["machine"]["cpu_count"] == 16 and run["machine"]["jax_backend"] == "gpu"
    wall, t, n = timing["wall_seconds_command"], run["timings"], run["trial_counts"]
    assert wall > 240 and "**still over the 4-minute goal**" in readme
    assert (f"**{wall:.0f} s** for the command ({wall:.1f} s; {run['seconds']:.0f} s in the run: "
            f"trials {t['trials']:.0f} s, evaluation {t['evaluate']:.0f} s, contexts "
            f"{t['contexts']:.0f} s") in readme
    assert (f"choosing {t['choose']:.0f} s, updates {t['update']:.0f} s; round 0 saved at "
            "91 s, round 1 at 153 s") in readme
    log = (folder / "log.txt").read_text()
    assert "round 0/5 saved at 91 s; contexts 54 s" in log and "round 1/5 saved at 153 s" in log
    assert "(54 s waited before round 0's evaluation" in readme
    assert (f"{n['simulated']:,} trials simulated for {n['requested']:,} policy grasps") in readme
    user, sys_ = timing["cpu_seconds_user_sys"]
    assert f"User time (seconds): {user:.2f}" in (folder / "time_v.txt").read_text()
    assert f"{user + sys_:,.0f} CPU-seconds, {(user + sys_) / wall:.1f} of 16 cores" in readme
    # per-round seconds quoted: rounds 2-4 and round 5 from the log's 'saved at' lines
    import re

    saved = [int(x) for x in re.findall(r"round \d/5 saved at (\d+) s", log)]
    took = np.diff(saved)
    assert f"rounds 2–4 then take {min(took[1:4])}–{max(took[1:4])} s" in readme
    assert f"round 5 (nothing left to prefetch) {took[4]} s" in readme
    diag = (folder.parent / "diag_g" / "diag_h100.txt").read_text()
    per_trial = float(re.search(r"1 thread: ([\d.]+) ms/trial", diag).group(1))
    assert f"{n['simulated']:,} trials × {per_trial:.1f} ms on one core" in readme
    assert f"~{n['simulated'] * per_trial / 1e3 / 16:.0f} s at a perfect 16 cores" in readme
    # before -> after, against the committed one-command run
    assert (f"trials {old['timings']['trials']:.0f} s → {t['trials']:.0f} s and evaluation "
            f"{old['timings']['evaluate']:.0f} s → {t['evaluate']:.0f} s") in readme

    def differing(a, b, field):
        x, y = np.asarray(a[field]), np.asarray(b[field])
        return [int((x[r] != y[r]).sum()) for r in range(x.shape[0])]

    for field in ("lowvar_eval", "paper_eval", "explore_success"):
        assert differing(run, old, field)[0] == 0, field  # round 0: every cell equal
        assert timing["vs_committed_one_command_run_cells_differing_per_round"][field] == \
            differing(run, old, field)
        assert timing["intermediate_run"]["cells_differing_from_the_final_run_per_round"][
            field] == differing(mid, run, field)
    cells = np.asarray(run["paper_eval"])[5].size
    assert differing(mid, run, "paper_eval")[5] == 3 and sum(differing(mid, run, "paper_eval")) == 3
    assert sum(differing(mid, run, "lowvar_eval") + differing(mid, run, "explore_success")) == 0
    assert f"differ in 3 of {cells:,} round-5 cells of the 5-grasp figure" in readme


def test_stream_keys_in_one_call_equal_each_copys_stream():
    """The runner derives a stream's [O, S] keys in one jitted call: the keys of one eager
    ``_stream`` per (object, seed), for lists of keys and for a key array."""
    from sern_jax.grasp.online import runner

    root = jax.random.key(3)
    keys_os = [[runner.object_key(root, name, s) for s in range(3)] for name in ("a", "bb")]
    arr = jax.numpy.stack([jax.numpy.stack(row) for row in keys_os])
    seen = set()
    for stream, r in ((runner.EXPLORE_CONTEXT, 1), (runner.EVAL_TRIAL, 5), (runner.ACT, 0),
                      (runner.ORACLE_VALUE, 2**20)):
        want = np.asarray(jax.random.key_data(jax.numpy.stack([jax.numpy.stack(
            [runner._stream(k, stream, r) for k in row]) for row in keys_os])))
        for given in (keys_os, arr):
            got = np.asarray(jax.random.key_data(runner._stream_keys(given, stream, r)))
            assert got.tobytes() == want.tobytes(), (stream, r)
        seen.add(want.tobytes())
    assert len(seen) == 4


def test_readme_quotes_the_two_round_check_after_f66087f():
    """The README's 2-round check after f66087f: round 1's saved-at time, its stages adding up
    to its length, and its figures equal to the 5-round run's, from the committed files."""
    import json
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    folder = root / "experiments" / "results" / "strong" / "single_command_h100_dbe31c2"
    readme = " ".join((root / "README.md").read_text().split())
    log = (folder / "rounds2_f66087f_log.txt").read_text()
    full_log = (folder / "log.txt").read_text()
    r2 = json.loads((folder / "rounds2_f66087f_strong.json").read_text())
    full = json.loads((folder / "strong.json").read_text())
    assert " --rounds 2" in r2["command"] and r2["rounds_done"] == 2

    def rounds(text):
        return [(int(a), {k: int(v) for k, v in re.findall(r"(\w+) (\d+) s", b)})
                for a, b in re.findall(r"round \d/\d saved at (\d+) s; (.*)", text)]

    (t0, s0), (t1, s1), _ = rounds(log)
    stages = sum(s1.values()) - sum(s0.values())
    assert t1 - t0 == stages == 52 and "its 52 s with nothing lost outside them" in readme
    before = rounds(full_log)[1][0]
    assert f"saved round 1 at {t1} s instead of {before} s" in readme
    for field in ("lowvar_eval", "paper_eval", "explore_success"):
        assert np.array_equal(np.asarray(r2[field]), np.asarray(full[field])[:3]), field
    assert "rounds 0–2 equal the 5-round run's in every cell" in readme
    # the per-round main-thread fold-ins the README counts at dbe31c2: 4 key streams of the
    # learners + 3 trial-noise streams per round, 2 fold-ins per (object, seed), and 2 kinds
    # of contexts queued per round
    copies = len(full["objects"]) * full["seeds"]
    assert (4 + 3 + 2) * 2 * copies == 2160 and 2 * 2 * copies == 480
    assert "2,160 per round, 480 of them queueing the next contexts" in readme


def test_readme_quotes_the_lead_strong_run_at_0787e20():
    """The lead's one-command strong run at 0787e20 (still over 4 minutes): the README row's
    figures recomputed from the committed record."""
    import json
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    folder = root / "experiments" / "results" / "strong" / "single_command_h100_0787e20"
    readme = " ".join((root / "README.md").read_text().split())
    run = json.loads((folder / "strong.json").read_text())
    t, n = run["timings"], run["trial_counts"]
    wall = float(re.search(r"wall ([\d.]+) rc 0", (folder / "context.txt").read_text()).group(1))
    assert run["seeds"] == 20 and run["rounds_done"] == 5 and wall > 240
    assert run["machine"]["jax_backend"] == "gpu" and run["machine"]["cpu_count"] == 16
    log = (folder / "log.txt").read_text()
    round0 = int(re.search(r"round 0/5 saved at (\d+) s", log).group(1))
    quoted = (f"**{wall:.0f} s** for the command ({run['seconds']:.0f} s in the run: trials "
              f"{t['trials']:.0f} s, evaluation {t['evaluate']:.0f} s, contexts "
              f"{t['contexts']:.0f} s, choosing {t['choose']:.0f} s, updates {t['update']:.0f} s; "
              f"round 0 saved at {round0} s; {n['simulated']:,} trials simulated): **still over "
              "the 4-minute goal**")
    assert quoted in readme, quoted
    assert (f"the lead ran it at 0787e20 (the row above): {wall:.0f} s" in readme
            and f"trials ({t['trials']:.0f} s) and evaluation ({t['evaluate']:.0f} s)" in readme
            and f"round 0 saved at {round0} s)" in readme)
    old = json.loads((folder.parent / "single_command_h100" / "strong.json").read_text())
    for field in ("lowvar_eval", "paper_eval", "explore_success"):
        assert np.array_equal(np.asarray(run[field])[0], np.asarray(old[field])[0]), field


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
    ahead (the runner's settling threads) equal the ones made in one go; poses of another
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


@pytest.mark.parametrize("commit", ["cbeac03", "6fcb56d"])
def test_readme_quotes_the_lead_strong_runs_under_4_minutes(commit):
    """The lead's one-command strong runs at cbeac03 and 6fcb56d (under 4 minutes): the README
    rows' figures recomputed from the committed records, their round 0 equal to the first
    one-command run's in every cell, and the cells that differ later as the README says."""
    import json
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    folder = root / "experiments" / "results" / "strong" / f"single_command_h100_{commit}"
    readme = " ".join((root / "README.md").read_text().split())
    run = json.loads((folder / "strong.json").read_text())
    n = run["trial_counts"]
    wall = float(re.search(r"wall ([\d.]+) rc 0", (folder / "context.txt").read_text()).group(1))
    assert run["seeds"] == 20 and run["rounds_done"] == 5 and wall <= 240
    assert run["machine"]["jax_backend"] == "gpu" and run["machine"]["cpu_count"] == 16
    log = (folder / "log.txt").read_text()
    saved = {int(r): int(t) for r, t in re.findall(r"round (\d)/5 saved at (\d+) s", log)}
    time_v = (folder / "time_v.txt").read_text()
    cpu = sum(float(re.search(rf"{k} time \(seconds\): ([\d.]+)", time_v).group(1))
              for k in ("User", "System"))
    quoted = (f"**{wall:.0f} s** for the command ({run['seconds']:.0f} s in the run; round 0 "
              f"saved at {saved[0]} s, round 5 at {saved[5]} s; {n['simulated']:,} trials "
              f"simulated; {cpu:,.0f} CPU-seconds, {cpu / wall:.1f} of 16 cores on average): "
              "**under the 4-minute goal**")
    assert quoted in readme, quoted
    headline = "**The strong setting now takes 214 s on the H100 machine (6fcb56d; 216 s at cbeac03)"
    assert headline in readme and f"{wall:.0f} s" in headline
    old = json.loads((folder.parent / "single_command_h100" / "strong.json").read_text())
    differ = {}
    for field in ("lowvar_eval", "paper_eval", "explore_success"):
        new_f = np.asarray(run[field], float)
        old_f = np.asarray(old[field], float)
        assert np.array_equal(new_f[0], old_f[0], equal_nan=True), field
        differ[field] = int((~((new_f == old_f) | (np.isnan(new_f) & np.isnan(old_f)))).sum())
    assert 0 < sum(differ.values())  # control: the comparison sees differences
    assert (f"Its later rounds differ in {differ['lowvar_eval']} low-variance, "
            f"{differ['paper_eval']} five-grasp and {differ['explore_success']} exploration "
            "cells of 2,160") in readme, differ
