"""Every registered learner runs wherever it is offered: through the neural engine
(``sern regret --estimator neural`` on the wheel, finite and linear problems, and
``sern bench neural``) on the synthetic problems' network, whose features are per-arm
(``ArmFeatures``), at tiny sizes. A learner added to the registry that cannot run there fails
here, not in a user's run."""

import jax
import numpy as np
import pytest

from sern_jax.bench import neural as nb
from sern_jax.core import contextual_problems as cp
from sern_jax.engine import networks
from sern_jax.engine import neural as nr
from sern_jax.learners import base, registry

HORIZON, EVERY = 4, 2
PROBLEMS = {
    "wheel": lambda: cp.make_problem("wheel", delta=0.5),
    "finite": lambda: cp.make_problem("finite", num_arms=3, num_contexts=2, gap=0.2,
                                      context_dim=2, seed=0),
    "linear": lambda: cp.make_problem("linear", num_arms=3, context_dim=2, seed=0),
}
# every learner, with each choice of a hyperparameter that changes the learner's structure
VARIANTS = [(name, {}) for name in registry.names()] + [
    ("ensemble_ts", {"ensemble_heads": "networks"}),
    ("neural_lints", {"nl_sigma2": "arm", "nl_prior_mean": "zero"}),
]


def _run(name: str, hyper: dict, problem) -> nr.NeuralRunOutput:
    model = networks.mlp_model(problem.num_arms, problem.context_dim, (3,))
    train = base.TrainConfig(horizon=HORIZON, fit_steps=1, batch_size=2)
    learner = registry.make(name, model, train, registry.make_config(name, hyper))
    cfg = nr.NeuralRunConfig(horizon=HORIZON, update_every=EVERY, num_checkpoints=2)
    return nr.run_seeds(nr.make_run(cfg, problem, learner, model), seed=0, num_seeds=2)


def _check(out: nr.NeuralRunOutput, num_arms: int) -> None:
    assert out.counts.shape == (2, 2, num_arms)
    np.testing.assert_array_equal(out.counts[:, -1].sum(axis=1), HORIZON)
    for field in ("regret", "regret_paper", "regret_rb", "regret_rb_paper", "compensator",
                  "min_prob"):
        assert np.isfinite(getattr(out, field)).all(), field
    np.testing.assert_allclose(out.compensator[:, -1].sum(axis=1), HORIZON, rtol=1e-5)


def test_the_contract_covers_every_registered_learner_and_problem():
    assert {name for name, _ in VARIANTS} == set(registry.names())
    assert {problem for _, _, problem in ROTATION} == set(PROBLEMS)


# each variant on one problem, the problems in turn (the full cross product is slow, below)
ROTATION = [(name, hyper, list(PROBLEMS)[i % len(PROBLEMS)])
            for i, (name, hyper) in enumerate(VARIANTS)]
ROTATION_IDS = [f"{n}{''.join(f'-{v}' for v in h.values())}-{p}" for n, h, p in ROTATION]

# Rotation entries whose learner (with the same hyperparameters) another default test runs
# through the neural engine, with this file's checks (counts and compensator sum to T, every
# regret field finite): each compile is seconds on 2 cores, so the default run leaves these to
# that test and runs them here with -m slow.
COVERED_ELSEWHERE = {
    "sern-wheel": "tests/test_neural_runner.py::"
                  "test_batched_equals_unbatched_and_seed_alone_equals_seed_among_many",
    "sern_log-finite": "tests/test_neural_runner.py::"
                       "test_exact_oracle_sern_log_reproduces_the_k2_closed_form",
    "neural_lints-linear": "tests/test_neural_linear_arms.py::"
                           "test_neural_lints_batched_equals_unbatched_on_the_wheel",
}


def test_the_tests_covering_rotation_entries_exist():
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    assert set(COVERED_ELSEWHERE) <= set(ROTATION_IDS)
    for entry, where in COVERED_ELSEWHERE.items():
        path, name = where.split("::")
        assert f"def {name}(" in (root / path).read_text(), (entry, where)


@pytest.mark.parametrize("name, hyper, problem_name", [
    pytest.param(*entry, id=i, marks=[pytest.mark.slow] if i in COVERED_ELSEWHERE else [])
    for entry, i in zip(ROTATION, ROTATION_IDS)])
def test_every_learner_runs_through_the_neural_engine(name, hyper, problem_name):
    problem = PROBLEMS[problem_name]()
    _check(_run(name, hyper, problem), problem.num_arms)


@pytest.mark.slow
@pytest.mark.parametrize("problem_name", list(PROBLEMS))
@pytest.mark.parametrize("name", registry.names())
def test_every_learner_runs_on_every_neural_problem(name, problem_name):
    problem = PROBLEMS[problem_name]()
    _check(_run(name, {}, problem), problem.num_arms)


def _bench_loop(name: str) -> None:
    cfg = nb.NeuralBenchConfig(learner=name, num_seeds=2, horizon=HORIZON,
                               update_every=EVERY, hidden=(3,), fit_steps=1, batch_size=2,
                               loop_seeds=1, loop_rounds=EVERY)
    problem, model, learner, _ = nb.build(cfg)
    actions, regret = nb.python_loop(problem, model, learner, EVERY, jax.random.key(0), EVERY)
    assert actions.shape == (EVERY,) and np.all((actions >= 0) & (actions < problem.num_arms))
    assert np.isfinite(regret)


def test_the_neural_benchmarks_per_seed_loop_runs_ensemble_ts():
    # ``sern bench neural --learner ensemble_ts`` (its batched path is the engine's, above;
    # its reference a Python loop over jitted act / update on one seed)
    _bench_loop("ensemble_ts")


@pytest.mark.slow
@pytest.mark.parametrize("name", registry.names())
def test_every_learner_runs_in_the_neural_benchmarks_per_seed_loop(name):
    _bench_loop(name)
