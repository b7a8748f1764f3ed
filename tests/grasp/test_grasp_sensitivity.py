"""experiments.grasp_sensitivity: cell names map to worlds, and summarise's paired
t intervals, Holm and transfer figures match a hand computation on synthetic cells."""

import math

import numpy as np
import pytest
from scipy import stats as sps

from experiments import grasp_sensitivity as gs
from sern_jax import io, stats


def test_world_of_each_cell():
    ctx, trial = gs.world("20N_mu0.2-0.5_d435")
    assert ctx.scene.finger_force == 20.0 and trial.friction_range == (0.2, 0.5)
    assert ctx.noise and ctx.camera.noise_model == "realsense"
    ctx, trial = gs.world(gs.WORLD_A)
    assert ctx.scene.finger_force == 6.0 and trial.friction_range == (0.3, 0.8)
    assert not ctx.noise
    assert len(gs.CELLS) == 8
    with pytest.raises(ValueError, match="unknown cell"):
        gs.world("7N_mu0.3-0.8_clean")


def _doc(cell, lv):
    return {"cell": cell, "world": {}, "objects": ["a", "b"],
            "policies": ["sern", "egreedy", "greedy"], "seeds": lv.shape[-1], "rounds": 2,
            "lowvar_eval": lv.tolist(), "paper_eval": lv.tolist(),
            "explore_success": lv.tolist(), "seconds": 1.0, "machine": {}}


def test_summarise_by_hand(tmp_path):
    rng = np.random.default_rng(0)
    s = 6
    lv_a = rng.uniform(0.5, 0.7, (3, 2, 3, s))
    lv_a[0] = 0.6  # θ0 in A: 0.6 for every policy and seed
    lv_b = rng.uniform(0.3, 0.9, (3, 2, 3, s))
    lv_b[0] = 0.4  # θ0 in B: 0.4 (gap 0.2)
    lv_b[-1, :, 0, :] = lv_b[-1, :, 2, :] + 0.2 + rng.normal(0, 0.02, (2, s))  # SERN above
    cell_b = "20N_mu0.2-0.5_clean"
    io.save_json(tmp_path / f"{gs.WORLD_A}.json", _doc(gs.WORLD_A, lv_a))
    io.save_json(tmp_path / f"{cell_b}.json", _doc(cell_b, lv_b))
    out = gs.summarise(tmp_path)
    diffs, names = [], []
    for cell, lv in ((gs.WORLD_A, lv_a), (cell_b, lv_b)):
        pooled = lv[-1].mean(0)  # [Q, S]
        for q, peer in ((2, "greedy"), (1, "egreedy")):
            d = pooled[0] - pooled[q]
            diffs.append(d)
            names.append((cell, peer))
            comp = out["cells"][cell]["comparisons"][f"sern - {peer}"]
            half = sps.t.ppf(0.975, s - 1) * d.std(ddof=1) / math.sqrt(s)
            assert comp["mean"] == pytest.approx(d.mean(), abs=1e-6)
            assert comp["half"] == pytest.approx(half, abs=1e-6)
    p = [2 * sps.t.sf(abs(d.mean()) / (d.std(ddof=1) / math.sqrt(s)), s - 1) for d in diffs]
    _, adj = stats.holm(p, 0.05)
    for (cell, peer), a in zip(names, adj):
        assert out["cells"][cell]["comparisons"][f"sern - {peer}"]["pvalue_holm"] == \
            pytest.approx(a, abs=1e-6)
    assert f"{cell_b}: sern - greedy" in out["resolved"]
    t = out["transfer"][cell_b]
    assert t["gap"] == pytest.approx(0.2, abs=1e-5)
    gain = lv_b[-1, :, 0, :].mean() - 0.4
    assert t["policies"]["sern"]["recovered_round2"] == pytest.approx(gain / 0.2, abs=1e-3)
    assert out["transfer"][gs.WORLD_A]["policies"]["sern"]["recovered_round2"] is None
    assert out["cells_missing"] == [c for c in gs.CELLS if c not in (gs.WORLD_A, cell_b)]
