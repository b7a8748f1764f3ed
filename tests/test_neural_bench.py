"""The neural benchmark's Python-loop reference makes the runner's decisions (so the two
paths time the same work); its workload validates flags. No timing asserted."""

import jax
import numpy as np
import pytest

from sern_jax.bench import neural as nb
from sern_jax.engine import neural as nr
from sern_jax.engine.simulate import seed_keys


def test_python_loop_reproduces_the_runner():
    cfg = nb.NeuralBenchConfig(learner="sern", delta=0.5, num_seeds=2, horizon=40,
                               update_every=20, hidden=(4,), fit_steps=2, batch_size=8,
                               loop_seeds=1, loop_rounds=40)
    problem, model, learner, run_cfg = nb.build(cfg)
    out = nr.run_seeds(nr.make_run(run_cfg, problem, learner, model), 0, 2, workers=1)
    key = seed_keys(jax.random.key(0), 2)[1]
    actions, regret = nb.python_loop(problem, model, learner, 20, key, 40)
    np.testing.assert_array_equal(np.bincount(actions, minlength=5), out.counts[1, -1])
    np.testing.assert_allclose(regret, out.regret_rb[1, -1], rtol=1e-4)


@pytest.mark.parametrize("kw, flag", [({"horizon": 45}, "--update-every"),
                                      ({"learner": "nope"}, "--learner"),
                                      ({"loop_rounds": 30}, "--loop-rounds"),
                                      ({"num_seeds": 0}, "--seeds")])
def test_bad_workload_names_the_flag(kw, flag):
    with pytest.raises(ValueError, match=flag):
        nb.NeuralBenchConfig(**kw)
