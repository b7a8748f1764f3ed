"""Runs of the neural runner shared by the checks on a real neural estimator (n1_neural_floor,
a3_neural_error): an MLP fine-tuned online by each learner on a finite-context problem whose
expected rewards are exact (``contextual_problems.finite``), cached per size.

Problem: M = 4 contexts with Gaussian features (d = 4), K = 3 Bernoulli arms, gap Δ2 = 0.2 in
every context. Network: one hidden layer of 16 ReLU units; updates every 20 rounds by 10 Adam
steps (lr 1e-2) on 32 rows drawn from the buffer. Quick: 32 seeds x T = 1000; full: 64 x 2000.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["sizes", "run", "FROZEN_LR"]

FROZEN_LR = 1.2e-38  # float32's smallest normal: Adam's steps are ~1e-38, θ stays θ0


def sizes(ctx) -> dict:
    return {"seeds": ctx.num_seeds(64, 32), "horizon": 1000 if ctx.quick else 2000}


@functools.lru_cache(maxsize=None)
def _run(learner: str, alpha: float, lr: float, seeds: int, horizon: int, root_seed: int):
    import jax

    from sern_jax import contextual_problems as cp
    from sern_jax import networks
    from sern_jax import neural_runner as nr
    from sern_jax.learners import base, registry

    problem = cp.finite(jax.random.fold_in(jax.random.key(root_seed), 19), num_contexts=4,
                        num_arms=3, gap=0.2, context_dim=4)
    model = networks.mlp_model(3, 4, (16,))
    train = base.TrainConfig(horizon=horizon, fit_steps=10, batch_size=32, learning_rate=lr)
    cfg = nr.NeuralRunConfig(horizon=horizon, update_every=20, num_checkpoints=10,
                             diagnostics=True)
    learn = registry.make(learner, model, train, {"alpha": alpha})
    out = nr.run_seeds(nr.make_run(cfg, problem, learn, model), root_seed, seeds)
    return out, nr.checkpoint_times(cfg).astype(np.float64), problem


def run(ctx, learner: str, alpha: float = 0.5, lr: float = 1e-2):
    """(NeuralRunOutput of numpy arrays [S, ...], checkpoint times [G], problem)."""
    s = sizes(ctx)
    ctx.note(f"neural runs: {learner} α={alpha} lr={lr:g}, {s['seeds']} seeds x T={s['horizon']}")
    return _run(learner, float(alpha), float(lr), s["seeds"], s["horizon"], ctx.root_seed)
