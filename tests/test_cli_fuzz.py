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
