"""Writes tests/grasp/data/learn_reference.npz: what tests/grasp/test_runner.py's
``test_same_results_as_the_pre_refactor_runner`` compares the runner with, bit for bit.

The first copy was written by the pre-refactor ``online.run`` (commit 2b20d9d) under the
6 N trial. The trial changed on 2026-11-24 (20 N fingers, Newton 20 / 20 iterations,
docs/GRASP.md), which changes every outcome, so the reference was re-derived with this
script from the runner of the ``trial:`` commit (the runner itself unchanged; it had been
checked bit for bit against 2b20d9d under the old trial). Run from the repository root:

    python tests/grasp/data/make_learn_reference.py

Besides the bit-for-bit arrays it records the JAX version it ran under and a float64
projection of each copy's final parameters, which the test compares within a tolerance
when it runs under another JAX version (where the parameters' last bits move).
"""

import json
import sys
import tempfile
from pathlib import Path

import jax
import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

from sern_jax.grasp.world import objects
from sern_jax.grasp.online import driver  # noqa: E402
from tests.grasp.conftest import make_tiny_theta0  # noqa: E402
from tests.grasp.test_runner import CONFIG, OBJECT, params_digests, params_projections  # noqa: E402


def main() -> None:
    with tempfile.TemporaryDirectory() as out:
        res = driver.run(CONFIG, [objects.make_object(OBJECT)], out, theta0=make_tiny_theta0(),
                         progress=False, log=lambda *_: None)
    arrays = {name: np.asarray(getattr(res["results"], name))
              for name in res["results"]._fields}
    arrays["table"] = np.asarray(json.dumps(
        [{k: v for k, v in r.items() if k not in ("sd", "se")} for r in res["table"]]))
    digests, labels, weights = params_digests(res), [], []
    for q in range(len(CONFIG.policies)):
        state = res["states"][q]
        labels.append(np.asarray(state.buffer.reward)[0, :, :CONFIG.horizon])
        weights.append(np.asarray(state.buffer.weight)[0, :, :CONFIG.horizon])
    arrays["params_digest"] = np.asarray(json.dumps(digests))
    arrays["params_projection"] = params_projections(res)  # [Q, S, 9]
    arrays["jax_version"] = np.asarray(jax.__version__)
    arrays["buffer_label"] = np.stack(labels, 1)[None]  # [1, S, Q, H]
    arrays["buffer_weight"] = np.stack(weights, 1)[None]
    path = Path(__file__).with_name("learn_reference.npz")
    np.savez(path, **arrays)
    print(f"wrote {path}: " + ", ".join(f"{k} {v.shape}" for k, v in arrays.items()))


if __name__ == "__main__":
    main()
