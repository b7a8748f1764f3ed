"""On the GPU, are the contexts made from poses settled ahead (the grasp runner's settling
threads, context.resting_poses) the same as the contexts made in one go? The strong setting's
six objects, the runner's three batch kinds, seeds 0-3; prints the number of differing array
elements.

Written against the grasp runner of commit cbeac03 (``runner._contexts_of_stream``,
``runner._poses_of_stream``; now ``driver.contexts_of_stream``,
``driver.poses_of_stream``). Run from the repository root:
    python3 experiments/diagnostics/settled_contexts_equal.py
Record: experiments/results/strong/timeline/settled_equal_h100.txt.
"""
import concurrent.futures

import jax
import numpy as np

from sern_jax.grasp.world import context, objects
from sern_jax.grasp.online import driver
from sern_jax.grasp.online import keys as keys_lib

NAMES = ["triangular_prism", "tless_part_a", "detergent_bottle", "pipe_tee_steel",
         "tless_part_a_steel", "tless_part_b_steel"]
config = context.ContextConfig()
root = jax.random.key(0)
pool = concurrent.futures.ThreadPoolExecutor(4, thread_name_prefix="sern-context-settle")
diff = total = 0
for name in NAMES:
    spec = objects.make_object(name)
    model = context.scene_model(spec, config)
    for stream, r, num in ((keys_lib.LOWVAR_CONTEXT, 0, 8), (keys_lib.EVAL_CONTEXT, 0, 5),
                           (keys_lib.EXPLORE_CONTEXT, 1, 20)):
        for s in range(4):
            key_os = keys_lib.object_key(root, name, s)
            whole = driver.contexts_of_stream(key_os, stream, r, spec, num, model, config)
            settled = pool.submit(driver.poses_of_stream, key_os, stream, r, num, model, config)
            staged = driver.contexts_of_stream(key_os, stream, r, spec, num, model, config,
                                               settled)
            for a, b in zip(jax.tree.leaves(whole), jax.tree.leaves(staged)):
                a, b = np.asarray(a), np.asarray(b)
                diff += int((a != b).sum())
                total += a.size
    print(f"{name}: differing elements so far {diff} of {total}", flush=True)
print(f"backend {jax.default_backend()}: {diff} of {total} elements differ")
