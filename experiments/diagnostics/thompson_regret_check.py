"""Thompson's regret with the current Beta sampler against an earlier commit's and NumPy's.

The sampler changed (one shared log/exp, no squeezes, min(a, b) = 2 by order statistics), so
the draws differ from the earlier code's; both are exact, so Thompson's mean regret at T must
agree within its standard error. Runs fast_thompson (the current one, and OLD_COMMIT's loaded
from git with the flat layout's paths ``sern_jax/prng.py``, ``sern_jax/fast_thompson.py``) on
the same 4,096 seeds (same per-seed means and reward streams, so the difference is paired by
seed), and the NumPy reference (Generator.beta) on 2,048 seeds of its own; K = 64, T = 2,000,
U[0,1] means (the bench workload). Prints means, SEs (SD/sqrt(n)) and z.

Run from the repository root:
    python experiments/diagnostics/thompson_regret_check.py [OLD_COMMIT]
Record: experiments/results/bench/bandit_thompson_regret_check.txt (OLD_COMMIT 16e89b0).
"""
import os
import subprocess
import sys
import tempfile
import time

import jax
import numpy as np

jax.config.update("jax_threefry_partitionable", True)
from sern_jax.bench import bandit as benchmarks
from sern_jax.engine import fast_thompson  # noqa: E402
from sern_jax.engine import simulate as sim  # noqa: E402

old = sys.argv[1] if len(sys.argv) > 1 else "16e89b0"
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

S, T = 4096, 2000
w = benchmarks.BanditWorkload(policy="thompson", horizon=T, seeds=S)
config, params = benchmarks.bandit_config(w)
keys = sim.seed_keys(jax.random.key(7), S)
head = subprocess.run(["git", "-C", root, "rev-parse", "--short", "HEAD"], capture_output=True,
                      text=True).stdout.strip()
print(f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; jax {jax.__version__}; "
      f"K=64 T={T}; root key 7")
res = {}
for label, mod in ((f"HEAD {head}", fast_thompson), (f"old {old}", old_fast_thompson)):
    fn = jax.jit(mod.make_batched(config, chunk=256))
    res[label] = np.asarray(fn(keys, params).regret[:, -1], np.float64)
    r = res[label]
    print(f"{label}: {S} seeds, mean regret at T {r.mean():.3f}, SE {r.std(ddof=1) / S**0.5:.3f}")
new, prev = res.values()
d = new - prev
se_d = d.std(ddof=1) / S**0.5
print(f"paired HEAD - old: {d.mean():.3f}, SE {se_d:.3f}, z {d.mean() / se_d:.2f}")
n_np = 2048
out = benchmarks.numpy_reference(n_np, 64, T, 0.05, sim.checkpoint_times(config), seed=3,
                                 policy="thompson")
r = out["regret"][:, -1].astype(np.float64)
se = np.hypot(r.std(ddof=1) / n_np**0.5, new.std(ddof=1) / S**0.5)
print(f"NumPy reference (Generator.beta, seed 3): {n_np} seeds, mean regret at T "
      f"{r.mean():.3f}, SE {r.std(ddof=1) / n_np**0.5:.3f}; HEAD - NumPy z "
      f"{(new.mean() - r.mean()) / se:.2f}")
