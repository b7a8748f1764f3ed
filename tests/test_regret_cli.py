"""`sern regret`: run directory contents, resume after interruption, bad input."""

import json

import numpy as np
import pytest

from sern_jax import cli, io

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
    for name in ("softmax_00000.npz", "softmax_00001.npz"):
        (out / "chunks" / name).write_bytes((run_dir / "chunks" / name).read_bytes())
    (out / "config.json").write_text((run_dir / "config.json").read_text())
    assert cli.main(ARGS + ["--out", str(out), "--no-figures"]) == 0
    a = io.load_npz(run_dir / "results.npz")
    b = io.load_npz(out / "results.npz")
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])


def test_different_experiment_in_same_dir_is_refused(run_dir):
    assert cli.main(ARGS[:-1] + ["--alpha", "0.5", "--out", str(run_dir)]) == 2


@pytest.mark.parametrize("bad,match", [
    (["--alpha", "0"], "alpha0"), (["--epsilon", "2"], "epsilon"), (["--arms", "1"], "num_arms"),
    (["--horizon", "0"], "horizon"), (["--seeds", "0"], "seeds"),
    (["--policies", "softmax,bogus"], "bogus"), (["--estimator", "nn"], "nn"),
    (["--means", "0.1,0.2"], "--means"),
])
def test_bad_input_names_the_value(bad, match, tmp_path, capsys):
    assert cli.main(ARGS + bad + ["--out", str(tmp_path / "x")]) == 2
    assert match in capsys.readouterr().err


def test_summary_saves_theorem1_floor_for_the_figure(run_dir):
    # experiments/regret.py saves α(T), c = e^{-1/α}/K and π_min; the figure only reads them.
    floor = io.load_json(run_dir / "summary.json")["theorem1"]
    assert floor["alpha"] == pytest.approx(0.1)  # constant schedule, default α0
    assert floor["c"] == pytest.approx(np.exp(-1 / 0.1) / 4, rel=1e-12)
    assert floor["pi_min"] == pytest.approx(1 / (1 + 3 * np.exp(1 / 0.1)), rel=1e-12)
