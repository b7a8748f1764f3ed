"""Writes tests/grasp/data/learn_reference.npz: what tests/grasp/test_runner.py's
``test_same_results_as_the_pre_refactor_runner`` compares the runner with, bit for bit.

The first copy was written by the pre-refactor ``online.run`` (commit 2b20d9d) under the
6 N trial. The trial changed on 2026-11-24 (20 N fingers, Newton 20 / 20 iterations,
docs/GRASP.md), which changes every outcome, so the reference was re-derived with this
script from the runner of the ``trial:`` commit (the runner itself unchanged; it had been
checked bit for bit against 2b20d9d under the old trial). Run from the repository root:

    python tests/grasp/data/make_learn_reference.py
"""

import hashlib
import json
import sys
import tempfile
from pathlib import Path

import jax
import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

from sern_jax.grasp import artifacts, objects, runner  # noqa: E402
from sern_jax.grasp import quality_net as qn  # noqa: E402
from tests.grasp.conftest import CORE_K  # noqa: E402
from tests.grasp.test_runner import CONFIG, OBJECT  # noqa: E402


def tiny_theta0():
    """The conftest fixture ``tiny_theta0``, made the same way."""
    network = qn.make_quality_network()
    params = network.init(jax.random.key(0))
    s = network.config.crop_size
    rng = np.random.default_rng(0)
    core = {}
    for kind in ("dpp", "random"):
        core[f"{kind}_image"] = rng.normal(0.0, 0.01, (CORE_K, s, s)).astype(np.float32)
        core[f"{kind}_depth"] = rng.uniform(0.55, 0.6, CORE_K).astype(np.float32)
        core[f"{kind}_label"] = (rng.random(CORE_K) < 0.5).astype(np.float32)
        core[f"{kind}_index"] = np.arange(CORE_K)
    return artifacts.Theta0(network, params, core, manifest={}, fingerprint="test",
                            screen=None)


def main() -> None:
    with tempfile.TemporaryDirectory() as out:
        res = runner.run(CONFIG, [objects.make_object(OBJECT)], out, theta0=tiny_theta0(),
                         progress=False, log=lambda *_: None)
    arrays = {name: np.asarray(getattr(res["results"], name))
              for name in res["results"]._fields}
    arrays["table"] = np.asarray(json.dumps(
        [{k: v for k, v in r.items() if k not in ("sd", "se")} for r in res["table"]]))
    digests, labels, weights = {}, [], []
    for q, name in enumerate(CONFIG.policies):
        state = res["states"][q]
        for s in range(CONFIG.num_seeds):
            h = hashlib.sha256()
            for leaf in jax.tree.leaves(state.params):
                h.update(np.ascontiguousarray(np.asarray(leaf)[0, s]).tobytes())
            digests[f"{name}/{s}"] = h.hexdigest()
        labels.append(np.asarray(state.buffer.reward)[0, :, :CONFIG.horizon])
        weights.append(np.asarray(state.buffer.weight)[0, :, :CONFIG.horizon])
    arrays["params_digest"] = np.asarray(json.dumps(digests))
    arrays["buffer_label"] = np.stack(labels, 1)[None]  # [1, S, Q, H]
    arrays["buffer_weight"] = np.stack(weights, 1)[None]
    path = Path(__file__).with_name("learn_reference.npz")
    np.savez(path, **arrays)
    print(f"wrote {path}: " + ", ".join(f"{k} {v.shape}" for k, v in arrays.items()))


if __name__ == "__main__":
    main()
