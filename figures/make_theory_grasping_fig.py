"""Assumption 3 per context and Δ2 at several trial counts on the grasp pipeline, from the
``results.json`` and ``per_context.npz`` of experiments/theory_on_grasping.py.

Panels: (a) the network's error against n + 1, one line per context (seed means), corrected
for the ground truth's binomial error, beside the uncorrected median and the ground truth's
own error (the floor); (b) the per-context β_s = sup_n err_s(n)·√(n + 1), with β > 1 marked
vacuous at n = 0; (c) the per-context log-log slope against Assumption 3's −1/2; (d) Δ2 per
context at each trial count M.

Usage: ``python -m figures.make_theory_grasping_fig RUN_DIR [OUT.png]``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

__all__ = ["make_figure"]


def make_figure(run_dir: str | Path, out: str | Path | None = None) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sern_jax.infra import io

    run_dir = Path(run_dir)
    res = io.load_json(run_dir / "results.json")
    z = np.load(run_dir / "per_context.npz")
    ns = np.asarray(z["ns"], float)
    err, raw, floor = z["err"].mean(-1), z["err_raw"].mean(-1), z["floor"]  # [O, C, n], [O, C]
    names = [str(n) for n in z["objects"]]
    summ = res["summary"]
    fig, axes = plt.subplots(2, 2, figsize=(11, 8))
    ax = axes[0, 0]
    for i, name in enumerate(names):
        for c in range(err.shape[1]):
            ax.plot(ns + 1, np.maximum(err[i, c], 1e-3), "-", lw=0.8, color=f"C{i}",
                    alpha=0.7, label=name if c == 0 else None)
    ax.plot(ns + 1, np.median(raw.reshape(-1, len(ns)), 0), "k:", lw=1.5,
            label="uncorrected, median over contexts")
    lo, hi = float(floor.min()), float(floor.max())
    ax.axhspan(lo, hi, color="0.85", zorder=0,
               label=f"ground truth's own error (floor) {lo:.3f}-{hi:.3f}")
    b = summ["beta_ctx_median"]
    grid = np.geomspace(1, ns[-1] + 1, 200)
    ax.plot(grid, np.where(b / np.sqrt(grid) <= 1, b / np.sqrt(grid), np.nan), "k--", lw=1,
            label=f"β/√(n+1), median β_s = {b:.2f}")
    if b > 1:
        ax.axvspan(1, min(b * b, ns[-1] + 1), color="r", alpha=0.07,
                   label=f"n + 1 < β² = {b * b:.0f}: the median bound is above 1 (vacuous)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("n + 1 (labelled grasps of the object used to fine-tune θ0, + 1)")
    ax.set_ylabel("RMS |r̂ − r| over a context's valid candidates\n"
                  "(binomial variance of r's estimate subtracted; 1e-3 = corrected to 0)")
    ax.set_title("(a) Assumption 3 per context (lines: seed means)", fontsize=9)
    # room below the lowest line and the floor, so the legend covers no data
    low = min(lo, float(np.nanmin(np.maximum(err, 1e-3))))
    ax.set_ylim(low / 8, ax.get_ylim()[1])
    ax.legend(fontsize=6, loc="lower left", ncol=2)
    ax = axes[0, 1]
    bc = np.concatenate([v["beta_ctx"] for v in summ["per_object"].values()])
    ax.hist(bc, bins=20, color="C0")
    ax.yaxis.get_major_locator().set_params(integer=True)
    ax.axvline(1.0, color="r", lw=1,
               label="β = 1: right of it β/√(n+1) > 1 at n = 0 (vacuous there)")
    ax.legend(fontsize=7, loc="upper left")
    ax.set_ylim(0, ax.get_ylim()[1] * 1.25)  # room for the legend above the bars
    ax.set_xlabel("β_s = sup_n err_s(n)·√(n + 1) (per context)")
    ax.set_ylabel("contexts")
    ax.set_title(f"(b) β per context: median {b:.2f}, range {summ['beta_ctx_min']:.2f}-"
                 f"{summ['beta_ctx_max']:.2f}", fontsize=9)
    ax = axes[1, 0]
    sc = np.concatenate([v["slope_ctx"] for v in summ["per_object"].values()])
    ax.hist(sc, bins=20, color="C1")
    ax.yaxis.get_major_locator().set_params(integer=True)
    ax.axvline(-0.5, color="k", ls="--", lw=1, label="Assumption 3: −1/2")
    ax.set_xlabel("log-log slope of err_s(n) against n + 1, n ≥ 10 (per context)")
    ax.set_ylabel("contexts")
    ax.set_title(f"(c) slope per context: median {summ['slope_ctx_median']:+.2f} "
                 f"(uncorrected {summ['slope_ctx_raw_median']:+.2f})", fontsize=9)
    ax.legend(fontsize=7)
    ax = axes[1, 1]
    d2 = z["delta2"].reshape(-1, z["delta2"].shape[-1])
    d2 = d2[~np.isnan(d2).any(1)]
    ms = [int(m) for m in z["delta2_ms"]]
    rng = np.random.default_rng(0)
    for j, m in enumerate(ms):
        ax.scatter(j + rng.uniform(-0.15, 0.15, len(d2)), d2[:, j], s=10, color=f"C{j}")
    top = max(0.05, float(d2.max()) * 1.15)
    for j, m in enumerate(ms):
        ax.text(j, top * 0.97, f"zero in {100 * summ['delta2'][str(m)]['zero_fraction']:.0f}%\n"
                f"median {summ['delta2'][str(m)]['median']:.3f}", ha="center", va="top",
                fontsize=7)
    ax.set_ylim(-0.01, top)
    ax.set_xticks(range(len(ms)), [f"M = {m}" for m in ms])
    ax.set_ylabel("Δ2(s) = best − second-best frequency of M trials")
    sp = summ["delta2_split"]
    ax.set_title(f"(d) Δ2 per context. Best vs second ranked on one half of the deep trials,\n"
                 f"valued on the other ({sp['trials_per_half']} trials): gap resolved in "
                 f"{sp['resolved_holm']}/{sp['contexts']} contexts (Holm, 5 %)", fontsize=9)
    fig.tight_layout()
    out = Path(out) if out else run_dir / "theory_grasping.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return out


if __name__ == "__main__":
    if len(sys.argv) < 2:
        raise SystemExit("usage: python -m figures.make_theory_grasping_fig RUN_DIR [OUT.png]")
    print(make_figure(sys.argv[1], sys.argv[2] if len(sys.argv) > 2 else None))
