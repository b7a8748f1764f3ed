"""`sern regret`: run directory contents, resume after interruption, bad input."""

import json

import numpy as np
import pytest

from sern_jax.infra import io
from sern_jax.commands import main as cli

ARGS = ["regret", "--policies", "softmax,greedy", "--arms", "4", "--horizon", "200",
        "--seeds", "60", "--chunk-size", "25", "--checkpoints", "8", "--no-progress"]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("regret") / "run"
    assert cli.main(ARGS + ["--out", str(out)]) == 0
    return out


def test_run_directory_contents(run_dir):
    for name in ("config.json", "metadata.json", "results.npz", "summary.json", "report.md",
                 "figures/regret.png", "figures/exploration.png"):
        assert (run_dir / name).exists(), name
    res = io.load_npz(run_dir / "results.npz")
    assert res["softmax__counts"].shape == (60, res["t"].size, 4)
    assert res["t"][-1] == 200
    meta = io.load_json(run_dir / "metadata.json")
    assert meta["versions"]["jax"] and "threefry_partitionable" in meta["jax"]
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["policies"]["greedy"]["regret_T_mean"] > 0


def test_resume_after_interruption_loses_nothing(run_dir, tmp_path):
    # Simulate a run killed after some chunks: copy two finished chunks, rerun, compare.
    out = tmp_path / "resumed"
    (out / "chunks").mkdir(parents=True)
    for path in sorted((run_dir / "chunks").glob("softmax__*.npz"))[:2]:
        (out / "chunks" / path.name).write_bytes(path.read_bytes())
    (out / "config.json").write_text((run_dir / "config.json").read_text())
    assert cli.main(ARGS + ["--out", str(out), "--no-figures"]) == 0
    a = io.load_npz(run_dir / "results.npz")
    b = io.load_npz(out / "results.npz")
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])


def test_different_experiment_in_same_dir_is_refused(run_dir, tmp_path, capsys):
    before = (run_dir / "config.json").read_bytes()
    capsys.readouterr()
    assert cli.main(ARGS[:-1] + ["--alpha", "0.5", "--out", str(run_dir)]) == 2
    err = capsys.readouterr().err.strip()
    assert f"{run_dir} holds a different experiment (fingerprint " in err, err
    assert err.endswith("choose another --out or delete it") and "\n" not in err, err
    assert (run_dir / "config.json").read_bytes() == before
    a_file = tmp_path / "file"
    a_file.write_text("")
    assert cli.main(ARGS + ["--out", str(a_file)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith(f"--out {a_file} exists and is not a directory") and "\n" not in err


@pytest.mark.parametrize("bad,match", [
    (["--alpha", "0"], "--alpha"), (["--epsilon", "2"], "--epsilon"), (["--arms", "1"], "--arms"),
    (["--horizon", "0"], "--horizon"), (["--seeds", "0"], "--seeds"),
    (["--policies", "softmax,bogus"], "bogus"), (["--estimator", "nn"], "nn"),
    (["--means", "0.1,0.2"], "--means"),
])
def test_bad_input_names_the_value(bad, match, tmp_path, capsys):
    assert cli.main(ARGS + bad + ["--out", str(tmp_path / "x")]) == 2
    assert match in capsys.readouterr().err


def test_summary_saves_theorem1_floor_for_the_figure(run_dir):
    # sern_jax/experiment/regret.py saves α(T), c = e^{-1/α}/K and π_min; the figure only reads them.
    floor = io.load_json(run_dir / "summary.json")["theorem1"]
    assert floor["alpha"] == pytest.approx(0.1)  # constant schedule, default α0
    assert floor["c"] == pytest.approx(np.exp(-1 / 0.1) / 4, rel=1e-12)
    assert floor["pi_min"] == pytest.approx(1 / (1 + 3 * np.exp(1 / 0.1)), rel=1e-12)


def _snapshot(root):
    return {p.relative_to(root): (p.read_bytes(), p.stat().st_mtime_ns)
            for p in sorted(root.rglob("*")) if p.is_file()}


def _copy(src, dst):
    import shutil

    shutil.copytree(src, dst)
    return dst


@pytest.mark.parametrize("chunk", ["7", "60"])
def test_rerun_with_another_chunk_size_never_mixes_layouts(run_dir, tmp_path, chunk):
    # A rerun with another --chunk-size used to merge both layouts (duplicated
    # seeds, wrong R_T, summary saying S seeds). Now the saved seeds are reused or recomputed
    # and the merged results equal the first run's exactly.
    out = _copy(run_dir, tmp_path / "d")
    args = [a for a in ARGS] + ["--out", str(out), "--no-figures"]
    args[args.index("--chunk-size") + 1] = chunk
    assert cli.main(args) == 0
    a = io.load_npz(run_dir / "results.npz")
    b = io.load_npz(out / "results.npz")
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    assert b["softmax__regret"].shape[0] == 60
    summary = json.loads((out / "summary.json").read_text())
    assert summary["num_seeds"] == 60


def test_partly_saved_other_layout_is_completed_not_merged(run_dir, tmp_path):
    # a run killed after one chunk of size 25, resumed with --chunk-size 40
    out = tmp_path / "d"
    (out / "chunks").mkdir(parents=True)
    (out / "config.json").write_text((run_dir / "config.json").read_text())
    for path in sorted((run_dir / "chunks").glob("*__seeds_000000000000-*.npz")):
        (out / "chunks" / path.name).write_bytes(path.read_bytes())
    args = list(ARGS) + ["--out", str(out), "--no-figures"]
    args[args.index("--chunk-size") + 1] = "40"
    assert cli.main(args) == 0
    a = io.load_npz(run_dir / "results.npz")
    b = io.load_npz(out / "results.npz")
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_metadata_after_resume_times_every_policy(run_dir, tmp_path):
    out = tmp_path / "resumed"
    (out / "chunks").mkdir(parents=True)
    for path in sorted((run_dir / "chunks").glob("softmax__*.npz")):
        (out / "chunks" / path.name).write_bytes(path.read_bytes())
    (out / "config.json").write_text((run_dir / "config.json").read_text())
    assert cli.main(ARGS + ["--out", str(out), "--no-figures"]) == 0
    timings = io.load_json(out / "metadata.json")["wall_seconds_per_policy"]
    assert set(timings) == {"softmax", "greedy"} and all(v > 0 for v in timings.values())


@pytest.mark.parametrize("bad", [["--devices", "4"], ["--devices", "0"], ["--alpha", "0.5"],
                                 ["--seed", "99999999999999999999"]])
def test_failed_command_leaves_a_finished_run_untouched(run_dir, tmp_path, bad, capsys):
    # `--devices 4` on a finished directory exited 2 after rewriting config.json.
    out = _copy(run_dir, tmp_path / "d")
    before = _snapshot(out)
    assert cli.main(ARGS + bad + ["--out", str(out), "--no-figures"]) == 2
    assert _snapshot(out) == before
    assert "Traceback" not in capsys.readouterr().err


def test_failed_command_creates_no_directory(tmp_path):
    out = tmp_path / "new" / "run"
    assert cli.main(ARGS + ["--devices", "4", "--out", str(out)]) == 2
    assert not (tmp_path / "new").exists() or not out.exists()


@pytest.mark.parametrize("argv,limit", [(["--alpha", "1e-40"], "1.18e-38"),
                                        (["--alpha", "1e-300"], "1e-300")])
def test_alpha_below_smallest_normal_is_refused(argv, limit, tmp_path, capsys):
    # --alpha 1e-40 passed validation and gave NaN rows with exit 0.
    out = tmp_path / "x"
    assert cli.main(ARGS + argv + ["--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--alpha" in err and limit in err and "greedy" in err
    assert not out.exists()


def test_alpha_below_smallest_normal_float64_is_refused(tmp_path, capsys):
    out = tmp_path / "x"
    assert cli.main(ARGS + ["--float64", "--alpha", "1e-320", "--out", str(out)]) == 2
    assert "2.23e-308" in capsys.readouterr().err
    assert not out.exists()


def test_tiny_normal_alpha_gives_finite_results(tmp_path):
    out = tmp_path / "x"
    assert cli.main(["regret", "--policies", "softmax", "--arms", "3", "--horizon", "50",
                     "--seeds", "4", "--checkpoints", "4", "--no-progress", "--no-figures",
                     "--alpha", "1e-37", "--out", str(out)]) == 0
    res = io.load_npz(out / "results.npz")
    assert np.isfinite(res["softmax__regret_rb"]).all()


@pytest.mark.parametrize("how", ["truncate", "empty", "random"])
def test_damaged_seed_chunk_is_recomputed(run_dir, tmp_path, how, capsys):
    """A damaged chunk file is set aside and its seeds computed again: the same results as
    the run that never lost it."""
    out = tmp_path / "damaged"
    (out / "chunks").mkdir(parents=True)
    for path in sorted((run_dir / "chunks").glob("*.npz")):
        (out / "chunks" / path.name).write_bytes(path.read_bytes())
    (out / "config.json").write_text((run_dir / "config.json").read_text())
    victim = sorted((out / "chunks").glob("softmax__*.npz"))[1]
    data = victim.read_bytes()
    victim.write_bytes({"truncate": data[: len(data) // 2], "empty": b"",
                        "random": np.random.default_rng(0).bytes(len(data))}[how])
    assert cli.main(ARGS + ["--out", str(out), "--no-figures"]) == 0
    assert f"{victim}: damaged" in capsys.readouterr().out
    assert victim.with_name(victim.name + ".damaged").exists()
    a = io.load_npz(run_dir / "results.npz")
    b = io.load_npz(out / "results.npz")
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])


def test_regret_run_directory_is_locked(run_dir, capsys):
    import subprocess
    import sys

    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time\nfrom sern_jax.infra import io\n"
         "with io.run_lock(sys.argv[1], command='sern regret (another)'):\n"
         "    print('locked', flush=True)\n    time.sleep(120)\n", str(run_dir)],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        assert cli.main(ARGS + ["--out", str(run_dir), "--no-figures"]) == 2
    finally:
        holder.kill()
        holder.wait()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "in use by" in err[0] and "sern regret (another)" in err[0]
