"""Every number docs/RESULTS.md (and docs/GRASP.md) quotes from the committed per-seed
results under experiments/results/ is recomputed here from those files (issue 17)."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from experiments import grasp_sensitivity, paper_table1

RESULTS = Path(__file__).resolve().parents[1] / "experiments" / "results"
SENS = RESULTS / "sensitivity"


def _pct(x):
    return round(100 * x, 1)


@pytest.fixture(scope="module")
def sens(tmp_path_factory):
    out = tmp_path_factory.mktemp("sens")
    for f in SENS.glob("*_*.json"):
        shutil.copy(f, out / f.name)
    return grasp_sensitivity.summarise(out)


def test_committed_summary_is_what_the_cells_give(sens):
    committed = json.loads((SENS / "summary.json").read_text())
    assert committed == json.loads(json.dumps(sens))


def test_sensitivity_table(sens):
    quoted = {  # cell: (θ0 %, SERN round 5 %, SERN − greedy, SERN − ε-greedy) (mean, half)
        "6N_mu0.3-0.8_clean": (61.0, 79.2, (3.4, 3.6), (2.2, 3.3)),
        "6N_mu0.2-0.5_clean": (40.6, 65.5, (0.6, 3.8), (-2.0, 2.5)),
        "20N_mu0.3-0.8_clean": (83.0, 92.5, (0.1, 2.3), (0.3, 1.8)),
        "20N_mu0.3-0.8_d435": (89.1, 94.7, (-0.5, 1.5), (0.1, 1.8)),
        "20N_mu0.2-0.5_clean": (74.1, 90.0, (2.3, 1.9), (1.4, 2.3)),
    }
    assert set(sens["cells"]) == set(quoted)
    assert sens["cells_missing"] == ["6N_mu0.3-0.8_d435", "6N_mu0.2-0.5_d435",
                                     "20N_mu0.2-0.5_d435"]
    for cell, (t0, r5, g, e) in quoted.items():
        c = sens["cells"][cell]
        lv = c["policies"]["sern"]["lowvar_by_round"]
        assert (_pct(lv[0]), _pct(lv[-1])) == (t0, r5)
        for peer, (m, h) in (("greedy", g), ("egreedy", e)):
            comp = c["comparisons"][f"sern - {peer}"]
            assert (_pct(comp["mean"]), _pct(comp["half"])) == (m, h)
            assert comp["n"] == 10 and not comp["resolved"]
    holm = [c["comparisons"][k]["pvalue_holm"] for c in sens["cells"].values()
            for k in c["comparisons"]]
    assert len(holm) == 10 and round(min(holm), 2) == 0.21
    assert sens["resolved"] == []
    signs = {p: [np.sign(c["comparisons"][f"sern - {p}"]["mean"]) for c in
                 sens["cells"].values()] for p in ("greedy", "egreedy")}
    assert sorted(signs["greedy"]) == [-1, 1, 1, 1, 1]
    assert sorted(signs["egreedy"]) == [-1, 1, 1, 1, 1]
    means = [abs(c["comparisons"][k]["mean"]) for c in sens["cells"].values()
             for k in c["comparisons"]]
    assert _pct(max(means)) == 3.4


def test_transfer_numbers(sens):
    t = sens["transfer"]["6N_mu0.2-0.5_clean"]
    assert (_pct(t["theta0_A"]), _pct(t["theta0_B"]), _pct(t["gap"])) == (61.0, 40.6, 20.4)
    rec = {p: (_pct(v["recovered_round1"]), _pct(v["recovered_round5"]))
           for p, v in t["policies"].items()}
    assert rec == {"sern": (71.4, 121.7), "egreedy": (68.1, 131.4), "greedy": (64.5, 118.9)}
    c = sens["cells"]["20N_mu0.3-0.8_clean"]["policies"]
    assert (_pct(c["sern"]["round5_minus_theta0"]["mean"]),
            _pct(c["sern"]["round5_minus_theta0"]["half"])) == (9.5, 2.2)
    assert (_pct(c["greedy"]["round5_minus_theta0"]["mean"]),
            _pct(c["greedy"]["round5_minus_theta0"]["half"])) == (9.4, 2.2)
    gains = [v["round5_minus_theta0"]["mean"] for cell, cc in sens["cells"].items()
             if cell.startswith("20N") for v in cc["policies"].values()]
    assert (_pct(min(gains)), _pct(max(gains))) == (5.5, 15.9)


def test_fixed_pose_evaluation_noise():
    d = json.loads((SENS / "6N_mu0.3-0.8_clean.json").read_text())
    lv, pe = np.array(d["lowvar_eval"]), np.array(d["paper_eval"])  # [R+1, O, Q, S]
    r0 = lv[0, :, 0, :]  # θ0: the same network on every seed, so pure evaluation noise
    assert _pct(r0.std(1, ddof=1).mean()) == 16.1
    assert _pct(r0.mean(0).std(ddof=1)) == 6.3
    p0 = pe[0, :, 0, :]
    assert _pct(p0.std(1, ddof=1).mean()) == 18.9 and _pct(p0.mean(0).std(ddof=1)) == 10.8
    s = lv[-1].mean(0)  # [Q, S]
    assert _pct((s[0] - s[2]).std(ddof=1)) == 5.0


def test_trial_checks():
    d = json.loads((RESULTS / "trial_checks.json").read_text())
    ts = d["timestep"]
    assert (ts["5ms_vs_2.5ms"]["agree"], ts["5ms_vs_2.5ms"]["n"]) == (376, 384)
    assert _pct(ts["5ms_vs_2.5ms"]["fraction"]) == 97.9
    assert [_pct(v) for v in ts["5ms_vs_2.5ms"]["ci95"]] == [95.9, 99.1]
    assert ts["5ms_vs_1.25ms"]["agree"] == 371 and _pct(ts["5ms_vs_1.25ms"]["fraction"]) == 96.6
    assert [_pct(v) for v in ts["5ms_vs_1.25ms"]["ci95"]] == [94.3, 98.2]
    assert _pct(ts["2.5ms_vs_1.25ms"]["fraction"]) == 97.7
    assert [_pct(v) for v in ts["success"].values()] == [33.3, 33.3, 32.6]
    g20, g40 = d["grip"]["20N"], d["grip"]["40N"]
    assert _pct(d["default_success"]) == 33.3
    assert (384 - round(d["default_success"] * 384)) == 256
    assert (g20["fail_at_6N_success_at_f"], g20["success_at_6N_fail_at_f"]) == (119, 14)
    assert (_pct(g20["success"]), _pct(g40["success"])) == (60.7, 61.7)


def test_paper_table1_counts():
    res = paper_table1.check()
    s = res["statistics"]
    assert res["cells"] == 75 and res["means_on_grid"] == 59
    assert (s["se_sample"]["value_possible"], s["se_sample"]["jointly_with_mean"]) == (75, 56)
    assert (s["sd_pop"]["value_possible"], s["sd_pop"]["jointly_with_mean"]) == (12, 0)
    assert (s["sd_sample"]["value_possible"], s["sd_sample"]["jointly_with_mean"]) == (6, 0)
    assert s["se_pop"]["jointly_with_mean"] == 0
    assert len(s["se_sample"]["not_joint"]) == 19
    assert res["smallest_se_sample"][1:5] == [4.0, 4.9, 6.32, 7.48]
    assert res["smallest_sd_pop"][1:4] == [8.0, 9.8, 12.65]


def test_screen_with_fresh_trials():
    d = json.loads((RESULTS / "screen_fresh.json").read_text())
    rows = {r["object"]: r for r in d["objects"]}
    quoted = {  # object: (greedy, best max, best fresh, hard)
        "triangular_prism": (0.61, 1.00, 1.00, False), "pipe_tee": (0.53, 0.98, 0.86, True),
        "handle_jug": (0.58, 0.77, 0.56, False), "tless_part_a": (0.39, 1.00, 0.98, True),
        "tless_part_b": (0.84, 1.00, 0.89, False), "tless_part_c": (0.55, 1.00, 0.95, True),
        "detergent_bottle": (0.23, 0.77, 0.70, False)}
    assert set(rows) == set(quoted)
    from sern_jax.grasp import pretrain

    for name, (g, b, f, hard) in quoted.items():
        r = rows[name]
        assert (round(r["greedy_success"], 2), round(r["best_success"], 2),
                round(r["best_success_fresh"], 2)) == (g, b, f)
        assert r["hard"] is hard and pretrain.is_hard(r) is hard
        assert r["best_success_fresh"] == pytest.approx(np.mean(r["best_fresh_per_pose"]))
