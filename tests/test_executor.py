"""The seed driver and its plan: runner choice, chunking, pinned-host copies, sharding,
memory, one validation per call, and the engine's import graph around the one driver."""

import ast
import dataclasses
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from sern_jax.core import problems
from sern_jax.engine import drive as executor
from sern_jax.engine import plan as plan_lib
from sern_jax.engine import simulate as sim
from sern_jax.engine import summary

CFG = sim.RunConfig(policy="softmax", estimator="addhalf", num_arms=5, horizon=300,
                    num_checkpoints=12)
PROB = problems.bernoulli([0.9, 0.8, 0.5, 0.3, 0.1])

def test_no_recompile_when_alpha_changes():
    cfg = sim.RunConfig(num_arms=4, horizon=50, num_checkpoints=5)
    prob = problems.bernoulli([0.2, 0.4, 0.6, 0.8])
    for runner in ("general", "fast"):
        lo, hi = (sim.default_params(cfg, prob, alpha0=a) for a in (0.1, 2.0))
        fn = executor.plan_run(cfg, lo, 64, runner=runner).fn
        a = executor.run_seeds(cfg, lo, num_seeds=64, runner=runner)
        b = executor.run_seeds(cfg, hi, num_seeds=64, runner=runner)
        c = executor.run_seeds(cfg, lo, num_seeds=10, runner=runner, chunk_size=64)
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
    assert executor.plan_run(CFG, params, 10).fast
    assert not executor.plan_run(CFG, params, 10, runner="general").fast
    diag_cfg = dataclasses.replace(CFG, diagnostics=True)
    assert not executor.plan_run(diag_cfg, params, 10).fast
    tiny = sim.default_params(CFG, PROB, alpha0=0.005)
    assert not executor.plan_run(CFG, tiny, 10).fast
    assert np.isfinite(executor.run_seeds(CFG, tiny, num_seeds=8).regret_rb).all()
    with pytest.raises(ValueError, match="runner='fast'"):
        executor.plan_run(dataclasses.replace(CFG, policy="ucb1"), params, 10, runner="fast")
    with pytest.raises(ValueError, match="unknown runner 'quick'"):
        executor.run_seeds(CFG, params, num_seeds=4, runner="quick")
    with pytest.raises(ValueError, match="chunk_size must be a positive integer, got 0"):
        executor.run_seeds(CFG, params, num_seeds=4, chunk_size=0)
    with pytest.raises(ValueError, match="first_seed"):
        executor.run_seeds(CFG, params, num_seeds=4, first_seed=-1)


def test_a_call_validates_once_and_computes_its_grid_once(monkeypatch):
    # One plan per call: once the call's runner is built (and cached), a run_seeds call
    # validates its config once and computes its checkpoint grid once, on every path.
    calls = {"validate": 0, "checkpoint_times": 0}
    for name in calls:
        def counted(*args, _original=getattr(sim, name), _name=name, **kwargs):
            calls[_name] += 1
            return _original(*args, **kwargs)
        monkeypatch.setattr(sim, name, counted)
    thompson = dataclasses.replace(CFG, policy="thompson", estimator="mean")
    for cfg, runner, summary in ((CFG, "fast", False), (CFG, "general", False),
                                 (CFG, "auto", True), (thompson, "auto", False)):
        p = sim.default_params(cfg, PROB, alpha0=0.1)
        executor.run_seeds(cfg, p, num_seeds=8, runner=runner, summary=summary)
        calls.update(validate=0, checkpoint_times=0)
        executor.run_seeds(cfg, p, num_seeds=8, runner=runner, summary=summary)
        assert calls == {"validate": 1, "checkpoint_times": 1}, (cfg.policy, runner, summary)


def test_fast_and_general_runners_agree_through_run_seeds_float64():
    with jax.enable_x64():
        cfg = dataclasses.replace(CFG, dtype="float64")
        params = sim.default_params(cfg, problems.bernoulli(PROB.means[0], dtype=jnp.float64),
                                    alpha0=0.1)
        fast = executor.run_seeds(cfg, params, seed=3, num_seeds=64, runner="fast")
        general = executor.run_seeds(cfg, params, seed=3, num_seeds=64, runner="general")
    np.testing.assert_array_equal(fast.counts, general.counts)
    np.testing.assert_allclose(fast.regret_rb, general.regret_rb, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(fast.compensator, general.compensator, rtol=1e-9, atol=1e-9)


def test_pinned_host_transfer_gives_the_same_outputs(monkeypatch):
    # The accelerator path (outputs staged through page-locked host memory), forced on CPU,
    # which has that memory kind too: one call holding every seed, and several padded calls.
    assert not executor.use_pinned_host(None)  # CPU: outputs are already host memory
    params = sim.default_params(CFG, PROB, alpha0=0.1)
    plain = [executor.run_seeds(CFG, params, seed=5, num_seeds=24, chunk_size=c) for c in (None, 10)]
    monkeypatch.setattr(plan_lib, "use_pinned_host", lambda mesh: True)
    pinned = [executor.run_seeds(CFG, params, seed=5, num_seeds=24, chunk_size=c) for c in (None, 10)]
    for a, b in zip(plain, pinned):
        for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
            assert isinstance(y, np.ndarray) and y.shape[0] == 24
            np.testing.assert_array_equal(x, y)


def test_default_chunk_size_bounds_one_call():
    big = sim.RunConfig(num_arms=64, horizon=100_000, num_checkpoints=40)
    per_call = executor.default_chunk_size(big, 10_000, backend="cpu") * executor.bytes_per_seed(big)
    assert per_call <= 64 * 2**20
    assert executor.default_chunk_size(big, 10_000, backend="gpu") == 10_000
    assert executor.default_chunk_size(CFG, 7, backend="cpu") == 7
    # balanced calls: the padded last call wastes less than one seed per call
    chunk = executor.default_chunk_size(big, 10_000, backend="cpu")
    calls = -(-10_000 // chunk)
    assert calls > 1 and chunk * calls - 10_000 < calls
    # one share per concurrent caller
    assert executor.default_chunk_size(CFG, 1000, backend="cpu", workers=2) == 500
    # summaries copy nothing per seed: on CPU the same bound, the accelerator's is not smaller
    assert executor.default_chunk_size(big, 10_000, backend="cpu", summary=True) == chunk


SHARD_SCRIPT = textwrap.dedent("""
    import json, numpy as np, jax
    from sern_jax.core import problems
    from sern_jax.engine import drive as executor, plan, simulate as sim
    cfg = sim.RunConfig(num_arms=6, horizon=200, num_checkpoints=8)
    prob = problems.bernoulli([0.1, 0.3, 0.5, 0.6, 0.7, 0.75])
    params = sim.default_params(cfg, prob, alpha0=0.1)
    from sern_jax.infra.sharding import seed_mesh
    mesh = seed_mesh(4)
    sharded = executor.run_seeds(cfg, params, seed=3, num_seeds=103, mesh=mesh)
    plain = executor.run_seeds(cfg, params, seed=3, num_seeds=103)
    plan.use_pinned_host = lambda mesh: True  # the accelerator transfer path, on the CPU mesh
    pinned = executor.run_seeds(cfg, params, seed=3, num_seeds=103, mesh=mesh, chunk_size=40)
    summ = executor.run_seeds(cfg, params, seed=3, num_seeds=103, mesh=mesh, chunk_size=40,
                              summary=True)  # reduced on the mesh, merged over 3 calls
    print(json.dumps({"devices": len(jax.devices()),
                      "summary_hist_equal": bool(np.array_equal(
                          summ.counts.hist.sum(-1), np.full(summ.counts.hist.shape[:-1], 103))
                          and np.array_equal(summ.counts.min, plain.counts.min(0))),
                      "summary_mean_maxdiff": float(np.abs(
                          summ.regret_rb.mean - plain.regret_rb.astype(float).mean(0)).max()),
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
    assert report["summary_hist_equal"] and report["summary_mean_maxdiff"] <= 1e-4


MEM_SCRIPT = textwrap.dedent("""
    import json, sys
    from sern_jax.core import problems
    from sern_jax.engine import drive as executor, simulate as sim
    from sern_jax.infra import io
    horizon = int(sys.argv[1])
    cfg = sim.RunConfig(num_arms=64, horizon=horizon, num_checkpoints=40, random_means=True)
    params = sim.default_params(cfg, problems.bernoulli([0.5] * 64), alpha0=0.05)
    out = executor.run_seeds(cfg, params, num_seeds=10_000)
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
    # A large size: S = 10,000, T = 100,000, K = 64 (10^9 seed-rounds; minutes on 2 cores).
    assert _peak_rss_mb(100_000) < 2048


# ----------------------------------------------------------------------------- import graph
#
# The layers as a whole (the core imports no other layer, imports point down, no circle) are
# tests/test_layers.py's; here the engine's own modules around the one seed driver.

ROOT = Path(__file__).resolve().parents[1]


def _modules() -> dict[str, Path]:
    """Every module of the package by dotted name (a package by its folder's name)."""
    out = {}
    for path in (ROOT / "sern_jax").rglob("*.py"):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _imports(module: str) -> set[str]:
    """Every module ``module`` imports, at any depth (function-level too): ``from p import
    n`` counts as p.n where that is a module, else as p."""
    tree = ast.parse(MODULES[module].read_text())
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            for a in node.names:
                sub = f"{node.module}.{a.name}"
                names.add(sub if sub in MODULES else node.module)
    return names


def _layer(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else None


def test_engine_modules_import_down_the_one_driver():
    # the seed driver runs plans; the plan, the summaries and the runners never import it
    assert {"sern_jax.engine.plan", "sern_jax.engine.summary"} <= _imports("sern_jax.engine.drive")
    assert "sern_jax.engine.drive" in _imports("sern_jax.engine.neural")
    for module in ("plan", "summary", "simulate", "fast_softmax", "fast_thompson"):
        assert "sern_jax.engine.drive" not in _imports(f"sern_jax.engine.{module}"), module
    assert not _imports("sern_jax.engine.simulate") & {
        f"sern_jax.engine.{m}" for m in ("plan", "summary", "fast_softmax", "fast_thompson")}
    # the engine runs below the grasp world and the experiments, and without flax or mujoco
    # except in the synthetic problems' network
    for module in (m for m in MODULES if _layer(m) == "engine"):
        deps = _imports(module)
        assert not {_layer(d) for d in deps if d.startswith("sern_jax.")} & {
            "grasp", "experiment", "bench", "commands"}, module
        tops = {d.split(".")[0] for d in deps}
        assert "mujoco" not in tops, module
        assert "flax" not in tops or module == "sern_jax.engine.networks", module


# Imports each module named on the command line in a fresh interpreter of its own, forked from
# one that has imported jax and numpy and no module of sern_jax (every module checked imports
# them first anyway): each check pays for jax's import once, not once per module. The XLA
# backend is not started before the forks. Prints and exits non-zero on the modules that fail.
_IMPORT_EACH_ALONE = textwrap.dedent("""
    import importlib, os, sys, traceback
    import jax, numpy
    assert not any(m == "sern_jax" or m.startswith("sern_jax.") for m in sys.modules)
    failed = []
    for name in sys.argv[1:]:
        pid = os.fork()
        if pid == 0:
            try:
                importlib.import_module(name)
            except BaseException:
                traceback.print_exc()
                os._exit(1)
            os._exit(0)
        if os.waitpid(pid, 0)[1] != 0:
            failed.append(name)
    print("failed:", " ".join(failed))
    sys.exit(1 if failed else 0)
""")


def _import_each_alone(modules, cwd):
    return subprocess.run([sys.executable, "-c", _IMPORT_EACH_ALONE, *modules], cwd=cwd,
                          env=dict(os.environ, JAX_PLATFORMS="cpu"), capture_output=True,
                          text=True, timeout=300)


def test_each_engine_and_core_module_imports_alone_in_a_fresh_interpreter():
    # One interpreter per module: an import that only works after another module was imported
    # first (the symptom of a circle) fails here.
    names = sorted(m for m in MODULES if _layer(m) in ("core", "engine"))
    res = _import_each_alone(["sern_jax", *names], ROOT)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    assert res.stdout.strip() == "failed:"


def test_the_fresh_interpreter_check_fails_a_module_that_needs_another_first(tmp_path):
    # control: the check above can fail (each module starts from the forked interpreter, not
    # from the state the previous one left)
    (tmp_path / "first_one.py").write_text("x = 1\n")
    (tmp_path / "needs_first.py").write_text("import sys\nsys.modules['first_one'].x\n")
    res = _import_each_alone(["first_one", "needs_first"], tmp_path)
    assert res.returncode == 1 and res.stdout.strip() == "failed: needs_first", res.stdout


def test_package_loads_its_layers_lazily():
    script = textwrap.dedent("""
        import sys, sern_jax
        assert not {"jax", "mujoco", "flax"} & set(sys.modules), "import sern_jax is not lazy"
        from sern_jax.engine import drive, summary
        for module in (drive, summary):
            missing = [n for n in module.__all__ if not hasattr(module, n)]
            assert not missing, missing
        assert sern_jax.engine.drive.run_seeds
        assert not {"mujoco", "flax"} & set(sys.modules), "the engine imported mujoco/flax"
    """)
    res = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True,
                         text=True, timeout=300, env=dict(os.environ, JAX_PLATFORMS="cpu"))
    assert res.returncode == 0, res.stderr[-2000:]


def test_summary_integer_paths_equal_the_float_paths():
    # The counts histogram looks bins up in a table and the counts mean comes from exact int32
    # partial sums; both must equal the float paths they
    # replace: the table equals _bin_index on every integer 0..T, and the block sums (forced
    # small here, with padding and masked seeds) equal the compensated float sum.
    config = sim.RunConfig(policy="softmax", estimator="addhalf", num_arms=4, horizon=3000)
    edges = summary.summary_edges(config)["counts"]  # [G, 65]
    table = summary._bin_table(edges)
    num_g = edges.shape[0]
    values = jnp.broadcast_to(jnp.arange(3001, dtype=jnp.float32)[:, None, None], (3001, num_g, 1))
    ref = summary._bin_index(values, jnp.asarray(edges, jnp.float32), jnp.float32)
    np.testing.assert_array_equal(table.T, np.asarray(ref)[:, :, 0])
    x = jax.random.randint(jax.random.key(3), (37, 5, 4), 0, 3001, jnp.int32)
    valid = jnp.arange(37) < 33
    want = summary.compensated_sum(jnp.where(valid[:, None, None], x, 0).astype(jnp.float32))
    for top in (3000, 2**31 // 7, 2**30):  # blocks of all seeds, 7 seeds, 1 seed
        got = summary._int_field_sum(x, valid, top, jnp.float32)
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
    assert np.asarray(want).sum() == int(jnp.sum(jnp.where(valid[:, None, None], x, 0)))
