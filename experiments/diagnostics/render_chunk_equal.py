"""Is the JAX renderer's batch (render + candidate sampling) the same per pose whatever the
batch size? For the strong setting's six objects and the grasp runner's three batch sizes (5,
8, 20 poses), renders each batch whole and in padded chunks of CHUNK poses, and counts the
array elements that differ. Meant for a GPU.

Run from the repository root:
    python3 experiments/diagnostics/render_chunk_equal.py
Record: experiments/results/strong/timeline/chunk_equal_h100.txt (code of commit cbeac03).
"""
import time

import jax
import numpy as np

from sern_jax.grasp.world import context, objects
from sern_jax.grasp.world import depth as depth_lib

NAMES = ["triangular_prism", "tless_part_a", "detergent_bottle", "pipe_tee_steel",
         "tless_part_a_steel", "tless_part_b_steel"]
config = context.ContextConfig(renderer="jax")
fn = context._pipeline(config.camera, config.candidates, config.noise)
params = depth_lib.overhead_params(config.camera)


def run(m, gp, kn, kc, chunk):
    n = len(kn)
    if chunk is None:
        return jax.tree.map(np.asarray, fn(m, gp, params, kn, kc))
    pad = (-n) % chunk
    idx = np.concatenate([np.arange(n), np.full(pad, n - 1)])
    parts = [fn(m, jax.tree.map(lambda x: x[idx[i:i + chunk]], gp), params,
                kn[idx[i:i + chunk]], kc[idx[i:i + chunk]]) for i in range(0, n + pad, chunk)]
    return jax.tree.map(lambda *xs: np.concatenate([np.asarray(x) for x in xs])[:n], *parts)


for chunk in (8, 20):
    t = time.perf_counter()
    diff = total = 0
    for name in NAMES:
        model = context.scene_model(objects.make_object(name), config)
        m = context._camera_model(model)
        for p, seed in ((5, 1), (8, 2), (20, 3), (5, 4), (20, 5)):
            keys = context._keys(jax.random.key(seed), p)
            seeds, kn, kc = context._streams(keys)
            poses = context._resting_poses(model, np.asarray(seeds), config)
            gp = context._geom_poses(model, poses)
            whole = run(m, gp, kn, kc, None)
            parts = run(m, gp, kn, kc, chunk)
            for a, b in zip(jax.tree.leaves(whole), jax.tree.leaves(parts)):
                assert a.shape == b.shape and a.dtype == b.dtype
                diff += int((a != b).sum())
                total += a.size
            print(f"chunk {chunk} {name} P={p} seed {seed}: differing elements so far {diff}",
                  flush=True)
    print(f"chunk {chunk}: {diff} of {total} elements differ; {time.perf_counter() - t:.0f} s")
