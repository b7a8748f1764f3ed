"""Figures of a ``sern grasp learn`` run, from its saved ``results.npz`` and ``config.json``.

* ``figures/success.png``: per object, greedy success per round (round 0 = θ0) for each policy,
  mean over seeds with a 95 % Student-t band over seeds (n − 1 dof; clipped to [0, 100] %),
  the paper's 5-grasp
  evaluation solid and the low-variance evaluation dashed where it was run.
* ``figures/paired.png``: per object and pooled, the final-round difference SERN − peer
  (low-variance evaluation where available) with paired 95 % confidence intervals over seeds.

No numerics beyond means and intervals of the saved per-seed figures.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["make_figures"]


def _band(x: np.ndarray):
    """Mean and 95 % Student-t half-width (n − 1 dof) over the last axis (seeds); zero
    width with one seed (no interval: the title says how many seeds)."""
    from sern_jax import stats

    n = x.shape[-1]
    mean = x.mean(-1)
    if n < 2:
        return mean, np.zeros_like(mean)
    return mean, np.asarray(stats.t_half_width(x.std(-1, ddof=1), n, 0.95))


def _fill(ax, x, m, h, **kwargs):
    """A band m ± h clipped to the possible range [0, 100] %."""
    ax.fill_between(x, np.clip(m - h, 0, 100), np.clip(m + h, 0, 100), **kwargs)


def make_figures(run_dir: str | Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sern_jax import io

    run_dir = Path(run_dir)
    res = io.load_npz(run_dir / "results.npz")
    cfg = io.load_json(run_dir / "config.json")
    objects = cfg["objects"]
    policies = cfg["config"]["policies"]
    paper = 100 * res["paper_eval"]  # [R+1, O, Q, S]
    lowvar = 100 * res["lowvar_eval"]
    has_lv = np.isfinite(lowvar).all()
    rounds = np.arange(paper.shape[0])
    num_o = len(objects)
    cols = min(num_o, 3)
    rows = int(np.ceil(num_o / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.2 * rows), squeeze=False)
    colours = {"sern": "C3", "sern_log": "C1", "egreedy": "C0", "greedy": "C2"}
    for o, name in enumerate(objects):
        ax = axes[o // cols][o % cols]
        for q, pol in enumerate(policies):
            c = colours.get(pol, f"C{q + 4}")
            m, h = _band(paper[:, o, q, :])
            ax.plot(rounds, m, "-o", color=c, ms=3, label=f"{pol} (paper eval)")
            _fill(ax, rounds, m, h, color=c, alpha=0.12)
            if has_lv:
                m, h = _band(lowvar[:, o, q, :])
                ax.plot(rounds, m, "--", color=c, lw=1.2, label=f"{pol} (low-variance)")
                _fill(ax, rounds, m, h, color=c, alpha=0.08)
        ax.set_title(name, fontsize=10)
        ax.set_xlabel("round (0 = θ0)")
        ax.set_ylabel("greedy success %")
        ax.set_ylim(-5, 105)
        ax.set_xticks(rounds)
    for k in range(num_o, rows * cols):
        axes[k // cols][k % cols].axis("off")
    axes[0][0].legend(fontsize=6, loc="lower right")
    seeds = paper.shape[-1]
    bands = ("95% t bands over seeds; a band of zero width means every seed gave the "
             "same value" if seeds > 1 else "one seed: no interval (no bands)")
    fig.suptitle(f"Greedy success per round, mean over {seeds} seed{'s' * (seeds > 1)}\n"
                 f"{bands}", fontsize=10)
    fig.tight_layout()
    out = [run_dir / "figures" / "success.png"]
    out[0].parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out[0], dpi=120, bbox_inches="tight")
    plt.close(fig)

    if "sern" in policies and len(policies) > 1 and seeds > 1:
        metric = lowvar if has_lv else paper
        label = "low-variance evaluation" if has_lv else "paper evaluation (5 grasps)"
        s = policies.index("sern")
        peers = [q for q in range(len(policies)) if q != s]
        fig, ax = plt.subplots(figsize=(6.5, 0.45 * (num_o + 1) * len(peers) + 1.2))
        y, ticks = 0, []
        for q in peers:
            for o in list(range(num_o)) + [None]:
                if o is None:
                    d = (metric[-1, :, s, :] - metric[-1, :, q, :]).mean(0)  # pooled per seed
                    name = "pooled"
                else:
                    d = metric[-1, o, s, :] - metric[-1, o, q, :]
                    name = objects[o]
                m, h = _band(d)
                ax.errorbar(m, y, xerr=h, fmt="o", color="C3" if o is None else "k", ms=4)
                ticks.append((y, f"SERN − {policies[q]}: {name}"))
                y += 1
            y += 0.5
        ax.axvline(0, color="grey", lw=0.8)
        ax.set_yticks([t[0] for t in ticks], [t[1] for t in ticks], fontsize=7)
        ax.invert_yaxis()
        ax.set_xlabel(f"final-round success difference, percentage points ({label})")
        ax.set_title(f"Paired differences over {seeds} seeds (common random numbers), "
                     "95% t intervals (unadjusted)",
                     fontsize=9)
        fig.tight_layout()
        out.append(run_dir / "figures" / "paired.png")
        fig.savefig(out[-1], dpi=120, bbox_inches="tight")
        plt.close(fig)
    return out
