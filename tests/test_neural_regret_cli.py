"""`sern regret --estimator neural`: run directory, resume, aliases, bad input (one line
naming the flag, exit 2, nothing written). Tiny networks and horizons."""

import json

import numpy as np
import pytest

from sern_jax.infra import io
from sern_jax.commands import main as cli

ARGS = ["regret", "--estimator", "neural", "--problem", "wheel", "--delta", "0.5",
        "--policies", "sern,uniform", "-T", "40", "--update-every", "20", "-S", "4",
        "--chunk-size", "2", "--hidden", "4", "--fit-steps", "2", "--batch-size", "8",
        "--checkpoints", "4", "--no-progress", "--no-figures"]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("neural") / "run"
    assert cli.main(ARGS + ["--out", str(out)]) == 0
    return out


def test_run_directory_and_summary(run_dir):
    for name in ("config.json", "metadata.json", "results.npz", "summary.json", "report.md"):
        assert (run_dir / name).exists(), name
    res = io.load_npz(run_dir / "results.npz")
    assert res["sern__counts"].shape == (4, res["t"].size, 5)
    assert res["t"][-1] == 40
    np.testing.assert_array_equal(res["sern__counts"][:, -1].sum(-1), 40)
    summary = json.loads((run_dir / "summary.json").read_text())
    for policy in ("sern", "uniform"):
        assert summary["policies"][policy]["regret_T_mean"] > 0
    assert summary["normalised_by_uniform"]["uniform"]["ratio"] == pytest.approx(1.0)


def test_resume_equals_uninterrupted_and_aliases(run_dir, tmp_path):
    out = tmp_path / "resumed"
    (out / "chunks").mkdir(parents=True)
    first = sorted((run_dir / "chunks").glob("sern__*.npz"))[0]  # seeds 0-1 of sern only
    (out / "chunks" / first.name).write_bytes(first.read_bytes())
    assert cli.main(ARGS + ["--out", str(out)]) == 0
    a, b = io.load_npz(run_dir / "results.npz"), io.load_npz(out / "results.npz")
    assert set(a) == set(b)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    # the tabular name is an alias of the registry's: softmax runs sern (same numbers)
    alias = tmp_path / "alias"
    args = [x if x != "sern,uniform" else "softmax" for x in ARGS]
    args[args.index("-S") + 1] = "2"
    assert cli.main(args + ["--out", str(alias)]) == 0
    c = io.load_npz(alias / "results.npz")
    np.testing.assert_array_equal(c["softmax__counts"], a["sern__counts"][:2])
    np.testing.assert_allclose(c["softmax__regret_rb"], a["sern__regret_rb"][:2], rtol=1e-6)


@pytest.mark.parametrize("extra, flag", [
    (["--delta", "1.5"], "--delta"),
    (["--delta", "0"], "--delta"),
    (["--policies", "ucb1"], "--policies"),
    (["--policies", "sern,softmax"], "--policies"),
    (["--update-every", "30"], "--update-every"),
    (["--hidden", "0"], "--hidden"),
    (["--hidden", "a"], "--hidden"),
    (["--problem", "finite", "--arms", "1"], "--arms"),
    (["--problem", "finite", "--gap", "1.2"], "--gap"),
    (["--problem", "wheel", "--arms", "3"], "--arms"),
    (["--problem", "bernoulli"], "--problem"),
    (["--fit-steps", "0"], "--fit-steps"),
    (["--learning-rate", "-1"], "--learning-rate"),
    (["--float64"], "--float64"),
    (["--nl-sigma2", "shared"], "--nl-sigma2"),
    (["--nl-prior-mean", "one"], "--nl-prior-mean"),
])
def test_bad_input_is_one_line_naming_the_flag(extra, flag, tmp_path, capsys):
    out = tmp_path / "bad"
    base = ARGS
    if "finite" in extra:  # --delta is the wheel's: refused with another problem
        i = ARGS.index("--delta")
        base = ARGS[:i] + ARGS[i + 2:]
    assert cli.main(base + extra + ["--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert flag in err and "\n" not in err, err
    assert not out.exists()


def test_problem_without_neural_estimator_is_refused(tmp_path, capsys):
    out = tmp_path / "bad"
    assert cli.main(["regret", "--problem", "wheel", "--out", str(out)]) == 2
    assert "--problem" in capsys.readouterr().err
    assert not out.exists()


def test_neural_linear_flags_are_refused_by_the_tabular_estimators(tmp_path, capsys):
    out = tmp_path / "bad"
    assert cli.main(["regret", "--nl-sigma2", "pooled", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "--nl-sigma2" in err and "\n" not in err
    assert not out.exists()


def test_neural_linear_options_enter_the_fingerprint_only_when_set():
    """Runs made before --nl-sigma2 / --nl-prior-mean existed (arm, network) keep their
    fingerprint, so they resume; another value is another run."""
    import dataclasses

    from sern_jax.experiment.neural_regret import NeuralRegretExperiment as Exp

    nl_pol = ("neural_lints", "uniform")
    legacy = Exp(policies=nl_pol, nl_sigma2="arm", nl_prior_mean="network")
    fields = {f: v for f, v in __import__("dataclasses").asdict(legacy).items()
              if f not in ("nl_sigma2", "nl_prior_mean")}
    import hashlib
    fields.pop("chunk_size")
    before = hashlib.sha256(json.dumps(fields, sort_keys=True).encode()).hexdigest()[:16]
    assert legacy.fingerprint() == before  # the hash of a run made before the fields
    assert Exp().nl_sigma2 == "pooled"  # today's default: another run
    assert legacy.fingerprint() != Exp(policies=nl_pol).fingerprint()
    assert legacy.fingerprint() != Exp(policies=nl_pol, nl_sigma2="arm",
                                       nl_prior_mean="zero").fingerprint()
    # without a Neural-Linear learner the options change nothing, so they never enter
    plain = Exp(policies=("sern", "greedy"), nl_sigma2="arm")
    assert plain.fingerprint() == Exp(policies=("sern", "greedy")).fingerprint()
    assert plain.fingerprint() == Exp(policies=("sern", "greedy"), nl_sigma2="pooled",
                                      nl_prior_mean="zero").fingerprint()
    nl = Exp(policies=("sern", "neural_lints"))
    assert nl.fingerprint() != dataclasses.replace(nl, nl_sigma2="arm").fingerprint()


def test_delta_sweep_compiles_once_and_matches_single_runs(run_dir, tmp_path):
    """--deltas 0.5,0.7: one run directory per δ; the second δ reuses the first one's
    compilation (one program in each policy's jit cache), and d0.5 holds the same numbers as
    the single --delta 0.5 run."""
    import dataclasses

    from sern_jax.experiment import neural_regret as nreg
    from sern_jax.engine import neural as nr

    out = tmp_path / "sweep"
    argv = [a for a in ARGS]
    argv[argv.index("--delta"):argv.index("--delta") + 2] = []
    assert cli.main(argv + ["--deltas", "0.5,0.7", "--out", str(out)]) == 0
    a = io.load_npz(run_dir / "results.npz")
    b = io.load_npz(out / "d0.5" / "results.npz")
    np.testing.assert_array_equal(a["sern__counts"], b["sern__counts"])
    np.testing.assert_allclose(a["sern__regret_rb"], b["sern__regret_rb"], rtol=1e-6, atol=1e-3)
    c = io.load_npz(out / "d0.7" / "results.npz")
    assert not np.array_equal(b["uniform__regret_rb"], c["uniform__regret_rb"])
    assert json.loads((out / "d0.7" / "config.json").read_text())["experiment"]["delta"] == 0.7
    # in-process: a sweep of two δ leaves one compiled program per policy
    exp = nreg.NeuralRegretExperiment(policies=("sern",), horizon=40, update_every=20,
                                      num_seeds=2, chunk_size=2, hidden=(4,), fit_steps=2,
                                      batch_size=8, num_checkpoints=2)
    cache: dict = {}
    for d in (0.6, 0.8):
        nreg.run_experiment(dataclasses.replace(exp, delta=d), tmp_path / f"lib{d}",
                            progress=False, sweep_cache=cache)
    (runs, _, _), = cache.values()
    assert nr._batched(runs[0][1], traced=True)._cache_size() == 1


@pytest.mark.parametrize("extra, flag", [
    (["--deltas", "0.5,1.5"], "--deltas"),
    (["--deltas", "0.5,nan"], "--deltas"),
    (["--deltas", "0.5,x"], "--deltas"),
    (["--deltas", "0.5,0.5"], "--deltas"),
    (["--deltas", "0.95,0.950000001"], "--deltas"),  # one folder name, d0.95
    (["--deltas", "0.5", "--delta", "0.9"], "--deltas replaces --delta"),
    (["--deltas", "0.5", "--problem", "linear"], "--deltas"),
])
def test_bad_deltas_are_one_line_before_anything_runs(extra, flag, tmp_path, capsys):
    out = tmp_path / "bad"
    argv = [a for a in ARGS]
    argv[argv.index("--delta"):argv.index("--delta") + 2] = []
    assert cli.main(argv + extra + ["--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert flag in err and "\n" not in err, err
    assert not out.exists()


def test_delta_sweep_checks_every_folder_before_the_first_runs(tmp_path, capsys):
    """A sweep whose second folder holds another experiment is refused before d0.5 runs."""
    out = tmp_path / "sweep"
    (out / "d0.7").mkdir(parents=True)
    (out / "d0.7" / "config.json").write_text(json.dumps({"fingerprint": "other"}))
    argv = [a for a in ARGS]
    argv[argv.index("--delta"):argv.index("--delta") + 2] = []
    assert cli.main(argv + ["--deltas", "0.5,0.7", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "d0.7" in err and "\n" not in err, err
    assert not (out / "d0.5").exists()


def test_other_experiment_in_the_folder_is_refused_in_one_line(run_dir, capsys):
    """The fingerprint check (io.check_run_dir) before anything runs: another δ is another
    experiment; the folder's config.json is left as it was."""
    before = (run_dir / "config.json").read_bytes()
    argv = list(ARGS)
    argv[argv.index("--delta") + 1] = "0.6"
    capsys.readouterr()
    assert cli.main(argv + ["--out", str(run_dir)]) == 2
    err = capsys.readouterr().err.strip()
    assert f"{run_dir} holds a different experiment (fingerprint " in err, err
    assert err.endswith("choose another --out or delete it") and "\n" not in err, err
    assert (run_dir / "config.json").read_bytes() == before
