"""Figures of grasp learning runs: from a ``sern grasp learn`` run directory (its
``results.npz`` and ``config.json``) or from the committed per-seed results of
``experiments.grasp_learning`` (``experiments/results/<setting>/``).

* ``success.png``: per object, greedy success per round (round 0 = θ0) for each policy,
  mean over seeds with a 95 % Student-t band over seeds (n − 1 dof; clipped to [0, 100] %),
  the paper's 5-grasp evaluation solid and the fixed-pose evaluation dashed where it was run.
* ``paired.png``: per object and pooled, the final-round difference SERN − peer (fixed-pose
  evaluation where available) with paired 95 % t intervals over seeds (unadjusted).
* ``ablations.png`` (``--ablations``): per ablation, each variant's pooled final-round
  fixed-pose success minus the paper configuration's, paired 95 % t intervals over seeds.

    python -m figures.make_learn_figs experiments/results/paper docs/img/table1
    python -m figures.make_learn_figs experiments/results/strong docs/img/strong
    python -m figures.make_learn_figs --ablations experiments/results docs/img/ablations.png

(the first two write ``<prefix>_success.png`` and ``<prefix>_paired.png``). No numerics
beyond means and intervals of the saved per-seed figures.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["make_figures", "figures_from_results", "ablation_figure", "main"]
ABLATIONS = ("alpha", "core_set", "loss", "schedule")


def _band(x: np.ndarray):
    """Mean and 95 % Student-t half-width (n − 1 dof) over the last axis (seeds); zero
    width with one seed (no interval: the title says how many seeds)."""
    from sern_jax.analysis import stats

    n = x.shape[-1]
    mean = x.mean(-1)
    if n < 2:
        return mean, np.zeros_like(mean)
    return mean, np.asarray(stats.t_half_width(x.std(-1, ddof=1), n, 0.95))


def _fill(ax, x, m, h, **kwargs):
    """A band m ± h clipped to the possible range [0, 100] %."""
    ax.fill_between(x, np.clip(m - h, 0, 100), np.clip(m + h, 0, 100), **kwargs)


def make_figures(run_dir: str | Path) -> list[Path]:
    """``<run_dir>/figures/success.png`` and ``paired.png`` of a ``sern grasp learn`` run."""
    from sern_jax.infra import io

    run_dir = Path(run_dir)
    res = io.load_npz(run_dir / "results.npz")
    cfg = io.load_json(run_dir / "config.json")
    return _plot(res["paper_eval"], res["lowvar_eval"], cfg["objects"],
                 cfg["config"]["policies"], run_dir / "figures" / "success.png",
                 run_dir / "figures" / "paired.png")


def figures_from_results(results_dir: str | Path, prefix: str | Path) -> list[Path]:
    """``<prefix>_success.png`` and ``<prefix>_paired.png`` from a setting's per-seed
    files (one run label: paper, strong, regret)."""
    from sern_jax.commands.scripts import script_module
    grasp_learning = script_module("experiments", "grasp_learning")

    docs = grasp_learning.load_results(results_dir)
    if len(docs) != 1:
        raise ValueError(f"{results_dir} holds {len(docs)} runs; name one setting's directory")
    d = next(iter(docs.values()))
    prefix = Path(prefix)
    return _plot(d["paper_eval"], d["lowvar_eval"], d["objects"], d["policies"],
                 prefix.with_name(prefix.name + "_success.png"),
                 prefix.with_name(prefix.name + "_paired.png"))


def _plot(paper, lowvar, objects, policies, success_png: Path, paired_png: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paper = 100 * np.asarray(paper, np.float64)  # [R+1, O, Q, S]
    lowvar = 100 * np.asarray(lowvar, np.float64)
    objects, policies = list(objects), list(policies)
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
                ax.plot(rounds, m, "--", color=c, lw=1.2, label=f"{pol} (fixed-pose)")
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
    out = [Path(success_png)]
    out[0].parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out[0], dpi=120, bbox_inches="tight")
    plt.close(fig)

    if "sern" in policies and len(policies) > 1 and seeds > 1:
        metric = lowvar if has_lv else paper
        label = "fixed-pose evaluation" if has_lv else "paper evaluation (5 grasps)"
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
                     "95% t intervals (unadjusted)\n(an interval of zero width: the same "
                     "difference on every seed)", fontsize=9)
        fig.tight_layout()
        out.append(Path(paired_png))
        fig.savefig(out[-1], dpi=120, bbox_inches="tight")
        plt.close(fig)
    return out


def ablation_figure(results_root: str | Path, out_png: str | Path) -> Path:
    """Each ablation's variants against its first variant, pooled final-round fixed-pose
    success, paired 95 % t intervals over seeds (from the settings' summary files, which
    ``experiments.grasp_learning summarise`` rebuilds from the per-seed files)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sern_jax.commands.scripts import script_module
    grasp_learning = script_module("experiments", "grasp_learning")

    rows = []
    for name in ABLATIONS:
        d = Path(results_root) / name
        if not d.exists():
            continue
        s = grasp_learning.summarise(d, write=False)
        for c in s["comparisons"].get("final_round", []):
            if c["name"].endswith("fixed-pose, pooled"):
                rows.append((name, c))
    if not rows:
        raise ValueError(f"no ablation results under {results_root}")
    fig, ax = plt.subplots(figsize=(7, 0.42 * len(rows) + 1.4))
    for y, (name, c) in enumerate(rows):
        ax.errorbar(100 * c["mean"], y, xerr=100 * c["half"], fmt="o", color="k", ms=4)
    labels = [f"{name}: {grasp_learning._short(c['name']).split(', fixed-pose')[0]}"
              for name, c in rows]
    ax.set_yticks(range(len(rows)), labels, fontsize=7)
    ax.invert_yaxis()
    ax.axvline(0, color="grey", lw=0.8)
    n = rows[0][1]["n"]
    ax.set_xlabel("final-round success difference, percentage points (fixed-pose, pooled)")
    ax.set_title(f"Ablations: variant − the paper's configuration (schedule: SERN − "
                 f"sern_log),\npaired over {n} seeds, 95% t intervals (unadjusted)", fontsize=9)
    fig.tight_layout()
    out = Path(out_png)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return out


def main(argv=None) -> int:
    import argparse

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--ablations", action="store_true")
    p.add_argument("results")
    p.add_argument("out")
    a = p.parse_args(argv)
    paths = ([ablation_figure(a.results, a.out)] if a.ablations
             else figures_from_results(a.results, a.out))
    for f in paths:
        print(f"wrote {f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
