"""Writes tests/data/layout_pins.json: digests of what the engines and commands compute, so
that a change of layout or of a driver (code moved, not maths) is checked bit for bit on the
CPU by tests/test_layout_pins.py.

Run from the repository root, with the code whose outputs are the reference:

    python tests/data/make_layout_pins.py [--slow]

``--slow`` adds the full Table I setting of ``sern grasp learn`` (minutes on 2 cores). The
JSON records the jax version; under another version the test skips the float digests.
"""

from __future__ import annotations

import hashlib
import importlib
import json
import sys
import tempfile
from pathlib import Path

import jax
import numpy as np

OUT = Path(__file__).with_name("layout_pins.json")

# (name, argv) of each command pinned; {out} is a fresh run directory
COMMANDS = {
    "regret_tabular": ["regret", "--policies", "softmax,greedy,thompson", "--arms", "4",
                       "--horizon", "200", "--seeds", "64", "--no-figures", "--no-progress"],
    "regret_neural": ["regret", "--estimator", "neural", "--problem", "wheel",
                      "--policies", "sern,egreedy", "--horizon", "100", "--update-every", "25", "--seeds", "4",
                      "--no-figures", "--no-progress"],
    "grasp_learn_small": ["grasp", "learn", "--seeds", "1", "--rounds", "1", "--explore", "4",
                          "--evaluate", "4", "--eval-poses", "2", "--eval-trials", "2",
                          "--policies", "sern,greedy", "--no-figures", "--no-progress",
                          "small_box"],
}
SLOW_COMMANDS = {
    "grasp_learn_table1": ["grasp", "learn", "--no-figures", "--no-progress"],
}
RUN_FILES = ("results.npz", "checkpoint.npz")


def _module(new: str, old: str):
    try:
        return importlib.import_module(new)
    except ModuleNotFoundError:
        return importlib.import_module(old)


def digest_arrays(arrays: dict) -> str:
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(np.asarray(arrays[name]))
        h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes() if a.dtype != object else repr(a.tolist()).encode())
    return h.hexdigest()


def digest_tree(tree) -> str:
    """The digest of every leaf of a pytree (NamedTuples of arrays), named by its path."""
    leaves = jax.tree_util.tree_flatten_with_path(tree)[0]
    return digest_arrays({jax.tree_util.keystr(path): leaf for path, leaf in leaves})


def engine_pins() -> dict[str, str]:
    drive = _module("sern_jax.engine.drive", "sern_jax.executor")
    sim = _module("sern_jax.engine.simulate", "sern_jax.simulate")
    problems = _module("sern_jax.core.problems", "sern_jax.problems")
    prob = problems.bernoulli([0.9, 0.8, 0.5, 0.3, 0.1])
    pins = {}
    soft = sim.RunConfig(policy="softmax", estimator="addhalf", num_arms=5, horizon=300,
                         num_checkpoints=12)
    params = sim.default_params(soft, prob, alpha0=0.1)
    pins["run_seeds_fast"] = digest_tree(drive.run_seeds(soft, params, num_seeds=200,
                                                          runner="fast"))
    pins["run_seeds_general"] = digest_tree(drive.run_seeds(soft, params, num_seeds=200,
                                                             runner="general"))
    pins["run_seeds_summary"] = digest_tree(drive.run_seeds(soft, params, num_seeds=200,
                                                            summary=True))
    ts = sim.RunConfig(policy="thompson", estimator="mean", num_arms=5, horizon=300,
                       num_checkpoints=12)
    pins["run_seeds_thompson"] = digest_tree(drive.run_seeds(
        ts, sim.default_params(ts, prob), num_seeds=200))
    return pins


def command_pins(commands: dict) -> dict[str, str]:
    main = importlib.import_module("sern_jax.commands.main")
    pins = {}
    for name, argv in commands.items():
        with tempfile.TemporaryDirectory() as tmp:
            run = Path(tmp) / "run"
            rc = main.main([*argv, "--out", str(run)])
            assert rc in (0, None), (name, rc)
            for f in RUN_FILES:
                if (run / f).exists():
                    with np.load(run / f, allow_pickle=False) as z:
                        pins[f"{name}/{f}"] = digest_arrays({k: z[k] for k in z.files})
    return pins


def compute(slow: bool = False) -> dict[str, str]:
    pins = engine_pins()
    pins |= command_pins(COMMANDS)
    if slow:
        pins |= command_pins(SLOW_COMMANDS)
    return pins


def main(argv: list[str]) -> None:
    pins = compute(slow="--slow" in argv)
    OUT.write_text(json.dumps({"jax": jax.__version__, "pins": pins}, indent=1,
                              sort_keys=True) + "\n")
    print(f"wrote {OUT}: {len(pins)} digests")


if __name__ == "__main__":
    main(sys.argv[1:])
