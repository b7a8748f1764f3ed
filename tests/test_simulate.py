"""The runner: closed-form regret, seed conventions, no recompiles, sharding, bad input."""

import dataclasses
import json
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from sern_jax import problems
from sern_jax import simulate as sim

CFG = sim.RunConfig(policy="softmax", estimator="addhalf", num_arms=5, horizon=300,
                    num_checkpoints=12)
PROB = problems.bernoulli([0.9, 0.8, 0.5, 0.3, 0.1])


@pytest.fixture(scope="module")
def thousand_seeds():
    params = sim.default_params(CFG, PROB, alpha0=0.1)
    return params, sim.run_seeds(CFG, params, seed=7, num_seeds=1000)


def test_k2_exact_oracle_closed_form_float64():
    # audit §3.10: with r̂ = r, K = 2 and α = α0/ln(T^p), π(worse) = 1/(1 + T^{pΔ/α0}), so the
    # Rao–Blackwellised regret is exactly ΔT/(1 + T^{pΔ/α0}).
    with jax.enable_x64():
        for horizon, delta, alpha0, p in [(100, 0.3, 1.0, 0.3), (1000, 0.5, 0.5, 0.2),
                                          (5000, 0.1, 2.0, 0.3)]:
            cfg = sim.RunConfig(policy="softmax", estimator="exact", schedule="log",
                                num_arms=2, horizon=horizon, num_checkpoints=4,
                                dtype="float64")
            prob = problems.bernoulli([0.7, 0.7 - delta], dtype=jnp.float64)
            params = sim.default_params(cfg, prob, alpha0=alpha0, p=p)
            out = sim.run_seeds(cfg, params, num_seeds=3)
            closed = delta * horizon / (1.0 + horizon ** (p * delta / alpha0))
            np.testing.assert_allclose(out.regret_rb[:, -1], closed, rtol=1e-9)
            np.testing.assert_allclose(out.regret_rb_paper[:, -1], closed, rtol=1e-9)


def test_bookkeeping(thousand_seeds):
    params, out = thousand_seeds
    t = sim.checkpoint_times(CFG)
    assert t[-1] == CFG.horizon and np.all(np.diff(t) > 0)
    np.testing.assert_array_equal(out.counts.sum(-1), np.broadcast_to(t, (1000, t.size)))
    np.testing.assert_allclose(out.compensator.sum(-1), np.broadcast_to(t, (1000, t.size)),
                               rtol=1e-5)
    assert np.all(np.diff(out.regret, axis=1) >= -1e-5)  # one context: regret is non-decreasing
    # Theorem 1 pathwise with clipped r̂: π_t(a) ≥ π_min = 1/(1 + (K−1)e^{1/α}).
    pi_min = 1.0 / (1.0 + 4 * np.exp(1 / 0.1))
    assert out.min_prob.min() >= pi_min * (1 - 1e-5)


def test_rao_blackwell_agrees_with_realised_regret(thousand_seeds):
    _, out = thousand_seeds
    diff = out.regret[:, -1] - out.regret_rb[:, -1]
    se = diff.std(ddof=1) / np.sqrt(diff.size)
    assert abs(diff.mean()) < 5 * se + 1e-9


def test_seed_diversity(thousand_seeds):
    _, out = thousand_seeds
    rows = {out.counts[i].tobytes() for i in range(200)}
    assert len(rows) == 200


def test_seed_alone_equals_seed_in_batch(thousand_seeds):
    params, out = thousand_seeds
    run = jax.jit(sim.make_run(CFG))
    root = jax.random.key(7)
    for i in (0, 417, 999):
        alone = run(jax.random.fold_in(root, i), params)
        np.testing.assert_array_equal(np.asarray(alone.counts), out.counts[i])
        np.testing.assert_allclose(np.asarray(alone.regret_rb), out.regret_rb[i], rtol=1e-6,
                                   atol=1e-4)


def test_chunked_equals_unchunked(thousand_seeds):
    params, out = thousand_seeds
    chunked = sim.run_seeds(CFG, params, seed=7, num_seeds=1000, chunk_size=300)
    np.testing.assert_array_equal(chunked.counts, out.counts)


def test_no_recompile_when_alpha_changes():
    cfg = sim.RunConfig(num_arms=4, horizon=50, num_checkpoints=5)
    prob = problems.bernoulli([0.2, 0.4, 0.6, 0.8])
    for runner in ("general", "fast"):
        lo, hi = (sim.default_params(cfg, prob, alpha0=a) for a in (0.1, 2.0))
        fn = sim.plan_run(cfg, lo, 64, runner=runner).fn
        a = sim.run_seeds(cfg, lo, num_seeds=64, runner=runner)
        b = sim.run_seeds(cfg, hi, num_seeds=64, runner=runner)
        c = sim.run_seeds(cfg, lo, num_seeds=10, runner=runner, chunk_size=64)
        assert fn._cache_size() == 1, runner
        assert not np.array_equal(a.counts, b.counts)
        np.testing.assert_array_equal(c.counts, a.counts[:10])
    # a vmapped α sweep is one program too
    run = sim.make_run(cfg)
    params = sim.default_params(cfg, prob)
    sweep = jax.jit(jax.vmap(jax.vmap(run, (0, None)), (None, 0)))
    axes = jax.tree.map(lambda _: None, params)._replace(alpha0=0)
    keys = sim.seed_keys(jax.random.key(0), 32)
    sweep_fn = jax.jit(jax.vmap(jax.vmap(run, (0, None)), (None, axes)))
    for grid in ([0.1, 0.5, 1.0], [0.2, 0.3, 3.0]):
        out = sweep_fn(keys, params._replace(alpha0=jnp.asarray(grid)))
        assert out.regret.shape == (3, 32, 5)
    assert sweep_fn._cache_size() == 1
    del sweep


def test_run_seeds_dispatches_to_the_exact_fast_runner():
    # auto takes fast_softmax exactly where it reproduces make_run, and the general runner
    # elsewhere (diagnostics, other policies, α below the fast runner's float32 floor).
    params = sim.default_params(CFG, PROB, alpha0=0.1)
    assert sim.plan_run(CFG, params, 10).fast
    assert not sim.plan_run(CFG, params, 10, runner="general").fast
    diag_cfg = dataclasses.replace(CFG, diagnostics=True)
    assert not sim.plan_run(diag_cfg, params, 10).fast
    tiny = sim.default_params(CFG, PROB, alpha0=0.005)
    assert not sim.plan_run(CFG, tiny, 10).fast
    assert np.isfinite(sim.run_seeds(CFG, tiny, num_seeds=8).regret_rb).all()
    with pytest.raises(ValueError, match="runner='fast'"):
        sim.plan_run(dataclasses.replace(CFG, policy="ucb1"), params, 10, runner="fast")
    with pytest.raises(ValueError, match="unknown runner 'quick'"):
        sim.run_seeds(CFG, params, num_seeds=4, runner="quick")
    with pytest.raises(ValueError, match="chunk_size must be a positive integer, got 0"):
        sim.run_seeds(CFG, params, num_seeds=4, chunk_size=0)
    with pytest.raises(ValueError, match="first_seed"):
        sim.run_seeds(CFG, params, num_seeds=4, first_seed=-1)


def test_fast_and_general_runners_agree_through_run_seeds_float64():
    with jax.enable_x64():
        cfg = dataclasses.replace(CFG, dtype="float64")
        params = sim.default_params(cfg, problems.bernoulli(PROB.means[0], dtype=jnp.float64),
                                    alpha0=0.1)
        fast = sim.run_seeds(cfg, params, seed=3, num_seeds=64, runner="fast")
        general = sim.run_seeds(cfg, params, seed=3, num_seeds=64, runner="general")
    np.testing.assert_array_equal(fast.counts, general.counts)
    np.testing.assert_allclose(fast.regret_rb, general.regret_rb, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(fast.compensator, general.compensator, rtol=1e-9, atol=1e-9)


def test_pinned_host_transfer_gives_the_same_outputs(monkeypatch):
    # The accelerator path (outputs staged through page-locked host memory), forced on CPU,
    # which has that memory kind too: one call holding every seed, and several padded calls.
    assert not sim._use_pinned_host(None)  # CPU: outputs are already host memory
    params = sim.default_params(CFG, PROB, alpha0=0.1)
    plain = [sim.run_seeds(CFG, params, seed=5, num_seeds=24, chunk_size=c) for c in (None, 10)]
    monkeypatch.setattr(sim, "_use_pinned_host", lambda mesh: True)
    pinned = [sim.run_seeds(CFG, params, seed=5, num_seeds=24, chunk_size=c) for c in (None, 10)]
    for a, b in zip(plain, pinned):
        for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
            assert isinstance(y, np.ndarray) and y.shape[0] == 24
            np.testing.assert_array_equal(x, y)


def test_default_chunk_size_bounds_one_call():
    big = sim.RunConfig(num_arms=64, horizon=100_000, num_checkpoints=40)
    per_call = sim.default_chunk_size(big, 10_000, backend="cpu") * sim.bytes_per_seed(big)
    assert per_call <= 64 * 2**20
    assert sim.default_chunk_size(big, 10_000, backend="gpu") == 10_000
    assert sim.default_chunk_size(CFG, 7, backend="cpu") == 7
    # balanced calls: the padded last call wastes less than one seed per call
    chunk = sim.default_chunk_size(big, 10_000, backend="cpu")
    calls = -(-10_000 // chunk)
    assert calls > 1 and chunk * calls - 10_000 < calls
    # one share per concurrent caller
    assert sim.default_chunk_size(CFG, 1000, backend="cpu", workers=2) == 500


def test_policies_and_estimators_run_finite():
    prob = problems.contextual_with_gap(jax.random.key(3), 3, 4, gap=0.2)
    for policy in ("softmax", "greedy", "epsilon_greedy", "ucb1", "thompson",
                   "boltzmann_gumbel", "exp3"):
        for estimator in ("addhalf", "gauss"):
            cfg = sim.RunConfig(policy=policy, estimator=estimator, num_arms=4, num_contexts=3,
                                horizon=40, num_checkpoints=4, diagnostics=True)
            out = sim.run_seeds(cfg, sim.default_params(cfg, prob, alpha0=0.2), num_seeds=8)
            for leaf in jax.tree.leaves(out):
                assert np.all(np.isfinite(leaf)), (policy, estimator)
            assert np.all(out.counts[:, -1].sum(-1) == 40)
            assert np.all(out.regret_rb[:, -1] >= -1e-5)


def test_greedy_with_exact_oracle_has_zero_regret():
    cfg = sim.RunConfig(policy="greedy", estimator="exact", num_arms=3, num_contexts=2,
                        horizon=100, num_checkpoints=3)
    prob = problems.contextual([[0.1, 0.9, 0.5], [0.8, 0.2, 0.3]])
    out = sim.run_seeds(cfg, sim.default_params(cfg, prob), num_seeds=16)
    np.testing.assert_allclose(out.regret[:, -1], 0.0, atol=1e-6)
    # The paper's comparator (best arm on average: arm 1, mean 0.55) can be beaten per context.
    assert np.all(out.regret_paper[:, -1] < 0)


def test_random_means_differ_per_seed():
    cfg = sim.RunConfig(num_arms=4, horizon=20, num_checkpoints=2, random_means=True,
                        policy="greedy", estimator="exact")
    out = sim.run_seeds(cfg, sim.default_params(cfg, problems.bernoulli([0.5] * 4)),
                        num_seeds=50)
    assert len({out.counts[i, -1].tobytes() for i in range(50)}) > 1


BAD = [
    (dict(num_arms=1), {}, "num_arms"),
    (dict(horizon=0), {}, "horizon"),
    (dict(policy="softmaxx"), {}, "softmaxx"),
    (dict(estimator="ridge"), {}, "ridge"),
    (dict(schedule="cosine"), {}, "cosine"),
    ({}, dict(alpha0=0.0), "alpha0"),
    ({}, dict(alpha0=-1.0), "alpha0"),
    ({}, dict(epsilon=1.5), "epsilon"),
    ({}, dict(epsilon=-0.1), "epsilon"),
]


@pytest.mark.parametrize("cfg_kw,param_kw,match", BAD)
def test_bad_input_raises_before_compile(cfg_kw, param_kw, match):
    cfg = sim.RunConfig(**{**dict(num_arms=3, horizon=10), **cfg_kw})
    prob = problems.bernoulli([0.1, 0.2, 0.3])
    with pytest.raises(ValueError, match=match):
        params = sim.default_params(cfg, prob, **param_kw)
        sim.run_seeds(cfg, params, num_seeds=2)


def test_bad_problems_and_seeds_raise():
    cfg = sim.RunConfig(num_arms=3, horizon=10)
    with pytest.raises(ValueError, match="NaN"):
        problems.bernoulli([0.1, float("nan"), 0.3])
    with pytest.raises(ValueError, match="1.2"):
        problems.bernoulli([0.1, 1.2, 0.3])
    with pytest.raises(ValueError, match="num_arms=3"):
        sim.run_seeds(cfg, sim.default_params(cfg, problems.bernoulli([0.1, 0.2])), num_seeds=2)
    with pytest.raises(ValueError, match="num_seeds"):
        sim.run_seeds(cfg, sim.default_params(cfg, problems.bernoulli([0.1, 0.2, 0.3])),
                      num_seeds=0)
    with pytest.raises(ValueError, match="T >= 2"):
        c = sim.RunConfig(num_arms=3, horizon=1, schedule="log")
        sim.run_seeds(c, sim.default_params(c, problems.bernoulli([0.1, 0.2, 0.3])), num_seeds=1)
    with pytest.raises(ValueError, match="x64"):
        sim.validate(sim.RunConfig(dtype="float64"))


SHARD_SCRIPT = textwrap.dedent("""
    import json, numpy as np, jax
    from sern_jax import problems, simulate as sim
    cfg = sim.RunConfig(num_arms=6, horizon=200, num_checkpoints=8)
    prob = problems.bernoulli([0.1, 0.3, 0.5, 0.6, 0.7, 0.75])
    params = sim.default_params(cfg, prob, alpha0=0.1)
    from sern_jax.sharding import seed_mesh
    mesh = seed_mesh(4)
    sharded = sim.run_seeds(cfg, params, seed=3, num_seeds=103, mesh=mesh)
    plain = sim.run_seeds(cfg, params, seed=3, num_seeds=103)
    sim._use_pinned_host = lambda mesh: True  # the accelerator transfer path, on the CPU mesh
    pinned = sim.run_seeds(cfg, params, seed=3, num_seeds=103, mesh=mesh, chunk_size=40)
    print(json.dumps({"devices": len(jax.devices()),
                      "counts_equal": bool(np.array_equal(sharded.counts, plain.counts)),
                      "pinned_equal": bool(np.array_equal(pinned.counts, sharded.counts)
                                           and np.array_equal(pinned.regret_rb, sharded.regret_rb)),
                      "regret_maxdiff": float(np.abs(sharded.regret_rb - plain.regret_rb).max())}))
""")


def test_sharded_equals_unsharded():
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=4",
               JAX_PLATFORMS="cpu")
    res = subprocess.run([sys.executable, "-c", SHARD_SCRIPT], env=env, capture_output=True,
                         text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    report = json.loads(res.stdout.strip().splitlines()[-1])
    assert report["devices"] == 4
    assert report["counts_equal"] and report["pinned_equal"]
    assert report["regret_maxdiff"] <= 1e-4


def test_diagnostics_exact_oracle_identities():
    # With r̂ = r every error sum is 0, misidentification never happens (distinct means), the
    # entropy sum equals T·S(π) for the constant π, and inv_sqrt_all ≥ inv_sqrt_rb.
    cfg = sim.RunConfig(policy="softmax", estimator="exact", num_arms=3, horizon=64,
                        num_checkpoints=4, diagnostics=True)
    prob = problems.bernoulli([0.2, 0.5, 0.9])
    out = sim.run_seeds(cfg, sim.default_params(cfg, prob, alpha0=0.5), num_seeds=4)
    d = out.diag
    for f in ("err_best", "err_rb", "err_chosen", "misid", "misid_strict"):
        np.testing.assert_allclose(getattr(d, f), 0.0, atol=1e-6)
    pi = np.exp(np.array([0.2, 0.5, 0.9]) / 0.5)
    pi /= pi.sum()
    np.testing.assert_allclose(d.entropy[:, -1], 64 * -(pi * np.log(pi)).sum(), rtol=1e-5)
    assert np.all(d.inv_sqrt_all >= d.inv_sqrt_rb - 1e-6)
    np.testing.assert_allclose(d.inv_sqrt_all[:, 0], 3.0, rtol=1e-6)  # t = 1: all counts 0


MEM_SCRIPT = textwrap.dedent("""
    import json, sys
    from sern_jax import io, problems, simulate as sim
    horizon = int(sys.argv[1])
    cfg = sim.RunConfig(num_arms=64, horizon=horizon, num_checkpoints=40, random_means=True)
    params = sim.default_params(cfg, problems.bernoulli([0.5] * 64), alpha0=0.05)
    out = sim.run_seeds(cfg, params, num_seeds=10_000)
    assert out.counts.shape == (10_000, sim.checkpoint_times(cfg).size, 64)
    # io.peak_rss_mb reads VmHWM: getrusage's ru_maxrss would carry the parent's peak over
    # fork/exec (pytest's own ~2 GB after the other tests).
    print(json.dumps({"peak_rss_mb": io.peak_rss_mb()}))
""")


def _peak_rss_mb(horizon):
    res = subprocess.run([sys.executable, "-c", MEM_SCRIPT, str(horizon)], capture_output=True,
                         text=True, timeout=3000, env=dict(os.environ, JAX_PLATFORMS="cpu"))
    assert res.returncode == 0, res.stderr[-2000:]
    return json.loads(res.stdout.strip().splitlines()[-1])["peak_rss_mb"]


def test_memory_does_not_grow_with_horizon_small():
    # S = 10,000 seeds, K = 64: peak RSS stays under 2 GiB; memory is O(S·G·K), not O(S·T·K).
    assert _peak_rss_mb(500) < 2048


@pytest.mark.slow
def test_memory_full_size():
    # The size: S = 10,000, T = 100,000, K = 64 (10^9 seed-rounds; minutes on 2 cores).
    assert _peak_rss_mb(100_000) < 2048
