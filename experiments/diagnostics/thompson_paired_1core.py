"""Fast Thompson runner: the current code against an earlier commit's, paired on one core.

Measures the wall and CPU seconds of ``fast_thompson.make_batched`` for 256 seeds (one chunk),
K = 64, T = 2,000 (the ``sern bench bandit --policy thompson`` workload), alternating the two
versions, with loop steps per round, seed-rounds/s and the mean regret at T for each. The
process is pinned to CPU 0 (os.sched_setaffinity, before JAX starts); the earlier commit's
``sern_jax/prng.py`` and ``sern_jax/fast_thompson.py`` are read with ``git show`` (the paths
of the flat layout, so OLD_COMMIT must predate the layout by role) and loaded as separate
modules. CPU time is the figure that stays meaningful when other jobs share the core.

Run from the repository root:
    python experiments/diagnostics/thompson_paired_1core.py [OLD_COMMIT] [REPEATS]
Record: experiments/results/bench/bandit_thompson_1core_paired.txt (OLD_COMMIT 16e89b0).
"""
import os
import subprocess
import sys
import tempfile
import time

os.sched_setaffinity(0, {0})
import jax  # noqa: E402
import numpy as np  # noqa: E402

jax.config.update("jax_threefry_partitionable", True)
from sern_jax.bench import bandit as benchmarks
from sern_jax.engine import fast_thompson  # noqa: E402
from sern_jax.engine import simulate as sim  # noqa: E402

old = sys.argv[1] if len(sys.argv) > 1 else "16e89b0"
repeats = int(sys.argv[2]) if len(sys.argv) > 2 else 3
root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
tmp = tempfile.mkdtemp()
for name in ("prng", "fast_thompson"):
    src = subprocess.run(["git", "-C", root, "show", f"{old}:sern_jax/{name}.py"], check=True,
                         capture_output=True, text=True).stdout
    src = src.replace("from sern_jax import fast_softmax, prng",
                      "from sern_jax import fast_softmax\nimport old_prng as prng")
    with open(os.path.join(tmp, f"old_{name}.py"), "w") as f:
        f.write(src)
sys.path.insert(0, tmp)
import old_fast_thompson  # noqa: E402

C, T = 256, 2000
w = benchmarks.BanditWorkload(policy="thompson", horizon=T, seeds=C)
config, params = benchmarks.bandit_config(w)
keys = sim.seed_keys(jax.random.key(0), C)
head = subprocess.run(["git", "-C", root, "rev-parse", "--short", "HEAD"], capture_output=True,
                      text=True).stdout.strip()
print(f"machine: {os.cpu_count()} cores, pinned to CPU 0; jax {jax.__version__}; "
      f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; load {os.getloadavg()[0]:.2f}")
compiled = {}
for label, mod in ((f"HEAD {head}", fast_thompson), (f"old {old}", old_fast_thompson)):
    fn = jax.jit(mod.make_batched(config, chunk=C, with_steps=True))
    compiled[label] = fn.lower(keys, params).compile()
    out, steps = compiled[label](keys, params)
    compiled[label] = (compiled[label], int(np.asarray(steps)[0]),
                       float(np.mean(np.asarray(out.regret)[:, -1])))
rows = {label: [] for label in compiled}
for _ in range(repeats):
    for label, (fn, _, _) in compiled.items():
        t0, p0 = time.perf_counter(), time.process_time()
        jax.block_until_ready(fn(keys, params))
        rows[label].append((time.perf_counter() - t0, time.process_time() - p0))
for label, (fn, steps, regret) in compiled.items():
    wall = np.array([r[0] for r in rows[label]])
    cpu = np.array([r[1] for r in rows[label]])
    print(f"{label}: steps/round {steps / T:.3f}, mean regret at T {regret:.2f}; wall s "
          f"{np.round(wall, 3).tolist()}, CPU s {np.round(cpu, 3).tolist()}; median "
          f"{C * T / np.median(wall) / 1e6:.3f}M seed-rounds/s wall, "
          f"{C * T / np.median(cpu) / 1e6:.3f}M per CPU-second")
print(f"load after {os.getloadavg()[0]:.2f}")
