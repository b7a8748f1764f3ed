"""Forgetting against adaptation for each core set, from experiments/core_set_forgetting.py.

    python -m figures.make_forgetting_fig runs/forgetting   # -> runs/forgetting/forgetting.png
    python -m figures.make_forgetting_fig experiments/results/forgetting \
        docs/img/core_set_forgetting.png                     # the figure docs/RESULTS.md shows
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np


def make_figure(run_dir: str | Path, out: str | Path | None = None) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sern_jax.infra import io

    run_dir = Path(run_dir)
    res = io.load_json(run_dir / "results.json")
    fig, ax = plt.subplots(figsize=(5.2, 4.2))
    t0 = res["theta0"]
    ax.scatter(t0["new"]["roc_auc"], t0["d0"]["roc_auc"], marker="*", s=160, c="k",
               label="θ0 (before fine-tuning)")
    colours = {"none": "C0", "random": "C2", "dpp": "C3"}
    for kind in ("none", "random", "dpp"):
        rows = res.get(kind, [])
        x = np.array([r["new"]["roc_auc"] for r in rows])
        y = np.array([r["d0"]["roc_auc"] for r in rows])
        ax.scatter(x, y, c=colours[kind], alpha=0.5, s=18)
        ax.errorbar(x.mean(), y.mean(), xerr=x.std(ddof=1), yerr=y.std(ddof=1), fmt="o",
                    c=colours[kind],
                    ms=7, label=f"core set: {kind} (mean ± sd over {len(rows)} seeds)")
    ax.set_xlabel("ROC-AUC on the new object's held-out poses (adaptation)")
    ax.set_ylabel("ROC-AUC on D0-like objects (higher = less forgetting)")
    cfg = run_dir / "config.json"
    obj = io.load_json(cfg)["args"]["object"] if cfg.exists() else "one hard object"
    ax.set_title(f"Fine-tuning θ0 on {obj} (one-trial labels)", fontsize=10)
    ax.legend(fontsize=7)
    fig.tight_layout()
    out = Path(out) if out else run_dir / "forgetting.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=130, bbox_inches="tight")
    plt.close(fig)
    return out


if __name__ == "__main__":
    print(make_figure(sys.argv[1] if len(sys.argv) > 1 else "runs/forgetting",
                      sys.argv[2] if len(sys.argv) > 2 else None))
