"""Per-object MJX trial programs against the one uniform program, on the same objects and
trials: each object's first call (its compile) and trials/s at a fixed batch.

    python experiments/diagnostics/mjx_program_pair.py OUT.json TRIALS OBJECT,OBJECT,...

Record: experiments/results/mjx_one_program/program_pair_h200.json.
"""
import json, sys, time
import jax, numpy as np
from sern_jax.grasp.world import objects, scene as scene_lib, sim
from sern_jax.bench.grasp import random_grasps
out = sys.argv[1]; n = int(sys.argv[2]); names = sys.argv[3].split(",")
res = {"trials": n, "objects": names}
key = jax.random.key(0)
models = [scene_lib.build_scene(objects.make_object(o), seed=0) for o in names]
for shape in (None, "auto"):
    rows = []
    for i, m in enumerate(models):
        g = random_grasps(jax.random.fold_in(key, i), m, n)
        noise = sim.sample_noise(jax.random.fold_in(key, 100 + i), n)
        s = sim.GraspSimulator(m, "mjx", mjx_batch=n, mjx_shape=shape)
        t0 = time.perf_counter(); r = s.run_trials(g, noise); t1 = time.perf_counter()
        r2 = s.run_trials(g, noise); t2 = time.perf_counter()
        rows.append({"object": names[i], "first_s": round(t1 - t0, 2), "second_s": round(t2 - t1, 3),
                     "trials_per_s": round(n / (t2 - t1), 1), "success": float(np.mean(r.success)),
                     "same_rerun": bool(np.array_equal(r.success, r2.success))})
        res[str(shape)] = rows
        json.dump(res, open(out, "w"), indent=1)
        print(shape, rows[-1], flush=True)
