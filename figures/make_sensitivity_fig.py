"""Heat maps of the sensitivity grid, from ``experiments.grasp_sensitivity``'s summary.json.

Panels: SERN − greedy and SERN − ε-greedy (final-round fixed-pose success, pooled over
the objects, mean over seeds, percentage points) per cell, each annotated with its 95 %
Student-t half-width over seeds and a star where the sign is resolved after Holm over all
the grid's comparisons (the colour scale runs to the largest |mean| + half-width, so no
unresolved mean gets the strongest colour); a third panel gives θ0's success in each world (round 0) and the
greedy policy's after the last round (sim-to-sim transfer). Cells not run are grey.

Usage: ``python -m figures.make_sensitivity_fig RUN_DIR [OUT.png]``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

__all__ = ["make_figure"]

_FORCES = {"20N trial": ("20N", "10N"), None: ("6N", "20N")}  # by summary["grid"]
_ROWS = (("mu0.3-0.8", "clean"), ("mu0.3-0.8", "d435"), ("mu0.2-0.5", "clean"),
         ("mu0.2-0.5", "d435"))


def _label(row) -> str:
    mu, noise = row
    lo, hi = mu[2:].split("-")
    return f"μ~U[{lo}, {hi}]\n{'D435 noise' if noise == 'd435' else 'no depth noise'}"


def make_figure(run_dir: str | Path, out: str | Path | None = None) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sern_jax.infra import io

    run_dir = Path(run_dir)
    summary = io.load_json(run_dir / "summary.json")
    cells = summary["cells"]
    seeds = sorted({c["seeds"] for c in cells.values()})
    # today's grid (20 N and 10 N) or the previous trial's record (6 N and 20 N, 6 N θ0)
    forces = _FORCES[summary.get("grid")]
    fig, axes = plt.subplots(1, 3, figsize=(13.5, 4.6))
    lim = 0.0
    grids = {}
    for peer in ("greedy", "egreedy"):
        m = np.full((len(_ROWS), len(forces)), np.nan)
        for i, row in enumerate(_ROWS):
            for j, f in enumerate(forces):
                c = cells.get(f"{f}_{row[0]}_{row[1]}")
                if c is not None:
                    comp = c["comparisons"][f"sern - {peer}"]
                    m[i, j] = 100 * comp["mean"]
                    # the colour scale reaches the widest interval's end, so an unresolved
                    # mean is never drawn in the strongest colour
                    lim = max(lim, 100 * (abs(comp["mean"]) + comp["half"]))
        grids[peer] = m
    lim = max(lim, 1.0)
    cmap = matplotlib.colormaps["RdBu"].copy()
    cmap.set_bad("0.85")
    for ax, peer, title in ((axes[0], "greedy", "SERN − greedy"),
                            (axes[1], "egreedy", "SERN − ε-greedy")):
        im = ax.imshow(np.ma.masked_invalid(grids[peer]), cmap=cmap, vmin=-lim, vmax=lim,
                       aspect="auto")
        for i, row in enumerate(_ROWS):
            for j, f in enumerate(forces):
                c = cells.get(f"{f}_{row[0]}_{row[1]}")
                if c is None:
                    ax.text(j, i, "not run", ha="center", va="center", fontsize=8)
                    continue
                comp = c["comparisons"][f"sern - {peer}"]
                ax.text(j, i, f"{100 * comp['mean']:+.1f}\n± {100 * comp['half']:.1f}"
                        f"{' *' if comp['resolved'] else ''}", ha="center", va="center",
                        fontsize=9,
                        color="w" if abs(100 * comp["mean"]) > 0.6 * lim else "k")
        ax.set_xticks(range(len(forces)), [f"{f[:-1]} N per finger" for f in forces])
        ax.set_yticks(range(len(_ROWS)), [_label(r) for r in _ROWS], fontsize=8)
        ax.set_title(f"{title}, points", fontsize=10)
        fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04)
    ax = axes[2]
    t = np.full((len(_ROWS), len(forces)), np.nan)
    for i, row in enumerate(_ROWS):
        for j, f in enumerate(forces):
            c = cells.get(f"{f}_{row[0]}_{row[1]}")
            if c is not None:
                t[i, j] = 100 * c["policies"]["greedy"]["lowvar_by_round"][0]
    cmap_t = matplotlib.colormaps["viridis"].copy()
    cmap_t.set_bad("0.85")
    im = ax.imshow(np.ma.masked_invalid(t), cmap=cmap_t, vmin=0,
                   vmax=100, aspect="auto")
    for i, row in enumerate(_ROWS):
        for j, f in enumerate(forces):
            c = cells.get(f"{f}_{row[0]}_{row[1]}")
            if c is None:
                ax.text(j, i, "not run", ha="center", va="center", fontsize=8)
                continue
            lv = c["policies"]["greedy"]["lowvar_by_round"]
            ax.text(j, i, f"θ0 {100 * lv[0]:.0f} %\n→ {100 * lv[-1]:.0f} %", ha="center",
                    va="center", fontsize=9, color="w" if lv[0] < 0.6 else "k")
    ax.set_xticks(range(len(forces)), [f"{f[:-1]} N per finger" for f in forces])
    ax.set_yticks(range(len(_ROWS)), [_label(r) for r in _ROWS], fontsize=8)
    ax.set_title("transfer: θ0 in each world → greedy after\nthe last round (success %)",
                 fontsize=10)
    fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04)
    n = "/".join(str(s) for s in seeds)
    trial = ("θ0 of the 20 N trial" if summary.get("grid") else
             "previous trial: θ0 of the 6 N trial")
    num = sum(len(c["comparisons"]) for c in cells.values())
    fig.suptitle(f"Sensitivity of the final-round comparison ({trial}; fixed-pose evaluation, "
                 f"pooled over the hard set; {n} seeds; 95 % t intervals; * = resolved after "
                 f"Holm over all {num} comparisons)", fontsize=9)
    fig.tight_layout()
    out = Path(out) if out else run_dir / "sensitivity.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return out


if __name__ == "__main__":
    print(make_figure(sys.argv[1], sys.argv[2] if len(sys.argv) > 2 else None))
