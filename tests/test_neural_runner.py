"""The neural runner: jit(vmap(scan)) over seeds of the learners of sern_jax.learners on
exact-reward problems. Batched equals unbatched, seed i alone equals seed i among many, an
exact-oracle SERN reproduces the tabular engine's K = 2 closed form, bad input raises before
compiling. Tiny networks and horizons (2 shared cores)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from sern_jax.core import contextual_problems as cp
from sern_jax.engine import networks
from sern_jax.engine import neural as nr
from sern_jax.engine import simulate as sim
from sern_jax.learners import base, registry

T, E = 60, 10


@pytest.fixture(scope="module")
def wheel_sern():
    problem = cp.wheel(0.5)
    model = networks.mlp_model(5, 2, (8,))
    train = base.TrainConfig(horizon=T, fit_steps=3, batch_size=8, learning_rate=1e-2)
    learner = registry.make("sern", model, train, {"alpha": 0.05})
    cfg = nr.NeuralRunConfig(horizon=T, update_every=E, num_checkpoints=4)
    return nr.make_run(cfg, problem, learner, model), cfg


def test_batched_equals_unbatched_and_seed_alone_equals_seed_among_many(wheel_sern):
    run, cfg = wheel_sern
    many = nr.run_seeds(run, seed=7, num_seeds=6, chunk_size=6, workers=1)
    assert many.regret.shape == (6, nr.checkpoint_times(cfg).size)
    # seed-diversity: six seeds, six trajectories
    assert len({tuple(np.round(r, 4)) for r in many.regret_rb}) == 6
    # the learner contract's checks (tests/learners/test_engine_contract.py leaves this learner
    # to this test in the default run): counts and compensator sum to T, all fields finite
    np.testing.assert_array_equal(many.counts[:, -1].sum(axis=1), T)
    np.testing.assert_allclose(many.compensator[:, -1].sum(axis=1), T, rtol=1e-5)
    for field in ("regret", "regret_paper", "regret_rb", "regret_rb_paper", "compensator",
                  "min_prob"):
        assert np.isfinite(getattr(many, field)).all(), field
    alone = nr.run_seeds(run, seed=7, num_seeds=2, first_seed=3, chunk_size=6, workers=1)
    single = jax.jit(run)(sim.seed_keys(jax.random.key(7), 1, 4)[0])  # unbatched seed 4
    np.testing.assert_array_equal(alone.counts, many.counts[3:5])
    np.testing.assert_array_equal(np.asarray(single.counts), many.counts[4])
    for field in ("regret", "regret_paper", "regret_rb", "regret_rb_paper", "min_prob"):
        np.testing.assert_allclose(getattr(alone, field), getattr(many, field)[3:5],
                                   rtol=1e-6, atol=1e-6, err_msg=field)
        np.testing.assert_allclose(np.asarray(getattr(single, field)),
                                   getattr(many, field)[4], rtol=1e-5, atol=1e-5,
                                   err_msg=field)


def test_chunked_calls_through_the_seed_driver_report_progress(wheel_sern):
    # three padded calls of 2 seeds (the one seed driver's loop): the same seeds as one call
    run, _ = wheel_sern
    one = nr.run_seeds(run, seed=7, num_seeds=6, chunk_size=6)
    seen = []
    chunked = nr.run_seeds(run, seed=7, num_seeds=5, chunk_size=2, progress=seen.append)
    assert seen == [2, 4, 5]
    assert chunked.counts.shape == (5,) + one.counts.shape[1:] and chunked.diag is None
    np.testing.assert_array_equal(chunked.counts, one.counts[:5])
    for field in ("regret", "regret_rb", "compensator", "min_prob"):
        np.testing.assert_allclose(getattr(chunked, field), getattr(one, field)[:5],
                                   rtol=1e-6, atol=1e-6, err_msg=field)


def test_common_random_numbers_and_uniform_regret():
    # uniform's expected per-round regret on the wheel is closed form: outside the disc
    # 50 - (50 + 3 + 1.2)/5, inside 1.2 - (4 + 1.2)/5; P(outside) = 1 - δ²
    delta = 0.7
    problem = cp.wheel(delta)
    model = networks.mlp_model(5, 2, (4,))
    cfg = nr.NeuralRunConfig(horizon=50, update_every=50, num_checkpoints=1)
    out = nr.run_seeds(nr.make_run(cfg, problem, nr.uniform_learner(5), model), 0, 400,
                       workers=1)
    per_round = (1 - delta**2) * (50 - 54.2 / 5) + delta**2 * (1.2 - 5.2 / 5)
    r = out.regret_rb[:, -1].astype(np.float64)
    assert abs(r.mean() - 50 * per_round) <= 5 * r.std() / np.sqrt(r.size)
    np.testing.assert_allclose(out.min_prob, 0.2, rtol=1e-6)


@pytest.mark.parametrize("delta_gap", [0.3])
def test_exact_oracle_sern_log_reproduces_the_k2_closed_form(delta_gap):
    # audit §3.10 / tests/test_simulate.py: K = 2, r̂ = r, α = α0/ln(T^p):
    # R_T = Δ T / (1 + T^{pΔ/α0}), here through the learner interface and the neural runner
    horizon, alpha0, p = 100, 0.5, 0.3
    problem = cp.finite_from_table([[0.9, 0.9 - delta_gap]], [[1.0]])
    model = networks.oracle_model(problem)
    train = base.TrainConfig(horizon=horizon, fit_steps=1, batch_size=4)
    learner = registry.make("sern_log", model, train, {"alpha0": alpha0, "p": p})
    cfg = nr.NeuralRunConfig(horizon=horizon, update_every=10, num_checkpoints=3)
    out = nr.run_seeds(nr.make_run(cfg, problem, learner, model), 0, 3, workers=1)
    # the learner contract's checks (tests/learners/test_engine_contract.py leaves this learner
    # to this test in the default run): counts and compensator sum to T, all fields finite
    np.testing.assert_array_equal(out.counts[:, -1].sum(axis=1), horizon)
    np.testing.assert_allclose(out.compensator[:, -1].sum(axis=1), horizon, rtol=1e-5)
    for field in ("regret", "regret_paper", "regret_rb", "regret_rb_paper", "compensator",
                  "min_prob"):
        assert np.isfinite(getattr(out, field)).all(), field
    closed = delta_gap * horizon / (1.0 + horizon ** (p * delta_gap / alpha0))
    np.testing.assert_allclose(out.regret_rb[:, -1], closed, rtol=2e-5)
    np.testing.assert_allclose(out.regret_rb_paper[:, -1], closed, rtol=2e-5)
    # ... and the tabular engine's exact-oracle run gives the same number
    scfg = sim.RunConfig(policy="softmax", estimator="exact", schedule="log", num_arms=2,
                         horizon=horizon, num_checkpoints=3)
    sp = sim.default_params(scfg, sim.prob_lib.bernoulli([0.9, 0.9 - delta_gap]),
                            alpha0=alpha0, p=p)
    tab = jax.jit(sim.make_run(scfg))(jax.random.key(0), sp)
    np.testing.assert_allclose(out.regret_rb[0, -1], np.asarray(tab.regret_rb)[-1], rtol=2e-5)
    # Theorem 1's floor holds exactly: min π = 1/(1 + e^{Δ/α})
    alpha = alpha0 / np.log(horizon ** p)
    np.testing.assert_allclose(out.min_prob[:, -1], 1 / (1 + np.exp(delta_gap / alpha)),
                               rtol=1e-5)


def test_bad_input_raises_before_compiling():
    problem = cp.wheel(0.5)
    model = networks.mlp_model(5, 2, (4,))
    train = base.TrainConfig(horizon=40, fit_steps=1, batch_size=4)
    learner = registry.make("greedy", model, train)
    with pytest.raises(ValueError, match="--update-every"):
        nr.make_run(nr.NeuralRunConfig(horizon=45, update_every=10), problem, learner, model)
    with pytest.raises(ValueError, match="--horizon"):  # more rounds than the buffer holds
        nr.make_run(nr.NeuralRunConfig(horizon=50, update_every=10), problem, learner, model)
    with pytest.raises(ValueError, match="--hidden network .*d \\+ K") as err:
        wrong = networks.mlp_model(5, 3, (4,))  # a network for another context shape
        nr.make_run(nr.NeuralRunConfig(horizon=40, update_every=10), problem,
                    registry.make("greedy", wrong, train), wrong)
    assert "\n" not in str(err.value)  # one line, naming the flag
    for bad, flag in ((lambda: cp.wheel(1.0), "--delta"), (lambda: cp.wheel(0.0), "--delta"),
                      (lambda: cp.linear(jax.random.key(0), num_arms=1), "--arms"),
                      (lambda: cp.finite(jax.random.key(0), num_arms=1), "--arms")):
        with pytest.raises(ValueError, match=flag) as err:
            bad()
        assert "\n" not in str(err.value)


def test_diagnostics_per_context_table():
    # n_{s,a} sums to N_a over contexts; the oracle's error is 0 everywhere; counts are whole
    problem = cp.finite(jax.random.key(1), num_contexts=3, num_arms=2, gap=0.3, context_dim=2)
    model = networks.oracle_model(problem)
    train = base.TrainConfig(horizon=40, fit_steps=1, batch_size=4)
    learner = registry.make("sern", model, train, {"alpha": 0.3})
    cfg = nr.NeuralRunConfig(horizon=40, update_every=10, num_checkpoints=3, diagnostics=True)
    out = nr.run_seeds(nr.make_run(cfg, problem, learner, model), 0, 2, workers=1)
    d = out.diag
    assert d.table_err.shape == (2, 3, 3, 2) and d.table_counts.shape == (2, 3, 3, 2)
    np.testing.assert_array_equal(d.table_counts.sum(axis=2), out.counts)
    np.testing.assert_allclose(d.table_err, 0.0, atol=1e-6)
    np.testing.assert_allclose(d.err_chosen, 0.0, atol=1e-5)
    assert np.all(np.diff(d.inv_sqrt_chosen, axis=1) > 0)


def test_traced_delta_one_compile_for_a_sweep_and_same_result_as_closed_over():
    """run(key, WheelParams(δ)) equals the closed-over wheel(δ) run, and a δ sweep through
    run_seeds(..., params=...) traces the run once (a counter in the bound problem counts
    traces; the jitted function's cache holds one program)."""
    # wheel_sern's settings: the closed-over δ = 0.5 reference is the fixture's program (the
    # run's persistent compilation cache serves it), one compile fewer
    model = networks.mlp_model(5, 2, (8,))
    train = base.TrainConfig(horizon=T, fit_steps=3, batch_size=8, learning_rate=1e-2)
    learner = registry.make("sern", model, train, {"alpha": 0.05})
    cfg = nr.NeuralRunConfig(horizon=T, update_every=E, num_checkpoints=4)
    traces = []
    base_problem = cp.wheel(0.5)

    def counting_bind(params):
        traces.append(1)
        return base_problem.bind(params)

    run = nr.make_run(cfg, base_problem._replace(bind=counting_bind), learner, model)
    outs = {d: nr.run_seeds(run, 1, 6, chunk_size=6, params=cp.WheelParams(d))
            for d in (0.5, 0.7, 0.9)}
    assert len(traces) == 1
    assert nr._batched(run, traced=True)._cache_size() == 1
    for d in (0.5, 0.9):  # the same numbers as the problem with δ closed over
        ref = nr.run_seeds(nr.make_run(cfg, cp.wheel(d), learner, model), 1, 6, chunk_size=6)
        np.testing.assert_array_equal(outs[d].counts, ref.counts)
        for field in ("regret", "regret_paper", "regret_rb", "regret_rb_paper"):
            np.testing.assert_allclose(getattr(outs[d], field), getattr(ref, field),
                                       rtol=1e-6, atol=1e-3, err_msg=f"{field}, δ={d}")
    assert not np.array_equal(outs[0.5].regret_rb, outs[0.9].regret_rb)  # δ does reach it
    with pytest.raises(ValueError, match="diagnostics"):
        diag_run = nr.make_run(nr.NeuralRunConfig(horizon=T, update_every=E, diagnostics=True),
                               base_problem, learner, model)
        diag_run(jax.random.key(0), cp.WheelParams(jnp.float32(0.7)))
