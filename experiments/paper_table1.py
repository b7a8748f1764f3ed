"""Which statistic are the paper's Table I "(standard deviation)" cells?

Each Table I cell is a mean over 5 seeds of a success rate measured by 5 greedy evaluation
grasps, so each seed's rate is one of 0, 20, ..., 100 % and the cell's mean is a multiple of
4 %. Enumerating all 252 multisets of five such rates gives every value that each candidate
statistic can take, and every (mean, statistic) pair. A cell is *consistent* with a
statistic when its printed value (2 decimals) is one of those values, and *jointly
consistent* when one multiset gives both the printed mean (to the rounding of a whole
percent) and the printed value. Candidates: the population SD (ddof 0), the sample SD
(ddof 1), and the standard error sd / √5 with either.

    python -m experiments.paper_table1

The table below is transcribed from ``shared/paper/SERN-paper.txt`` (Table I: object,
algorithm, then mean % and the parenthesised value for rounds 1-5).
"""

from __future__ import annotations

import itertools
import math

import numpy as np

__all__ = ["PAPER_TABLE1", "STATISTICS", "possible_values", "check", "main"]

PAPER_TABLE1 = """\
Marjoram sern 52 4.90 72 10.20 88 6.32 75 11.66 75 6.32
Marjoram egreedy 72 4.90 55 4.90 61 9.80 76 10.20 70 6.32
Marjoram greedy 48 12.00 60 6.32 64 7.48 68 10.20 68 8.00
SaltCylinderSmall sern 68 10.20 60 10.95 56 9.80 56 11.66 76 11.66
SaltCylinderSmall egreedy 64 11.66 52 12.00 60 8.94 60 8.94 56 4.00
SaltCylinderSmall greedy 64 11.66 52 10.20 48 4.90 40 6.32 48 10.20
BathDetergent sern 36 13.27 48 13.56 48 8.00 60 6.32 64 7.48
BathDetergent egreedy 60 16.73 52 13.56 48 12.00 60 18.97 52 16.25
BathDetergent greedy 36 11.66 40 6.32 36 9.80 60 6.32 20 6.32
T-Less10 sern 56 7.48 74 10.20 52 14.14 71 12.00 81 7.48
T-Less10 egreedy 52 4.90 50 9.80 61 12.00 71 8.00 73 13.56
T-Less10 greedy 36 7.48 50 7.48 49 7.48 55 9.80 69 16.00
T-Less20 sern 72 8.00 60 10.95 60 6.32 72 10.20 84 4.00
T-Less20 egreedy 72 8.00 60 6.32 44 4.00 68 4.90 68 4.90
T-Less20 greedy 68 10.20 76 4.00 60 6.32 64 9.80 68 13.56
"""

STATISTICS = {
    "sd_pop": lambda x: x.std(),
    "sd_sample": lambda x: x.std(ddof=1),
    "se_sample": lambda x: x.std(ddof=1) / math.sqrt(len(x)),
    "se_pop": lambda x: x.std() / math.sqrt(len(x)),
}


def cells() -> list[tuple[str, str, int, float, float]]:
    """(object, algorithm, round, mean %, printed value) for the 75 cells."""
    out = []
    for line in PAPER_TABLE1.splitlines():
        f = line.split()
        vals = [float(v) for v in f[2:]]
        out += [(f[0], f[1], r + 1, vals[2 * r], vals[2 * r + 1]) for r in range(5)]
    return out


def possible_values(num_seeds: int = 5, num_grasps: int = 5) -> list[dict]:
    """Mean and each statistic (percent) of every multiset of per-seed success rates
    k / num_grasps, k = 0..num_grasps."""
    rows = []
    for ks in itertools.combinations_with_replacement(range(num_grasps + 1), num_seeds):
        x = 100.0 * np.asarray(ks, np.float64) / num_grasps
        rows.append({"mean": float(x.mean()), **{k: float(f(x)) for k, f in STATISTICS.items()}})
    return rows


def check(num_seeds: int = 5, num_grasps: int = 5) -> dict:
    """Cell-by-cell consistency of the printed values with each statistic."""
    poss = possible_values(num_seeds, num_grasps)
    grain = 100.0 / (num_seeds * num_grasps)  # means are multiples of this (4 %)
    table = cells()
    out = {"cells": len(table),
           "means_on_grid": sum(abs(m / grain - round(m / grain)) < 1e-9 for *_, m, _ in table),
           "statistics": {}}
    for name in STATISTICS:
        values = {round(p[name], 2) for p in poss}
        pairs = {(p["mean"], round(p[name], 2)) for p in poss}
        alone, joint, failing = 0, 0, []
        for obj, alg, r, mean, value in table:
            a = any(abs(v - value) < 0.006 for v in values)
            j = any(abs(pm - mean) <= 0.5 and abs(pv - value) < 0.006 for pm, pv in pairs)
            alone += a
            joint += j
            if not j:
                failing.append(f"{obj} {alg} round {r}: {mean:g} % (±{value:.2f})")
        out["statistics"][name] = {"value_possible": alone, "jointly_with_mean": joint,
                                   "not_joint": failing}
    smallest = sorted({round(p["se_sample"], 2) for p in poss})[:6]
    out["smallest_se_sample"] = smallest
    out["smallest_sd_pop"] = sorted({round(p["sd_pop"], 2) for p in poss})[:6]
    return out


def main(argv=None) -> int:
    from sern_jax.infra import validate

    # no flags of its own: anything else is one line, exit 2 (validate's parser); --help
    validate.script_parser(__spec__, description=__doc__.splitlines()[0]).parse_args(argv)
    res = check()
    print(f"{res['cells']} cells; means on the 4 % grid of 5 seeds x 5 grasps: "
          f"{res['means_on_grid']}")
    for name, s in res["statistics"].items():
        print(f"{name:>10s}: printed value possible in {s['value_possible']}/{res['cells']}, "
              f"jointly with the printed mean in {s['jointly_with_mean']}/{res['cells']}")
    print("smallest possible values: SE (ddof 1)", res["smallest_se_sample"],
          "; population SD", res["smallest_sd_pop"])
    print("cells not jointly consistent with SE (ddof 1):")
    for c in res["statistics"]["se_sample"]["not_joint"]:
        print("  " + c)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
