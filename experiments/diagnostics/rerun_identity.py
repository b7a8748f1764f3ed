"""Whether a command gives the same bits when it is run again: runs a small ``sern grasp
learn`` (or a ``sern regret``) twice into fresh directories, compares every array of every
``.npz`` the runs wrote, and prints one JSON object (arrays and elements that differ, each
run's wall time).

    python -m experiments.diagnostics.rerun_identity --out DIR [--command learn|learn_mjx|regret]
        [--seeds N] [--nondeterministic]

``--nondeterministic`` sets ``SERN_GPU_NONDETERMINISTIC=1`` (XLA's autotuning and
non-deterministic GPU kernels left on), the control for the cost and the effect of the
deterministic options that ``sern`` applies by default. NaN placeholders compare as equal.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

COMMANDS = {
    "learn": ["grasp", "learn", "triangular_prism", "tless_part_a", "--policies",
              "sern,greedy,egreedy", "--seeds", "6", "--rounds", "2", "--no-figures",
              "--no-progress"],
    "learn_mjx": ["grasp", "learn", "triangular_prism", "tless_part_a", "--policies",
                  "sern,greedy", "--seeds", "4", "--rounds", "1", "--backend", "mjx",
                  "--no-figures", "--no-progress"],
    "regret": ["regret", "--policies", "softmax,thompson,epsilon_greedy", "--arms", "64",
               "--horizon", "10000", "--seeds", "20000", "--no-figures", "--no-progress"],
}


def compare(a: Path, b: Path) -> dict:
    """Arrays (and their elements) that differ between two run directories' .npz files."""
    out = {"files": 0, "arrays": 0, "arrays_differing": [], "elements_differing": 0}
    for fa in sorted(a.rglob("*.npz")):
        fb = b / fa.relative_to(a)
        out["files"] += 1
        with np.load(fa) as za, np.load(fb) as zb:
            for name in za.files:
                if name == "wall_s" or name.startswith("__"):  # compute time; file digest
                    continue
                out["arrays"] += 1
                x, y = za[name], zb[name]
                same = (x.shape == y.shape and
                        (np.array_equal(x, y, equal_nan=x.dtype.kind == "f")))
                if not same:
                    diff = (int(np.sum(~((x == y) | (np.isnan(x) & np.isnan(y)))))
                            if x.shape == y.shape and x.dtype.kind == "f" else
                            int(np.sum(x != y)) if x.shape == y.shape else -1)
                    out["arrays_differing"].append(f"{fa.relative_to(a)}:{name}")
                    out["elements_differing"] += diff
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="a new directory for the two runs")
    p.add_argument("--command", choices=sorted(COMMANDS), default="learn")
    p.add_argument("--seeds", type=int, default=None,
                   help="the command's --seeds instead of its default (a smaller rerun)")
    p.add_argument("--nondeterministic", action="store_true",
                   help="leave XLA's GPU autotuning and non-deterministic kernels on")
    args = p.parse_args(argv)
    out = Path(args.out)
    if out.exists():
        p.error(f"--out {out} exists; give a new directory")
    command = list(COMMANDS[args.command])
    if args.seeds is not None:
        if args.seeds < 1:
            p.error(f"--seeds must be >= 1, got {args.seeds}")
        command[command.index("--seeds") + 1] = str(args.seeds)
    env = dict(os.environ)
    if args.nondeterministic:
        env["SERN_GPU_NONDETERMINISTIC"] = "1"
    walls = []
    for name in ("a", "b"):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "sern_jax.commands.main",
                        *command, "--out", str(out / name)],
                       env=env, check=True, stdout=subprocess.DEVNULL)
        walls.append(round(time.perf_counter() - t0, 1))
    result = {"command": "sern " + " ".join(command),
              "nondeterministic": args.nondeterministic, "wall_s": walls,
              **compare(out / "a", out / "b")}
    print(json.dumps(result))
    return 0 if not result["arrays_differing"] else 1


if __name__ == "__main__":
    sys.exit(main())
