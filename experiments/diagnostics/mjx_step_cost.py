"""Per-step cost of the uniform MJX scene for several hull sizes (vertices, face vertices).

``python -m experiments.diagnostics.mjx_step_cost BATCH STEPS V:F[,V:F...] OUT.json`` steps
BATCH copies of the handle's uniform scene (4 parts) STEPS times in one ``jit(vmap(scan))``
for each hull size V (``UniformShape.vertices``) and padded face size F (vertices per face,
``UniformShape.face_vertices``, 20 in the product), with the deterministic XLA options of
``sern`` (``SERN_GPU_NONDETERMINISTIC=1`` leaves them off), and writes one row per size.
"""
import json, sys, time
import jax, jax.numpy as jnp, numpy as np
from sern_jax.infra import hosts
print("deterministic XLA:", hosts.use_deterministic_xla(), flush=True)
from sern_jax.grasp.world import objects as o, scene as sc, uniform as un, mjx_solver
from sern_jax.grasp.world._mjx import mjx

B, S = int(sys.argv[1]), int(sys.argv[2])
variants = [tuple(int(x) for x in v.split(":")) for v in sys.argv[3].split(",")]
exact = sc.build_scene(o.resolve_object("handle"))
out = []
for V, fv in variants:
    class Shape(un.UniformShape):
        @property
        def face_vertices(self):
            return fv
    sh = Shape(parts=4, vertices=V)
    t0 = time.perf_counter()
    u = un.uniform_scene(exact, sh)
    mx = un.put_uniform(u, sh)
    d = mjx.make_data(mx)
    d = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (B,) + x.shape) if hasattr(x, "shape") else x, d)
    def run(m, d):
        with jax.numpy_rank_promotion("allow"):
            return jax.lax.scan(lambda d, _: (mjx.step(m, d), None), d, None, length=S)[0]
    f = jax.jit(jax.vmap(mjx_solver.block_hessian(run), in_axes=(None, 0)))
    t1 = time.perf_counter(); r = jax.block_until_ready(f(mx, d)); t2 = time.perf_counter()
    r = jax.block_until_ready(f(mx, d)); t3 = time.perf_counter()
    row = {"vertices": V, "face_vertices": fv, "batch": B, "steps": S, "compile_s": t2 - t1 - (t3 - t2),
           "ms_per_step": (t3 - t2) / S * 1e3, "steps_per_s": B * S / (t3 - t2),
           "trials_per_s_equiv": B * S / (t3 - t2) / 290}
    print(json.dumps(row), flush=True)
    out.append(row)
json.dump(out, open(sys.argv[4], "w"), indent=1)
