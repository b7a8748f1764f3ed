"""Does a subset of seeds (a smaller vmapped batch) give bit-identical per-seed results?"""
import sys, time, json
import jax, numpy as np
sys.path.insert(0, "/work/main"); sys.path.insert(0, "/work/main/tests/grasp")
from sern_jax.grasp import runner, objects, artifacts
which = sys.argv[1] if len(sys.argv) > 1 else "tiny"
if which == "tiny":
    from conftest import make_tiny_theta0
    theta0 = make_tiny_theta0()
else:
    theta0 = artifacts.load_theta0()
cfg = runner.OnlineConfig(policies=("sern", "egreedy", "greedy"), num_seeds=4, rounds=2,
                          explore=3, evaluate=2, eval_poses=1, eval_trials=2, fit_steps=4,
                          batch_size=8, learning_rate=1e-2)
spec = [objects.make_object("triangular_prism")]
q = lambda *_: None
t = time.time()
full = runner.run(cfg, spec, f"/tmp/y/full_{which}", theta0=theta0, progress=False, log=q)
print("full", time.time() - t, flush=True)
report = {}
for subset in [(1, 3), (2,), (0, 1, 2)]:
    t = time.time()
    sub = runner.run(cfg, spec, f"/tmp/y/sub_{which}_{'_'.join(map(str, subset))}",
                     theta0=theta0, progress=False, log=q, seed_indices=subset)
    idx = list(subset)
    diffs = {}
    for f in full["results"]._fields:
        a = np.asarray(getattr(full["results"], f))[:, :, :, idx]
        b = np.asarray(getattr(sub["results"], f))
        diffs[f] = bool(np.array_equal(a, b, equal_nan=True) and a.tobytes() == b.tobytes())
    st = []
    for sa, sb in zip(full["states"], sub["states"]):
        la, lb = jax.tree.leaves(sa), jax.tree.leaves(sb)
        eq = [bool(np.asarray(x)[:, idx].tobytes() == np.asarray(y).tobytes()) for x, y in zip(la, lb)]
        md = max(float(np.max(np.abs(np.asarray(x)[:, idx].astype(np.float64) - np.asarray(y).astype(np.float64)), initial=0)) for x, y in zip(la, lb) if np.asarray(x).dtype.kind == "f")
        st.append({"leaves_equal": sum(eq), "leaves": len(eq), "max_abs_diff": md})
    report[str(subset)] = {"results_equal": diffs, "states": st}
    print(subset, time.time() - t, json.dumps(report[str(subset)]), flush=True)
json.dump(report, open(f"/tmp/y/report_{which}.json", "w"), indent=1)
