"""The numbers docs/NEURAL.md quotes for the per-arm Neural-Linear Thompson learner on the
wheel bandit are recomputed from the committed per-seed files
(experiments/results/wheel_neural_lints/d<δ>/results.npz: regret_rb [S, G] per policy, with
the command in config.json / metadata.json)."""

from pathlib import Path

import numpy as np
import pytest

from sern_jax import io

ROOT = Path(__file__).resolve().parents[1]
RUNS = ROOT / "experiments" / "results" / "wheel_neural_lints"
DELTAS = ("0.5", "0.7", "0.9", "0.95", "0.99")


def _ratio_interval(num, den, num_boot=2000, seed=0):
    """experiments/neural_regret.py's paired seed-bootstrap, restated."""
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, num.size, (num_boot, num.size))
    boots = num[idx].mean(1) / den[idx].mean(1)
    return num.mean() / den.mean(), np.percentile(boots, 2.5), np.percentile(boots, 97.5)


def test_quoted_row_and_uniform_regret_match_the_per_seed_files():
    doc = " ".join((ROOT / "docs" / "NEURAL.md").read_text().split())  # reflow-proof
    cells, uniform = [], []
    for d in DELTAS:
        res = io.load_npz(RUNS / f"d{d}" / "results.npz")
        cfg = io.load_json(RUNS / f"d{d}" / "config.json")["experiment"]
        assert float(cfg["delta"]) == float(d) and cfg["num_seeds"] == 20
        assert cfg["horizon"] == 1000
        num = res["neural_lints__regret_rb"][:, -1].astype(np.float64)
        den = res["uniform__regret_rb"][:, -1].astype(np.float64)
        r, lo, hi = _ratio_interval(num, den)
        cells.append(f"{r:.3f} [{lo:.3f}, {hi:.3f}]")
        uniform.append(f"{den.mean():,.0f}")
        summary = io.load_json(RUNS / f"d{d}" / "summary.json")
        assert summary["normalised_by_uniform"]["neural_lints"]["ratio"] == pytest.approx(r)
    row = "| neural_lints (per-arm, 2026-11-24) | " + " | ".join(cells) + " |"
    assert row in doc, row
    assert f"Uniform's R_T on these seeds: {', '.join(uniform)}" in doc
