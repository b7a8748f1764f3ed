"""Cost of the phases of one MJX step of the uniform grasp scene.

``python -m experiments.diagnostics.mjx_phase_cost BATCH OUT.json`` times, on BATCH copies of
the handle's uniform scene at rest (after one ``forward``), four nested parts of a step:
collision alone, the position stage (kinematics and collision), ``forward`` (adds velocity,
actuation, constraints and the Newton solver) and ``step``; ms per call, the mean of 5 calls
after a first (compile) call, with ``sern``'s deterministic XLA options unless
``SERN_GPU_NONDETERMINISTIC=1``.
"""
import json, sys, time
import jax, jax.numpy as jnp
from sern_jax.infra import hosts
det = hosts.use_deterministic_xla()
from sern_jax.grasp.world import objects as o, scene as sc, uniform as un, mjx_solver
from sern_jax.grasp.world._mjx import mjx
from mujoco.mjx._src import collision_driver, forward

B = int(sys.argv[1])
exact = sc.build_scene(o.resolve_object("handle"))
sh = un.UniformShape()
mx = un.put_uniform(un.uniform_scene(exact, sh), sh)
d = jax.jit(mjx_solver.block_hessian(lambda m, d: mjx.forward(m, d)))(mx, mjx.make_data(mx))
d = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (B,) + x.shape) if hasattr(x, "shape") else x, d)
rows = {"deterministic": det, "batch": B}
for name, fn in [("collision", collision_driver.collision), ("fwd_position", forward.fwd_position),
                 ("forward", mjx.forward), ("step", mjx.step)]:
    def f(m, d, fn=fn):
        with jax.numpy_rank_promotion("allow"):
            return fn(m, d)
    jf = jax.jit(jax.vmap(mjx_solver.block_hessian(f), in_axes=(None, 0)))
    t0 = time.perf_counter(); jax.block_until_ready(jf(mx, d)); t1 = time.perf_counter()
    for _ in range(5): jax.block_until_ready(jf(mx, d))
    rows[name + "_ms"] = (time.perf_counter() - t1) / 5 * 1e3
    rows[name + "_compile_s"] = t1 - t0
    print(json.dumps({name: rows[name + "_ms"]}), flush=True)
json.dump(rows, open(sys.argv[2], "w"), indent=1)
