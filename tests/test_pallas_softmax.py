"""The fused Pallas kernel (sern_jax.engine.pallas_softmax) makes the engine's draws and outputs.

Run here in Pallas' interpreter (CPU): the kernel's jaxpr evaluated by XLA:CPU, i.e. the same
code that Triton compiles on a GPU, op for op. Against ``fast_softmax`` every output is equal
bit for bit, except the Rao–Blackwellised regret, which is held to ``t·K·2^-23``: its
``Σ_a w_a r_a`` is ``sum(w·r)`` in the kernel and ``dot(w, r)`` in the engine, two summation
orders of K positive terms (relative difference ≤ K·2^-24 each rebase, carried into each
round's term ``best − Σ w r / W`` with ``Σ w r / W ≤ 1``). The GPU figures (counts, regret,
compensator and min π equal on all 200,000 seeds; the Rao–Blackwellised regret differs on every
seed, within that bound, at most 0.0016; 5.00G seed-rounds/s) are in
experiments/results/bench/pallas_README.md.
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from sern_jax.bench import bandit as benchmarks
from sern_jax.core import problems
from sern_jax.engine import fast_softmax as fs
from sern_jax.engine import pallas_softmax as ps
from sern_jax.engine import simulate as sim
from sern_jax.commands import main as cli

EXACT = ("regret", "regret_paper", "counts", "compensator", "min_prob")


def _setup(num_arms, horizon, estimator="addhalf", schedule="constant", random_means=True,
           alpha0=0.05, **over):
    cfg = sim.RunConfig(estimator=estimator, schedule=schedule, num_arms=num_arms,
                        horizon=horizon, num_checkpoints=12, random_means=random_means)
    params = sim.default_params(cfg, problems.bernoulli(np.linspace(0.1, 0.9, num_arms)),
                                alpha0=alpha0, **over)
    return cfg, params


def _engine(cfg, params, keys):
    return jax.tree.map(np.asarray,
                        jax.jit(jax.vmap(fs.make_fast_run(cfg), (0, None)))(keys, params))


def _kernel(cfg, params, keys, **kw):
    kw.setdefault("interpret", True)
    return jax.tree.map(np.asarray, jax.jit(ps.make_pallas_run(cfg, **kw))(keys, params))


def _assert_same(got, want, cfg):
    for name in EXACT:
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
    bound = sim.checkpoint_times(cfg) * cfg.num_arms * 2.0**-23  # [G]
    diff = np.abs(got.regret_rb.astype(np.float64) - want.regret_rb)
    assert np.all(diff <= bound), (diff.max(), bound)
    np.testing.assert_array_equal(got.regret_rb, got.regret_rb_paper)
    assert got.diag is None


@pytest.fixture(scope="module")
def k64():
    cfg, params = _setup(64, 300)  # 4 full blocks + remainders, 12 checkpoints
    keys = sim.seed_keys(jax.random.key(3), 20)  # 20 seeds: padded to 32 (2 programs)
    return cfg, params, keys, _engine(cfg, params, keys)


def test_k64_outputs_equal_the_engine(k64):
    cfg, params, keys, eng = k64
    got = _kernel(cfg, params, keys)
    _assert_same(got, eng, cfg)
    assert got.counts.shape == (20, sim.checkpoint_times(cfg).size, 64)
    np.testing.assert_array_equal(got.counts[:, -1].sum(-1), 300)
    # seed diversity: 20 seeds, 20 different trajectories
    assert len({got.counts[i].tobytes() for i in range(20)}) == 20


def test_fewer_seeds_are_the_first_seeds(k64):
    cfg, params, keys, eng = k64
    got = _kernel(cfg, params, keys[:5], seeds_per_program=16)  # one padded program
    for name in EXACT:
        np.testing.assert_array_equal(getattr(got, name), getattr(eng, name)[:5])


@pytest.mark.slow
def test_scan_rebase_is_xla_cumsum_in_the_interpreter(k64):
    cfg, params, keys, eng = k64
    _assert_same(_kernel(cfg, params, keys, rebase="scan"), eng, cfg)


@pytest.mark.parametrize("num_arms", [2, pytest.param(4, marks=pytest.mark.slow),
                                      pytest.param(8, marks=pytest.mark.slow)])
def test_small_k_outputs_equal_the_engine(num_arms):
    """K = 2, 4, 8 (one tile shorter than 16; sern bench bandit --pallas accepts them); the
    default run keeps K = 2 (4 and 8 take the same path: slow, for the suite's 20 minutes)."""
    cfg, params = _setup(num_arms, 140)
    keys = sim.seed_keys(jax.random.key(5), 16)
    _assert_same(_kernel(cfg, params, keys), _engine(cfg, params, keys), cfg)


@pytest.mark.parametrize("estimator,schedule,random_means,alpha0", [
    ("l1median", "theorem4", True, 1.0),  # the default run's case; the others are slow
    pytest.param("mean", "log", False, 1.0, marks=pytest.mark.slow),
    pytest.param("exact", "constant", False, 0.2, marks=pytest.mark.slow),
    pytest.param("pinned", "constant", True, 0.3, marks=pytest.mark.slow),
])
def test_other_local_estimators_equal_the_engine(estimator, schedule, random_means, alpha0):
    cfg, params = _setup(16, 140, estimator, schedule, random_means, alpha0, pinned_arm=1)
    assert ps.supports(cfg, params)
    keys = sim.seed_keys(jax.random.key(11), 16)
    _assert_same(_kernel(cfg, params, keys), _engine(cfg, params, keys), cfg)


@pytest.mark.gpu
def test_gpu_kernel_outputs_equal_the_engine():
    """On a GPU (Triton): every seed's outputs equal the engine's (K = 64, T = 2,000)."""
    if jax.default_backend() != "gpu":
        pytest.skip("needs a GPU")
    cfg, params = _setup(64, 2000)
    keys = sim.seed_keys(jax.random.key(0), 4096)
    got = _kernel(cfg, params, keys, interpret=False)
    eng = jax.tree.map(np.asarray, jax.jit(fs.make_batched(cfg))(keys, params))
    _assert_same(got, eng, cfg)


def test_tiled_prefix_sums_are_xla_cumsum_bit_for_bit():
    rng = np.random.default_rng(0)
    cumsum = jax.jit(lambda v: jnp.cumsum(v, axis=1))
    tiled = jax.jit(ps._tiled_prefix_sums, static_argnums=1)
    for k in (2, 4, 8, 16, 32, 64, 128, 256):
        w = jnp.asarray(rng.random((64, k), np.float32) + 1e-3)
        np.testing.assert_array_equal(np.asarray(tiled(w, 16)),
                                      np.asarray(cumsum(w)), err_msg=str(k))
    assert ps.MAX_ARMS == 256
    # above 16 tiles XLA sums the tile totals in tiles too: another order, so K = 512 is
    # unsupported (the kernel would not reproduce the engine there)
    w = jnp.asarray(rng.random((64, 512), np.float32) + 1e-3)
    assert not np.array_equal(np.asarray(tiled(w, 16)), np.asarray(cumsum(w)))
    for k, ok in ((2, True), (4, True), (8, True), (256, True), (512, False), (1024, False)):
        assert ps.supports(sim.RunConfig(num_arms=k, horizon=50)) is ok, k
    # the control: a plain left-to-right sum is another order (differs at K = 64), so the
    # test above can tell orders apart
    w = jnp.asarray(rng.random((64, 64), np.float32))
    assert not np.array_equal(np.asarray(tiled(w, 64)), np.asarray(cumsum(w)))
    np.testing.assert_array_equal(np.asarray(tiled(w, 64)),
                                  np.cumsum(np.asarray(w), axis=1, dtype=np.float32))


@pytest.mark.slow
def test_alpha_below_the_float32_minimum_gives_nan_like_the_engine():
    cfg, params = _setup(16, 70, alpha0=1.0 / 100.0)
    keys = sim.seed_keys(jax.random.key(1), 4)
    got, eng = _kernel(cfg, params, keys), _engine(cfg, params, keys)
    assert np.all(np.isnan(got.regret)) and np.all(np.isnan(eng.regret))
    assert np.all(np.isnan(got.compensator)) and np.all(np.isnan(got.min_prob))


@pytest.mark.parametrize("cfg_kw,kw,match", [
    ({"policy": "thompson"}, {}, "supports what fast_softmax supports"),
    ({"num_arms": 12}, {}, "power of two"),
    ({"num_arms": 512}, {}, r"power of two in \[2, 256\]"),
    ({"diagnostics": True}, {}, "diagnostics=True"),
    ({"num_contexts": 2}, {}, "num_contexts=2"),
    ({}, {"seeds_per_program": 12}, "seeds_per_program must be a power of two"),
    ({}, {"block": 0}, "block must be a power of two"),
    ({}, {"num_warps": 3}, "num_warps must be one of"),
    ({}, {"rebase": "tree"}, "rebase must be one of"),
])
def test_bad_input_is_refused_before_tracing(cfg_kw, kw, match):
    cfg = sim.RunConfig(**{"num_arms": 16, "horizon": 50, **cfg_kw})
    with pytest.raises(ValueError, match=match):
        ps.make_pallas_run(cfg, interpret=True, **kw)


def test_float64_is_refused():
    with jax.enable_x64():
        cfg = sim.RunConfig(num_arms=16, horizon=50, dtype="float64")
        assert not ps.supports(cfg)
        with pytest.raises(ValueError, match="float32"):
            ps.make_pallas_run(cfg, interpret=True)


def test_kernel_lowers_to_triton_for_cuda():
    """Pallas' Triton lowering of the real kernel (K = 64, T = 10^4), done on this CPU machine:
    catches a lowering regression without a GPU (Triton's own compile runs on the GPU only)."""
    cfg, params = _setup(64, 10_000)
    keys = sim.seed_keys(jax.random.key(0), 64)
    lowered = jax.jit(ps.make_pallas_run(cfg)).trace(keys, params).lower(
        lowering_platforms=("cuda",))
    text = lowered.as_text()
    assert "xla.gpu.triton" in text and "sern_softmax_fused" in text


def test_bench_pallas_path_agrees_seed_by_seed():
    """``bandit_benchmark(pallas=True)`` on CPU (interpreter): the new JSON fields."""
    w = benchmarks.BanditWorkload(arms=16, horizon=100, seeds=20, repeats=1, numpy_seeds=0,
                                  general_repeats=0, naive_repeats=0, summary_repeats=0,
                                  pallas=True)
    r = benchmarks.bandit_benchmark(w)
    agree = r["regret_agreement"]
    assert r["pallas"]["interpret"] and r["pallas"]["rebase"] == "tiled16"
    assert r["pallas_seed_rounds_per_s"] == r["pallas"]["seed_rounds_per_s"] > 0
    assert r["pallas_over_fast"] == pytest.approx(r["pallas_seed_rounds_per_s"]
                                                  / r["fast_seed_rounds_per_s"])
    for name in ("counts", "regret", "compensator", "min_prob"):
        key = "pallas_counts_equal_fast_fraction" if name == "counts" else \
            f"pallas_{name}_equal_fast_fraction"
        assert agree[key] == 1.0, key
    assert agree["pallas_mean_regret_T"] == agree["fast_mean_regret_T"]
    assert benchmarks.BanditWorkload().pallas is False  # the default stays off
    off = benchmarks.bandit_benchmark(dataclasses.replace(w, pallas=False))
    assert "pallas" not in off and off["pallas_seed_rounds_per_s"] is None


@pytest.mark.parametrize("argv,match", [
    (["--pallas", "--policy", "thompson"], "--pallas needs --policy softmax"),
    (["--pallas", "--arms", "12"], "--pallas needs --arms a power of two"),
    (["--pallas", "--arms", "2048"], "--pallas needs --arms a power of two"),
    (["--pallas", "--arms", "512"], "--pallas needs --arms a power of two in [2, 256]"),
    (["--pallas", "--devices", "2"], "--pallas runs on one device"),
    (["--pallas"], "--pallas needs a GPU"),  # off-GPU only (skipped on a GPU)
    (["--pallas", "--arms", "4"], "--pallas needs a GPU"),  # K = 4 passes the --arms check
])
def test_bench_pallas_bad_input(argv, match, capsys):
    if "needs a GPU" in match and jax.default_backend() == "gpu":
        pytest.skip("runs on a GPU")
    assert cli.main(["bench", "bandit", "--json", *argv]) == 2
    err = capsys.readouterr().err
    assert match in err and len(err.strip().splitlines()) == 1


def test_run_seeds_takes_the_kernel_where_it_applies(monkeypatch):
    """``runner="pallas"`` through the one seed driver (interpreter on the CPU) gives the fast
    runner's outputs; ``auto`` takes the kernel only on a GPU, where it applies, where this
    jax still lowers Pallas to Triton, and without a mesh."""
    from sern_jax.engine import drive, plan

    cfg, params = _setup(8, 60)
    got = drive.run_seeds(cfg, params, num_seeds=40, runner="pallas", chunk_size=24)
    fast = drive.run_seeds(cfg, params, num_seeds=40, runner="fast")
    _assert_same(got, fast, cfg)
    assert plan.plan_run(cfg, params, 40, runner="pallas").chunk % 16 == 0
    assert plan.plan_run(cfg, params, 40).runner == ("pallas" if plan.pallas_by_default(
        cfg, params) else "fast")
    monkeypatch.setattr(plan.jax, "default_backend", lambda: "gpu")
    assert plan.pallas_by_default(cfg, params)
    assert not plan.pallas_by_default(*_setup(12, 60))  # K not a power of two
    monkeypatch.setattr(ps, "available", lambda: False)  # a jax without the Triton lowering
    assert not plan.pallas_by_default(cfg, params)
    with pytest.raises(ValueError, match="runner='pallas' needs"):
        plan.plan_run(dataclasses.replace(cfg, policy="greedy"), params, 8, runner="pallas")
