"""The grasp-exploration benchmark's figures, from its ``summary.json`` only.

    python -m figures.benchmark [experiments/results/benchmark/summary.json] [--out docs/img]

* ``benchmark_curves.png``: each learner's fixed-pose greedy success per round (round 0 =
  θ0), mean over objects of the objects' means over seeds, band ± the 95 % Student-t
  half-width over the object means (objects − 1 degrees of freedom);
* ``benchmark_forest.png``: per other learner, the reference minus that learner on
  ``curve_area`` (mean fixed-pose greedy success over rounds 1..R) per object (95 % t over
  seeds) and, below the objects, over objects (95 % t over the object means, Holm p of the
  primary family).

No numerics beyond reading the summary (``experiments/benchmark.py`` computes it).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

__all__ = ["make_figures", "main"]

ROOT = Path(__file__).resolve().parents[1]
NAMES = {"sern": "SERN", "egreedy": "ε-greedy", "greedy": "greedy",
         "ensemble_ts": "ensemble TS", "neural_lints": "Neural-Linear Thompson",
         "neural_linucb": "Neural-Linear UCB", "neural_ucb": "NeuralUCB"}


def _name(k: str) -> str:
    return NAMES.get(k, k)


def make_figures(summary_path: str | Path, out: str | Path) -> list[Path]:
    """Draws both figures into the folder ``out``; returns their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = json.loads(Path(summary_path).read_text())
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ref = s["reference"]
    head = (f"{s['benchmark']['name']} v{s['benchmark']['version']}: "
            f"{len(s['objects'])} objects, {s['seeds']} seeds")
    paths = []

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for q, learner in enumerate(s["learners"]):
        pts = s["curves"][learner]
        rounds = sorted(int(r) for r in pts)
        m = [pts[str(r)]["mean"] for r in rounds]
        h = [pts[str(r)]["half"] or 0.0 for r in rounds]
        style = {"lw": 2.5, "color": "k"} if learner == ref else {"lw": 1.3, "color": f"C{q}"}
        ax.plot(rounds, m, label=_name(learner), **style)
        ax.fill_between(rounds, [max(a - b, 0.0) for a, b in zip(m, h)],
                        [min(a + b, 100.0) for a, b in zip(m, h)], alpha=0.12,
                        color=style["color"])
    ax.set_xticks(rounds)
    ax.set(xlabel="round (0 = θ0)", ylabel="fixed-pose greedy success (%)",
           title=f"{head}\nmean over objects, band: 95 % t over the object means")
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = out / "benchmark_curves.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    paths.append(path)

    peers = [q for q in s["learners"] if q != ref]
    objects = s["objects"]
    fig, axes = plt.subplots(1, len(peers), figsize=(3.6 * len(peers), 1.2 + 0.32 * len(objects)),
                             squeeze=False, sharey=True)
    for ax, peer in zip(axes[0], peers):
        rows = {r["object"]: r for r in s["per_object"]
                if r["metric"] == "curve_area" and r["b"] == peer}
        overall = next(c for c in s["comparisons"]
                       if c["metric"] == "curve_area" and c["b"] == peer)
        for y, o in enumerate(objects):
            r = rows[o]
            lo = r["ci_low"] if r["ci_low"] is not None else r["diff"]
            hi = r["ci_high"] if r["ci_high"] is not None else r["diff"]
            ax.errorbar(r["diff"], y, xerr=[[r["diff"] - lo], [hi - r["diff"]]], fmt="o",
                        color="0.3", ms=4, capsize=2)
        y = len(objects) + 0.5
        resolved = overall["holm_p"] < 0.05
        color = "C3" if resolved else "k"
        ax.errorbar(overall["diff"], y, xerr=[[overall["diff"] - overall["ci_low"]],
                                               [overall["ci_high"] - overall["diff"]]],
                    fmt="D", color=color, ms=7, capsize=3)
        ax.axvline(0, color="k", lw=0.8)
        ax.set_title(f"{_name(ref)} − {_name(peer)}\nHolm p {overall['holm_p']:.2g}",
                     fontsize=9)
        ax.set_xlabel("curve area difference (points)")
    axes[0, 0].set_yticks(list(range(len(objects))) + [len(objects) + 0.5],
                          objects + ["over objects"], fontsize=7)
    axes[0, 0].invert_yaxis()
    fig.suptitle(f"{head}; per object: 95 % t over seeds; over objects: 95 % t over the "
                 "object means (red: resolved after Holm)", fontsize=9)
    fig.tight_layout()
    path = out / "benchmark_forest.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    paths.append(path)
    return paths


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m figures.benchmark",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("summary", nargs="?", type=Path,
                    default=ROOT / "experiments" / "results" / "benchmark" / "summary.json")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "img")
    args = ap.parse_args(argv)
    if not args.summary.is_file():
        ap.error(f"summary: no such file {args.summary}")
    for path in make_figures(args.summary, args.out):
        print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
