"""`sern bench bandit --json` prints one valid JSON object with positive figures."""

import json

import numpy as np
import pytest

from sern_jax.commands import main as cli


def test_bench_bandit_json(capsys):
    code = cli.main(["bench", "bandit", "--json", "--seeds", "64", "--horizon", "200",
                     "--numpy-seeds", "64", "--repeats", "1"])
    assert code == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1
    result = json.loads(out[0])
    for field in ("seed_rounds_per_s", "compile_s", "peak_rss_mb", "numpy_seed_rounds_per_s",
                  "speedup_vs_numpy", "fast_seed_rounds_per_s", "general_seed_rounds_per_s",
                  "run_seeds_seed_rounds_per_s", "run_seeds_concurrent_calls"):
        assert isinstance(result[field], (int, float)) and result[field] > 0, field
    assert result["numpy_seeds"] == 64
    assert result["repeats"] == 1
    assert result["jax_version"]
    assert result["device"]["backend"]
    assert result["engine_path"]
    agree = result["regret_agreement"]
    assert agree["fast_mean_regret_T"] > 0 and agree["numpy_mean_regret_T"] > 0
    # same random streams: the fast path and the general runner draw the same arms
    assert agree["fast_general_counts_identical_fraction"] >= 0.9
    # the public entry point ran the fast runner on the same seeds
    assert result["run_seeds"]["fast"] and agree["run_seeds_counts_equal_fast"]
    assert result[result["best_path"]]["seed_rounds_per_s"] == result["seed_rounds_per_s"]
    # different streams (NumPy vs JAX), same workload: means agree within a few SE
    assert abs(agree["z_fast_vs_numpy"]) < 6
    # the public path with on-device summaries and the naive jit(vmap(scan)) peer
    for field in ("naive_jax_seed_rounds_per_s", "run_seeds_summary_seed_rounds_per_s",
                  "public_over_fast", "public_over_naive_jax"):
        assert isinstance(result[field], (int, float)) and result[field] > 0, field
    assert agree["summary_mean_rel_diff_vs_fast"] < 1e-5  # the same seeds, reduced on device
    assert agree["summary_counts_min_equal_fast"]
    assert abs(agree["z_fast_vs_naive_jax"]) < 6
    # K = 64, G = 32: ~1.9 MB of float64/int64 statistics and histograms, whatever the seeds
    assert result["run_seeds_summary"]["summary_bytes"] < 2_500_000
    _check_copy_split(result["run_seeds"], seeds=64, horizon=200, repeats=1)


def test_bench_bandit_thompson_json(capsys):
    code = cli.main(["bench", "bandit", "--json", "--policy", "thompson", "--seeds", "48",
                     "--horizon", "150", "--numpy-seeds", "48", "--repeats", "1",
                     "--naive-repeats", "0"])
    assert code == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["workload"]["policy"] == "thompson"
    assert result["fast"]["engine_path"] == "sern_jax.engine.fast_thompson.make_batched"
    agree = result["regret_agreement"]
    assert result["run_seeds"]["fast"] and agree["run_seeds_counts_equal_fast"]
    assert agree["fast_general_counts_identical_fraction"] == 1.0
    assert abs(agree["z_fast_vs_numpy"]) < 6  # NumPy's Generator.beta, the same workload
    assert result["naive_jax_seed_rounds_per_s"] is None  # skipped with --naive-repeats 0


@pytest.mark.parametrize("argv,match", [(["--arms", "1"], "arms"),
                                         (["--alpha", "0"], "alpha"),
                                         (["--alpha", "0.001"], "alpha"),
                                         (["--numpy-seeds", "1"], "numpy-seeds"),
                                         (["--policy", "ucb1"], "policy"),
                                         (["--naive-repeats", "-1"], "naive-repeats")])
def test_bench_bandit_bad_input(argv, match, capsys):
    assert cli.main(["bench", "bandit", "--json", *argv]) == 2
    assert match in capsys.readouterr().err


@pytest.mark.parametrize("argv,match", [(["--smpybandits-seeds", "4"], "policy thompson"),
                                         (["--policy", "thompson", "--smpybandits-seeds", "1"],
                                          "smpybandits-seeds"),
                                         (["--policy", "thompson", "--smpybandits-seeds", "-2"],
                                          "smpybandits-seeds")])
def test_bench_bandit_smpybandits_bad_input(argv, match, capsys):
    assert cli.main(["bench", "bandit", "--json", *argv]) == 2
    assert match in capsys.readouterr().err


def test_bench_bandit_smpybandits_reference_or_a_named_refusal(capsys):
    """SMPyBandits' Thompson beside ours when the library is installed; without it the flag is
    refused in one line naming it and what to install (exit 2, before any compile)."""
    from sern_jax.bench import bandit as benchmarks

    argv = ["bench", "bandit", "--json", "--policy", "thompson", "--seeds", "16", "--horizon",
            "60", "--numpy-seeds", "0", "--repeats", "1", "--naive-repeats", "0",
            "--general-repeats", "0", "--summary-repeats", "0", "--smpybandits-seeds", "3"]
    try:
        benchmarks.smpybandits_thompson()
    except ImportError:
        assert cli.main(argv) == 2
        err = capsys.readouterr().err
        assert "--smpybandits-seeds" in err and "pip install SMPyBandits" in err
        return
    assert cli.main(argv) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["smpybandits"]["policy"] == "SMPyBandits.Policies.Thompson"
    assert result["smpybandits_seed_rounds_per_s"] > 0
    out = benchmarks.smpybandits_reference(3, 4, 60, np.array([30, 60]), seed=5)
    assert out["counts"][:, -1].sum(-1).tolist() == [60] * 3
    assert np.all(out["regret"][:, -1] >= out["regret"][:, 0]) and np.all(out["regret"] >= 0)


def _finite_positive(x) -> bool:
    return isinstance(x, (int, float)) and np.isfinite(x) and x > 0


def _check_copy_split(rs: dict, seeds: int, horizon: int, repeats: int) -> None:
    """The per-seed run_seeds entry says, from measured times, whether copying its outputs to
    the host bounds it: bytes returned, copy seconds, compute-only seconds, their fractions."""
    from sern_jax.bench import bandit as benchmarks
    from sern_jax.engine import simulate as sim

    for field in ("output_bytes", "output_copied_bytes", "output_copy_s",
                  "output_copy_bytes_per_s", "compute_s", "compute_seed_rounds_per_s",
                  "call_s", "copy_fraction", "compute_fraction"):
        assert _finite_positive(rs[field]), (field, rs.get(field))
    assert np.isfinite(rs["other_s"])
    assert len(rs["output_copy_times_s"]) == len(rs["compute_times_s"]) == repeats
    # counts [S, G, K] int32 and compensator [S, G, K] float32 at least
    config, _ = benchmarks.bandit_config(
        benchmarks.BanditWorkload(horizon=horizon, seeds=seeds))
    g = sim.checkpoint_times(config).size
    assert rs["output_bytes"] >= seeds * g * config.num_arms * 8
    assert rs["output_copied_bytes"] >= rs["output_bytes"]
    assert rs["call_s"] == rs["min_s"]
    assert rs["copy_fraction"] == pytest.approx(rs["output_copy_s"] / rs["call_s"])
    assert rs["bound"] == ("output copy" if rs["copy_fraction"] >= 0.5 else "compute")


def test_bench_bandit_output_copy_bound_rule():
    """The same measured split against a near-zero and a huge run_seeds call: copy-bound and
    compute-bound, with the bytes of the per-seed arrays run_seeds returns."""
    import jax

    from sern_jax.bench import bandit as benchmarks
    from sern_jax.engine import drive as executor
    from sern_jax.infra import timing

    w = benchmarks.BanditWorkload(horizon=200, seeds=64, repeats=1)
    s = benchmarks.bandit_setup(w)
    plan = executor.plan_run(s.config, s.params, w.seeds, mesh=s.mesh)
    out = executor.run_seeds(s.config, s.params, w.seed, w.seeds, mesh=s.mesh)
    fast = benchmarks._copy_split(s, plan, timing.Timing(out, None, (1e-9,), (1e-9,)))
    slow = benchmarks._copy_split(s, plan, timing.Timing(out, None, (1e9,), (1e9,)))
    assert fast["bound"] == "output copy" and fast["copy_fraction"] > 1
    assert slow["bound"] == "compute" and slow["copy_fraction"] < 1e-6
    nbytes = sum(x.nbytes for x in jax.tree.leaves(out))  # None fields are not leaves
    assert fast["output_bytes"] == slow["output_bytes"] == nbytes > 0
    assert fast["compute_s"] > 0 and slow["output_copy_s"] > 0
