"""Assumption 3 and Δ2 on the grasp pipeline, from experiments/theory_on_grasping.py.

    python -m figures.make_theory_grasping_fig runs/theory_grasping
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np


def make_figure(run_dir: str | Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sern_jax import io

    run_dir = Path(run_dir)
    res = io.load_json(run_dir / "results.json")
    ns = np.asarray(res["ns"], float)
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    for i, (name, row) in enumerate(res["objects"].items()):
        m, s = np.asarray(row["error_mean"]), np.asarray(row["error_sd"])
        ax1.errorbar(ns + 1, m, yerr=s, fmt="-o", ms=3, color=f"C{i}", label=name)
    t = res["theory"]
    ref = t["beta_fit"] / np.sqrt(ns + 1)
    ax1.plot(ns + 1, ref, "k--", lw=1, label=f"β/√(n+1), β = {t['beta_fit']:.2f}")
    ax1.set_xscale("log")
    ax1.set_yscale("log")
    ax1.set_xlabel("n + 1 (labelled grasps of the object used to fine-tune θ0, + 1)")
    ax1.set_ylabel("mean |r̂ − r| over valid candidates")
    ax1.set_title(f"Assumption 3 on the network (pooled log-log slope "
                  f"{t['loglog_slope_pooled']:+.2f}; the assumption: −0.5)", fontsize=9)
    ax1.legend(fontsize=6)
    d2 = np.concatenate([row["delta2"] for row in res["objects"].values()])
    ax2.hist(d2, bins=np.linspace(0, max(0.05, d2.max()) + 1e-9, 21), color="C0")
    ax2.set_xlabel("Δ2(s) = best − second-best candidate success (per context)")
    ax2.set_ylabel("contexts")
    ax2.set_title(f"Δ2 over contexts: median {t['delta2_median_pooled']:.3f}, zero in "
                  f"{100 * t['delta2_zero_fraction_pooled']:.0f}%", fontsize=9)
    fig.tight_layout()
    out = run_dir / "theory_grasping.png"
    fig.savefig(out, dpi=130, bbox_inches="tight")
    plt.close(fig)
    return out


if __name__ == "__main__":
    print(make_figure(sys.argv[1] if len(sys.argv) > 1 else "runs/theory_grasping"))
