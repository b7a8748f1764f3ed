"""Sim-to-sim transfer figure, from the per-seed files of
``experiments.grasp_sensitivity transfer`` (``experiments/results/transfer/``).

One panel per world B: each policy's fixed-pose greedy success per round (round 0 = θ0),
pooled over the objects, mean over seeds with a 95 % Student-t band over seeds (n − 1 dof,
clipped to [0, 100] %); the dotted line is θ0's success in world A (the level the gap is
measured from), the grey line SERN learning in world A itself.

    python -m figures.make_transfer_fig experiments/results/transfer docs/img/transfer.png
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

__all__ = ["make_figure"]

COLOURS = {"sern": "C3", "egreedy": "C0", "greedy": "C2"}


def make_figure(results_dir: str | Path, out_png: str | Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sern_jax.commands.scripts import script_module
    grasp_learning = script_module("experiments", "grasp_learning")
    from .make_learn_figs import _band, _fill

    docs = grasp_learning.load_results(results_dir)
    if "A" not in docs:
        raise ValueError(f"{results_dir} has no world-A cell")
    a = docs["A"]
    theta_a = 100 * a["lowvar_eval"][0, :, 0, :].mean(0)  # [S]
    cells = list(docs)
    cols = min(len(cells), 4)
    rows = int(np.ceil(len(cells) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 3.0 * rows), squeeze=False)
    for k, cell in enumerate(cells):
        d = docs[cell]
        ax = axes[k // cols][k % cols]
        lv = 100 * d["lowvar_eval"][:d["rounds_done"] + 1]  # [R+1, O, Q, S]
        x = np.arange(lv.shape[0])
        for q, pol in enumerate(d["policies"]):
            m, h = _band(lv[:, :, q, :].mean(1))
            c = COLOURS.get(pol, f"C{q + 4}")
            ax.plot(x, m, "-", color=c, lw=1.2, label=pol)
            _fill(ax, x, m, h, color=c, alpha=0.12)
        if cell != "A" and "sern" in a["policies"]:
            la = 100 * a["lowvar_eval"][:a["rounds_done"] + 1, :, a["policies"].index("sern"), :]
            ax.plot(np.arange(la.shape[0]), la.mean((1, 2)), "-", color="grey", lw=0.8,
                    label="sern in A")
        ax.axhline(theta_a.mean(), color="k", ls=":", lw=0.8, label="θ0 in A")
        stopped = (f" (stopped after round {d['rounds_done']})"
                   if d["rounds_done"] < d["rounds"] else "")
        ax.set_title(f"{cell}{stopped}", fontsize=9)
        ax.set_xlabel("round (0 = θ0)", fontsize=8)
        ax.set_ylabel("fixed-pose success %", fontsize=8)
        ax.set_ylim(0, 100)
        ax.tick_params(labelsize=7)
    for k in range(len(cells), rows * cols):
        axes[k // cols][k % cols].axis("off")
    axes[0][0].legend(fontsize=6, loc="lower right")
    fig.suptitle(f"Transfer: θ0 from world A learning online in world B; {len(a['objects'])} "
                 f"objects pooled, mean over {a['seeds']} seeds, 95% t bands over seeds\n"
                 "(a band of zero width: every seed gave the same value)", fontsize=9)
    fig.tight_layout()
    out = Path(out_png)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return out


if __name__ == "__main__":
    if len(sys.argv) != 3:
        raise SystemExit("usage: python -m figures.make_transfer_fig RESULTS_DIR OUT.png")
    print(f"wrote {make_figure(sys.argv[1], sys.argv[2])}")
