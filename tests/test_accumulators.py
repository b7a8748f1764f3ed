"""Long-horizon float32 sums: the regret and compensator accumulators of both
runners are compensated, so they do not stall when the total's spacing exceeds the increment."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from sern_jax.engine import drive as executor
from sern_jax.core import problems
from sern_jax.engine import simulate as sim


def test_kahan_add_keeps_2_to_the_25_small_increments():
    n, x = 2**25, jnp.float32(1e-3)

    def body(i, c):
        total, err, naive = c
        total, err = sim.kahan_add(total, err, x)
        return total, err, naive + x

    zero = jnp.float32(0)
    total, err, naive = jax.jit(lambda: jax.lax.fori_loop(0, n, body, (zero, zero, zero)))()
    exact = n * float(x)
    assert abs(float(total - err) - exact) / exact < 1e-6
    assert abs(float(naive) - exact) / exact > 0.02  # what the accumulators did before


@pytest.mark.parametrize("runner", ["general", "fast"])
def test_float32_run_whose_sums_stall_naively(runner):
    # Exact oracle, constant α: every round adds the same float32 increments, so R_T = T·R_1
    # and A_a(T) = T·A_a(1) exactly. With inc ≈ 2e-5 and 2^21 rounds a naive float32 sum is
    # off by several per cent (the sum's spacing is a few increments).
    horizon = 2**21
    cfg = sim.RunConfig(policy="softmax", estimator="exact", num_arms=2, horizon=horizon,
                        num_checkpoints=4)
    params = sim.default_params(cfg, problems.bernoulli([0.5, 0.0]), alpha0=0.05)
    out = executor.run_seeds(cfg, params, 0, 1, runner=runner)
    assert sim.checkpoint_times(cfg)[0] == 1
    for name in ("regret_rb", "regret_rb_paper"):
        curve = getattr(out, name)[0].astype(np.float64)
        np.testing.assert_allclose(curve[-1], horizon * curve[0], rtol=2e-6, err_msg=name)
    comp = out.compensator[0].astype(np.float64)
    np.testing.assert_allclose(comp[-1], horizon * comp[0], rtol=2e-6)
