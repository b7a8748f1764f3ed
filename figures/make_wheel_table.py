"""The wheel-bandit table of Riquelme et al. 2018 from saved runs: each policy's cumulative
regret divided by Uniform's, one column per δ (reads each run's summary.json only).

Usage: ``python -m figures.make_wheel_table RUN_DIR [RUN_DIR ...]`` where every RUN_DIR is a
``sern regret --estimator neural --problem wheel --delta δ ...`` run with ``uniform`` among
its policies. Prints a markdown table (ratio and its paired seed-bootstrap 95% interval).

Riquelme et al. publish this table (normalised cumulative regret per δ); we could not find
its numbers in a copy we can read here, so this table has no published column.
"""

from __future__ import annotations

import sys
from pathlib import Path

from sern_jax.infra import io

__all__ = ["wheel_table"]


def wheel_table(run_dirs) -> str:
    columns = []
    for run_dir in run_dirs:
        run_dir = Path(run_dir)
        exp = io.load_json(run_dir / "config.json")["experiment"]
        summary = io.load_json(run_dir / "summary.json")
        if exp.get("problem") != "wheel" or "normalised_by_uniform" not in summary:
            raise ValueError(f"{run_dir}: not a wheel run with uniform among its policies")
        columns.append((float(exp["delta"]), exp, summary["normalised_by_uniform"]))
    columns.sort(key=lambda c: c[0])
    policies = list(columns[0][2])
    sizes = {(c[1]["num_seeds"], c[1]["horizon"]) for c in columns}
    lines = [f"Cumulative regret / Uniform's (seeds x T: "
             f"{', '.join(f'{s} x {t}' for s, t in sorted(sizes))}; paired seed-bootstrap "
             f"95% interval)", "",
             "| policy | " + " | ".join(f"δ = {d:g}" for d, _, _ in columns) + " |",
             "|---|" + "---|" * len(columns)]
    for policy in policies:
        cells = []
        for _, _, norm in columns:
            n = norm.get(policy)
            cells.append("–" if n is None else
                         f"{n['ratio']:.3f} [{n['ci95_bootstrap'][0]:.3f}, "
                         f"{n['ci95_bootstrap'][1]:.3f}]")
        lines.append(f"| {policy} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    print(wheel_table(sys.argv[1:]))
