"""Do renderer compiles for different objects overlap when made from several threads?

Compiles the context pipeline (depth.render + candidates.sample, JAX renderer) for 4 objects
at P = 8 from 4 threads at once, (a) through the one shared jitted function of
context._pipeline, (b) through a fresh jax.jit of the same function per thread; prints each
compile's span. Meant for a GPU.

Run from the repository root:
    python3 experiments/diagnostics/render_compile_overlap.py
Record: experiments/results/strong/timeline/compile_overlap_h100.txt (code of commit cbeac03).
"""
import threading
import time

import jax
import jax.monitoring
import numpy as np

from sern_jax.grasp.world import context, objects

T0 = time.perf_counter()
EVENTS = []


def on_duration(event, duration, **kw):
    if event.endswith("backend_compile_duration"):
        end = time.perf_counter() - T0
        EVENTS.append((threading.current_thread().name, end - duration, end))


jax.monitoring.register_event_duration_secs_listener(on_duration)
NAMES = ["triangular_prism", "tless_part_a", "detergent_bottle", "pipe_tee_steel",
         "tless_part_a_steel", "tless_part_b_steel"]
config = context.ContextConfig(renderer="jax")


def inputs(name, p):
    spec = objects.make_object(name)
    model = context.scene_model(spec, config)
    keys = context._keys(jax.random.key(0), p)
    seeds, kn, kc = context._streams(keys)
    poses = context._resting_poses(model, np.asarray(seeds), config)
    from sern_jax.grasp.world import depth as depth_lib
    params = depth_lib.overhead_params(config.camera)
    return (context._camera_model(model), context._geom_poses(model, poses), params, kn, kc)


def trial(label, fn_of, p):
    EVENTS.clear()
    args = {n: inputs(n, p) for n in NAMES}
    t = time.perf_counter()
    threads = [threading.Thread(target=lambda n=n: jax.block_until_ready(fn_of(n)(*args[n])),
                                name=n) for n in NAMES]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    wall = time.perf_counter() - t
    spans = sorted(EVENTS, key=lambda e: e[1])
    total = sum(e[2] - e[1] for e in spans)
    print(f"{label}: {len(NAMES)} objects, P={p}: wall {wall:.1f} s, compiles {len(spans)}, "
          f"sum {total:.1f} s")
    for name, a, b in spans:
        print(f"   {name:20s} {a - spans[0][1]:6.1f} .. {b - spans[0][1]:6.1f}")


shared = context._pipeline(config.camera, config.candidates, config.noise)
trial("one shared jit", lambda n: shared, 8)
fresh = {}


def fresh_fn(n):
    # the same Python function, a jit object of its own per object
    return fresh.setdefault(n, jax.jit(shared.__wrapped__))


trial("a jit per object", fresh_fn, 9)
