"""Regret figures from a saved run directory (reads results only; no numerics beyond means:
α(T), Theorem 1's c and π_min come from the run's summary.json).

Usage: ``python -m figures.make_regret_figs RUN_DIR`` (``sern regret`` calls it for you).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from sern_jax.infra import io
from sern_jax.analysis import stats

__all__ = ["make_figures"]


def make_figures(run_dir: str | Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    run_dir = Path(run_dir)
    res = io.load_npz(run_dir / "results.npz")
    cfg = io.load_json(run_dir / "config.json")["experiment"]
    summary = io.load_json(run_dir / "summary.json")
    t = res["t"].astype(float)
    policies = cfg["policies"]
    out_dir = run_dir / "figures"
    out_dir.mkdir(exist_ok=True)
    written = []

    fig, ax = plt.subplots(figsize=(7, 5))
    for policy in policies:
        reg = res[f"{policy}__regret_rb"].astype(float)
        mean = reg.mean(0)
        n = reg.shape[0]
        half = (np.asarray(stats.t_half_width(reg.std(0, ddof=1), n, 0.95)) if n > 1
                else 0 * mean)  # Student t over seeds, n - 1 dof
        sl = summary["policies"][policy]["slope_last_decade"]
        line, = ax.plot(t, mean, label=f"{policy} (slope {sl['slope']:.2f})")
        ax.fill_between(t, np.maximum(mean - half, 1e-3), mean + half,
                        color=line.get_color(), alpha=0.25, linewidth=0)
    ax.plot(t, t * np.nanmax([res[f"{p}__regret_rb"][:, -1].mean() for p in policies])
            / t[-1], "k:", lw=1, label="linear reference")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("round t")
    ax.set_ylabel("cumulative pseudo-regret (Rao–Blackwellised)")
    ax.set_title(f"K={cfg['num_arms']}, {cfg['num_seeds']} seeds, α0={cfg['alpha0']} "
                 f"({cfg['schedule']}), ε={cfg['epsilon']}\nbands: 95% t interval of the mean"
                 f"{' (one seed: none)' if cfg['num_seeds'] < 2 else ''}; "
                 f"slopes over the last decade")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    path = out_dir / "regret.png"
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    written.append(path)

    if "softmax" in policies:
        counts = res["softmax__counts"].astype(float)  # [S, G, K]
        frac = counts.mean(0) / t[:, None]  # [G, K]
        k = counts.shape[-1]
        floor = summary.get("theorem1")  # saved by sern_jax/experiment/regret.py (absent in old runs)
        fig, ax = plt.subplots(figsize=(7, 5))
        means = res["means"].reshape(-1, k).mean(0)
        order = np.argsort(-means)
        cmap = plt.get_cmap("viridis")
        for rank, a in enumerate(order):
            ax.plot(t, np.maximum(frac[:, a], 1e-12), color=cmap(rank / max(k - 1, 1)), lw=1,
                    label=f"arm {a} (r={means[a]:.2f})" if k <= 12 else None)
        if floor is not None:
            c, pi_min = floor["c"], floor["pi_min"]
            ax.axhline(c, color="r", ls="--",
                       label=f"Theorem 1 floor c = e^(-1/α)/K = {c:.2e}")
            ax.axhline(pi_min, color="m", ls=":", label=f"exact π_min = {pi_min:.2e}")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("round t")
        ax.set_ylabel("E[N_a(t)] / t (mean over seeds)")
        ax.set_title("SERN softmax exploration"
                     + (f", α = {floor['alpha']:.3g}" if floor is not None else ""))
        ax.legend(fontsize=7)
        ax.grid(True, which="both", alpha=0.3)
        fig.tight_layout()
        path = out_dir / "exploration.png"
        fig.savefig(path, dpi=120, bbox_inches="tight")
        plt.close(fig)
        written.append(path)
    return written


if __name__ == "__main__":
    for p in make_figures(sys.argv[1]):
        print(p)
