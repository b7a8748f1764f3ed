"""Bad values for every command's flags (issue 9): exit 2, one line on stderr naming the flag,
no traceback, nothing written, and quickly (everything is checked before any work)."""

import os
import time

import pytest

from sern_jax.commands import main as cli

REGRET = ["regret", "--policies", "softmax", "--arms", "3", "--horizon", "20", "--seeds", "2",
          "--no-progress", "--no-figures", "--out", "run"]
CHECK = ["check", "--quick", "--only", "t1_expected_count", "--no-figures", "--out", "runs"]
BENCH_BANDIT = ["bench", "bandit", "--json", "--arms", "4", "--horizon", "10", "--seeds", "4",
                "--numpy-seeds", "0", "--general-repeats", "0"]
BENCH_GRASP = ["bench", "grasp", "--json", "--quick"]
SHOW = ["grasp", "show", "box", "--no-render", "--trials", "1", "--out", "show"]

CASES = [
    # (base argv, extra argv, text the message must contain)
    (REGRET, ["--arms", "1"], "--arms"),
    (REGRET, ["--arms", "100000000"], "--arms"),
    (REGRET, ["--horizon", "0"], "--horizon"),
    (REGRET, ["--horizon", "99999999999999"], "--horizon"),
    (REGRET, ["--float64", "--horizon", "99999999999999"], "--horizon"),
    (REGRET, ["--seeds", "0"], "--seeds"),
    (REGRET, ["--seeds", "99999999999999"], "--seeds"),
    (REGRET, ["--alpha", "0"], "--alpha"),
    (REGRET, ["--alpha", "nan"], "--alpha"),
    (REGRET, ["--alpha", "1e-40"], "--alpha"),
    (REGRET, ["--alpha", "1e-300"], "1e-300"),
    (REGRET, ["--epsilon", "2"], "--epsilon"),
    (REGRET, ["--contexts", "3", "--gap", "-0.1"], "--gap"),
    (REGRET, ["--contexts", "3", "--gap", "nan"], "--gap"),
    (REGRET, ["--contexts", "3", "--means", "0.1,0.2,0.3"], "--means"),
    (REGRET, ["--means", "0.1,0.2"], "--means"),
    (REGRET, ["--policies="], "--policies"),
    (REGRET, ["--policies", "softmax,bogus"], "bogus"),
    (REGRET, ["--estimator", "nn"], "nn"),
    (REGRET, ["--schedule", "nope"], "nope"),
    (REGRET, ["--seed", "99999999999999999999"], "--seed"),
    (REGRET, ["--seed", "-1"], "--seed"),
    (REGRET, ["--devices", "0"], "--devices"),
    (REGRET, ["--devices", "4"], "--devices"),
    (REGRET, ["--chunk-size", "0"], "--chunk-size"),
    (REGRET, ["--checkpoints", "0"], "--checkpoints"),
    (REGRET, ["--out", "a_file"], "--out"),
    (REGRET, ["--out", "/proc/x"], "--out"),
    (CHECK, ["--seeds", "1"], "--seeds"),
    (CHECK, ["--seeds", "99999999999"], "--seeds"),
    (CHECK, ["--alpha", "0.7"], "--alpha"),
    (CHECK, ["--seed", "-1"], "--seed"),
    (CHECK, ["--json-out", "."], "--json-out"),
    (CHECK, ["--json-out", "/proc/x/y.json"], "--json-out"),
    (CHECK, ["--json-out", "/proc/x.json"], "--json-out"),
    (CHECK, ["--out", "/proc"], "--out"),
    (CHECK, ["--out", "a_file"], "--out"),
    (CHECK, ["--out", "/proc/x"], "--out"),
    (BENCH_BANDIT, ["--arms", "1000000000"], "--arms"),
    (BENCH_BANDIT, ["--arms", "1"], "--arms"),
    (BENCH_BANDIT, ["--seeds", "1000000000000"], "--seeds"),
    (BENCH_BANDIT, ["--horizon", "16777216"], "--horizon"),
    (BENCH_BANDIT, ["--alpha", "0"], "--alpha"),
    (BENCH_BANDIT, ["--repeats", "0"], "--repeats"),
    (BENCH_BANDIT, ["--numpy-seeds", "1"], "--numpy-seeds"),
    (BENCH_BANDIT, ["--seed", "99999999999999999999"], "--seed"),
    (BENCH_GRASP, ["--native-batch", "0"], "--native-batch"),
    (BENCH_GRASP, ["--native-batch=-4"], "--native-batch"),
    (BENCH_GRASP, ["--native-batch", "abc"], "--native-batch"),
    (BENCH_GRASP, ["--native-batch", "1000000000"], "--native-batch"),
    (BENCH_GRASP, ["--repeats", "0"], "--repeats"),
    (BENCH_GRASP, ["--agreement", "-1"], "--agreement"),
    (BENCH_GRASP, ["--out", "."], "--out"),
    (BENCH_GRASP, ["--agreement", "1", "--agreement-objects", "no_such"], "no_such"),
    (SHOW, ["--trials", "-1"], "--trials"),
    (SHOW, ["--trials", "1000000000"], "--trials"),
    (SHOW, ["--seed", "99999999999999999999"], "--seed"),
    (SHOW, ["--out", "a_file"], "--out"),
    (["grasp", "show", "box_99999999999999999999_0", "--no-render"], [], "box_9999"),
]


@pytest.mark.parametrize("base,extra,flag", CASES,
                         ids=[" ".join(b[:2] + e) for b, e, _ in CASES])
def test_bad_flag_value(base, extra, flag, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "a_file").write_text("keep")
    before = sorted(p.name for p in tmp_path.rglob("*"))
    t0 = time.perf_counter()
    assert cli.main(base + extra) == 2
    elapsed = time.perf_counter() - t0
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert flag in lines[0] and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.rglob("*")) == before
    assert (tmp_path / "a_file").read_text() == "keep"
    assert elapsed < 20, elapsed  # refused up front (first call of a kind pays the imports)


# ----------------------------------------------------------------------------- grasp commands
# Issue 16: every case of the probe (the silent NaN of --alpha 1e-300, sizes that ran out of
# memory or never ended, output paths that failed after the work, argparse's usage block), all
# refused in one line naming the flag, exit 2, nothing written, before any compile.

LEARN = ["grasp", "learn", "pipe_tee", "--no-progress", "--no-figures", "--out", "learn"]
DATASET = ["grasp", "dataset", "--no-progress", "--out", "d0new"]
PRETRAIN = ["grasp", "pretrain", "--no-progress", "--data", "d0", "--out", "theta"]
SCREEN = ["grasp", "screen", "box", "--no-progress"]
REPRODUCE = ["reproduce", "--quick", "--no-progress"]

GRASP_CASES = [
    (LEARN, ["--alpha", "1e-300"], "--alpha"),
    (LEARN, ["--alpha", "1e-40"], "--alpha"),
    (LEARN, ["--alpha", "nan"], "--alpha"),
    (LEARN, ["--alpha", "inf"], "--alpha"),
    (LEARN, ["--alpha", "0"], "--alpha"),
    (LEARN, ["--alpha", "-0.05"], "--alpha"),
    (LEARN, ["--epsilon", "2"], "--epsilon"),
    (LEARN, ["--epsilon", "nan"], "--epsilon"),
    (LEARN, ["--epsilon", "1e-45"], "--epsilon"),
    (LEARN, ["--alpha0", "1e-39"], "--alpha0"),
    (LEARN, ["--p", "1"], "--p"),
    (LEARN, ["--p", "nan"], "--p"),
    (LEARN, ["--policies", "sern_log", "--alpha0", "2e-38", "--p", "0.9"], "--alpha0"),
    (LEARN, ["--policies", "sern_log", "--rounds", "1", "--explore", "1"], "--rounds"),
    (LEARN, ["--policies", "sern,bogus"], "bogus"),
    (LEARN, ["--policies", "sern,sern"], "policies"),
    (LEARN, ["--ucb-width", "1e-39"], "--ucb-width"),
    (LEARN, ["--ucb-width", "nan"], "--ucb-width"),
    (LEARN, ["--lambda-prior", "1e-300"], "--lambda-prior"),
    (LEARN, ["--lambda-prior", "inf"], "--lambda-prior"),
    (LEARN, ["--decay-alpha0", "1e-40"], "--decay-alpha0"),
    (LEARN, ["--decay-epsilon0", "1e39"], "--decay-epsilon0"),
    (LEARN, ["--nu", "nan"], "--nu"),
    (LEARN, ["--ensemble-size", "0"], "--ensemble-size"),
    (LEARN, ["--policies", "ensemble_ts", "--ensemble-size", "1024", "--seeds", "1000"],
     "--ensemble-size"),
    (LEARN, ["--eval-poses", "1000000000"], "--eval-poses"),
    (LEARN, ["--eval-poses", "-1"], "--eval-poses"),
    (LEARN, ["--eval-trials", "100000000"], "--eval-trials"),
    (LEARN, ["--regret-trials", "100000000"], "--regret-trials"),
    (LEARN, ["--regret-trials", "-3"], "--regret-trials"),
    (LEARN, ["--seeds", "0"], "--seeds"),
    (LEARN, ["--seeds", "abc"], "--seeds"),
    (LEARN, ["--seeds", "100000000"], "--seeds"),
    (LEARN, ["--rounds", "0"], "--rounds"),
    (LEARN, ["--explore", "0"], "--explore"),
    (LEARN, ["--explore", "1000000"], "--explore"),
    (LEARN, ["--evaluate", "0"], "--evaluate"),
    (LEARN, ["--fit-steps", "0"], "--fit-steps"),
    (LEARN, ["--seed", "-1"], "--seed"),
    (LEARN, ["--core-set", "bogus"], "--core-set"),
    (LEARN, ["--backend", "gpu"], "--backend"),
    (LEARN, ["--json-out", "/proc/x.json"], "--json-out"),
    (LEARN, ["--json-out", "."], "--json-out"),
    (LEARN, ["--out", "a_file"], "--out"),
    (LEARN, ["--out", "/proc/x"], "--out"),
    (LEARN, ["--bogus-flag"], "--bogus-flag"),
    (LEARN, ["--mesh", "no_such.obj"], "no_such.obj"),
    (["grasp", "learn", "no_such_object", "--out", "learn"], [], "no_such_object"),
    (DATASET, ["--objects", "0"], "--objects"),
    (DATASET, ["--objects", "100000000"], "--objects"),
    (DATASET, ["--poses", "0"], "--poses"),
    (DATASET, ["--objects", "1", "--poses", "5000000"], "--poses"),
    (DATASET, ["--trials", "0"], "--trials"),
    (DATASET, ["--trials", "1000000"], "--trials"),
    (DATASET, ["--seed", "-1"], "--seed"),
    (DATASET, ["--backend", "gpu"], "--backend"),
    (DATASET, ["--out", "a_file"], "--out"),
    (DATASET, ["--out", "/proc/x"], "--out"),
    (PRETRAIN, ["--epochs", "0"], "--epochs"),
    (PRETRAIN, ["--epochs", "1000000000"], "--epochs"),
    (PRETRAIN, ["--batch-size", "0"], "--batch-size"),
    (PRETRAIN, ["--batch-size", "1000000000"], "--batch-size"),
    (PRETRAIN, ["--lr", "0"], "--lr"),
    (PRETRAIN, ["--lr", "nan"], "--lr"),
    (PRETRAIN, ["--lr", "1e-40"], "--lr"),
    (PRETRAIN, ["--core-k", "0"], "--core-k"),
    (PRETRAIN, ["--core-k", "513"], "--core-k"),
    (PRETRAIN, ["--heldout-trials", "100000000"], "--heldout"),
    (PRETRAIN, ["--heldout-objects", "100000000"], "--heldout"),
    (PRETRAIN, ["--screen-trials", "100000000"], "--screen"),
    (PRETRAIN, ["--seed", "-1"], "--seed"),
    (PRETRAIN, ["--data", "no_such_dir"], "--data"),
    (PRETRAIN, ["--out", "a_file"], "--out"),
    (PRETRAIN, ["--out", "/proc/x"], "--out"),
    (SCREEN, ["--poses", "0"], "--poses"),
    (SCREEN, ["--poses", "100000000"], "--poses"),
    (SCREEN, ["--trials", "100000000"], "--trials"),
    (SCREEN, ["--seed", "-1"], "--seed"),
    (SCREEN, ["--json-out", "/proc/x.json"], "--json-out"),
    (SCREEN, ["--json-out", "."], "--json-out"),
    (SCREEN, ["--mesh-units", "inch"], "--mesh-units"),
    (["grasp", "screen", "no_such_object"], [], "no_such_object"),
    (REPRODUCE, ["--out", "a_file"], "--out"),
    (REPRODUCE, ["--out", "/proc/x"], "--out"),
    (REPRODUCE, ["--bogus"], "--bogus"),
    (["grasp", "bogus"], [], "bogus"),
    (["bogus"], [], "bogus"),
]


def _main(argv) -> int:
    """cli.main's exit status, whether it returns it or argparse exits with it."""
    try:
        return cli.main(argv)
    except SystemExit as exc:
        return exc.code


def _fake_dataset(root):
    """A D0 directory as `sern grasp dataset` leaves it: config.json (no shards needed: every
    pretrain case below is refused before the shards are read)."""
    from sern_jax.infra import io
    from sern_jax.grasp.model import dataset

    config = dataset.DatasetConfig(num_objects=20, poses_per_object=4)
    io.save_json(root / "d0" / "config.json", {"config": config,
                                               "fingerprint": config.fingerprint()})


@pytest.mark.parametrize("base,extra,flag", GRASP_CASES,
                         ids=[" ".join(b[:2] + e) for b, e, _ in GRASP_CASES])
def test_bad_grasp_flag_value(base, extra, flag, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "a_file").write_text("keep")
    _fake_dataset(tmp_path)
    before = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*"))
    t0 = time.perf_counter()
    assert _main(base + extra) == 2
    elapsed = time.perf_counter() - t0
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert flag in lines[0] and "Traceback" not in err and "usage:" not in err
    assert sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*")) == before
    assert (tmp_path / "a_file").read_text() == "keep"
    assert elapsed < 20, elapsed  # refused up front (the first call pays the imports)


def test_help_is_unchanged(capsys):
    """--help still prints the full usage and the flags (exit 0)."""
    assert _main(["grasp", "learn", "--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage:") and "--alpha" in out and "--regret-trials" in out


# The probe's passing cases, kept as regressions: values at the edges are accepted.


@pytest.mark.parametrize("extra", [
    ["--alpha", "1.2e-38"], ["--alpha", "1e30"], ["--epsilon", "0"], ["--epsilon", "1"],
    ["--eval-poses", "0"], ["--regret-trials", "0"], ["--policies", "sern_log", "--p", "0.5"],
    ["--policies", "greedy", "--seeds", "1", "--rounds", "1", "--explore", "1"],
])
def test_edge_values_are_accepted(extra, tmp_path):
    from sern_jax.commands import grasp_learn
    from sern_jax.commands import main as cli_main

    parser = cli_main.build_parser()
    args = parser.parse_args(LEARN[:3] + extra + ["--out", str(tmp_path / "run")])
    config = grasp_learn.check_learn_args(args, num_objects=1)
    assert config.num_seeds >= 1
    assert not (tmp_path / "run").exists()


def _learn_run_dir(tmp_path, **arrays):
    from sern_jax.infra import io

    run = tmp_path / "learn"
    run.mkdir()
    io.save_npz(run / "checkpoint.npz", **arrays)
    io.save_json(run / "config.json", {"fingerprint": "someone else's"})
    return run


def _listing(root):
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file()}


def test_learn_into_another_runs_directory_leaves_it_byte_identical(tmp_path, monkeypatch,
                                                                    capsys):
    """The probe's passing case: reuse with other settings is refused and the directory is
    left byte-identical (no lock file either)."""
    monkeypatch.chdir(tmp_path)
    run = _learn_run_dir(tmp_path, fingerprint="0123456789abcdef")
    before = _listing(run)
    assert _main(LEARN) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "different learning run" in err[0]
    assert _listing(run) == before


@pytest.mark.parametrize("how", ["truncate", "empty", "random"])
def test_learn_damaged_checkpoint_is_one_line(tmp_path, monkeypatch, capsys, how):
    import numpy as np

    monkeypatch.chdir(tmp_path)
    run = _learn_run_dir(tmp_path, fingerprint="x", big=np.arange(20_000.0))
    ckpt = run / "checkpoint.npz"
    data = ckpt.read_bytes()
    ckpt.write_bytes({"truncate": data[: len(data) // 2], "empty": b"",
                      "random": np.random.default_rng(0).bytes(len(data))}[how])
    before = _listing(run)
    assert _main(LEARN) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "checkpoint.npz is damaged" in err[0] and "delete it" in err[0]
    assert _listing(run) == before


def test_learn_run_directory_held_by_another_process(tmp_path, monkeypatch, capsys):
    """Two commands into one --out: the second is refused in one line naming the holder
    (a real second process holds the lock)."""
    import signal
    import subprocess
    import sys

    monkeypatch.chdir(tmp_path)
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time\nfrom sern_jax import io\n"
         "with io.run_lock(sys.argv[1], command='sern grasp learn (first)'):\n"
         "    print('locked', flush=True)\n    time.sleep(60)\n", str(tmp_path / "learn")],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        assert _main(LEARN) == 2
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"pid {holder.pid}" in err[0] and "(first)" in err[0]
    assert sorted(p.name for p in (tmp_path / "learn").iterdir()) == [".sern.lock"]
