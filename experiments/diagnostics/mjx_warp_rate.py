"""MuJoCo Warp (mujoco-mjx's ``impl="warp"``) beside the JAX MJX trial, on one object's uniform scene.

``python -m experiments.diagnostics.mjx_warp_rate OBJECT TRIALS[,TRIALS...] OUT.json [JAX_MAX]``

For each batch size N: N random grasps (``bench.grasp.random_grasps``) with trial noise
(``sim.sample_noise``) on OBJECT's uniform scene (``uniform.uniform_scene``), run by

* native MuJoCo (the reference outcomes, once, at the largest N),
* the JAX MJX trial (``GraspSimulator(..., "mjx", mjx_batch=N)``, for N up to ``JAX_MAX``:
  the product's MJX path, cone-block Hessian, the deterministic XLA options unless ``SERN_GPU_NONDETERMINISTIC=1``),
* the same trial with MuJoCo Warp stepping it: ``mjx.put_model(u, impl="warp")`` and
  ``mjx.make_data(u, impl="warp", ...)`` in the trial's scan, vmapped over trials (a probe
  here, not a product path),

each timed as the best of two calls after a first call (compile), and writes one row per
(backend, N): trials/s, the first call's seconds, the success rate, the paired agreement with
native MuJoCo, whether a second call gave the same bits, and for Warp the largest contact
and constraint counts seen (to check the capacities). The Warp rows need ``warp-lang``; they
run on a CUDA GPU, or slowly on the CPU.
"""
import copy
import functools
import json
import sys
import time

from sern_jax.infra import hosts

DETERMINISTIC = hosts.use_deterministic_xla()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from sern_jax.bench.grasp import random_grasps  # noqa: E402
from sern_jax.grasp.world import objects as objects_lib  # noqa: E402
from sern_jax.grasp.world import scene as scene_lib  # noqa: E402
from sern_jax.grasp.world import sim  # noqa: E402
from sern_jax.grasp.world import uniform  # noqa: E402
from sern_jax.grasp.world._mjx import mjx  # noqa: E402

CONTACTS_PER_WORLD = 32
CONSTRAINTS_PER_WORLD = 160
JAX_MAX = 4096  # the JAX trial is timed up to this batch (or argv[3]); Warp at every size


def warp_model(u):
    """A copy of ``u`` without the autoreset flag, which MuJoCo Warp refuses.

    The scene disables autoreset so that native MuJoCo never resets a diverging trial behind
    the trial's back (the trial flags it as non-finite instead); Warp never resets a world,
    so clearing the flag for Warp leaves the same behaviour.
    """
    w = copy.copy(u)
    w.opt.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_AUTORESET)
    return w


def warp_program(u, config: sim.TrialConfig, n: int):
    """jit(vmap(trial)) with MuJoCo Warp stepping the trial of ``sim.make_execute``."""
    ids = scene_lib.scene_ids(u)
    half_open, dt = sim._half_open(u, ids), float(u.opt.timestep)
    d0 = mjx.make_data(u, impl="warp", naconmax=n * CONTACTS_PER_WORLD,
                       njmax=CONSTRAINTS_PER_WORLD)

    def execute(mx, pose, grasp, tp):
        # the product trial's pieces (sim._make_execute), with Warp's data in place of MJX's
        palm0, ctrl = sim._schedule(jnp, grasp + tp.grasp_error, config, half_open, dt)
        m, qpos0 = sim._trial_model(mx, ids, pose, palm0, tp)
        d = d0.replace(qpos=qpos0, ctrl=ctrl[0])

        def step(carry, ctrl_t):
            d, finite, peak = carry
            d = mjx.step(m, d.replace(ctrl=ctrl_t))
            peak = jnp.maximum(peak, jnp.stack([jnp.max(d._impl.nacon),
                                                jnp.max(d._impl.nefc)]).astype(jnp.int32))
            return (d, sim._still_finite(finite, d), peak), None

        init = (d, jnp.array(True), jnp.zeros(2, jnp.int32))
        (d, finite, peak), _ = jax.lax.scan(step, init, ctrl)
        rise, gap = sim._rise_and_gap(d, qpos0, ids)
        return finite, rise, gap, peak

    def run(mx, poses, grasps, params):
        with jax.numpy_rank_promotion("allow"):
            return jax.vmap(execute, in_axes=(None, 0, 0, 0))(mx, poses, grasps, params)

    return jax.jit(run)


def timed(call, repeats=2):
    t0 = time.perf_counter()
    first = call()
    first_s = time.perf_counter() - t0
    best, out = float("inf"), None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = call()
        best = min(best, time.perf_counter() - t0)
    return first, out, first_s, best


def main(argv):
    name, sizes, path = argv[0], [int(x) for x in argv[1].split(",")], argv[2]
    jax_max = int(argv[3]) if len(argv) > 3 else JAX_MAX
    exact = scene_lib.build_scene(objects_lib.resolve_object(name), seed=0)
    shape = uniform.shape_for(exact)
    u = uniform.uniform_scene(exact, shape)
    config = sim.TrialConfig()
    key = jax.random.key(0)
    nmax = max(sizes)
    grasps = random_grasps(jax.random.fold_in(key, 1), exact, nmax)
    noise = sim.sample_noise(jax.random.fold_in(key, 2), nmax)
    pose0 = scene_lib.object_pose(u)
    t0 = time.perf_counter()
    native = sim.GraspSimulator(u, "native").run_trials(grasps, noise)
    native_s = time.perf_counter() - t0
    rows = [{"backend": "native", "object": name, "trials": nmax, "seconds": native_s,
             "trials_per_s": nmax / native_s, "threads": hosts.cpu_threads(),
             "success_rate": float(native.success.mean())}]
    print(json.dumps(rows[-1]), flush=True)
    mx_warp = None
    for n in sizes:
        g, z = grasps[:n], sim.TrialNoise(*(np.asarray(a)[:n] for a in noise))
        ref = native.success[:n]
        jx_success = None
        if n <= jax_max:
            jx = sim.GraspSimulator(exact, "mjx", mjx_batch=n)
            first, out, first_s, best = timed(lambda: jx.run_trials(g, z))
            rows.append({"backend": "mjx_jax", "object": name, "trials": n,
                         "deterministic_xla": DETERMINISTIC, "first_call_s": first_s,
                         "seconds": best, "trials_per_s": n / best,
                         "success_rate": float(out.success.mean()),
                         "agreement_native": float(np.mean(out.success == ref)),
                         "rerun_equal": bool(np.array_equal(first.rise, out.rise,
                                                            equal_nan=True))})
            print(json.dumps(rows[-1]), flush=True)
            jx_success = out.success
        try:
            mx_warp = mx_warp or mjx.put_model(warp_model(u), impl="warp")
            prog = warp_program(u, config, n)
            f32 = functools.partial(jnp.asarray, dtype=jnp.float32)
            args = (mx_warp, f32(np.tile(pose0, (n, 1))), f32(g),
                    sim.TrialNoise(*(f32(a) for a in z)))

            def call():
                finite, rise, gap, peak = jax.block_until_ready(prog(*args))
                return np.asarray(finite), np.asarray(rise, np.float64), \
                    np.asarray(gap, np.float64), np.asarray(peak)
            first, out, first_s, best = timed(call)
            finite, rise, gap, peak = out
            success = sim.succeeded(finite, rise, gap, config)
            rows.append({"backend": "mjx_warp", "object": name, "trials": n,
                         "first_call_s": first_s, "seconds": best, "trials_per_s": n / best,
                         "success_rate": float(success.mean()),
                         "nonfinite": int((~finite).sum()),
                         "agreement_native": float(np.mean(success == ref)),
                         "agreement_mjx_jax": (None if jx_success is None
                                               else float(np.mean(success == jx_success))),
                         "rerun_equal": bool(np.array_equal(first[1], rise)),
                         "rerun_label_flips": int(np.sum(
                             sim.succeeded(*first[:3], config) != success)),
                         "peak_contacts_all_worlds": int(peak[:, 0].max()),
                         "peak_constraints_per_world": int(peak[:, 1].max()),
                         "capacity": [n * CONTACTS_PER_WORLD, CONSTRAINTS_PER_WORLD]})
        except Exception as e:  # record why, keep the other rows
            rows.append({"backend": "mjx_warp", "object": name, "trials": n,
                         "error": f"{type(e).__name__}: {e}"[:2000]})
        print(json.dumps(rows[-1]), flush=True)
        with open(path, "w") as fh:
            json.dump({"machine": {"jax": jax.__version__, "devices": str(jax.devices())},
                       "rows": rows}, fh, indent=1)


if __name__ == "__main__":
    main(sys.argv[1:])
