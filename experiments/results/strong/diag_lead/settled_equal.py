"""On the GPU, are the contexts made from poses settled ahead (the runner's settling
threads, context.resting_poses) the same as the contexts made in one go? (the lead,
issue 20). The strong setting's six objects, the runner's three batch kinds, seeds 0-3;
prints the number of differing array elements. Device-only diagnostic.

    python3 experiments/results/strong/diag_lead/settled_equal.py
"""
import concurrent.futures

import jax
import numpy as np

from sern_jax.grasp.world import context, objects
from sern_jax.grasp.online import runner

NAMES = ["triangular_prism", "tless_part_a", "detergent_bottle", "pipe_tee_steel",
         "tless_part_a_steel", "tless_part_b_steel"]
config = context.ContextConfig()
root = jax.random.key(0)
pool = concurrent.futures.ThreadPoolExecutor(4, thread_name_prefix="sern-context-settle")
diff = total = 0
for name in NAMES:
    spec = objects.make_object(name)
    model = context.scene_model(spec, config)
    for stream, r, num in ((runner.LOWVAR_CONTEXT, 0, 8), (runner.EVAL_CONTEXT, 0, 5),
                           (runner.EXPLORE_CONTEXT, 1, 20)):
        for s in range(4):
            key_os = runner.object_key(root, name, s)
            whole = runner._contexts_of_stream(key_os, stream, r, spec, num, model, config)
            settled = pool.submit(runner._poses_of_stream, key_os, stream, r, num, model, config)
            staged = runner._contexts_of_stream(key_os, stream, r, spec, num, model, config,
                                                settled)
            for a, b in zip(jax.tree.leaves(whole), jax.tree.leaves(staged)):
                a, b = np.asarray(a), np.asarray(b)
                diff += int((a != b).sum())
                total += a.size
    print(f"{name}: differing elements so far {diff} of {total}", flush=True)
print(f"backend {jax.default_backend()}: {diff} of {total} elements differ")
