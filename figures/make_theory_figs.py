"""Theory-check figures from a saved ``sern check`` run directory (reads results only).

Usage: ``python -m figures.make_theory_figs RUN_DIR`` (``sern check`` calls it for you). Reads
``RUN_DIR/figure_data.json`` (written by proofs_check) and writes ``RUN_DIR/figures/*.png``.
Every number plotted was computed by the checks; this module only draws.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from sern_jax.infra import io

__all__ = ["make_all"]


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path, written: list) -> None:
    fig.tight_layout()
    fig.savefig(path, dpi=120, bbox_inches="tight")
    written.append(path)
    import matplotlib.pyplot as plt

    plt.close(fig)


def fig_counts(data, out, written):
    """N_a(t)/t (least and most pulled arm) vs t, with c and π_min."""
    plt = _plt()
    curves = data["curves"]
    ks = sorted({c["K"] for c in curves})
    est0 = curves[0]["est"]
    fig, axes = plt.subplots(1, len(ks), figsize=(5 * len(ks), 4), squeeze=False)
    for ax, K in zip(axes[0], ks):
        for i, c in enumerate([c for c in curves if c["K"] == K and c["est"] == est0]):
            col = f"C{i}"
            ax.plot(c["times"], c["frac_min"], color=col, label=f"α={c['alpha']:g}: min_a N_a/t")
            ax.plot(c["times"], c["frac_max"], color=col, ls=":", alpha=0.6)
            ax.axhline(c["c"], color=col, ls="--", lw=1)
            ax.axhline(c["pi_min"], color=col, ls="-.", lw=1)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("t")
        ax.set_ylabel("mean N_a(t)/t")
        ax.set_title(f"{est0}, K={K}: dashed c = e^(-1/α)/K, dash-dot π_min")
        ax.legend(fontsize=7)
    _save(fig, out / "counts_vs_c.png", written)


def fig_tail(data, out, written):
    plt = _plt()
    curves = data["curves"]
    fig, axes = plt.subplots(1, len(curves), figsize=(4.5 * len(curves), 4), squeeze=False)
    for ax, c in zip(axes[0], curves):
        x = np.asarray(c["delta"]) / np.sqrt(c["t"])
        emp = np.asarray(c["emp"])
        ax.semilogy(x, np.where(emp > 0, emp, np.nan), "k.-", label="MC P(N < ct − δ)")
        ax.semilogy(x, c["paper"], label="paper e^(−δ²/8t)")
        ax.semilogy(x, c["azuma"], label="Azuma e^(−2δ²/t)")
        fr = np.asarray(c["freedman"])
        ok = np.asarray(c["delta"]) <= c["c"] * c["t"]
        ax.semilogy(x[ok], fr[ok], label="Freedman/Chernoff e^(−δ²/2ct)")
        ax.set_ylim(1e-5, 1.5)
        ax.set_xlabel("δ/√t")
        ax.set_title(f"α={c['alpha']:g}, t={c['t']} (c={c['c']:.3f})")
        ax.legend(fontsize=7)
    _save(fig, out / "tail_bounds.png", written)


def fig_regret_vs_bounds(data, out, written):
    plt = _plt()
    if "curves" not in data:
        return
    curves = data["curves"][:4]
    rows = data["rows"]
    fig, axes = plt.subplots(1, len(curves), figsize=(5 * len(curves), 4.3), squeeze=False)
    for ax, c in zip(axes[0], curves):
        lt = np.asarray(c["log10_t"])
        b = np.asarray(c["log10_bound"])
        triv = np.asarray(c["log10_trivial"])
        ax.plot(lt, b, "k", lw=2, label="Thm 4 B(T)")
        for j, name in enumerate(("T1 (T^((3p+1)/2))", "T2", "T3", "T4 entropy")):
            ax.plot(lt, np.asarray(c["log10_terms"][j]), lw=0.8, ls="--", label=name)
        ax.plot(lt, c["log10_corrected"], color="C5", label="corrected (audit §3.8)")
        ax.plot(lt, triv, color="gray", label="Δ_max·T (trivial)")
        ax.fill_between(lt, triv, np.maximum(b, triv), where=b >= triv, color="red", alpha=0.12,
                        label="vacuous: B ≥ Δ_max·T")
        pts = [r for r in rows if all(r[k] == c[k] for k in ("est", "K", "beta", "d2", "alpha0", "p"))]
        if pts:
            ax.plot([np.log10(r["T"]) for r in pts], [np.log10(max(r["regret"], 1e-12)) for r in pts],
                    "o", color="C3", label="measured E R_T")
        ax.set_xlabel("log10 T")
        ax.set_ylabel("log10 regret / bound")
        ax.set_title(f"{c['est']} K={c['K']} β={c['beta']:g} Δ2={c['d2']:g} α0={c['alpha0']:g} "
                     f"p={c['p']:g}", fontsize=8)
        ax.set_ylim(0, max(10, float(np.nanmin(b)) + 10))
        ax.legend(fontsize=6)
    _save(fig, out / "regret_vs_bounds.png", written)


def fig_tstar(data, out, written):
    plt = _plt()
    if "tstar" not in data:
        return
    g = data["tstar"]
    v = np.asarray(g["log10_tstar"], dtype=float)  # [K, beta, d2, a0, p]; -1 = no crossing
    v = np.where(v < 0, np.nan, v)
    for k, d2 in enumerate(g["delta2"]):
        fig, axes = plt.subplots(len(g["beta"]), len(g["K"]),
                                 figsize=(4.2 * len(g["K"]), 3.6 * len(g["beta"])), squeeze=False,
                                 constrained_layout=True)
        for i, K in enumerate(g["K"]):
            for j, b in enumerate(g["beta"]):
                ax = axes[j][i]
                z = v[i, j, k]  # [a0, p]
                im = ax.imshow(z, origin="lower", aspect="auto", cmap="viridis",
                               vmin=np.nanmin(v), vmax=min(np.nanmax(v), 150))
                for m, a0 in enumerate(g["alpha0"]):
                    for n, _ in enumerate(g["p"]):
                        txt = "∞" if np.isnan(z[m, n]) else f"{z[m, n]:.0f}"
                        ax.text(n, m, txt, ha="center", va="center", fontsize=6, color="w")
                    if a0 < 1:
                        ax.axhspan(m - 0.5, m + 0.5, fill=False, hatch="//", lw=0)
                ax.set_xticks(range(len(g["p"])), [f"{p:g}" for p in g["p"]])
                ax.set_yticks(range(len(g["alpha0"])), [f"{a:g}" for a in g["alpha0"]])
                ax.set_xlabel("p")
                if i == 0:
                    ax.set_ylabel("α0")
                ax.set_title(f"log10 T*: K={K} β={b:g} Δ2={d2:g}", fontsize=9)
        fig.colorbar(im, ax=axes.ravel().tolist(), shrink=0.8, label="log10 T* (B(T) < T)")
        fig.suptitle("Theorem 4: first T with B(T) < T (hatched rows: α0 < 1, where Theorem 4's "
                     "c is not justified by Theorem 1)", fontsize=10)
        fig.savefig(out / f"tstar_heatmap_d2_{d2:g}.png", dpi=110, bbox_inches="tight")
        written.append(out / f"tstar_heatmap_d2_{d2:g}.png")
        plt.close(fig)


def fig_alpha0(fd, out, written):
    plt = _plt()
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 4.3))
    small = fd.get("t5_alpha0_small", {}).get("curves", {})
    for a0, c in small.items():
        ax.plot(c["ts"], c["ratio"], "o-", label=f"α0={float(a0):g} "
                f"({'<' if float(a0) < 0.267 else '>'} p·g = 0.267)")
    ax.set_title("r = (1, 0.9), adv oracle β = 1, p = 0.3")
    for c in fd.get("t5_ratio_decreasing", {}).get("curves", []):
        if c["est"] not in ("exact", "addhalf"):
            continue
        ax2.plot(c["ts"], c["ratio"], "o-" if c["est"] == "exact" else "s:", lw=1,
                 label=f"{c['est']} p={c['p']:g} Δ={c['delta']:g}")
    ax2.set_title("Algorithm 1 (α0 = 1), K = 2: exact oracle and add-half mean")
    for a in (ax, ax2):
        a.set_xscale("log")
        a.set_xlabel("T (separate run per T)")
        a.set_ylabel("R_T / T")
        a.legend(fontsize=6)
    _save(fig, out / "ratio_vs_T_alpha0.png", written)


_L1_PANELS = (  # check, instance title, uniform-play R/T, label of the tested estimator
    ("alg1_l1_median", "L1 argmin (median): r = (0.9, 0.6)", 0.15, "L1 loss, argmin (median)"),
    ("alg1_argmax_literal", "L1 argmax as printed: r = (0.9, 0.3)", 0.3,
     "L1 loss, argmax (1 − median)"),
)


def fig_l1(fd, out, written):
    """Algorithm 1's L1 fit (argmin and the printed argmax) against the squared-loss mean."""
    plt = _plt()
    panels = [p for p in _L1_PANELS if fd.get(p[0])]
    fig, axes = plt.subplots(1, len(panels), figsize=(5.5 * len(panels), 4), squeeze=False)
    for ax, (name, title, uniform, label) in zip(axes[0], panels):
        for est, c in fd[name]["curves"].items():
            lab = "add-half mean (squared loss)" if est == "addhalf" else label
            ax.plot(c["ts"], c["ratio"], "o-", label=lab)
        ax.axhline(uniform, color="gray", ls=":", label=f"{uniform:g} = uniform-policy regret/T")
        ax.set_xscale("log")
        ax.set_xlabel("T")
        ax.set_ylabel("R_T / T")
        ax.set_title(f"{title}, α = 1/ln(T^0.3)", fontsize=9)
        ax.legend(fontsize=7)
    _save(fig, out / "l1_loss_failure.png", written)


def fig_fixed_alpha(data, out, written):
    """R_T/T at the paper's fixed α = 0.05: flat at Σ π_a Δ_a, not decreasing to 0."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.5, 4))
    for est, c in data["curves"].items():
        ax.plot(c["ts"], c["ratio"], "o-", label=f"{est} estimator")
    ax.axhline(data["limit"], color="gray", ls=":",
               label=f"Σ_a softmax(r/α)_a Δ_a = {data['limit']:.4f}")
    ax.set_xscale("log")
    ax.set_ylim(bottom=0)
    ax.set_xlabel("T")
    ax.set_ylabel("R_T / T")
    ax.set_title("fixed α = 0.05, K = 64, means 0.9 … 0.1", fontsize=9)
    ax.legend(fontsize=7)
    _save(fig, out / "fixed_alpha.png", written)


def fig_flip(data, out, written):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.5, 4))
    rows = data["rows"]
    for a0 in sorted({r["alpha0"] for r in rows}):
        rr = [r for r in rows if r["alpha0"] == a0]
        ts = [r["T"] for r in rr]
        ax.loglog(ts, [r["rb"] for r in rr], "o-", label=f"Σ P(misid), α0={a0:g}")
        ax.loglog(ts, [r["term3"] for r in rr], "s--", label=f"claimed term 3, α0={a0:g}")
    ts = sorted({r["T"] for r in rows})
    ax.loglog(ts, [next(r["floor"] for r in rows if r["T"] == t) for t in ts], "k:",
              label="analytic floor 0.98(√(T+1)−1)")
    ax.set_xlabel("T")
    ax.set_title("Theorem 4's third term, flip oracle (p = 0.02)")
    ax.legend(fontsize=7)
    _save(fig, out / "term3_flip.png", written)


def make_all(run_dir: str | Path) -> list[Path]:
    """Writes every figure whose data the run has; returns the paths written."""
    run_dir = Path(run_dir)
    fd = io.load_json(run_dir / "figure_data.json")
    out = run_dir / "figures"
    out.mkdir(exist_ok=True)
    written: list[Path] = []
    makers = (("t1_minprob_pathwise", fig_counts), ("t2_tail_mc", fig_tail),
              ("t4_bound_vs_regret", fig_regret_vs_bounds), ("t4_bound_vs_regret", fig_tstar),
              ("t4_term3_flip", fig_flip), ("exp_fixed_alpha", fig_fixed_alpha))
    for name, fn in makers:
        if fd.get(name):
            fn(fd[name], out, written)
    if fd.get("t5_alpha0_small") or fd.get("t5_ratio_decreasing"):
        fig_alpha0(fd, out, written)
    if fd.get("alg1_l1_median") or fd.get("alg1_argmax_literal"):
        fig_l1(fd, out, written)
    return written


if __name__ == "__main__":
    for p in make_all(sys.argv[1]):
        print(p)
