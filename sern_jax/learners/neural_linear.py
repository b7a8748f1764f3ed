"""Neural-Linear (Riquelme, Tucker, Snoek 2018, "Deep Bayesian Bandits Showdown"): Bayesian
linear regression on the network's last hidden features, with UCB or Thompson sampling on
its posterior.

Model. A candidate's features ``φ = [model.features(θ, x), 1]`` ([d + 1]: the last hidden
layer plus an intercept, since our rewards average ~0.8 and the ReLU features need not span a
constant; the Showdown's latent features have none) and its reward ``r = φ·β + ε``,
``ε ~ N(0, σ²)``, with the Normal-inverse-Gamma prior of the Showdown:
``σ² ~ IG(a0, b0)``, ``β | σ² ~ N(0, σ²/λ I)``. One β is shared by all candidates (a
candidate is described by its features, as in LinUCB's shared model), where the Showdown's
classification problems keep one β per arm.

Posterior (closed form, :func:`fit_posterior`), on the weighted rows (φ_i, y_i, w_i) of
D ∪ C (w = 0 for empty rows)::

    Λ = λ I + Σ w φ φᵀ,   μ = Λ⁻¹ Σ w φ y,   a = a0 + Σ w / 2,
    b = b0 + ½ (Σ w (y − φ·μ)² + λ μ·μ)   (= b0 + ½ (Σ w y² − μᵀ Λ μ), never negative)

What we chose (the Showdown retrains the network every 50 steps and refits the regression
on all data after each step with the *current* features): the posterior is refitted from
scratch after every update, on D ∪ C (the rows the network trains on, core set included)
with features recomputed by the updated θ; ``init`` fits it on C with θ0's features, so the
first phase does not start from the prior. Within a phase the posterior is fixed (the
runners' act is batched over a phase, as for every learner).

Defaults (the Showdown's ``hparams_nlinear``, tensorflow/models
``research/deep_contextual_bandits/example_main.py``): λ = 0.25, a0 = b0 = 6. The network
is fine-tuned by the same optax update as every learner (``base.make_neural_update``).

* ``neural_lints`` (the Showdown's NeuralLinear): σ² ~ IG(a, b), β ~ N(μ, σ² Λ⁻¹), play
  the valid candidate of highest φ·β. π is not closed form: ``probs`` is the one-hot of the
  played candidate (:mod:`sern_jax.policies`' convention for index policies).
* ``neural_linucb``: play the valid candidate of highest ``φ·μ + c sqrt(b/a · φᵀ Λ⁻¹ φ)``,
  the posterior mean plus ``c`` scale units of its Student-t marginal (2a dof); ``c`` is
  ``--ucb-width`` (LinUCB's α, Li et al. 2010, which they tune; default 1).

Greedy evaluation (``predict``) uses the posterior mean φ·μ, the regression that acts.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl

from sern_jax import policies as pol
from sern_jax.learners import base
from sern_jax.types import Array, Key

__all__ = [
    "NeuralLinTSConfig",
    "NeuralLinUCBConfig",
    "NeuralLinearExtra",
    "Posterior",
    "design",
    "fit_posterior",
    "neural_lints",
    "neural_linucb",
    "posterior_mean",
    "thompson_scores",
    "ucb_index",
]


_PRIOR = {  # name: (default, flag, help); shared by both learners (one flag each)
    "lambda_prior": (0.25, "--lambda-prior", ("neural_lints/neural_linucb: prior precision "
                     "λ of β (β|σ² ~ N(0, σ²/λ I); Riquelme et al. 2018: 0.25)")),
    "a0": (6.0, "--a0", ("neural_lints/neural_linucb: σ² ~ IG(a0, b0) shape (Riquelme et "
                         "al. 2018: 6)")),
    "b0": (6.0, "--b0", ("neural_lints/neural_linucb: σ² ~ IG(a0, b0) scale (Riquelme et "
                         "al. 2018: 6)")),
}


def _prior(name: str):
    default, flag, help_ = _PRIOR[name]
    return dataclasses.field(default=default, metadata={"flag": flag, "help": help_})


@dataclasses.dataclass(frozen=True)
class NeuralLinTSConfig:
    """``neural_lints``'s hyperparameters (the Normal-inverse-Gamma prior)."""

    lambda_prior: float = _prior("lambda_prior")
    a0: float = _prior("a0")
    b0: float = _prior("b0")

    def __post_init__(self):
        for name in ("lambda_prior", "a0", "b0"):
            base.check_positive("--" + name.replace("_", "-"), getattr(self, name))


@dataclasses.dataclass(frozen=True)
class NeuralLinUCBConfig:
    """``neural_linucb``'s hyperparameters: the prior and the UCB width."""

    lambda_prior: float = _prior("lambda_prior")
    a0: float = _prior("a0")
    b0: float = _prior("b0")
    ucb_width: float = dataclasses.field(default=1.0, metadata={
        "flag": "--ucb-width", "help": "neural_linucb: c in φ·μ + c·sqrt(b/a φᵀΛ⁻¹φ) "
        "(LinUCB's α; default 1)"})

    def __post_init__(self):
        for name in ("lambda_prior", "a0", "b0", "ucb_width"):
            base.check_positive("--" + name.replace("_", "-"), getattr(self, name))


class Posterior(NamedTuple):
    """The Normal-inverse-Gamma posterior of (β, σ²)."""

    mean: Array  # [d] μ
    precision: Array  # [d, d] Λ
    chol: Array  # [d, d] lower Cholesky factor L of Λ (Λ = L Lᵀ)
    a: Array  # [] shape of σ²'s inverse Gamma
    b: Array  # [] scale of σ²'s inverse Gamma


class NeuralLinearExtra(NamedTuple):
    posterior: Posterior
    lambda_prior: Array  # [] float32 (traced: a sweep is a vmap)
    a0: Array  # [] float32
    b0: Array  # [] float32
    ucb_width: Array  # [] float32 (neural_lints: unused, 0)


def _dot(a: Array, b: Array) -> Array:
    """float32 products at full precision: GPUs' default TF32 matmuls (10-bit mantissa)
    would perturb Λ and μ by ~1e-3 relative."""
    return jnp.matmul(a, b, precision=jax.lax.Precision.HIGHEST)


def design(features: Array) -> Array:
    """[..., d] network features -> [..., d + 1] with the intercept 1 appended."""
    ones = jnp.ones(features.shape[:-1] + (1,), features.dtype)
    return jnp.concatenate([features, ones], axis=-1)


def fit_posterior(phi: Array, y: Array, w: Array, lambda_prior: Array, a0: Array,
                  b0: Array) -> Posterior:
    """The closed-form Normal-inverse-Gamma posterior of weighted Bayesian linear regression.

    Args:
      phi: [N, d] design rows φ_i.
      y: [N] targets.
      w: [N] row weights ≥ 0 (0: an empty row, ignored).
      lambda_prior: [] λ > 0, prior β | σ² ~ N(0, σ²/λ I).
      a0, b0: [] σ² ~ IG(a0, b0).

    Returns:
      :class:`Posterior` (see the module docstring for the formulas).
    """
    d = phi.shape[-1]
    phi = jnp.asarray(phi, jnp.float32)
    y = jnp.asarray(y, jnp.float32)
    w = jnp.maximum(jnp.asarray(w, jnp.float32), 0.0)
    precision = lambda_prior * jnp.eye(d, dtype=jnp.float32) + _dot((phi * w[:, None]).T, phi)
    chol = jnp.linalg.cholesky(precision)
    mean = jsl.cho_solve((chol, True), _dot(phi.T, w * y))
    resid = y - _dot(phi, mean)
    a = a0 + 0.5 * jnp.sum(w)
    b = b0 + 0.5 * (jnp.sum(w * resid * resid) + lambda_prior * jnp.dot(mean, mean))
    return Posterior(mean, precision, chol, a, b)


def posterior_mean(posterior: Posterior, phi: Array) -> Array:
    """[K, d] -> [K] φ·μ."""
    return _dot(phi, posterior.mean)


def ucb_index(posterior: Posterior, phi: Array, width: Array) -> Array:
    """[K, d] -> [K] ``φ·μ + c sqrt(b/a · φᵀ Λ⁻¹ φ)`` (φᵀΛ⁻¹φ = |L⁻¹ φ|²)."""
    v = jsl.solve_triangular(posterior.chol, phi.T, lower=True)  # [d, K]
    scale = jnp.sqrt(posterior.b / posterior.a * jnp.sum(v * v, axis=0))
    return posterior_mean(posterior, phi) + width * scale


def thompson_scores(key: Key, posterior: Posterior, phi: Array) -> Array:
    """One posterior draw's scores ``φ·β``, σ² ~ IG(a, b), β ~ N(μ, σ² Λ⁻¹). key is consumed.

    Args:
      phi: [K, d].

    Returns:
      [K] scores.
    """
    key_s, key_b = jax.random.split(key)
    sigma2 = posterior.b / jax.random.gamma(key_s, posterior.a)
    z = jax.random.normal(key_b, posterior.mean.shape, jnp.float32)
    # β = μ + σ L⁻ᵀ z has covariance σ² L⁻ᵀ L⁻¹ = σ² Λ⁻¹.
    beta = posterior.mean + jnp.sqrt(sigma2) * jsl.solve_triangular(
        posterior.chol.T, z, lower=False)
    return _dot(phi, beta)


def _refit(model: base.Model, state: base.LearnerState) -> base.LearnerState:
    """The posterior on D ∪ C with the current θ's features."""
    buf = state.buffer
    phi = design(model.features(state.params, *buf.inputs))
    ex = state.extra
    post = fit_posterior(phi, buf.reward, buf.weight, ex.lambda_prior, ex.a0, ex.b0)
    return state._replace(extra=ex._replace(posterior=post))


def _make(model: base.Model, train: base.TrainConfig, config, thompson: bool) -> base.Learner:
    width = 0.0 if thompson else config.ucb_width

    def extra_fn(key):
        del key
        # A placeholder posterior of the right shapes; init refits it on C at once.

    neural_init = base.make_neural_init(model, train, extra_fn)
    neural_update = base.make_neural_update(model, train)

    def init(key: Key, theta0, core_set: base.Data) -> base.LearnerState:
        state = neural_init(key, theta0, core_set)
        d = design(model.features(theta0, *(x[:1] for x in core_set.inputs))).shape[-1]
        empty = Posterior(jnp.zeros(d), jnp.eye(d), jnp.eye(d), jnp.float32(0),
                          jnp.float32(0))
        extra = NeuralLinearExtra(empty, jnp.float32(config.lambda_prior),
                                  jnp.float32(config.a0), jnp.float32(config.b0),
                                  jnp.float32(width))
        return _refit(model, state._replace(extra=extra))

    def update(key: Key, state: base.LearnerState, batch: base.Batch) -> base.LearnerState:
        return _refit(model, neural_update(key, state, batch))

    def act(key: Key, state: base.LearnerState, obs: base.Obs):
        phi = design(model.features(state.params, *obs.inputs))  # [K, d + 1]
        post = state.extra.posterior
        if thompson:
            scores = thompson_scores(key, post, phi)
        else:
            scores = ucb_index(post, phi, state.extra.ucb_width)
        probs = pol.greedy_probs(scores, mask=obs.valid)
        return pol.sample_icdf(obs.u, probs, mask=obs.valid), probs, state

    def predict(state: base.LearnerState, obs: base.Obs) -> Array:
        phi = design(model.features(state.params, *obs.inputs))
        return posterior_mean(state.extra.posterior, phi)

    return base.Learner(init, act, update, predict)


def neural_lints(model: base.Model, train: base.TrainConfig,
                 config: NeuralLinTSConfig = NeuralLinTSConfig()) -> base.Learner:
    """Neural-Linear Thompson sampling (the Showdown's NeuralLinear)."""
    return _make(model, train, config, thompson=True)


def neural_linucb(model: base.Model, train: base.TrainConfig,
                  config: NeuralLinUCBConfig = NeuralLinUCBConfig()) -> base.Learner:
    """Neural-Linear with an upper confidence bound on the posterior."""
    return _make(model, train, config, thompson=False)
