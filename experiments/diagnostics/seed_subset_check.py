"""Does a subset of the seeds (a smaller vmapped batch) give bit-identical per-seed results?

One object x 3 learners x 4 seeds x 2 rounds of grasp learning, then seeds (1, 3), (2,) and
(0, 1, 2) run alone; per subset, whether every results field and every learner-state array
equals the full run's for those seeds bit for bit (what (object, seed) units of work would
need). ``tiny`` uses the tests' θ0, anything else the shipped θ0; writes report_<which>.json in
the current folder.

Run from the repository root:
    python experiments/diagnostics/seed_subset_check.py tiny
Record: experiments/results/ray_scaling/seed_subset_cpu.json.
"""

import json
import sys
import time
from pathlib import Path

import jax
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT), str(ROOT / "tests" / "grasp")]

from sern_jax.grasp.model import artifacts
from sern_jax.grasp.world import objects
from sern_jax.grasp.online import config as online_config
from sern_jax.grasp.online import driver


def main() -> None:
    which = sys.argv[1] if len(sys.argv) > 1 else "tiny"
    if which == "tiny":
        from conftest import make_tiny_theta0

        theta0 = make_tiny_theta0()
    else:
        theta0 = artifacts.load_theta0()
    cfg = online_config.OnlineConfig(policies=("sern", "egreedy", "greedy"), num_seeds=4,
                                     rounds=2, explore=3, evaluate=2, eval_poses=1,
                                     eval_trials=2, fit_steps=4, batch_size=8,
                                     learning_rate=1e-2)
    spec = [objects.make_object("triangular_prism")]

    def quiet(*_):
        pass

    t = time.time()
    full = driver.run(cfg, spec, f"full_{which}", theta0=theta0, progress=False, log=quiet)
    print("full", time.time() - t, flush=True)
    report = {}
    for subset in [(1, 3), (2,), (0, 1, 2)]:
        t = time.time()
        sub = driver.run(cfg, spec, f"sub_{which}_{'_'.join(map(str, subset))}",
                         theta0=theta0, progress=False, log=quiet, seed_indices=subset)
        idx = list(subset)
        diffs = {}
        for f in full["results"]._fields:
            a = np.asarray(getattr(full["results"], f))[:, :, :, idx]
            b = np.asarray(getattr(sub["results"], f))
            diffs[f] = bool(np.array_equal(a, b, equal_nan=True)
                            and a.tobytes() == b.tobytes())
        states = []
        for sa, sb in zip(full["states"], sub["states"]):
            pairs = [(np.asarray(x)[:, idx], np.asarray(y))
                     for x, y in zip(jax.tree.leaves(sa), jax.tree.leaves(sb))]
            equal = [x.tobytes() == y.tobytes() for x, y in pairs]
            worst = max((float(np.max(np.abs(x.astype(np.float64) - y.astype(np.float64)),
                                      initial=0)) for x, y in pairs if x.dtype.kind == "f"),
                        default=0.0)
            states.append({"leaves_equal": sum(equal), "leaves": len(equal),
                           "max_abs_diff": worst})
        report[str(subset)] = {"results_equal": diffs, "states": states}
        print(subset, time.time() - t, json.dumps(report[str(subset)]), flush=True)
    Path(f"report_{which}.json").write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
