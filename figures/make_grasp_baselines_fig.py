"""The baselines comparison, from ``experiments.grasp_baselines``' saved files only.

    python -m figures.make_grasp_baselines_fig [--out experiments/results/grasp_baselines]

* ``baselines_curves.png``: low-variance greedy success per round (round 0 = θ0) for each
  learner, mean over seeds of the mean over the objects, 95 % Student-t band over seeds;
  and, when the run had ``--regret-trials``, pseudo-regret per round.
* ``baselines_paired.png``: per metric, each learner minus SERN, paired over seeds, with its
  95 % t interval (n − 1 dof) and the Holm decision from ``summary.json``.

No numerics beyond means and intervals of the saved per-seed figures.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

__all__ = ["make_figures"]

_LABELS = {"explore_success": "exploration success (%)",
           "final_lowvar": "final low-variance greedy success (%)",
           "paper_eval_mean": "paper's 5-grasp evaluation, mean over rounds (%)",
           "pseudo_regret_per_round": "pseudo-regret per round (successes lost / 20 grasps)"}


def _band(x: np.ndarray):
    from sern_jax.analysis import stats

    ci = stats.t_interval(x, 0.95)
    return ci.mean, np.nan_to_num(ci.half)


def make_figures(out: str | Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    per_seed = dict(np.load(out / "per_seed.npz"))
    meta = json.loads((out / "meta.json").read_text())
    summary = json.loads((out / "summary.json").read_text())
    names = meta["learners"]
    n = meta["num_seeds"]
    paths = []

    regret = per_seed["pseudo_regret"][1:]
    has_regret = bool(meta.get("regret_trials")) and np.isfinite(regret).all()
    fig, axes = plt.subplots(1, 2 if has_regret else 1, figsize=(12 if has_regret else 7, 4.5),
                             squeeze=False)
    lowvar = 100.0 * per_seed["lowvar_eval"].mean(axis=1)  # [R + 1, Q, S]
    rounds = np.arange(lowvar.shape[0])
    for q, name in enumerate(names):
        m, h = _band(lowvar[:, q])
        style = {"lw": 2.5, "color": "k"} if name == summary["reference"] else {"lw": 1.2}
        axes[0, 0].plot(rounds, m, label=name, **style)
        axes[0, 0].fill_between(rounds, np.clip(m - h, 0, 100), np.clip(m + h, 0, 100),
                                alpha=0.08, color=style.get("color"))
    axes[0, 0].set_xticks(rounds)
    axes[0, 0].set(xlabel="round (0 = θ0)", ylabel="greedy success (%)",
                   title=f"low-variance greedy success, {len(meta['objects'])} objects, "
                         f"{n} seeds (95 % t band)")
    axes[0, 0].legend(fontsize=7, ncol=2)
    if has_regret:
        pr = regret.mean(axis=1)  # [R, Q, S]
        for q, name in enumerate(names):
            m, h = _band(pr[:, q])
            axes[0, 1].errorbar(np.arange(1, pr.shape[0] + 1) + 0.03 * q, m, h, label=name,
                                capsize=2)
        axes[0, 1].set(xlabel="round", ylabel="pseudo-regret per round",
                       title="pseudo-regret (oracle of --regret-trials trials)")
    fig.tight_layout()
    path = out / "baselines_curves.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    paths.append(path)

    metrics = list(summary["metrics"])
    fig, axes = plt.subplots(1, len(metrics), figsize=(4.5 * len(metrics), 4.5), squeeze=False)
    for ax, metric in zip(axes[0], metrics):
        scale = 1.0 if metric == "pseudo_regret_per_round" else 100.0
        rows = summary["metrics"][metric]["paired"]
        y = np.arange(len(rows))
        mean = np.array([r["mean"] for r in rows]) * scale
        half = np.array([r["half"] for r in rows]) * scale
        colors = ["C3" if r["resolved"] else "0.5" for r in rows]
        for yi, m, h, c in zip(y, mean, half, colors):
            ax.errorbar(m, yi, xerr=h, fmt="o", color=c, ecolor=c, capsize=3)
        ax.axvline(0, color="k", lw=0.8)
        ax.set_yticks(y, [r["name"] for r in rows], fontsize=7)
        ax.set_title(f"{_LABELS.get(metric, metric)}\n(red: sign resolved after Holm)",
                     fontsize=8)
    fig.suptitle(f"paired differences vs {summary['reference']}, {n} seeds, 95 % t intervals")
    fig.tight_layout()
    path = out / "baselines_paired.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    paths.append(path)
    return paths


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=Path("experiments/results/grasp_baselines"))
    for path in make_figures(p.parse_args(argv).out):
        print(path)


if __name__ == "__main__":
    main()
