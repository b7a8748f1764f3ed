"""experiments.grasp_sensitivity: cell names map to worlds, and summarise's paired
t intervals, Holm and transfer figures match a hand computation on synthetic cells."""

import argparse
import math

import numpy as np
import pytest
from scipy import stats as sps

from experiments import grasp_learning as gl
from experiments import grasp_sensitivity as gs
from sern_jax.infra import distributed, io
from sern_jax.analysis import stats
from sern_jax.grasp.world import context, sim


def test_world_of_each_cell():
    ctx, trial = gs.world("10N_mu0.2-0.5_d435")
    assert ctx.scene.finger_force == 10.0 and trial.friction_range == (0.2, 0.5)
    assert ctx.noise and ctx.camera.noise_model == "realsense"
    ctx, trial = gs.world(gs.WORLD_A)  # today's world A: the shipped defaults
    assert gs.WORLD_A == "20N_mu0.3-0.8_clean"
    assert (ctx, trial) == (context.ContextConfig(), sim.TrialConfig())
    assert ctx.scene.finger_force == 20.0 and not ctx.noise
    assert len(gs.CELLS) == 8 and all(c.startswith(("20N_", "10N_")) for c in gs.CELLS)
    # the previous trial's cells still map to their worlds (their files are a record)
    assert gs.world(gs.WORLD_A_6N)[0].scene.finger_force == 6.0
    assert set(gs.CELLS_6N) & set(gs.CELLS) == {c for c in gs.CELLS if c.startswith("20N")}
    with pytest.raises(ValueError, match="unknown cell"):
        gs.world("7N_mu0.3-0.8_clean")


def _doc(cell, lv):
    return {"cell": cell, "world": {}, "objects": ["a", "b"],
            "policies": ["sern", "egreedy", "greedy"], "seeds": lv.shape[-1], "rounds": 2,
            "lowvar_eval": lv.tolist(), "paper_eval": lv.tolist(),
            "explore_success": lv.tolist(), "seconds": 1.0, "machine": {}}


def test_summarise_previous_grid_by_hand(tmp_path):
    """The previous trial's grid (older format, cells CELLS_6N, world A 6 N)."""
    rng = np.random.default_rng(0)
    s = 6
    lv_a = rng.uniform(0.5, 0.7, (3, 2, 3, s))
    lv_a[0] = 0.6  # θ0 in A: 0.6 for every policy and seed
    lv_b = rng.uniform(0.3, 0.9, (3, 2, 3, s))
    lv_b[0] = 0.4  # θ0 in B: 0.4 (gap 0.2)
    lv_b[-1, :, 0, :] = lv_b[-1, :, 2, :] + 0.2 + rng.normal(0, 0.02, (2, s))  # SERN above
    cell_b = "20N_mu0.2-0.5_clean"  # a 6 N θ0 at 20 N
    io.save_json(tmp_path / f"{gs.WORLD_A_6N}.json", _doc(gs.WORLD_A_6N, lv_a))
    io.save_json(tmp_path / f"{cell_b}.json", _doc(cell_b, lv_b))
    out = gs.summarise(tmp_path)
    diffs, names = [], []
    for cell, lv in ((gs.WORLD_A_6N, lv_a), (cell_b, lv_b)):
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
    assert out["transfer"][gs.WORLD_A_6N]["policies"]["sern"]["recovered_round2"] is None
    assert out["cells_missing"] == [c for c in gs.CELLS_6N if c not in (gs.WORLD_A_6N, cell_b)]


def _today(cell, lv, **extra):
    """A per-seed record of today's grid (grasp_learning's format) for ``cell``."""
    import dataclasses
    import json

    ctx, trial = gs.world(cell)
    r1, n = lv.shape[0], lv.shape[-1]
    ex = np.full(lv.shape, 0.5)
    ex[0] = -1.0
    doc = {"label": cell, "setting": "sensitivity", "objects": ["a", "b"],
           "all_objects": ["a", "b"], "policies": ["sern", "egreedy", "greedy"], "seeds": n,
           "rounds": r1 - 1, "rounds_done": r1 - 1, "lowvar_eval": lv.tolist(),
           "paper_eval": lv.tolist(), "explore_success": ex.tolist(),
           "pseudo_regret": np.full(lv.shape, -1.0).tolist(), "theta0_digest": "t0",
           "trial_config": json.loads(json.dumps(dataclasses.asdict(trial))),
           "scene_config": json.loads(json.dumps(dataclasses.asdict(ctx.scene))),
           "world": {"grid": gs.GRID, "grid_cell": cell}, "command": "c", "machine": {},
           "seconds": 1.0}
    doc.update(extra)
    return doc


def test_summarise_today_by_hand(tmp_path):
    """Today's grid: paired t intervals and Holm over the finished cells only, a stopped
    cell listed, the transfer gap and recovered share; mixing is refused."""
    rng = np.random.default_rng(1)
    s = 6
    lv_a = rng.uniform(0.5, 0.7, (3, 2, 3, s))
    lv_a[0] = 0.6
    lv_b = rng.uniform(0.3, 0.9, (3, 2, 3, s))
    lv_b[0] = 0.4
    lv_b[-1, :, 0, :] = lv_b[-1, :, 2, :] + 0.2 + rng.normal(0, 0.02, (2, s))  # SERN above
    cell_b = "10N_mu0.2-0.5_clean"
    gl.save_per_seed(tmp_path / f"{gs.WORLD_A}.json", _today(gs.WORLD_A, lv_a))
    gl.save_per_seed(tmp_path / f"{cell_b}.json", _today(cell_b, lv_b))
    stopped = lv_b.copy()
    stopped[2:] = -1.0
    gl.save_per_seed(tmp_path / "10N_mu0.3-0.8_d435.json",
                     _today("10N_mu0.3-0.8_d435", stopped, rounds_done=1, stopped_early=True))
    out = gs.summarise(tmp_path)
    assert set(out["cells"]) == {gs.WORLD_A, cell_b}
    assert out["cells_stopped"] == {"10N_mu0.3-0.8_d435": 1}
    diffs, names = [], []
    for cell, lv in ((gs.WORLD_A, lv_a), (cell_b, lv_b)):
        pooled = lv[-1].mean(0)  # [Q, S]
        for q, peer in ((2, "greedy"), (1, "egreedy")):
            d = pooled[0] - pooled[q]
            diffs.append(d)
            names.append((cell, peer))
            comp = out["cells"][cell]["comparisons"][f"sern - {peer}"]
            half = sps.t.ppf(0.975, s - 1) * d.std(ddof=1) / math.sqrt(s)
            assert comp["mean"] == pytest.approx(d.mean(), abs=1e-9)
            assert comp["half"] == pytest.approx(half, abs=1e-9)
    p = [2 * sps.t.sf(abs(d.mean()) / (d.std(ddof=1) / math.sqrt(s)), s - 1) for d in diffs]
    _, adj = stats.holm(p, 0.05)  # 4 comparisons: the stopped cell is not in the family
    for (cell, peer), a in zip(names, adj):
        assert out["cells"][cell]["comparisons"][f"sern - {peer}"]["pvalue_holm"] == \
            pytest.approx(a, abs=1e-9)
    assert f"{cell_b}: sern - greedy" in out["resolved"]
    t = out["transfer"][cell_b]
    assert t["gap"]["mean"] == pytest.approx(0.2) and t["gap"]["half"] == pytest.approx(0)
    gain = lv_b[-1, :, 0, :].mean() - 0.4
    assert t["policies"]["sern"]["recovered_round2"] == pytest.approx(gain / 0.2)
    assert out["transfer"][gs.WORLD_A]["policies"]["sern"]["recovered_round2"] is None
    md = gs.sensitivity_markdown(out)
    assert "| 20 N, U[0.3, 0.8], clean (world A) |" in md and "| 10 N, U[0.2, 0.5], clean |" in md
    assert md.splitlines()[0].count("Holm p") == 2
    # a cell file of another world (its name says 10 N, its scene 20 N) is refused
    bad = _today(cell_b, lv_b)
    bad["scene_config"]["finger_force"] = 20.0
    gl.save_per_seed(tmp_path / f"{cell_b}.json", bad)
    with pytest.raises(ValueError, match="scene_config"):
        gs.summarise(tmp_path)
    # and one of another θ0 or seed count
    gl.save_per_seed(tmp_path / f"{cell_b}.json", _today(cell_b, lv_b, theta0_digest="t1"))
    with pytest.raises(ValueError, match="theta0_digest"):
        gs.summarise(tmp_path)
    gl.save_per_seed(tmp_path / f"{cell_b}.json", _today(cell_b, lv_b))
    io.save_json(tmp_path / "6N_mu0.3-0.8_clean.json", _doc("6N_mu0.3-0.8_clean", lv_a))
    with pytest.raises(ValueError, match="mixes today's cell files"):
        gs.summarise(tmp_path)


def test_check_grid_pins_the_settings(tmp_path):
    """grid.json is written on first use; other seeds, rounds or objects are refused, naming
    what differs; an --out holding the previous trial's files is refused."""
    gs.check_grid(tmp_path, 10, 5, 6)
    assert io.load_json(tmp_path / "grid.json")["seeds"] == 10
    gs.check_grid(tmp_path, 10, 5, 6)  # the same settings: accepted
    with pytest.raises(gs.GridMismatch, match="seeds"):
        gs.check_grid(tmp_path, 3, 5, 6)
    with pytest.raises(gs.GridMismatch, match="objects, rounds"):
        gs.check_grid(tmp_path, 10, 4, 5)
    old = tmp_path / "old"
    old.mkdir()
    io.save_json(old / "6N_mu0.3-0.8_clean.json", {"cell": "6N_mu0.3-0.8_clean"})
    with pytest.raises(gs.GridMismatch, match="previous trial"):
        gs.check_grid(old, 10, 5, 6)
    assert not (old / "grid.json").exists()


def test_transfer_mjx_cell_on_ray_without_gpus_is_refused(tmp_path, capsys):
    """`transfer --ray` with the mjx cell and no --ray-gpus: one line naming --ray-gpus, exit 2,
    nothing written (its tasks would run MJX on the CPU). Control: a native cell alone passes
    this check (it is refused later only for want of a reachable Ray, which is not asked here)."""
    pytest.importorskip("ray")
    out = tmp_path / "t"
    code = gs.main(["transfer", "--ray", "--cells", "mjx", "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "--ray-gpus" in err[0]
    assert not out.exists()
    args = argparse.Namespace(ray=distributed.LOCAL, ray_workers=None, ray_cpus=1, ray_gpus=0.0, ray_retries=3)
    config = distributed.from_args(args)
    distributed.check_backend(gs.transfer_world("friction_low")[2], config)  # no error

