"""grasp_baselines' records and commands: the committed summary, table and per-seed file
rebuild from the run's checkpoint, and the commands' entries, timing records, refusals and
merge behave as documented."""

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from experiments import grasp_baselines

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "experiments" / "results" / "grasp_baselines"
OLD = SRC / "whole_networks_175aa72"  # the replaced table (ensemble_ts: M whole networks)


@pytest.fixture(scope="module")
def summary(tmp_path_factory):
    out = tmp_path_factory.mktemp("gb")
    for f in ("per_seed.npz", "meta.json"):
        shutil.copy(SRC / f, out / f)
    s = grasp_baselines.summarize(out)
    return s, out


def test_summary_and_table_rebuild_from_the_per_seed_file(summary):
    s, out = summary
    assert (out / "table.md").read_text() == (SRC / "table.md").read_text()
    assert json.loads((out / "summary.json").read_text()) == json.loads(
        (SRC / "summary.json").read_text())
    assert s["num_seeds"] == 20 and s["rounds"] == 5 and s["rounds_planned"] == 5


@pytest.mark.parametrize("src", [SRC, OLD], ids=["rerun", "whole_networks_175aa72"])
def test_per_seed_file_is_the_runs_checkpoint(tmp_path, src):
    """collect() turns the committed run checkpoint into the committed per-seed file (and
    the replaced table's summary and table rebuild from its per-seed file)."""
    shutil.copy(src / "meta.json", tmp_path / "meta.json")
    (tmp_path / "run").mkdir()
    shutil.copy(src / "run" / "checkpoint.npz", tmp_path / "run" / "checkpoint.npz")
    grasp_baselines.collect(tmp_path)
    a, b = np.load(tmp_path / "per_seed.npz"), np.load(src / "per_seed.npz")
    assert set(a) == set(b)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    assert (tmp_path / "table.md").read_text() == (src / "table.md").read_text()


def test_docs_copy_of_the_paired_figure_is_the_made_one():
    """docs/RESULTS.md shows docs/img/baselines_paired.png (the site cannot link outside docs/):
    it must be byte-identical to the figure made from the per-seed files."""
    import hashlib
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    made = root / "experiments/results/grasp_baselines/baselines_paired.png"
    shown = root / "docs/img/baselines_paired.png"
    assert hashlib.sha256(made.read_bytes()).digest() == hashlib.sha256(shown.read_bytes()).digest()


def test_bench_learner_entries_parse_and_refuse(capsys):
    """bench --learners NAME:field=value entries (the bench records them), and bad ones
    refused in one line naming the flag, exit 2, before anything compiles."""
    got = grasp_baselines.parse_bench_learners("sern,ensemble_ts:ensemble_size=5:bootstrap_p=0.5")
    assert got == [("sern", "sern", {}),
                   ("ensemble_ts:ensemble_size=5:bootstrap_p=0.5", "ensemble_ts",
                    {"ensemble_size": 5, "bootstrap_p": 0.5})]
    for bad, flag in (("ensemble_ts:nu=3", "--learners"), ("nope", "--learners"),
                      ("ensemble_ts:ensemble_size", "--learners"),
                      ("ensemble_ts:ensemble_size=0", "--ensemble-size"),
                      ("sern,sern", "--learners")):
        with pytest.raises(SystemExit) as e:
            grasp_baselines.main(["bench", "--learners", bad])
        assert e.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()[-1]
        assert flag in err, (bad, err)
    with pytest.raises(SystemExit) as e:
        grasp_baselines.main(["bench", "--copies", "6"])
    assert e.value.code == 2 and "--copies" in capsys.readouterr().err


def test_record_learn_timing_reads_the_three_files(tmp_path, capsys):
    """record-learn: wall seconds and machine from --json-out, CPU from /usr/bin/time -v,
    timings and trial counts from metadata.json; a missing file is refused naming the flag."""
    run = tmp_path / "r"
    run.mkdir()
    (run / "metadata.json").write_text(json.dumps(
        {"git_commit": "abc", "timings": {"update": 1.5}, "trial_counts": {"simulated": 7}}))
    (run / "config.json").write_text(json.dumps({"config": {"policies": ["sern"]}}))
    (tmp_path / "r.json").write_text(json.dumps({"seconds": 12.5, "machine": {"cpu": "x"}}))
    (tmp_path / "r.time").write_text(
        '\tCommand being timed: "sern grasp learn --out r"\n\tUser time (seconds): 20.25\n'
        "\tSystem time (seconds): 1.50\n\tPercent of CPU this job got: 170%\n"
        "\tElapsed (wall clock) time (h:mm:ss or m:ss): 0:12.60\n"
        "\tMaximum resident set size (kbytes): 1234\n")
    grasp_baselines.main(["record-learn", "--learn-run", str(run), "--json-out",
                          str(tmp_path / "out.json")])
    d = json.loads((tmp_path / "out.json").read_text())
    assert (d["seconds"], d["user_cpu_s"], d["system_cpu_s"], d["max_rss_kb"]) == (
        12.5, 20.25, 1.5, 1234)
    assert d["machine_at_end"] == {"cpu": "x"} and d["trial_counts"] == {"simulated": 7}
    assert d["command"].endswith("sern grasp learn --out r")
    (tmp_path / "r.time").unlink()
    with pytest.raises(SystemExit) as e:
        grasp_baselines.main(["record-learn", "--learn-run", str(run), "--json-out",
                              str(tmp_path / "out2.json")])
    assert e.value.code == 2 and "--learn-run" in capsys.readouterr().err
    assert not (tmp_path / "out2.json").exists()


def test_run_refuses_a_ray_unit_of_another_run_before_writing_meta(tmp_path, capsys,
                                                                   monkeypatch):
    """``run`` reads the --ray units' checkpoints too (run/units/object_*/checkpoint.npz,
    what a Ray run leaves, also one stopped before any join): a unit of a reported object
    with another fingerprint is refused in one line, exit 2, before meta.json is touched;
    the same settings' unit (and a unit of an object not run) passes to the runner."""
    from sern_jax.infra import io
    from sern_jax.grasp.online import config as online_config
    from sern_jax.grasp.online import learn_units

    argv = ["run", "--out", str(tmp_path), "--untuned", "--objects", "1", "--seeds", "2",
            "--rounds", "1", "--no-progress"]
    specs, theta0 = grasp_baselines.hard_specs()
    config = grasp_baselines.online_config(
        grasp_baselines.learners(), {}, num_seeds=2, rounds=1, explore=20, regret_trials=0,
        regret_grasps=0, backend="native")
    unit = learn_units.unit_dir(tmp_path / "run", specs[0]) / "checkpoint.npz"
    unit.parent.mkdir(parents=True)
    other = dataclasses.replace(config, num_seeds=3)  # another run's unit
    io.save_npz(unit, next_round=np.int64(1),
                fingerprint=np.str_(online_config.run_fingerprint(other, specs[:1], theta0)))
    meta = json.dumps({"num_seeds": 99, "calls": [{"start_round": 0}]})
    (tmp_path / "meta.json").write_text(meta)
    with pytest.raises(SystemExit) as exc:
        grasp_baselines.main(argv)
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 2 and len(err.splitlines()) == 1, err
    assert "a --ray unit of" in err and unit.parent.name in err
    assert (tmp_path / "meta.json").read_text() == meta
    assert not (tmp_path / "run" / "checkpoint.npz").exists()

    # control: this run's own unit, beside a unit of an object not run, is not refused
    io.save_npz(unit, next_round=np.int64(1),
                fingerprint=np.str_(online_config.run_fingerprint(config, specs[:1], theta0)))
    stray = learn_units.unit_dir(tmp_path / "run", specs[1]) / "checkpoint.npz"
    stray.parent.mkdir(parents=True)
    io.save_npz(stray, next_round=np.int64(1), fingerprint=np.str_("0123456789abcdef"))

    def reached(config, specs, run_dir, theta0, progress):
        raise RuntimeError("runner reached")

    monkeypatch.setattr(grasp_baselines, "_run", reached)
    with pytest.raises(RuntimeError, match="runner reached"):
        grasp_baselines.main(argv)
    assert json.loads((tmp_path / "meta.json").read_text())["num_seeds"] == 2


def _fake_comparison(root, learners, rng, regret=True):
    """A comparison's files as run/tune write them (2 objects, 3 seeds, 2 rounds)."""
    from sern_jax.infra import io

    r1, o, q, s, e = 3, 2, len(learners), 3, 4
    root.mkdir(parents=True)
    (root / "run").mkdir()
    arrays = {f: rng.random((r1, o, q, s)) for f in grasp_baselines.PER_SEED_FIELDS}
    if not regret:
        arrays["pseudo_regret"][:] = np.nan
    io.save_npz(root / "run" / "checkpoint.npz", fingerprint=np.str_("0123456789abcdef"),
                next_round=np.int64(r1), **arrays,
                explore_action=rng.integers(0, 64, (r1, o, q, s, e)).astype(np.int32),
                explore_reward=rng.integers(0, 2, (r1, o, s, q, e)).astype(np.int8))
    same = {k: k for k in grasp_baselines._MERGE_SAME}
    same.update(objects=["a", "b"], num_seeds=s, rounds=r1 - 1, regret_trials=2 * regret,
                reference="sern")
    meta = {**same, "learners": learners, "run_dir": str(root / "nowhere"),
            "learner_configs": {n: {"k": n} for n in learners},
            "hyperparameters": {"alpha": 0.02, "ensemble_size": 5}, "command": "old"}
    (root / "meta.json").write_text(json.dumps(meta))
    knobbed = [n for n in learners if n in grasp_baselines.GRID]
    tps = {"lowvar_eval": rng.random((3, r1, o, len(knobbed), s)).astype(np.float32),
           "explore_success": rng.random((3, r1, o, len(knobbed), s)).astype(np.float32)}
    np.savez_compressed(root / "tune_per_seed.npz", **tps)
    grid = {n: {"field": grasp_baselines.GRID[n][0], "settings": [1, 2, 3],
                "scores": [float(x) for x in tps["lowvar_eval"][:, 1:, :, i].mean((1, 2, 3))],
                "chosen": 1} for i, n in enumerate(knobbed)}
    (root / "tuned.json").write_text(json.dumps(
        {"objects": ["c"], "seeds": s, "rounds": r1 - 1, "explore": 20, "criterion": "x",
         "learners": knobbed, "grid": grid, "command": "tune"}))
    return arrays, tps


def test_merge_replaces_learners_only_when_the_reference_is_bit_identical(tmp_path, capsys):
    """merge: the rerun's ensemble_ts replaces the comparison's (per-seed file, tuning,
    configs), every other learner is kept, and the rerun's sern must equal the
    comparison's bit for bit in results, choices, rewards and tuning; a sern differing in
    one number is refused in one line, exit 2, nothing written."""
    from sern_jax.infra import io

    rng = np.random.default_rng(0)
    out, new = tmp_path / "out", tmp_path / "new"
    names = ["sern", "egreedy", "ensemble_ts"]
    old, old_tps = _fake_comparison(out, names, rng)
    fresh, fresh_tps = _fake_comparison(new, ["sern", "ensemble_ts"], rng)
    # the rerun's sern is the comparison's (what independence of learners gives)
    ck_old = io.load_npz(out / "run" / "checkpoint.npz")
    ck_new = dict(io.load_npz(new / "run" / "checkpoint.npz"))
    for f in grasp_baselines.PER_SEED_FIELDS + ("explore_action",):
        ck_new[f][:, :, 0] = ck_old[f][:, :, 0]
    ck_new["explore_reward"][..., 0, :] = ck_old["explore_reward"][..., 0, :]
    for f in fresh_tps:
        fresh_tps[f][:, :, :, 0] = old_tps[f][:, :, :, 0]
    np.savez_compressed(new / "tune_per_seed.npz", **fresh_tps)
    meta_new = json.loads((new / "meta.json").read_text())
    meta_new.update(learner_configs={"sern": {"k": "sern"}, "ensemble_ts": {"k": "shared"}},
                    hyperparameters={"alpha": 0.02, "ensemble_size": 10}, command="new")
    (new / "meta.json").write_text(json.dumps(meta_new))

    def write(ck):
        io.save_npz(new / "run" / "checkpoint.npz", **ck)

    # control first: one sern number differs -> refused, nothing written
    bad = {k: np.array(v) for k, v in ck_new.items()}
    bad["lowvar_eval"][2, 1, 0, 2] += 1e-7
    write(bad)
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    with pytest.raises(SystemExit) as exc:
        grasp_baselines.main(["merge", "--out", str(out), "--merge-from", str(new)])
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 2 and len(err.splitlines()) == 1, err
    assert "sern lowvar_eval differs" in err
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before

    write(ck_new)
    grasp_baselines.main(["merge", "--out", str(out), "--merge-from", str(new)])
    capsys.readouterr()
    got = np.load(out / "per_seed.npz")
    for f in grasp_baselines.PER_SEED_FIELDS:
        np.testing.assert_array_equal(got[f][:, :, 2], fresh[f][:, :, 1].astype(np.float32))
        np.testing.assert_array_equal(got[f][:, :, :2], old[f][:, :, :2].astype(np.float32))
    meta = json.loads((out / "meta.json").read_text())
    assert meta["learners"] == names and meta["command"] == "old"
    assert meta["learner_configs"]["ensemble_ts"] == {"k": "shared"}
    assert meta["hyperparameters"] == {"alpha": 0.02, "ensemble_size": 10}
    part = meta["merged"][0]
    assert part["learners"] == ["ensemble_ts"] and part["command"] == "new"
    assert (out / part["run_dir"] / "checkpoint.npz").exists()
    tuned = json.loads((out / "tuned.json").read_text())
    assert tuned["grid"]["ensemble_ts"]["scores"] == json.loads(
        (new / "tuned.json").read_text())["grid"]["ensemble_ts"]["scores"]
    assert tuned["replaced"]["ensemble_ts"]["scores"] != tuned["grid"]["ensemble_ts"]["scores"]
    assert set(tuned["resolution"]["learners"]) == {"sern", "egreedy", "ensemble_ts"}
    tps = np.load(out / "tune_per_seed.npz")
    np.testing.assert_array_equal(tps["lowvar_eval"][:, :, :, 2],
                                  fresh_tps["lowvar_eval"][:, :, :, 1])
    np.testing.assert_array_equal(tps["lowvar_eval"][:, :, :, :2],
                                  old_tps["lowvar_eval"][:, :, :, :2])
    # collect rebuilds the same per-seed file from the two checkpoints
    first = dict(got.items())
    grasp_baselines.collect(out)
    capsys.readouterr()
    again = np.load(out / "per_seed.npz")
    for f, value in first.items():
        np.testing.assert_array_equal(again[f], value)


def test_run_refuses_a_run_made_under_the_former_ensemble_default(tmp_path, capsys,
                                                                  monkeypatch):
    """The fingerprint holds the hyperparameters given, not defaults, so a run directory
    made when ensemble_ts defaulted to whole networks has the fingerprint of today's
    shared-heads default: ``run`` compares the learner configs meta.json recorded (a
    missing ensemble_heads = networks) and refuses in one line, exit 2, nothing written;
    a run recorded with shared heads resumes."""
    from sern_jax.infra import io
    from sern_jax.grasp.online import config as online_config

    argv = ["run", "--out", str(tmp_path), "--untuned", "--objects", "1", "--seeds", "2",
            "--rounds", "1", "--no-progress"]
    specs, theta0 = grasp_baselines.hard_specs()
    config = grasp_baselines.online_config(
        grasp_baselines.learners(), {}, num_seeds=2, rounds=1, explore=20, regret_trials=0,
        regret_grasps=0, backend="native")
    (tmp_path / "run").mkdir()
    io.save_npz(tmp_path / "run" / "checkpoint.npz", next_round=np.int64(1),
                fingerprint=np.str_(online_config.run_fingerprint(config, specs[:1], theta0)))
    old = {"ensemble_size": 3, "bootstrap": "bernoulli", "bootstrap_p": 0.95}
    meta = json.dumps({"num_seeds": 99, "learner_configs": {"ensemble_ts": old}})
    (tmp_path / "meta.json").write_text(meta)
    with pytest.raises(SystemExit) as exc:
        grasp_baselines.main(argv)
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 2 and len(err.splitlines()) == 1, err
    assert "ensemble_heads = 'networks'" in err and "'shared'" in err
    assert (tmp_path / "meta.json").read_text() == meta

    (tmp_path / "meta.json").write_text(json.dumps(
        {"num_seeds": 99, "learner_configs": {"ensemble_ts": {**old,
                                                               "ensemble_heads": "shared"}}}))

    def reached(config, specs, run_dir, theta0, progress):
        raise RuntimeError("runner reached")

    monkeypatch.setattr(grasp_baselines, "_run", reached)
    with pytest.raises(RuntimeError, match="runner reached"):
        grasp_baselines.main(argv)
