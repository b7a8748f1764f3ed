"""Where trial and context time goes on a many-core host (not a result file; prints timings).

Times resting poses (serial and in 4, 8, 16 threads), contexts made as the grasp runner made
them (120 (object, seed) batches of 20 in 16 threads), ``sim.sample_noise``, and native trials
of the six hard-set objects on one core and in a worker pool, side by side with the trials of
commit 2eed060 (its ``sern_jax/grasp/sim.py``, read with ``git show``).

Written against the grasp runner of commit b3fe045 (``runner._contexts``, now
``driver.contexts``). Run from the
repository root:
    python3 experiments/diagnostics/trial_context_timing.py
Record: experiments/results/strong/trial_context_timing/diag_h100.txt.
"""
import concurrent.futures as cf, os, sys, time, threading
import numpy as np, jax
# the trials before (sern_jax/grasp/sim.py at 2eed060), read from git rather than kept as a copy
import importlib.util, subprocess, tempfile
_src = subprocess.run(["git", "show", "2eed060:sern_jax/grasp/sim.py"], check=True,
                      capture_output=True, text=True).stdout
_path = os.path.join(tempfile.mkdtemp(), "sim_old.py")
open(_path, "w").write(_src)
_spec = importlib.util.spec_from_file_location("sim_old", _path)
sim_old = importlib.util.module_from_spec(_spec); _spec.loader.exec_module(sim_old)
from sern_jax.grasp.world import context as ctx, sim, objects as ol, scene
from sern_jax.grasp.online import driver
T = time.perf_counter
print("cores", os.cpu_count(), "backend", jax.default_backend(), flush=True)
names = ol.HARD_SET
specs = [ol.make_object(n) for n in names]
models = [ctx.scene_model(s) for s in specs]
# --- resting poses
m = models[1]
t = T(); [scene.resting_pose(m, s) for s in range(32)]; d = T() - t
print(f"resting_pose serial: {1e3*d/32:.2f} ms/pose", flush=True)
for th in (4, 8, 16):
    with cf.ThreadPoolExecutor(th) as ex:
        t = T(); list(ex.map(lambda s: scene.resting_pose(models[s % 6], s), range(320))); d = T() - t
    print(f"resting_pose {th} threads: {1e3*d/320:.2f} ms/pose wall", flush=True)
# --- contexts like the runner (one thread per (object, seed) batch of 20)
pool = cf.ThreadPoolExecutor(16)
for rep in range(3):
    t = T()
    jobs = [pool.submit(driver.contexts, jax.random.key(100 * rep + i), specs[i % 6], 20, models[i % 6]) for i in range(120)]
    out = [j.result() for j in jobs]; d = T() - t
    print(f"contexts rep {rep}: 120 batches x 20 in {d:.2f} s ({1e3*d/2400:.2f} ms/context wall)", flush=True)
# --- trials
grasps, poses = [], []
for o, (s, mdl) in enumerate(zip(specs, models)):
    c = out[o]
    valid = np.asarray(c[2].valid); g = np.asarray(c[2].grasps, np.float64)
    pi, ki = np.nonzero(valid); sel = np.arange(800) % len(pi)
    grasps.append(g[pi[sel], ki[sel]]); poses.append(np.asarray(c[0])[pi[sel]])
t = T(); noises = [sim.sample_noise(jax.random.key(o), 800) for o in range(6)]; print(f"sample_noise x6 (800): {T()-t:.3f} s", flush=True)
t = T(); [sim.sample_noise(jax.random.key(o), 128) for o in range(120)]; print(f"sample_noise x120 (128): {T()-t:.3f} s", flush=True)
one = sim.GraspSimulator(models[1], num_threads=1)
t = T(); one.run_trials(grasps[1][:64], sim.TrialNoise(*(a[:64] for a in noises[1])), object_pose=poses[1][:64]); d = T() - t
print(f"1 thread: {1e3*d/64:.2f} ms/trial", flush=True)
old = [sim_old.GraspSimulator(mdl) for mdl in models]
new = [sim.GraspSimulator(mdl) for mdl in models]
for rep in range(2):
    t = T(); ro = [old[o].run_trials(grasps[o], noises[o], object_pose=poses[o]) for o in range(6)]; d_old = T() - t
    t = T(); rs = [new[o].run_trials(grasps[o], noises[o], object_pose=poses[o]) for o in range(6)]; d_seq = T() - t
    with cf.ThreadPoolExecutor(6) as ex:
        t = T(); rn = list(ex.map(lambda o: new[o].run_trials(grasps[o], noises[o], object_pose=poses[o]), range(6))); d_new = T() - t
    same = all(a.rise.tobytes() == b.rise.tobytes() == c.rise.tobytes() and a.success.tobytes() == c.success.tobytes() for a, b, c in zip(ro, rs, rn))
    print(f"4800 trials: old {d_old:.2f} s ({1e3*d_old/4800:.3f} ms/trial), new per object {d_seq:.2f} s, new objects in threads {d_new:.2f} s ({1e3*d_new/4800:.3f} ms/trial); identical {same}", flush=True)
# trials while contexts run in the background (the runner's overlap)
bg = [pool.submit(driver.contexts, jax.random.key(900 + i), specs[i % 6], 20, models[i % 6]) for i in range(120)]
with cf.ThreadPoolExecutor(6) as ex:
    t = T(); rn = list(ex.map(lambda o: new[o].run_trials(grasps[o], noises[o], object_pose=poses[o]), range(6))); d_new = T() - t
t2 = T(); [j.result() for j in bg]; print(f"new trials with 120 context batches behind: {d_new:.2f} s; contexts done {T()-t2:.2f} s later", flush=True)
