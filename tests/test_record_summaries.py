"""The committed records under experiments/results/ are what their per-seed files give, were
made with the shipped θ0 and trial, and the summarising commands refuse what they cannot
summarise. (The docs' numbers are rebuilt from these files by figures/doc_tables.py.)"""

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from experiments import grasp_learning as gl
from experiments import grasp_sensitivity

RESULTS = Path(__file__).resolve().parents[1] / "experiments" / "results"
SENS = RESULTS / "sensitivity_6N"  # the earlier 6 N trial's grid, a labelled record
SENS_TODAY = RESULTS / "sensitivity"
SETTINGS = ("paper", "strong", "alpha", "core_set", "loss", "schedule")
THEORY = RESULTS / "theory_grasping"
FORGET = RESULTS / "forgetting"


@pytest.fixture(scope="module")
def sens(tmp_path_factory):
    out = tmp_path_factory.mktemp("sens")
    for f in SENS.glob("*_*.json"):
        shutil.copy(f, out / f.name)
    return grasp_sensitivity.summarise(out)


def test_committed_summary_is_what_the_cells_give(sens):
    committed = json.loads((SENS / "summary.json").read_text())
    assert committed == json.loads(json.dumps(sens))


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


def test_rms_errors_removes_the_ground_truths_binomial_error():
    from experiments.theory_on_grasping import rms_errors

    rng = np.random.default_rng(0)
    c, k, m = 400, 64, 16
    r = rng.uniform(0, 1, (c, k))
    f = rng.binomial(m, r) / m
    valid = rng.uniform(size=(c, k)) < 0.9
    mm = np.full((c, k), m)
    # a perfect estimator: the corrected error is ~0, the uncorrected one sits at the floor
    deb, raw, floor = rms_errors(r, f, mm, valid)
    assert np.mean(deb ** 2) < 2e-3 and np.mean(raw ** 2) > 0.008
    assert np.mean(raw ** 2) == pytest.approx(np.mean(floor ** 2), rel=0.1)
    # an estimator off by 0.2 everywhere: the corrected RMS recovers 0.2, the raw one does not
    deb, raw, _ = rms_errors(np.clip(r + 0.2, 0, 1), f, mm, valid)
    true = np.sqrt(np.mean(np.where(valid, (np.clip(r + 0.2, 0, 1) - r) ** 2, 0).sum(1)
                           / valid.sum(1)))
    assert np.sqrt(np.mean(deb ** 2)) == pytest.approx(true, rel=0.03)
    assert np.sqrt(np.mean(raw ** 2)) > true * 1.1


def test_delta2_split_test_on_synthetic_candidates():
    from experiments.theory_on_grasping import half_counts, split_test

    rng = np.random.default_rng(1)

    def p_values(probs, reps):
        out = []
        for _ in range(reps):
            y = (rng.uniform(size=(4, 256)) < np.asarray(probs)[:, None]).astype(float)
            out.append(split_test(*half_counts(y, np.arange(4)))[1])
        return np.asarray(out)

    # two equal candidates (Δ2 = 0): the one-sided test rejects at most ~5 % of the time
    assert np.mean(p_values([0.9, 0.9, 0.5, 0.4], 400) < 0.05) < 0.07
    # a gap of 0.2 between the best two is found on independent halves
    assert np.mean(p_values([0.9, 0.7, 0.5, 0.4], 50) < 0.05) > 0.9
    # the ranking uses the first half only: the second half decides the gap's sign
    counts = np.array([[128, 10], [0, 100], [0, 0], [0, 0]])
    gap, p, n2 = split_test(counts, 128, 128)
    assert (gap, n2) == ((10 - 100) / 128, 128) and p > 0.99


def test_theory_summary_is_what_the_per_context_file_gives():
    from experiments.theory_on_grasping import summarise_file

    committed = json.loads((THEORY / "results.json").read_text())
    _assert_same_summary(committed["summary"], json.loads(json.dumps(summarise_file(
        THEORY / "per_context.npz"))))


def test_theory_runs_were_made_with_the_shipped_theta0_and_trial():
    from sern_jax.grasp.model import artifacts
    from sern_jax.grasp.world import sim

    for d in (THEORY, RESULTS / "theory_grasping_other"):
        res = json.loads((d / "results.json").read_text())
        assert res["theta0_digest"] == artifacts.load_theta0().fingerprint, d
        assert res["physics"] == json.loads(json.dumps(sim.physics_settings())), d
        assert res["physics"]["scene"]["finger_force"] == 20.0


def test_theory_objects_are_chosen_by_todays_screen():
    """The first three objects of the shipped hard set: the one that meets the rule, then
    the lowest θ0 greedy success among those whose fresh best is >= 0.8; the other run
    takes the remaining three."""
    from sern_jax.grasp.model import artifacts

    hard = artifacts.hard_set(artifacts.load_theta0())
    res = json.loads((THEORY / "results.json").read_text())
    other = json.loads((RESULTS / "theory_grasping_other" / "results.json").read_text())
    assert res["config"]["objects"].split(",") == hard["objects"][:3]
    assert other["config"]["objects"].split(",") == hard["objects"][3:]
    assert hard["meets_rule"] == [True] + [False] * 5
    rows = {r["object"]: r for r in hard["rows"]}
    assert rows["triangular_prism"]["best_success_fresh"] >= 0.8


@pytest.mark.parametrize("argv,flag", [(["--seeds", "1"], "--seeds"), (["--top", "1"], "--top"),
                                       (["--trials", "32"], "--deep-trials"),
                                       (["--objects", "nope"], "--objects")])
def test_theory_bad_input_is_one_line_exit_2(tmp_path, capsys, argv, flag):
    from experiments import theory_on_grasping

    with pytest.raises(SystemExit) as e:
        theory_on_grasping.main(argv + ["--deep-trials", "16"] * (flag == "--deep-trials")
                                + ["--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert e.value.code == 2 and len(err.splitlines()) == 1 and flag in err
    assert not (tmp_path / "out").exists()


def _assert_same_summary(committed, recomputed, path="summary"):
    """The committed summary is what the per-context file gives: same keys, same strings and
    integers, floats equal to 1e-12 relative. Exact float equality failed on the H100
    machine's Python 3.12 / numpy 2.5.2 in the last bit of medians and Holm p-values
    (e.g. -0.1788033169921101 vs -0.17880331699211016): a platform's rounding, not a
    different result; a real change moves digits the quotes print."""
    if isinstance(committed, dict):
        assert isinstance(recomputed, dict) and committed.keys() == recomputed.keys(), path
        for k in committed:
            _assert_same_summary(committed[k], recomputed[k], f"{path}.{k}")
    elif isinstance(committed, list):
        assert isinstance(recomputed, list) and len(committed) == len(recomputed), path
        for i, (a, b) in enumerate(zip(committed, recomputed)):
            _assert_same_summary(a, b, f"{path}[{i}]")
    elif isinstance(committed, float) or isinstance(recomputed, float):
        assert committed == pytest.approx(recomputed, rel=1e-12, abs=1e-15, nan_ok=True), path
    else:
        assert committed == recomputed, path


def test_summary_comparison_still_catches_a_change():
    """Control: the tolerant comparison fails on a change in the 10th digit and on a
    changed key, so the theory tests above are not hollow."""
    base = {"a": -0.1788033169921101, "b": [1, 2.5], "c": "x"}
    _assert_same_summary(base, {"a": -0.17880331699211016, "b": [1, 2.5], "c": "x"})
    with pytest.raises(AssertionError):
        _assert_same_summary(base, {"a": -0.17880331, "b": [1, 2.5], "c": "x"})
    with pytest.raises(AssertionError):
        _assert_same_summary(base, {"a": -0.1788033169921101, "b": [1, 2.5], "d": "x"})


def test_forgetting_summary_is_what_the_per_seed_file_gives():
    from experiments.core_set_forgetting import summarise

    res = json.loads((FORGET / "results.json").read_text())
    committed = json.loads((FORGET / "summary.json").read_text())
    _assert_same_summary(committed, json.loads(json.dumps(summarise(res))))


def test_forgetting_was_made_with_the_shipped_theta0_and_trial():
    from sern_jax.grasp.model import artifacts
    from sern_jax.grasp.world import sim

    cfg = json.loads((FORGET / "config.json").read_text())
    assert cfg["theta0"] == artifacts.load_theta0().fingerprint
    assert cfg["physics"] == json.loads(json.dumps(sim.physics_settings()))
    assert cfg["physics"]["scene"]["finger_force"] == 20.0
    assert cfg["machine"]["cpu_count"] == 2 and cfg["command"].startswith(
        "python -m experiments.core_set_forgetting")


@pytest.mark.parametrize("flag,value", [("--seeds", "0"), ("--steps", "0"),
                                        ("--test-trials", "0"), ("--lr", "0"),
                                        ("--lr", "-0.001"), ("--lr", "nan"), ("--lr", "inf"),
                                        ("--object", "bogus")])
def test_forgetting_bad_input_is_one_line_exit_2(tmp_path, capsys, flag, value):
    from experiments import core_set_forgetting

    with pytest.raises(SystemExit) as e:
        core_set_forgetting.main([flag, value, "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert e.value.code == 2 and len(err.splitlines()) == 1 and flag in err
    assert not (tmp_path / "out").exists()
