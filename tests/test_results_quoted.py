"""Every number docs/RESULTS.md (and docs/GRASP.md) quotes from the committed per-seed
results under experiments/results/ is recomputed here from those files (issue 17)."""

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from experiments import grasp_sensitivity, paper_table1

RESULTS = Path(__file__).resolve().parents[1] / "experiments" / "results"
# The previous trial's grid (6 N θ0), kept as a record: experiments/results/sensitivity_6N
# (its README holds its table); today's grid is experiments/results/sensitivity (below).
SENS = RESULTS / "sensitivity_6N"


def _pct(x):
    return round(100 * x, 1)


def _pm(m, h=None, sign=True):
    """'+1.9 ± 4.5' (percentage points from fractions), with the docs' minus sign."""
    txt = f"{100 * m:+.1f}" if sign else f"{100 * m:.1f}"
    if h is not None:
        txt += f" ± {100 * h:.1f}"
    return txt.replace("-", "−")


def _section(title):
    """One section of docs/RESULTS.md with its line breaks as spaces, so a quoted sentence
    is found whatever its wrapping."""
    doc = (Path(__file__).resolve().parents[1] / "docs" / "RESULTS.md").read_text()
    start = doc.index(f"## {title}")
    end = doc.find("\n## ", start + 1)
    return " ".join(doc[start:end if end > 0 else None].split())


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
        "6N_mu0.3-0.8_d435": (69.9, 81.5, (0.7, 3.6), (0.7, 2.8)),
        "6N_mu0.2-0.5_clean": (40.6, 65.5, (0.6, 3.8), (-2.0, 2.5)),
        "6N_mu0.2-0.5_d435": (51.7, 69.5, (-0.4, 3.0), (-0.9, 3.6)),
        "20N_mu0.3-0.8_clean": (83.0, 92.5, (0.1, 2.3), (0.3, 1.8)),
        "20N_mu0.3-0.8_d435": (89.1, 94.7, (-0.5, 1.5), (0.1, 1.8)),
        "20N_mu0.2-0.5_clean": (74.1, 90.0, (2.3, 1.9), (1.4, 2.3)),
        "20N_mu0.2-0.5_d435": (81.8, 93.2, (1.1, 2.3), (-0.1, 2.6)),
    }
    assert set(sens["cells"]) == set(quoted)
    assert sens["cells_missing"] == []
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
    assert len(holm) == 16 and round(min(holm), 2) == 0.34
    assert sens["resolved"] == []
    signs = {p: [np.sign(c["comparisons"][f"sern - {p}"]["mean"]) for c in
                 sens["cells"].values()] for p in ("greedy", "egreedy")}
    assert sorted(signs["greedy"]) == [-1, -1, 1, 1, 1, 1, 1, 1]
    assert sorted(signs["egreedy"]) == [-1, -1, -1, 1, 1, 1, 1, 1]
    means = [abs(c["comparisons"][k]["mean"]) for c in sens["cells"].values()
             for k in c["comparisons"]]
    assert _pct(max(means)) == 3.4
    # the record's README prints this table
    readme = [ln.strip() for ln in (SENS / "README.md").read_text().splitlines()]

    def pm(m, h):
        return f"{m:+.1f} ± {h:.1f}".replace("-", "−")

    for t0, r5, g, e in quoted.values():
        row = f"| {t0:.1f} % | {r5:.1f} % | {pm(*g)} | {pm(*e)} |"
        assert any(ln.endswith(row) for ln in readme), row


def test_transfer_numbers(sens):
    t = sens["transfer"]["6N_mu0.2-0.5_clean"]
    assert (_pct(t["theta0_A"]), _pct(t["theta0_B"]), _pct(t["gap"])) == (61.0, 40.6, 20.4)
    rec = {p: (_pct(v["recovered_round1"]), _pct(v["recovered_round5"]))
           for p, v in t["policies"].items()}
    assert rec == {"sern": (71.4, 121.7), "egreedy": (68.1, 131.4), "greedy": (64.5, 118.9)}
    t = sens["transfer"]["6N_mu0.2-0.5_d435"]
    assert (_pct(t["theta0_B"]), _pct(t["gap"])) == (51.7, 9.3)
    assert {p: _pct(v["recovered_round1"]) for p, v in t["policies"].items()} == {
        "sern": 65.9, "egreedy": 54.7, "greedy": 64.2}
    assert all(v["recovered_round5"] > 1 for v in t["policies"].values())
    assert _pct(sens["transfer"]["6N_mu0.3-0.8_d435"]["theta0_B"]) == 69.9
    c = sens["cells"]["20N_mu0.3-0.8_clean"]["policies"]
    assert (_pct(c["sern"]["round5_minus_theta0"]["mean"]),
            _pct(c["sern"]["round5_minus_theta0"]["half"])) == (9.5, 2.2)
    assert (_pct(c["greedy"]["round5_minus_theta0"]["mean"]),
            _pct(c["greedy"]["round5_minus_theta0"]["half"])) == (9.4, 2.2)
    gains = [v["round5_minus_theta0"]["mean"] for cell, cc in sens["cells"].items()
             if cell.startswith("20N") for v in cc["policies"].values()]
    assert (_pct(min(gains)), _pct(max(gains))) == (5.5, 15.9)


# --- today's grid (20 N trial): experiments/results/sensitivity ---

SENS_TODAY = RESULTS / "sensitivity"


@pytest.fixture(scope="module")
def grid(tmp_path_factory):
    out = tmp_path_factory.mktemp("grid")
    for f in SENS_TODAY.glob("*.json"):
        if f.name != "summary.json":
            shutil.copy(f, out / f.name)
    return json.loads(json.dumps(grasp_sensitivity.summarise(out)))


def test_grid_summary_is_what_the_cells_give(grid):
    assert json.loads((SENS_TODAY / "summary.json").read_text()) == grid


def test_grid_cells_were_made_with_the_shipped_theta0_in_their_worlds():
    from sern_jax.grasp.model import artifacts

    theta0 = artifacts.load_theta0()
    hard = artifacts.hard_set(theta0, 6)["objects"]
    files = sorted(f for f in SENS_TODAY.glob("*.json")
                   if f.name not in ("summary.json", "grid.json"))
    assert [f.stem for f in files] == sorted(grasp_sensitivity.CELLS)
    for f in files:
        d = json.loads(f.read_text())
        ctx, trial = grasp_sensitivity.world(f.stem)
        assert d["theta0_digest"] == theta0.fingerprint, f
        assert d["objects"] == hard and (d["seeds"], d["rounds"], d["rounds_done"]) == (10, 5, 5)
        assert d["trial_config"] == json.loads(json.dumps(dataclasses.asdict(trial))), f
        assert d["scene_config"] == json.loads(json.dumps(dataclasses.asdict(ctx.scene))), f
        assert d["world"]["depth_noise"] == ("realsense" if f.stem.endswith("d435") else "none")
        assert d["command"].startswith("python -m experiments.grasp_sensitivity cell " + f.stem)
        assert d["machine"]["cpu"] and d["machine"]["jax_devices"] == ["cuda:0"], f


def test_grid_refuses_mixing_trials_and_settings(tmp_path):
    """Today's cells with the previous trial's, or a cell of another θ0, are refused; so is
    a cell run into a grid directory made with other seeds (one line naming --out, exit 2,
    before anything is computed)."""
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    shutil.copy(SENS_TODAY / "20N_mu0.3-0.8_clean.json", mixed)
    shutil.copy(SENS / "20N_mu0.3-0.8_clean.json", mixed / "x_20N_mu0.3-0.8_clean.json")
    with pytest.raises(ValueError, match="mixes today's cell files with the previous"):
        grasp_sensitivity.summarise(mixed)
    other = tmp_path / "other"
    other.mkdir()
    for name in ("20N_mu0.3-0.8_clean.json", "10N_mu0.3-0.8_clean.json"):
        shutil.copy(SENS_TODAY / name, other)
    grasp_sensitivity.summarise(other)  # control: the same files, unchanged, are accepted
    d = json.loads((other / "10N_mu0.3-0.8_clean.json").read_text())
    d["theta0_digest"] = "another"
    (other / "10N_mu0.3-0.8_clean.json").write_text(json.dumps(d))
    with pytest.raises(ValueError, match="theta0_digest"):
        grasp_sensitivity.summarise(other)
    d = json.loads((SENS_TODAY / "10N_mu0.3-0.8_clean.json").read_text())
    d["scene_config"]["finger_force"] = 20.0  # a 10 N cell's file made in another world
    (other / "10N_mu0.3-0.8_clean.json").write_text(json.dumps(d))
    with pytest.raises(ValueError, match="scene_config"):
        grasp_sensitivity.summarise(other)
    pinned = tmp_path / "pinned"
    pinned.mkdir()
    shutil.copy(SENS_TODAY / "grid.json", pinned)
    with pytest.raises(SystemExit) as exc:
        grasp_sensitivity.main(["cell", "20N_mu0.3-0.8_clean", "--out", str(pinned),
                                "--seeds", "3"])
    assert exc.value.code == 2 and sorted(p.name for p in pinned.iterdir()) == ["grid.json"]
    with pytest.raises(SystemExit) as exc:  # the previous trial's folder
        grasp_sensitivity.main(["cell", "20N_mu0.3-0.8_clean", "--out", str(SENS)])
    assert exc.value.code == 2


@pytest.mark.parametrize("what", ["summarise", "transfer-summarise"])
def test_summarise_of_a_folder_without_cells_is_one_line_exit_2(tmp_path, capsys, what):
    empty = tmp_path / "empty"
    empty.mkdir()
    for out in (tmp_path / "nonexistent", empty):
        assert grasp_sensitivity.main([what, str(out)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and str(out) in err and "Traceback" not in err
    assert list(empty.iterdir()) == [] and not (tmp_path / "nonexistent").exists()
    ok = tmp_path / "ok"  # control: the committed world-A cell alone is accepted
    ok.mkdir()
    shutil.copy(SENS_TODAY / "20N_mu0.3-0.8_clean.json" if what == "summarise"
                else RESULTS / "transfer" / "A.json", ok)
    assert grasp_sensitivity.main([what, str(ok)]) == 0


def test_grid_table_and_prose_quoted(grid):
    assert grasp_sensitivity.sensitivity_markdown(grid) in DOC
    cells = grid["cells"]
    assert grid["cells_missing"] == [] and grid["cells_stopped"] == {}
    comps = [v for c in cells.values() for v in c["comparisons"].values()]
    assert len(comps) == 16 and grid["resolved"] == []
    # no interval excludes 0 even before Holm; smallest raw p 0.10, every Holm p 1.00
    assert all(v["lower"] < 0 < v["upper"] for v in comps)
    assert round(min(v["pvalue"] for v in comps), 2) == 0.10
    assert round(min(v["pvalue_holm"] for v in comps), 2) == 1.0
    assert (_pct(min(v["mean"] for v in comps)), _pct(max(v["mean"] for v in comps))) == (
        -2.8, 2.0)
    assert (_pct(min(v["half"] for v in comps)), _pct(max(v["half"] for v in comps))) == (
        2.5, 6.2)
    assert (_pct(min(v["lower"] for v in comps)), _pct(max(v["upper"] for v in comps))) == (
        -7.5, 6.0)
    assert sorted(round(c["seconds"]) for c in cells.values())[::7] == [432, 474]
    # 40 seeds instead of 10: half-widths / 2 (1/sqrt(n))
    assert (_pct(min(v["half"] for v in comps) / 2), _pct(max(v["half"] for v in comps) / 2)
            ) == (1.2, 3.1)
    assert _pct(cells["10N_mu0.2-0.5_clean"]["theta0"]["mean"]) == 27.7
    t = grid["transfer"]
    assert _pct(t["20N_mu0.3-0.8_clean"]["theta0_B"]) == 77.8
    gaps = {c: (_pct(v["gap"]["mean"]), _pct(v["gap"]["half"])) for c, v in t.items()}
    assert gaps == {"20N_mu0.3-0.8_clean": (0.0, 0.0), "20N_mu0.3-0.8_d435": (-1.1, 3.5),
                    "20N_mu0.2-0.5_clean": (21.2, 1.9), "20N_mu0.2-0.5_d435": (20.1, 3.8),
                    "10N_mu0.3-0.8_clean": (26.4, 2.7), "10N_mu0.3-0.8_d435": (25.2, 3.6),
                    "10N_mu0.2-0.5_clean": (50.1, 2.8), "10N_mu0.2-0.5_d435": (50.2, 2.7)}

    def rec(cell, r):
        v = [t[cell]["policies"][p][f"recovered_round{r}"] for p in ("sern", "egreedy",
                                                                     "greedy")]
        return round(100 * min(v)), round(100 * max(v))

    assert rec("20N_mu0.2-0.5_clean", 5) == (153, 163)
    assert rec("10N_mu0.3-0.8_clean", 5) == (95, 105)
    assert rec("10N_mu0.2-0.5_clean", 5) == (69, 73)
    assert rec("10N_mu0.2-0.5_d435", 5) == (75, 78)
    gain_a = [t["20N_mu0.3-0.8_clean"]["policies"][p]["gain_round5"] for p in
              ("sern", "egreedy", "greedy")]
    assert [(_pct(g["mean"]), _pct(g["half"])) for g in gain_a] == [
        (15.5, 2.9), (15.5, 3.7), (15.2, 3.7)]

    # the prose says these figures (editing one there fails here)
    sec = _section("Sensitivity: is the comparison a property of SERN")
    lo_p = min(v["pvalue"] for v in comps)
    assert (f"smallest unadjusted p {lo_p:.2f}; every Holm-adjusted p "
            f"{min(v['pvalue_holm'] for v in comps):.2f}") in sec
    assert (f"from {_pm(min(v['mean'] for v in comps))} to "
            f"{_pm(max(v['mean'] for v in comps))} points") in sec
    halves = [v["half"] for v in comps]
    assert (f"intervals reach from {_pm(min(v['lower'] for v in comps))} to "
            f"{_pm(max(v['upper'] for v in comps))} points (half-widths "
            f"{_pm(min(halves), sign=False)}–{_pm(max(halves), sign=False)}") in sec
    assert ("So, per cell (each comparison's own 95 % interval), the grid rules out a SERN "
            "advantage, or disadvantage, of more than about 6–7 points") in sec
    # simultaneous over the 16: Bonferroni t at 0.05/32 with 9 dof (the summary's half_family)
    from scipy import stats as st

    q1, q16 = st.t.ppf(0.975, 9), st.t.ppf(1 - 0.05 / 32, 9)
    fam = [v["half_family"] for v in comps]
    assert all(abs(f / h - q16 / q1) < 1e-9 for f, h in zip(fam, halves))
    ends = max(max(abs(v["mean"] - f), abs(v["mean"] + f)) for v, f in zip(comps, fam))
    assert (f"taken simultaneously over the {len(comps)} comparisons (Bonferroni, t at "
            f"0.05/32 with 9 dof: {q16:.2f} against {q1:.2f}, intervals {q16 / q1:.2f} times "
            f"wider, half-widths {_pm(min(fam), sign=False)}–{_pm(max(fam), sign=False)}), it "
            f"rules out only differences of more than about {round(100 * ends)} points") in sec
    secs = sorted(c["seconds"] for c in cells.values())
    span = f"{secs[0]:.0f}–{secs[-1]:.0f} s per cell"
    assert span in sec and span in (SENS_TODAY / "README.md").read_text()
    assert (f"40 seeds per cell would bring them to about {_pm(min(halves) / 2, sign=False)}"
            f"–{_pm(max(halves) / 2, sign=False)} points") in sec
    assert f"({_pm(t['20N_mu0.3-0.8_clean']['theta0_B'], sign=False)} % pooled" in sec
    g = {c: v["gap"] for c, v in t.items()}
    def gap(c):
        return _pm(g[c]["mean"], g[c]["half"], sign=g[c]["mean"] < 0)

    assert f"(gap {gap('20N_mu0.3-0.8_d435')} points at 20 N)" in sec
    assert (f"Slipperier objects cost {gap('20N_mu0.2-0.5_clean')} points, the 10 N grip "
            f"{gap('10N_mu0.3-0.8_clean')}, and both together {gap('10N_mu0.2-0.5_clean')} "
            f"(θ0 at {_pm(cells['10N_mu0.2-0.5_clean']['theta0']['mean'], sign=False)} %)"
            ) in sec
    r = {c: rec(c, 5) for c in ("20N_mu0.2-0.5_clean", "10N_mu0.3-0.8_clean",
                                 "10N_mu0.2-0.5_clean", "10N_mu0.2-0.5_d435")}
    assert (f"recovered {r['20N_mu0.2-0.5_clean'][0]}–{r['20N_mu0.2-0.5_clean'][1]} % of the "
            "friction gap") in sec
    assert (f"{r['10N_mu0.3-0.8_clean'][0]}–{r['10N_mu0.3-0.8_clean'][1]} % of the weak-grip "
            f"gap, and only {r['10N_mu0.2-0.5_clean'][0]}–{r['10N_mu0.2-0.5_clean'][1]} % of "
            f"the combined one ({r['10N_mu0.2-0.5_d435'][0]}–{r['10N_mu0.2-0.5_d435'][1]} % "
            "with D435 noise)") in sec
    sg, eg, gg = gain_a
    assert (f"SERN gains {_pm(sg['mean'], sg['half'])} points by round 5, ε-greedy "
            f"{_pm(eg['mean'], eg['half'])}, greedy {_pm(gg['mean'], gg['half'])}") in sec


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
    d = json.loads((RESULTS / "trial_checks_6N.json").read_text())
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
    from sern_jax.grasp.model import pretrain

    for name, (g, b, f, hard) in quoted.items():
        r = rows[name]
        assert (round(r["greedy_success"], 2), round(r["best_success"], 2),
                round(r["best_success_fresh"], 2)) == (g, b, f)
        assert r["hard"] is hard and pretrain.is_hard(r) is hard
        assert r["best_success_fresh"] == pytest.approx(np.mean(r["best_fresh_per_pose"]))


# The theory-on-grasping checks moved to tests/test_results_quoted_trial.py (engineer T).


# The 'Baselines' section's numbers (issue 18) are checked in
# tests/test_results_quoted_baselines.py (engineer B's file).


# --- The headline runs (issue 17): Table I's paper setting, the 20-seed run, the ablations
# and sim-to-sim transfer, each from its committed per-seed files ---

from experiments import grasp_learning as gl  # noqa: E402

DOC = (Path(__file__).resolve().parents[1] / "docs" / "RESULTS.md").read_text()
SETTINGS = ("paper", "strong", "alpha", "core_set", "loss", "schedule")


def _rebuilt(setting, tmp_path):
    d = tmp_path / setting
    d.mkdir()
    for f in (RESULTS / setting).glob("*.json"):
        if f.name != "summary.json":
            shutil.copy(f, d / f.name)
    return json.loads(json.dumps(gl.summarise(d)))


@pytest.fixture(scope="module")
def headline(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("headline")
    return {s: _rebuilt(s, tmp) for s in SETTINGS}


@pytest.fixture(scope="module")
def transfer(tmp_path_factory):
    d = tmp_path_factory.mktemp("transfer")
    for f in (RESULTS / "transfer").glob("*.json"):
        if f.name != "summary.json":
            shutil.copy(f, d / f.name)
    return json.loads(json.dumps(grasp_sensitivity.summarise_transfer(d)))


@pytest.mark.parametrize("setting", SETTINGS)
def test_committed_headline_summary_is_what_the_per_seed_files_give(headline, setting):
    assert json.loads((RESULTS / setting / "summary.json").read_text()) == headline[setting]


def test_committed_transfer_summary_is_what_the_per_seed_files_give(transfer):
    assert json.loads((RESULTS / "transfer" / "summary.json").read_text()) == transfer


def test_headline_runs_were_made_with_the_shipped_theta0_and_trial():
    """A per-seed file made before the trial changed (another θ0) fails here."""
    from sern_jax.grasp.model import artifacts
    from sern_jax.grasp.world import scene, sim

    shipped = artifacts.load_theta0().fingerprint
    old = artifacts.load_theta0(grasp_sensitivity.THETA0_6N_DIR).fingerprint
    trial = json.loads(json.dumps(dataclasses.asdict(sim.TrialConfig())))
    files = [f for s in SETTINGS + ("transfer",) for f in (RESULTS / s).glob("*.json")
             if f.name != "summary.json"]
    assert len(files) == 21
    for f in files:
        d = json.loads(f.read_text())
        cell = d.get("world", {}).get("cell")
        want_trial = (json.loads(json.dumps(dataclasses.asdict(
            grasp_sensitivity.transfer_world(cell)[1]))) if cell else trial)
        assert d["trial_config"] == want_trial, f
        want_scene = json.loads(json.dumps(dataclasses.asdict(
            grasp_sensitivity.transfer_world(cell)[0].scene if cell else scene.SceneConfig())))
        assert d["scene_config"] == want_scene, f
        want = old if cell == "theta0_6N" else shipped
        assert d["theta0_digest"] == want, f
        assert d.get("world", {}).get("shipped_theta0_digest", shipped) == shipped, f
        assert d["machine"]["cpu"] and d["command"].startswith("python"), f


def test_table1_tables_are_the_committed_run(headline):
    s = headline["paper"]
    for md in (gl.table1_markdown(s, "paper"), gl.fixed_pose_markdown(s, "paper"),
               gl.pooled_markdown(s, "paper"), gl.comparisons_markdown(s),
               gl.comparisons_markdown(s, "explore_success")):
        assert md in DOC, md.splitlines()[2]


def test_strong_tables_are_the_committed_run(headline):
    s = headline["strong"]
    for md in (gl.pooled_markdown(s, "strong"), gl.comparisons_markdown(s),
               gl.comparisons_markdown(s, "explore_success")):
        assert md in DOC, md.splitlines()[2]


@pytest.mark.parametrize("setting", ("alpha", "core_set", "loss", "schedule"))
def test_ablation_tables_are_the_committed_runs(headline, setting):
    assert gl.comparisons_markdown(headline[setting]) in DOC


def test_transfer_table_is_the_committed_run(transfer):
    assert grasp_sensitivity.transfer_markdown(transfer) in DOC


def _c(s, fam, name):
    return next(c for c in s["comparisons"][fam] if gl._short(c["name"]) == name)


def test_fixed_pose_evaluation_noise_quoted():
    out = {}
    for st in ("paper", "strong"):
        d = gl.load_results(RESULTS / st)[st]
        lv, pe = d["lowvar_eval"], d["paper_eval"]
        r0 = lv[0, :, 0, :]  # θ0: every seed evaluates the same network
        s = lv[-1].mean(0)  # [Q, S]
        out[st] = (_pct(r0.std(1, ddof=1).mean()), _pct(r0.mean(0).std(ddof=1)),
                   _pct(pe[0, :, 0, :].std(1, ddof=1).mean()), _pct((s[0] - s[2]).std(ddof=1)))
    assert out["paper"] == (10.4, 5.4, 19.0, 6.1)
    assert (out["strong"][0], out["strong"][1], out["strong"][3]) == (6.8, 3.1, 2.5)


def test_table1_prose_quoted(headline):
    s = headline["paper"]
    run = s["runs"]["paper"]
    assert run["seeds"] == 5 and run["rounds_done"] == 5 and run["objects"] == [
        "triangular_prism", "tless_part_a", "detergent_bottle", "tless_part_a_steel",
        "pipe_tee_steel", "tless_part_b_steel"]
    fam = s["comparisons"]["final_round"]
    assert len(fam) == 16 and all(round(c["pvalue_holm"], 2) == 1.0 for c in fam)
    assert all(c["lower"] <= 0 <= c["upper"] for c in fam)
    assert _pct(_c(s, "final_round", "sern − egreedy, fixed-pose, pooled")["mean"]) == -2.5
    assert _pct(_c(s, "final_round", "sern − greedy, fixed-pose, pooled")["mean"]) == -3.8
    ex = {c["name"]: c for c in s["comparisons"]["explore_success"]}
    assert [(_pct(c["mean"]), c["resolved"]) for c in ex.values()] == [(-2.5, True), (-3.2, True)]
    gains = [v["final_minus_theta0_lowvar"] for v in run["policies_pooled"].values()]
    assert all(g["lower"] > 0 for g in gains)
    assert (_pct(min(g["mean"] for g in gains)), _pct(max(g["mean"] for g in gains))) == (12.2, 15.9)
    rows = {(r["object"], r["policy"]): r for r in run["table"]}
    tri = [rows[("triangular_prism", p)]["lowvar_rounds"] for p in ("sern", "egreedy", "greedy")]
    assert round(tri[0][0]) == 30 and sorted(round(t[-1]) for t in tri) == [88, 88, 89]
    assert sorted(round(t[2]) for t in tri) == [79, 83, 89]
    det = rows[("detergent_bottle", "sern")]["lowvar_rounds"]
    assert (round(det[0]), round(det[-1])) == (94, 86)
    fills = [rows[(o, "sern")]["lowvar_rounds"][0] for o in run["objects"][1:]]
    assert (round(min(fills)), round(max(fills))) == (74, 95)
    assert round(max(se for r in run["table"] for se in r["se"])) == 19
    imprv = [r["imprv"] for r in run["table"] if r["object"] == "triangular_prism"]
    strong_imprv = [r["imprv"] for r in headline["strong"]["runs"]["strong"]["table"]
                    if r["object"] == "triangular_prism"]
    assert (round(100 * min(imprv + strong_imprv)), round(100 * max(imprv + strong_imprv))) \
        == (90, 122)


def test_strong_prose_quoted(headline):
    s = headline["strong"]
    run = s["runs"]["strong"]
    assert run["seeds"] == 20 and run["rounds_done"] == 5 and len(run["parts"]) == 3
    g = _c(s, "final_round", "sern − greedy, fixed-pose, pooled")
    e = _c(s, "final_round", "sern − egreedy, fixed-pose, pooled")
    assert [_pct(v) for v in (g["mean"], g["lower"], g["upper"])] == [0.3, -0.9, 1.5]
    assert [_pct(v) for v in (e["mean"], e["lower"], e["upper"])] == [-0.4, -1.4, 0.6]
    fam = s["comparisons"]["final_round"]
    assert len(fam) == 16 and not any(c["resolved"] for c in fam)
    low = min(fam, key=lambda c: c["pvalue_holm"])
    assert gl._short(low["name"]) == "sern − egreedy, fixed-pose, tless_part_a"
    assert (round(low["pvalue_holm"], 2), _pct(low["mean"]), _pct(low["half"])) == (0.42, -2.6, 2.3)
    assert [c["name"] for c in fam if c["upper"] < 0 or c["lower"] > 0] == [low["name"]]
    pol = run["policies_pooled"]
    assert [_pct(pol[p]["explore_success"]) for p in ("sern", "egreedy", "greedy")] == [
        83.5, 86.8, 88.3]
    ex = s["comparisons"]["explore_success"]
    assert [(_pct(c["mean"]), c["resolved"]) for c in ex] == [(-3.2, True), (-4.8, True)]
    assert _pct(pol["sern"]["lowvar_by_round"][0]) == 77.2
    gains = [pol[p]["final_minus_theta0_lowvar"] for p in pol]
    assert all(g["lower"] > 0 and 16.5 <= _pct(g["mean"]) <= 17.5 for g in gains)
    rows = {(r["object"], r["policy"]): r for r in run["table"]}
    tri = [rows[("triangular_prism", p)]["lowvar_rounds"] for p in ("sern", "egreedy", "greedy")]
    assert round(tri[0][0]) == 39 and sorted(round(t[-1]) for t in tri) == [91, 92, 92]
    det = [rows[("detergent_bottle", p)] for p in ("sern", "egreedy", "greedy")]
    assert round(det[0]["lowvar_rounds"][0]) == 92 and round(det[0]["theta0"]) == 97
    assert sorted(round(r["lowvar_rounds"][-1]) for r in det) == [91, 92, 93]
    assert sorted(round(r["rounds"][-1]) for r in det) == [89, 92, 92]


def test_alpha_prose_quoted(headline):
    s = headline["alpha"]
    assert not any(c["resolved"] for c in s["comparisons"]["final_round"])
    ex = [_pct(s["runs"][f"alpha={a}"]["policies_pooled"]["sern"]["explore_success"])
          for a in ("0.01", "0.05", "0.2", "1.0")]
    assert ex == [87.0, 83.6, 78.7, 75.7]
    assert all(c["resolved"] for c in s["comparisons"]["explore_success"])


def test_transfer_prose_quoted(transfer):
    c = transfer["cells"]
    assert transfer["objects"] == ["triangular_prism", "tless_part_a", "detergent_bottle"]
    assert transfer["seeds"] == 5 and transfer["cells_missing"] == []
    assert all(v["rounds_done"] == 20 for v in c.values())  # mjx resumed: all 20 rounds
    assert _pct(c["A"]["theta0_B"]["mean"]) == 69.4
    assert [_pct(c[k]["theta0_B"]["mean"]) for k in ("friction_low", "heavy", "grip_6N")] == [
        46.0, 43.3, 24.0]
    rec5 = [c[k]["policies"][p]["recovered"]["5"] for k in ("friction_low", "heavy")
            for p in ("sern", "egreedy", "greedy")]
    assert (round(100 * min(rec5)), round(100 * max(rec5))) == (147, 203)
    a5 = [c["A"]["policies"][p]["gain"]["5"]["mean"] for p in ("sern", "egreedy", "greedy")]
    assert (_pct(min(a5)), _pct(max(a5))) == (20.4, 23.5)

    def minus_a(cell, p):
        m = c[cell]["policies"][p]["minus_A"]["20"]
        return (_pct(m["mean"]), _pct(m["half"]))

    assert [minus_a("friction_low", p) for p in ("sern", "egreedy", "greedy")] == [
        (-0.6, 2.2), (-2.5, 6.0), (-1.9, 5.4)]
    assert [minus_a("heavy", p) for p in ("sern", "egreedy", "greedy")] == [
        (-2.7, 3.0), (-2.1, 2.6), (-0.6, 3.1)]
    assert [minus_a("grip_6N", p) for p in ("sern", "egreedy", "greedy")] == [
        (-17.3, 2.0), (-23.5, 8.8), (-16.7, 3.7)]
    rec20 = [c["grip_6N"]["policies"][p]["recovered"]["20"] for p in ("sern", "egreedy", "greedy")]
    assert (round(100 * min(rec20)), round(100 * max(rec20))) == (106, 119)
    t6 = c["theta0_6N"]
    assert (_pct(t6["theta0_B"]["mean"]), _pct(t6["gap"]["mean"]), _pct(t6["gap"]["half"])) == (
        78.1, -8.8, 10.1)
    assert [minus_a("theta0_6N", p) for p in ("sern", "egreedy", "greedy")] == [
        (1.0, 1.8), (1.3, 1.4), (2.1, 1.8)]
    comps = transfer["comparisons"]
    assert len(comps) == 28 and not any(x["resolved"] for x in comps)
    low = min(comps, key=lambda x: x["pvalue_holm"])
    assert low["name"] == "heavy: sern - egreedy, round 5"
    assert (round(low["pvalue_holm"], 2), _pct(low["mean"]), _pct(low["half"])) == (0.68, -5.2, 4.1)
    # D435 depth noise and MJX physics (rounds 0-13 from the first call, 14-20 resumed)
    d4, mj = c["d435"], c["mjx"]
    assert (_pct(d4["theta0_B"]["mean"]), _pct(d4["gap"]["mean"]), _pct(d4["gap"]["half"])) == (
        66.7, 2.7, 6.2)
    assert d4["gap"]["lower"] < 0 and d4["policies"]["sern"]["recovered"]["20"] is None
    assert [minus_a("d435", p) for p in ("sern", "egreedy", "greedy")] == [
        (1.9, 4.5), (1.5, 3.9), (2.9, 7.0)]
    assert (_pct(mj["theta0_B"]["mean"]), _pct(mj["gap"]["mean"]), _pct(mj["gap"]["half"])) == (
        65.2, 4.2, 2.2)
    assert mj["gap"]["lower"] > 0 and mj["rounds_reported"] == [1, 5, 20]
    assert [minus_a("mjx", p) for p in ("sern", "egreedy", "greedy")] == [
        (0.6, 3.2), (-2.3, 4.0), (0.4, 3.2)]
    assert [_pct(mj["policies"][p]["gain"]["20"]["mean"]) for p in ("sern", "egreedy",
                                                                    "greedy")] == [30.6, 28.3, 29.6]
    g5 = [mj["policies"][p]["gain"]["5"]["mean"] for p in ("sern", "egreedy", "greedy")]
    assert (_pct(min(g5)), _pct(max(g5))) == (24.2, 25.4)
    # the mjx cell's progress log: round 0 done ~183 s after the script started, round 13 at
    # 537 s (27 s per round on average), stopped by the 545 s limit
    prog = [ln.split() for ln in (RESULTS / "transfer" / "mjx_progress.txt").read_text()
            .splitlines() if not ln.startswith("#")]
    first = {int(r[3]): int(r[0]) for r in reversed(prog)}
    assert (first[1], first[14], max(first)) == (183, 537, 14)
    assert round((first[14] - first[1]) / 13) == 27
    rec_mjx = [mj["policies"][p]["recovered"][r] for p in ("sern", "egreedy", "greedy")
               for r in ("5", "20")]
    assert (round(100 * min(rec_mjx)), round(100 * max(rec_mjx))) == (580, 735)
    ends = {r: max(max(abs(x["lower"]), abs(x["upper"])) for x in comps
                   if x["name"].endswith(f"round {r}")) for r in (5, 20)}
    assert (round(100 * ends[5]), round(100 * ends[20])) == (15, 13)
    # the native-MJX agreement quoted beside the mjx world (T's files, experiments/results/
    # agreement; tests/test_results_quoted_trial.py checks them against docs/GRASP.md)
    ag = [next(iter(json.loads(f.read_text())["agreement"]["objects"].values()))
          for f in (RESULTS / "agreement").glob("agreement_*.json")]
    agree = sum(round(a["agreement"] * a["num_trials"]) for a in ag)
    total = sum(a["num_trials"] for a in ag)
    assert _pct(agree / total) == 94.8 and round(100 * (1 - agree / total)) == 5
    jobs = (RESULTS / "transfer" / "device_jobs.txt").read_text()
    assert "transfer-mjx: exit 137 after 545 s on cores 0-15" in jobs
    assert "transfer-d435: exit 0 after 188 s on cores 0-15" in jobs

    # the prose says these figures (editing one there fails here)
    sec = _section("Sim-to-sim transfer")
    th = {k: _pm(v["theta0_B"]["mean"], sign=False) for k, v in c.items()}
    assert (f"from {th['A']} % in A to {th['friction_low']} % with slipperier objects, "
            f"{th['heavy']} % with heavier ones and {th['grip_6N']} % with a 6 N grip") in sec
    assert f"(recovered {round(100 * min(rec5))}–{round(100 * max(rec5))} %:" in sec
    assert (f"every policy gains {round(100 * min(a5))}–{round(100 * max(a5))} points by "
            "round 5") in sec

    def ma(cell, p, r="20"):
        m = c[cell]["policies"][p]["minus_A"][r]
        return _pm(m["mean"], m["half"], sign=m["mean"] < 0)

    # "not resolved from" (not "level with"): every such interval contains 0
    for cell, r in (("friction_low", "20"), ("heavy", "20"), ("d435", "20"), ("mjx", "20")):
        for p in ("sern", "egreedy", "greedy"):
            m = c[cell]["policies"][p]["minus_A"][r]
            assert m["lower"] < 0 < m["upper"], (cell, p)
    assert ("and by round 20 it is not resolved from the same policy learning in A (success in B "
            f"minus in A at round 20: SERN {ma('friction_low', 'sern')} and "
            f"{ma('heavy', 'sern')} points, ε-greedy {ma('friction_low', 'egreedy')} and "
            f"{ma('heavy', 'egreedy')}, greedy {ma('friction_low', 'greedy')} and "
            f"{ma('heavy', 'greedy')}, friction and mass)") in sec
    g6 = [c["grip_6N"]["policies"][p]["minus_A"]["20"]["mean"] for p in ("sern", "egreedy",
                                                                        "greedy")]
    assert (f"still {round(-100 * max(g6))}–{round(-100 * min(g6))} points below the same "
            f"policy in A (SERN {ma('grip_6N', 'sern')}, ε-greedy {ma('grip_6N', 'egreedy')}, "
            f"greedy {ma('grip_6N', 'greedy')})") in sec
    assert (f"though, as point estimates, each has recovered the gap to A's θ0 "
            f"({round(100 * min(rec20))}–{round(100 * max(rec20))} % of it)") in sec
    # shares are ratios of point estimates, given only for resolved gaps; every one of those
    # is >= 100 % at the last round, but grip_6N's egreedy gain does not exclude the gap
    resolved = {k for k, v in c.items() if v["gap"]["lower"] > 0}
    assert resolved == {"friction_low", "heavy", "grip_6N", "mjx"}
    assert all(v["gap"]["lower"] < 0 < v["gap"]["upper"] for k, v in c.items()
               if k in ("d435", "theta0_6N"))
    for k in resolved:
        last = str(c[k]["rounds_done"])
        assert all(c[k]["policies"][p]["recovered"][last] >= 1 for p in c[k]["policies"])
    ge, gp = c["grip_6N"]["policies"]["egreedy"]["gain"]["20"], c["grip_6N"]["gap"]
    assert ge["mean"] - ge["half"] < gp["mean"]  # 100 % is not shown
    assert ("As point estimates, online learning recovers all of each resolved gap under every "
            "policy; no difference between policies is resolved.** (The shares are ratios of "
            f"point estimates: for `grip_6N`, ε-greedy's gain of "
            f"{_pm(ge['mean'], ge['half'], sign=False)} points by round 20 against a gap of "
            f"{_pm(gp['mean'], gp['half'], sign=False)} does not show that 100 % is recovered; "
            "`d435` and `theta0_6N` have no resolved gap.)") in sec
    assert (f"({th['theta0_6N']} % against the shipped θ0's {th['A']} %; the difference, "
            f"{_pm(-t6['gap']['mean'], t6['gap']['half'], sign=False)} points in its favour, "
            "is not resolved)") in sec
    t6m = {p: t6["policies"][p]["minus_A"]["20"] for p in ("sern", "egreedy", "greedy")}
    assert [v["lower"] > 0 for v in t6m.values()] == [False, False, True]
    assert (f"its learners are {_pm(min(v['mean'] for v in t6m.values()))} to "
            f"{_pm(max(v['mean'] for v in t6m.values()))} points above the shipped θ0's (only "
            f"greedy's {_pm(t6m['greedy']['mean'], t6m['greedy']['half'])} excludes 0, before "
            f"any correction; SERN's {_pm(t6m['sern']['mean'], t6m['sern']['half'])} and "
            f"ε-greedy's {_pm(t6m['egreedy']['mean'], t6m['egreedy']['half'])} are not "
            "resolved from 0)") in sec
    assert (f"success is {th['d435']} % against {th['A']} % in A, a gap of "
            f"{_pm(d4['gap']['mean'], d4['gap']['half'])} points that is not resolved") in sec
    d4m = {p: (d4["policies"][p]["minus_A"]["20"]["mean"], d4["policies"][p]["minus_A"]["20"]
               ["half"]) for p in ("sern", "egreedy", "greedy")}
    assert ("after 20 rounds no policy is resolved from the same policy in A (SERN "
            f"{_pm(*d4m['sern'])}, ε-greedy {_pm(*d4m['egreedy'])}, greedy "
            f"{_pm(*d4m['greedy'])})") in sec
    assert (f"Under MJX physics θ0 falls to {th['mjx']} %, a small but resolved gap of "
            f"{_pm(mj['gap']['mean'], mj['gap']['half'])} points") in sec
    assert f"every policy gains {_pct(min(g5))}–{_pct(max(g5))} points by round 5" in sec
    assert (f"the recovered shares of {round(100 * min(rec_mjx))}–{round(100 * max(rec_mjx))} %"
            ) in sec
    mjm = {p: _pm(mj["policies"][p]["minus_A"]["20"]["mean"],
                  mj["policies"][p]["minus_A"]["20"]["half"]) for p in ("sern", "egreedy",
                                                                        "greedy")}
    assert ("by round 20 none is resolved from the same policy learning natively in A (SERN "
            f"{mjm['sern']}, ε-greedy {mjm['egreedy']}, greedy {mjm['greedy']} points; rounds "
            "14–20 come from a resumed run, below)") in sec
    assert (f"{len(comps)} comparisons (7 worlds × 2 peers × 2 rounds), none resolved after Holm "
            f"(smallest adjusted p {low['pvalue_holm']:.2f}: `heavy`, SERN − ε-greedy at round "
            f"5, {_pm(low['mean'], low['half'])})") in sec
    wide = {r: max((x for x in comps if x["name"].endswith(f"round {r}")),
                   key=lambda x: x["half"]) for r in (5, 20)}
    assert [x["name"] for x in wide.values()] == ["friction_low: sern - greedy, round 5",
                                                 "grip_6N: sern - egreedy, round 20"]
    assert (f"the largest SERN − peer half-widths are {_pct(wide[5]['half'])} points at round 5 "
            f"(`friction_low`, SERN − greedy) and {_pct(wide[20]['half'])} at round 20 "
            "(`grip_6N`, SERN − ε-greedy), and the intervals' ends reach "
            f"{_pct(ends[5])} points from 0 at round 5 and {_pct(ends[20])} at round 20") in sec
    assert (f"the two agree on {_pct(agree / total)} % of paired trials" in sec
            and f"disagree on about {round(100 * (1 - agree / total))} % of paired trials" in sec)
    assert (f"round 0 (the three objects' MJX compiles, θ0's evaluation) finished {first[1]} s "
            f"after the script started, and rounds 1–13 took "
            f"{round((first[14] - first[1]) / 13)} s each on average") in sec
    # which code and cores each call had, and the first call's killed mjx attempt
    done = {ln.split(":")[0]: ln for ln in jobs.splitlines() if ": exit " in ln}
    first_call = jobs.splitlines()[9]
    assert first_call.startswith("transfer-mjx: exit 137 after 440 s on cores 15:")
    assert ("first `mjx` attempt, on one core, was killed at 440 s before finishing round 0: "
            "line 10 of `device_jobs.txt`") in sec
    secs = [int(done[f"transfer-{k}"].split("after ")[1].split()[0]) for k in
            ("A", "friction_low", "heavy", "grip_6N", "theta0_6N")]
    assert f"3 cores per cell, {min(secs)}–{max(secs)} s each" in sec
    meta = {k: json.loads((RESULTS / "transfer" / f"{k}.json").read_text())["machine"]
            ["cores_usable"] for k in c}
    assert meta == {"A": 3, "friction_low": 3, "heavy": 3, "grip_6N": 3, "theta0_6N": 3,
                    "d435": 16, "mjx": 16}
    assert "code 3510cbc" in jobs and "those two on code 3510cbc" in sec
    # the resumed mjx cell: the fourth call's job line, its progress log and the prose
    resumed = jobs.split("# 2026-11-24 13:10-13:17 UTC")[1]
    assert "RESUME=experiments/results/transfer/resume_mjx" in resumed
    rline = next(ln for ln in resumed.splitlines() if ln.startswith("transfer-mjx: exit 0 after"))
    rsecs = int(rline.split("after ")[1].split()[0])
    assert rline.startswith(f"transfer-mjx: exit 0 after {rsecs} s on cores 0-15:")
    rprog = [ln.split() for ln in (RESULTS / "transfer" / "mjx_resume_progress.txt")
             .read_text().splitlines() if not ln.startswith("#")]
    rfirst = {int(r[3]): int(r[0]) for r in reversed(rprog)}
    assert (min(rfirst), max(rfirst), rfirst[15]) == (14, 20, 256)
    assert round((rfirst[20] - rfirst[15]) / 5) == 27
    assert (f"exit 0 after {rsecs} s; the restart (MJX compiles, the replay of rounds 1–13's updates) "
            f"and round 14 were done {rfirst[15]} s after the script started, rounds 15–19 took "
            f"{round((rfirst[20] - rfirst[15]) / 5)} s each") in sec
    from sern_jax.grasp.model import artifacts
    from sern_jax.grasp.world import objects as objs
    from sern_jax.grasp.online import runner as rn
    shipped = artifacts.load_theta0()
    cfg = rn.OnlineConfig(num_seeds=5, rounds=20, backend="mjx")
    fp = rn.run_fingerprint(cfg, [objs.make_object(n) for n in transfer["objects"]], shipped)
    ck = np.load(RESULTS / "transfer" / "resume_mjx" / "transfer" / "runs" / "mjx" /
                 "checkpoint.npz")
    assert str(ck["fingerprint"]) == fp == "79c48fa542de7f59" and int(ck["next_round"]) == 14
    assert f"the same run fingerprint, {fp}, checked" in sec
    # rounds 0-13 of the resumed file are the checkpoint's (the first call's) bit for bit
    full = json.loads((RESULTS / "transfer" / "mjx.json").read_text())
    for f in ("lowvar_eval", "paper_eval", "explore_success"):
        x = np.asarray(full[f], float)
        y = np.where(np.isnan(ck[f]), -1.0, np.asarray(ck[f], float))  # files store NaN as -1
        assert x.shape[0] == 21 and np.array_equal(x[:14], y[:14], equal_nan=True), f
    # the grid's world-A cell holds transfer A's 3 objects x 5 seeds: equal at round 0 and
    # for SERN in rounds 1-4, not for the peers (learning curves not reproduced exactly)
    ta = json.loads((RESULTS / "transfer" / "A.json").read_text())
    ga = json.loads((SENS_TODAY / "20N_mu0.3-0.8_clean.json").read_text())
    assert ga["objects"][:3] == ta["objects"] and ga["policies"] == ta["policies"]
    assert ga["machine"]["cores_usable"] == 2 and ga["theta0_digest"] == ta["theta0_digest"]
    x = np.asarray(ta["lowvar_eval"], float)[:6]
    y = np.asarray(ga["lowvar_eval"], float)[:, :3, :, :5]
    differ = {p: [r for r in range(6) if (x[r, :, q] != y[r, :, q]).any()]
              for q, p in enumerate(ta["policies"])}
    assert differ == {"sern": [5], "egreedy": [1, 4, 5], "greedy": [2, 5]}
    assert round(32 * np.abs(x - y).max()) == 3 and round(32 * np.abs(x[:5] - y[:5]).max()) == 2
    assert ("agree bit for bit at round 0 (θ0) and for SERN in rounds 1–4, but differ for "
            "ε-greedy at rounds 1, 4 and 5 and for greedy at rounds 2 and 5, by up to 3 of 32 "
            "trials per (object, seed) at round 5") in sec
    n_copies = (len(ta["objects"]) * ta["seeds"], len(ga["objects"]) * ga["seeds"])
    assert f"({n_copies[0]} here, {n_copies[1]} in the grid)" in sec


def test_other_ablations_prose_quoted(headline):
    lo = headline["loss"]
    l1 = _c(lo, "final_round", "loss=l1 − loss=bce, fixed-pose, pooled")
    assert [_pct(v) for v in (l1["mean"], l1["lower"], l1["upper"])] == [-12.9, -21.4, -4.4]
    assert l1["resolved"] and round(l1["pvalue_holm"], 2) == 0.03
    assert sum(c["resolved"] for fam in ("core_set", "schedule", "alpha") for c in
               headline[fam]["comparisons"]["final_round"]) == 0
    assert [c["resolved"] for c in lo["comparisons"]["final_round"]] == [True, False]
    run = lo["runs"]["loss=l1"]["policies_pooled"]["sern"]
    assert (_pct(run["lowvar_by_round"][-1]), _pct(run["lowvar_by_round"][0])) == (77.4, 78.1)
    ex = lo["comparisons"]["explore_success"][0]
    assert (_pct(ex["mean"]), ex["resolved"]) == (-5.8, True)
    cs = headline["core_set"]
    assert [_pct(_c(cs, "final_round", f"core={k} − core=dpp, fixed-pose, pooled")[f])
            for k in ("none", "random") for f in ("mean", "half")] == [3.0, 6.7, 1.2, 6.7]
    sc = headline["schedule"]
    d = _c(sc, "final_round", "sern − sern_log, fixed-pose, pooled")
    assert (_pct(d["mean"]), d["resolved"]) == (1.5, False)
    ex = sc["comparisons"]["explore_success"][0]
    assert (_pct(ex["mean"]), ex["resolved"]) == (7.2, True)
    # the CPU reference of the core-set and loss ablations is the Table I run's SERN, bit for bit
    ref = gl.load_results(RESULTS / "core_set")["core=dpp"]
    paper = gl.load_results(RESULTS / "paper")["paper"]
    for f in ("lowvar_eval", "paper_eval"):
        assert np.array_equal(ref[f][:, :, 0], paper[f][:, :, 0])


def test_regret_accounting_quoted(tmp_path):
    s = _rebuilt("regret", tmp_path)
    assert json.loads((RESULTS / "regret" / "summary.json").read_text()) == s
    assert gl.regret_markdown(s, "regret") in DOC
    assert gl.comparisons_markdown(s, "regret_total") in DOC
    d = json.loads((RESULTS / "regret" / "regret.json").read_text())
    assert (d["config"]["regret_trials"], d["config"]["regret_grasps"]) == (4, 2)
    assert round(d["seconds"]) == 690
    assert d["theta0_digest"] == __import__("sern_jax.grasp.model.artifacts", fromlist=["x"]
                                            ).load_theta0().fingerprint
    pr = gl.load_results(RESULTS / "regret")["regret"]["pseudo_regret"]
    assert int((pr[1:] < 0).sum()) == 65 and pr[1:].size == 225
    rows = {(r["object"], r["policy"]): r["pseudo_regret"] for r in s["runs"]["regret"]["table"]}
    tri = [rows[("triangular_prism", p)] for p in ("sern", "egreedy", "greedy")]
    assert sorted(round(r[0]) for r in tri) == [9, 9, 9]
    assert (round(min(r[1] for r in tri)), round(max(r[1] for r in tri))) == (14, 15)
    assert round(max(v for r in tri for v in r[2:]), 1) == 5.5
    tot = {k: v["regret_total"] for k, v in s["runs"]["regret"]["policies_pooled"].items()}
    others = [tot[p][o]["mean"] for p in tot for o in ("tless_part_a", "detergent_bottle")]
    assert (round(min(others), 1), round(max(others), 1)) == (0.4, 9.2)
    fam = s["comparisons"]["regret_total"]
    assert all(c["mean"] > 0 for c in fam) and not any(c["resolved"] for c in fam)
    assert (round(min(c["mean"] for c in fam), 1), round(max(c["mean"] for c in fam), 1)) == (
        0.2, 6.3)
    low = min(fam, key=lambda c: c["pvalue_holm"])
    assert gl._short(low["name"]) == "sern − greedy, triangular_prism"
    assert (round(low["pvalue_holm"], 2), round(low["mean"], 1), round(low["half"], 1)) == (
        0.33, 6.3, 6.5)
    ex = {gl._short(c["name"]): c for c in s["comparisons"]["explore_success"]}
    assert (_pct(ex["sern − greedy"]["mean"]), _pct(ex["sern − greedy"]["half"])) == (-1.7, 3.1)
    assert not any(c["resolved"] for c in ex.values())


def test_mjx_repeat_is_not_bit_identical():
    """docs/RESULTS.md (Transfer): a second run of the mjx cell (transfer/mjx_repeat/) differs
    from the committed one already at round 0 (θ0 before learning): MJX on the GPU is not
    bit-reproducible run to run. Control: the committed cell equals itself."""
    a = json.loads((RESULTS / "transfer" / "mjx.json").read_text())
    b = json.loads((RESULTS / "transfer" / "mjx_repeat" / "mjx.json").read_text())
    assert (a["rounds_done"], b["rounds_done"]) == (20, 13)  # the committed cell was resumed
    assert a["command"] == b["command"] and a["world"] == b["world"]
    x, y = np.asarray(a["lowvar_eval"], float)[:14], np.asarray(b["lowvar_eval"], float)
    differ = [int((x[r] != y[r]).sum()) for r in range(14)]
    assert (differ[0], x[0].size) == (15, 45)
    assert (min(differ[1:]), max(differ[1:])) == (13, 21)
    assert (_pct(y[0].mean()), _pct(x[0].mean())) == (64.8, 65.2)
    assert int((x[0] != x[0]).sum()) == 0

