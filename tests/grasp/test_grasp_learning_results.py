"""experiments.grasp_learning's per-seed files and summarise, and the transfer summary of
experiments.grasp_sensitivity, against hand computations on synthetic per-seed records."""

import math

import numpy as np
import pytest
from scipy import stats as sps

from experiments import grasp_learning as gl
from experiments import grasp_sensitivity as gs
from sern_jax.analysis import stats


def _doc(label, objects, all_objects, policies, lv, pe=None, rounds_done=None, **extra):
    r1, o, q, s = lv.shape
    ex = np.full(lv.shape, 0.5)
    ex[0] = -1.0
    return {"label": label, "setting": "test", "objects": objects, "all_objects": all_objects,
            "policies": policies, "seeds": s, "rounds": r1 - 1,
            "rounds_done": r1 - 1 if rounds_done is None else rounds_done,
            "lowvar_eval": lv.tolist(), "paper_eval": (lv if pe is None else pe).tolist(),
            "explore_success": ex.tolist(), "pseudo_regret": np.full(lv.shape, -1.0).tolist(),
            "theta0_digest": "x", "command": "c", "machine": {}, "seconds": 1.0, **extra}


def test_parts_join_and_paired_comparisons_by_hand(tmp_path):
    rng = np.random.default_rng(0)
    objs = ["a", "b", "c"]
    pol = ["sern", "egreedy", "greedy"]
    lv = rng.uniform(0.2, 0.9, (3, 3, 3, 5))  # [R+1, O, Q, S]
    gl.save_per_seed(tmp_path / "strong.part-a.json",
                     _doc("strong", ["a"], objs, pol, lv[:, :1]))
    gl.save_per_seed(tmp_path / "strong.part-b+c.json",
                     _doc("strong", ["b", "c"], objs, pol, lv[:, 1:]))
    docs = gl.load_results(tmp_path)
    assert docs["strong"]["objects"] == objs
    assert np.allclose(docs["strong"]["lowvar_eval"], lv)
    s = gl.summarise(tmp_path)
    fam = s["comparisons"]["final_round"]
    # per peer: fixed-pose pooled, 5-grasp pooled, fixed-pose per object: 2 x 5 in one family
    assert len(fam) == 10
    lvr = lv
    d = lvr[-1, :, 0, :].mean(0) - lvr[-1, :, 2, :].mean(0)
    row = next(c for c in fam if c["name"] == "strong:sern - strong:greedy | fixed-pose, pooled")
    half = sps.t.ppf(0.975, 4) * d.std(ddof=1) / math.sqrt(5)
    assert row["mean"] == pytest.approx(d.mean()) and row["half"] == pytest.approx(half)
    ps = [c["pvalue"] for c in fam]
    _, adj = stats.holm(ps, 0.05)
    assert [c["pvalue_holm"] for c in fam] == pytest.approx(list(adj))
    rows = s["runs"]["strong"]["table"]
    assert len(rows) == 9 and rows[0]["sd"] is not None
    t = s["runs"]["strong"]["policies_pooled"]["sern"]["final_minus_theta0_lowvar"]
    assert t["mean"] == pytest.approx((lvr[-1, :, 0] - lvr[0, :, 0]).mean())


def test_ablation_compares_each_variant_with_the_first(tmp_path):
    rng = np.random.default_rng(1)
    lv = {a: rng.uniform(0.3, 0.8, (2, 2, 1, 5)) for a in ("alpha=0.01", "alpha=0.05")}
    for a, x in lv.items():
        gl.save_per_seed(tmp_path / f"{a}.json", _doc(a, ["a", "b"], ["a", "b"], ["sern"], x))
    s = gl.summarise(tmp_path)
    fam = s["comparisons"]["final_round"]
    assert [c["name"] for c in fam] == [
        "alpha=0.01:sern - alpha=0.05:sern | fixed-pose, pooled",
        "alpha=0.01:sern - alpha=0.05:sern | 5-grasp, pooled"]
    x, y = (lv[k][-1, :, 0].mean(0) for k in ("alpha=0.01", "alpha=0.05"))
    assert fam[0]["mean"] == pytest.approx((x - y).mean())  # variant - the paper's alpha


def test_overlapping_parts_are_refused(tmp_path):
    lv = np.full((2, 1, 1, 3), 0.5)
    gl.save_per_seed(tmp_path / "p.part-a.json", _doc("p", ["a"], ["a", "b"], ["sern"], lv))
    gl.save_per_seed(tmp_path / "p.part-a2.json", _doc("p", ["a"], ["a", "b"], ["sern"], lv))
    with pytest.raises(ValueError, match="two part files"):
        gl.load_results(tmp_path)


def test_transfer_summary_by_hand(tmp_path):
    rng = np.random.default_rng(2)
    pol = ["sern", "egreedy", "greedy"]
    s = 6
    a = rng.uniform(0.5, 0.9, (21, 2, 3, s))
    a[0] = 0.7
    b = rng.uniform(0.3, 0.9, (21, 2, 3, s))
    b[0] = 0.4  # θ0 in B: 0.4, gap 0.3
    gl.save_per_seed(tmp_path / "A.json", _doc("A", ["x", "y"], ["x", "y"], pol, a))
    gl.save_per_seed(tmp_path / "friction_low.json",
                     _doc("friction_low", ["x", "y"], ["x", "y"], pol, b))
    # a cell stopped after round 7: reported at rounds 1, 5 and its last, 7
    c = b.copy()
    c[8:] = -1.0
    gl.save_per_seed(tmp_path / "heavy.json",
                     _doc("heavy", ["x", "y"], ["x", "y"], pol, c, rounds_done=7))
    out = gs.summarise_transfer(tmp_path)
    t = out["cells"]["friction_low"]
    assert t["gap"]["mean"] == pytest.approx(0.3)
    assert t["rounds_reported"] == [1, 5, 20]
    g = b[20, :, 0, :].mean(0) - 0.4
    assert t["policies"]["sern"]["gain"]["20"]["mean"] == pytest.approx(g.mean(), abs=1e-6)
    half = sps.t.ppf(0.975, s - 1) * g.std(ddof=1) / math.sqrt(s)
    assert t["policies"]["sern"]["gain"]["20"]["half"] == pytest.approx(half, abs=1e-6)
    assert t["policies"]["sern"]["recovered"]["20"] == pytest.approx(g.mean() / 0.3, abs=1e-5)
    assert out["cells"]["heavy"]["rounds_reported"] == [1, 5, 7]
    assert out["cells"]["A"]["policies"]["sern"]["recovered"]["5"] is None  # no gap
    names = [c["name"] for c in out["comparisons"]]
    assert "friction_low: sern - greedy, round 20" in names
    assert "heavy: sern - greedy, round 7" in names and len(names) == 2 * 2 * 3
    assert "mjx" in out["cells_missing"]


def test_transfer_worlds():
    ctx, trial, backend, theta0_dir = gs.transfer_world("friction_low")
    assert trial.friction_range == (0.2, 0.5) and backend == "native" and theta0_dir is None
    assert gs.transfer_world("mjx")[2] == "mjx"
    assert gs.transfer_world("grip_6N")[0].scene.finger_force == 6.0
    assert gs.transfer_world("d435")[0].noise
    assert (gs.THETA0_6N_DIR / "theta0.msgpack").exists()
    with pytest.raises(ValueError, match="unknown transfer cell"):
        gs.transfer_world("moon")


def test_negative_pseudo_regret_is_kept_and_round_0_is_not_measured(tmp_path):
    lv = np.full((3, 1, 1, 2), 0.5)
    d = _doc("regret", ["a"], ["a"], ["sern"], lv, config={"regret_trials": 4})
    pr = np.array([[[[-1.0, -1.0]]], [[[-0.25, 1.5]]], [[[-1.0, 0.5]]]])  # -1: a real value
    d["pseudo_regret"] = pr.tolist()
    gl.save_per_seed(tmp_path / "regret.json", d)
    got = gl.load_results(tmp_path)["regret"]["pseudo_regret"]
    assert np.isnan(got[0]).all() and np.array_equal(got[1:], pr[1:])
    d["config"] = {"regret_trials": 0}  # accounting off: nothing was measured
    gl.save_per_seed(tmp_path / "regret.json", d)
    assert np.isnan(gl.load_results(tmp_path)["regret"]["pseudo_regret"]).all()
