"""experiments/benchmark.py summarise: a fake benchmark of three parts (run directories
written the way `sern grasp learn` writes them, tiny arrays) joined into per-seed files and
summary.json; the summary recomputes from the per-seed files alone; bad parts are refused
in one line naming the flag with nothing written; the figures and the docs' tables build
from the summary."""

import json
import shutil

import numpy as np
import pytest

from experiments import benchmark as bm
from figures import doc_tables as dt
from sern_jax.analysis import benchmark_stats as bs
from sern_jax.infra import io

R, S, E = 2, 4, 5  # rounds, seeds, exploration grasps
CONFIG = {"num_seeds": S, "rounds": R, "explore": E, "evaluate": 5, "eval_poses": 2,
          "eval_trials": 4, "fit_steps": 40, "batch_size": 32, "learning_rate": 3e-4,
          "loss": "bce", "core_set": "dpp", "seed": 0, "backend": "native", "alpha": 0.02,
          "epsilon": 0.1, "alpha0": 1.0, "p": 0.3, "hyper": []}
OBJECTS = ["o1", "o2", "o3"]


def _values(rng, shape, bonus):
    """Fractions on the evaluation's 1/8 grid, rising over rounds."""
    base = rng.integers(2, 6, shape) + bonus + np.arange(shape[0]).reshape(-1, 1, 1, 1)
    return np.clip(base, 0, 8) / 8.0


def _part(path, objects, policies, rng, bench=None, **cfg):
    """A finished `sern grasp learn` run directory (config.json, metadata.json,
    results.npz), as commands/grasp_learn.write_learn_outputs writes it."""
    path.mkdir(parents=True)
    shape = (R + 1, len(objects), len(policies), S)
    bonus = np.array([2 if p == "sern" else 0 for p in policies]).reshape(1, 1, -1, 1)
    lv = _values(rng, shape, bonus)
    ex = _values(rng, shape, -bonus)
    ex[0] = np.nan
    config = {**CONFIG, **cfg, "policies": list(policies)}
    doc = {"config": config, "objects": objects, "theta0": "t0abc", "fingerprint": path.name}
    if bench:
        doc["benchmark"] = bench
    io.save_json(path / "config.json", doc)
    io.save_json(path / "metadata.json", {"host": "test"})
    io.save_npz(path / "results.npz", paper_eval=lv, lowvar_eval=lv, explore_success=ex,
                explore_action=np.zeros(shape + (E,), np.int32),
                pseudo_regret=np.full(shape, np.nan))
    return path


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    root = tmp_path_factory.mktemp("bench")
    rng = np.random.default_rng(0)
    parts = [_part(root / "a", ["o1", "o2"], ["sern", "greedy"], rng),
             _part(root / "b", ["o3"], ["sern", "greedy"], rng),
             _part(root / "c", OBJECTS, ["egreedy"], rng)]
    screen = root / "screen.json"
    io.save_json(screen, {"rule": {"max_greedy_success": 0.6, "min_best_success": 0.8},
                          "objects": [{"object": o, "greedy_success": g,
                                       "best_success_fresh": 0.9, "poses": 8, "trials": 16,
                                       "fresh_trials": 16, "hard": g <= 0.6}
                                      for o, g in zip(OBJECTS + ["other"],
                                                      (0.4, 0.5, 0.7, 0.1))]})
    bench = root / "toy.json"
    io.save_json(bench, {"name": "toy", "version": 1,
                         "objects": [{"name": o} for o in ["o3", "o1", "o2", "o4"]],
                         "metrics": {"primary": list(bs.PRIMARY),
                                     "secondary": list(bs.SECONDARY)}})
    out = root / "record"
    rc = bm.main(["summarise", "--runs", *map(str, parts), "--screen", str(screen),
                  "--benchmark", str(bench), "--out", str(out)])
    assert rc == 0
    return {"root": root, "parts": parts, "screen": screen, "bench": bench, "out": out,
            "summary": json.loads((out / "summary.json").read_text())}


def test_summary_has_the_contract_fields(world):
    s = world["summary"]
    for key in ("benchmark", "objects", "seeds", "learners", "screen", "comparisons",
                "per_object", "learner_means", "curves", "per_seed_files", "units",
                "conventions"):
        assert key in s, key
    assert s["benchmark"] == {"name": "toy", "version": 1}
    assert s["objects"] == ["o3", "o1", "o2"]  # the benchmark's order
    assert s["objects_missing"] == ["o4"]
    assert s["seeds"] == S and s["learners"] == ["sern", "greedy", "egreedy"]
    assert s["units"] == "percentage points"
    assert [e["object"] for e in s["screen"]] == s["objects"]
    e = s["screen"][0]
    assert (e["theta0_greedy"], e["best_fresh"], e["trials"], e["passed"]) == (70.0, 90.0, 16,
                                                                               False)
    assert len(s["comparisons"]) == 2 * len(bs.METRICS)
    for c in s["comparisons"]:
        assert c["a"] == "sern" and c["level"] == "objects"
        assert c["family"] == ("primary" if c["metric"] in bs.PRIMARY else "secondary")
        assert c["ci_low"] <= c["diff"] <= c["ci_high"] and 0 <= c["p"] <= c["holm_p"] <= 1
        assert set(c["tost"]) == {"margin", "p_lower", "p_upper", "p", "equivalent"}
    assert len(s["per_object"]) == 2 * len(bs.METRICS) * 3
    assert set(s["learner_means"]["greedy"]) == set(bs.METRICS)
    assert sorted(s["curves"]["sern"], key=int) == [str(r) for r in range(R + 1)]
    for f in s["per_seed_files"]:
        assert (world["out"] / f).is_file()


def test_a_comparison_by_hand(world):
    """sern − greedy on curve_area: the t interval over the object means of the per-seed
    paired differences, from the run directories' own arrays."""
    from scipy import stats as sps

    a = io.load_npz(world["parts"][0] / "results.npz")["lowvar_eval"]  # o1, o2
    b = io.load_npz(world["parts"][1] / "results.npz")["lowvar_eval"]  # o3
    lv = np.concatenate([b, a], axis=1)  # the summary's object order o3, o1, o2
    area = 100 * lv[1:].mean(0)  # [O, Q, S]
    m = (area[:, 0] - area[:, 1]).mean(1)
    se = m.std(ddof=1) / np.sqrt(3)
    c = next(c for c in world["summary"]["comparisons"]
             if c["metric"] == "curve_area" and c["b"] == "greedy")
    assert c["diff"] == pytest.approx(m.mean())
    assert c["ci_high"] == pytest.approx(m.mean() + sps.t.ppf(0.975, 2) * se)
    saved = io.load_npz(world["out"] / "per_seed" / "o3.npz")
    np.testing.assert_array_equal(saved["lowvar_eval"][:, :2], b[:, 0])  # sern, greedy
    np.testing.assert_array_equal(saved["metric_curve_area"][:2], area[0])
    assert list(saved["learners"]) == ["sern", "greedy", "egreedy"]


def test_summary_recomputes_from_the_per_seed_files_alone(world, tmp_path):
    import shutil

    copy = tmp_path / "record"
    shutil.copytree(world["out"], copy)
    (copy / "summary.json").unlink()
    assert bm.main(["summarise", "--out", str(copy)]) == 0
    assert json.loads((copy / "summary.json").read_text()) == world["summary"]
    # a per-seed file whose stored metric was changed is refused
    path = copy / "per_seed" / "o1.npz"
    arrays = io.load_npz(path)
    arrays["metric_round5"] = arrays["metric_round5"] + 1.0
    io.save_npz(path, **arrays)
    with pytest.raises(ValueError, match="metric_round5"):
        bm.load_record(copy)


def _refused(capsys, argv, flag, out):
    assert bm.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and flag in err[0], err
    assert not out.exists()
    return err[0]


def test_bad_parts_are_refused_in_one_line(world, tmp_path, capsys):
    out = tmp_path / "never"
    parts = list(map(str, world["parts"]))
    base = ["--screen", str(world["screen"]), "--benchmark", str(world["bench"]),
            "--out", str(out)]
    rng = np.random.default_rng(1)
    unfinished = _part(tmp_path / "unfinished", ["o1"], ["egreedy"], rng)
    (unfinished / "results.npz").unlink()
    assert "not finished" in _refused(
        capsys, ["summarise", "--runs", *parts[:2], str(unfinished), *base], "--runs", out)
    twice = _part(tmp_path / "twice", ["o1"], ["sern"], rng)
    assert "also in" in _refused(capsys, ["summarise", "--runs", *parts, str(twice), *base],
                                 "--runs", out)
    other = _part(tmp_path / "other", OBJECTS, ["egreedy"], rng, rounds=R)
    other_cfg = json.loads((other / "config.json").read_text())
    other_cfg["config"]["eval_trials"] = 16
    io.save_json(other / "config.json", other_cfg)
    assert "eval_trials" in _refused(
        capsys, ["summarise", "--runs", *parts[:2], str(other), *base], "--runs", out)
    assert "o3 × sern" in _refused(capsys, ["summarise", "--runs", *parts[:1], parts[2], *base],
                                 "--runs", out)  # o3 × sern, o3 × greedy missing
    no_row = tmp_path / "screen.json"
    io.save_json(no_row, {"objects": [{"object": "o1", "greedy_success": 0.4,
                                       "best_success_fresh": 0.9, "poses": 8, "trials": 16,
                                       "fresh_trials": 16}]})
    assert "o3" in _refused(capsys, ["summarise", "--runs", *parts, "--screen", str(no_row),
                                     "--benchmark", str(world["bench"]), "--out", str(out)],
                            "--screen", out)
    _refused(capsys, ["summarise", "--runs", *parts, "--screen", str(world["screen"]),
                      "--out", str(out)], "--benchmark", out)  # the parts name none
    _refused(capsys, ["summarise", "--runs", *parts, "--screen", str(world["screen"]),
                      "--benchmark", "no_such_benchmark", "--out", str(out)], "--benchmark",
             out)
    other_metrics = tmp_path / "metrics.json"
    io.save_json(other_metrics, {"name": "toy", "version": 1,
                                 "metrics": {"primary": ["round5"]}})
    assert "primary metrics" in _refused(
        capsys, ["summarise", "--runs", *parts, "--screen", str(world["screen"]),
                 "--benchmark", str(other_metrics), "--out", str(out)], "--benchmark", out)
    _refused(capsys, ["summarise", "--runs", *parts, *base, "--reference", "mine"],
             "--reference", out)
    _refused(capsys, ["summarise", "--out", str(out)], "--out", out)


def test_the_parts_may_name_their_benchmark(world, tmp_path):
    rng = np.random.default_rng(2)
    named = {"name": "toy", "version": 1}
    parts = [_part(tmp_path / "a", ["o1", "o2"], ["sern", "greedy"], rng, bench=named),
             _part(tmp_path / "b", ["o1", "o2"], ["egreedy"], rng, bench=named)]
    s = bm.summarise(tmp_path / "out", parts, [world["screen"]], write=False)
    assert s["benchmark"] == named and s["objects"] == ["o1", "o2"]
    assert s["objects_missing"] is None


def test_power_command(capsys, tmp_path):
    out = tmp_path / "power.json"
    assert bm.main(["power", "--sd-seed", "2,3.5", "--sd-object", "0", "--objects", "12",
                    "--seeds", "40", "--family", "4", "--json-out", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert [r["sd_seed"] for r in rows] == [2.0, 3.5]
    assert rows[0]["detectable"] == pytest.approx(
        bs.detectable_difference(2.0, 0.0, 12, 40, 0.05, 4).diff)
    assert bm.main(["power", "--sd-seed", "2,,3"]) == 2
    assert "--sd-seed" in capsys.readouterr().err


def test_figures_and_doc_tables_build_from_the_summary(world, tmp_path):
    from figures import benchmark as fig

    paths = fig.make_figures(world["out"] / "summary.json", tmp_path)
    assert [p.name for p in paths] == ["benchmark_curves.png", "benchmark_forest.png"]
    assert all(p.read_bytes()[:4] == b"\x89PNG" for p in paths)
    s = world["summary"]
    board = dt.benchmark_leaderboard(s)
    lines = board.splitlines()
    assert len(lines) == 2 + len(s["learners"])
    assert "(reference)" in next(line for line in lines if line.startswith("| SERN"))
    assert "Holm p" in board and "ε-greedy" in board
    comps = dt.benchmark_comparisons(s).splitlines()
    assert len(comps) == 2 + len(s["comparisons"])
    findings = dt.benchmark_findings(s)
    for c in s["comparisons"]:
        if c["metric"] == "curve_area":
            verdict = dt._bench_verdict(c)
            assert verdict in findings
            # the verdict follows the numbers: resolved exactly when Holm p < 0.05
            assert verdict.startswith("resolved") == (c["holm_p"] < 0.05)


def test_rerun_check_finds_equal_cells_equal_and_a_changed_cell(world, tmp_path):
    part = world["parts"][0]
    same = tmp_path / "same"
    shutil.copytree(part, same)
    arrays = {k: v for k, v in np.load(part / "results.npz").items() if k != io.DIGEST_KEY}
    arrays["lowvar_eval"][2, 1, 0, 3] += 1 / 8  # one cell of sern
    changed = tmp_path / "changed"
    shutil.copytree(part, changed)
    io.save_npz(changed / "results.npz", **arrays)
    report = bm.rerun_check(part, [same, changed])
    assert report["reruns"][0]["identical"]
    assert not report["reruns"][1]["identical"]
    assert report["reruns"][1]["learners"]["sern"]["lowvar_eval"]["differ"] == 1
    assert report["reruns"][1]["learners"]["greedy"]["lowvar_eval"]["differ"] == 0
    with pytest.raises(ValueError, match="not the part's"):
        bm.rerun_check(part, [world["parts"][1]])
