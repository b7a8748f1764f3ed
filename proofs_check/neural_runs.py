"""Runs of the neural runner shared by the checks on a real neural estimator (n1_neural_floor,
a3_neural_error): an MLP fine-tuned online by each learner on a finite-context problem whose
expected rewards are exact (``contextual_problems.finite``), cached per size.

Problem: M = 4 contexts with Gaussian features (d = 4), K = 3 Bernoulli arms, gap Δ2 = 0.2 in
every context. Network: one hidden layer of 16 ReLU units; updates every 20 rounds by 10 Adam
steps (lr 1e-2) on 32 rows drawn from the buffer. Quick: 32 seeds x T = 1000; full: 64 x 2000.

``problem="split"``: the same sizes on a table where each context's best arm pays 0.8 and the
others 0.2 and 0.3 (means on both sides of ½, where the median and the mean disagree about
which arm is best; used by alg1_neural_argmax).

``loss="l1argmax"``: Algorithm 1's update exactly as printed, θ = argmax_θ Σ|R − r̂| (the
same Adam steps ascending the L1 loss: ``base.make_fit`` with the negated ``base.l1_loss``),
a negative control; ``"bce"`` is the learners' own update.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["sizes", "run", "FROZEN_LR", "LOSSES"]

LOSSES = ("bce", "l1argmax")
PROBLEMS = ("gap", "split")
SPLIT_MEANS = ((0.8, 0.3, 0.2), (0.2, 0.8, 0.3), (0.3, 0.2, 0.8), (0.8, 0.2, 0.3))

FROZEN_LR = 1.2e-38  # float32's smallest normal: Adam's steps are ~1e-38, θ stays θ0


def sizes(ctx) -> dict:
    return {"seeds": ctx.num_seeds(64, 32), "horizon": 1000 if ctx.quick else 2000}


def _printed_update(model, train):
    """Algorithm 1's printed update: append the phase, then ``train.fit_steps`` Adam steps
    that *ascend* Σ|R − r̂| (the argmax), otherwise the learners' own update
    (``base.make_neural_update``)."""
    import optax

    from sern_jax.learners import base

    fit = base.make_fit(model, optax.adam(train.learning_rate),
                        lambda logits, label, w: -base.l1_loss(logits, label, w),
                        train.batch_size, train.fit_steps)

    def update(key, state, batch):
        buffer = base.append(state.buffer, batch)
        params, opt_state, _ = fit(key, state.params, state.opt_state,
                                   base.Data(buffer.inputs, buffer.reward, buffer.weight))
        return state._replace(params=params, opt_state=opt_state, buffer=buffer)

    return update


@functools.lru_cache(maxsize=None)
def _run(learner: str, alpha: float, lr: float, seeds: int, horizon: int, root_seed: int,
         loss: str = "bce", problem_name: str = "gap"):
    import jax

    from sern_jax.core import contextual_problems as cp
    from sern_jax.engine import networks
    from sern_jax.engine import neural as nr
    from sern_jax.learners import base, registry

    if problem_name == "split":
        features = jax.random.normal(jax.random.fold_in(jax.random.key(root_seed), 23), (4, 4))
        problem = cp.finite_from_table(np.asarray(SPLIT_MEANS), np.asarray(features))
    else:
        problem = cp.finite(jax.random.fold_in(jax.random.key(root_seed), 19), num_contexts=4,
                            num_arms=3, gap=0.2, context_dim=4)
    model = networks.mlp_model(3, 4, (16,))
    train = base.TrainConfig(horizon=horizon, fit_steps=10, batch_size=32, learning_rate=lr)
    cfg = nr.NeuralRunConfig(horizon=horizon, update_every=20, num_checkpoints=10,
                             diagnostics=True)
    learn = registry.make(learner, model, train, {"alpha": alpha})
    if loss == "l1argmax":
        learn = learn._replace(update=_printed_update(model, train))
    out = nr.run_seeds(nr.make_run(cfg, problem, learn, model), root_seed, seeds)
    return out, nr.checkpoint_times(cfg).astype(np.float64), problem


def run(ctx, learner: str, alpha: float = 0.5, lr: float = 1e-2, loss: str = "bce",
        problem: str = "gap"):
    """(NeuralRunOutput of numpy arrays [S, ...], checkpoint times [G], problem)."""
    if loss not in LOSSES or problem not in PROBLEMS:
        raise ValueError(f"loss must be one of {LOSSES} and problem one of {PROBLEMS}, got "
                         f"{loss!r}, {problem!r}")
    s = sizes(ctx)
    ctx.note(f"neural runs: {learner} α={alpha} lr={lr:g} loss={loss} problem={problem}, "
             f"{s['seeds']} seeds x T={s['horizon']}")
    return _run(learner, float(alpha), float(lr), s["seeds"], s["horizon"], ctx.root_seed,
                loss, problem)
