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
  played candidate (:mod:`sern_jax.core.policies`' convention for index policies).
* ``neural_linucb``: play the valid candidate of highest ``φ·μ + c sqrt(b/a · φᵀ Λ⁻¹ φ)``,
  the posterior mean plus ``c`` scale units of its Student-t marginal (2a dof); ``c`` is
  ``--ucb-width`` (LinUCB's α, Li et al. 2010, which they tune; default 1).

Greedy evaluation (``predict``) uses the posterior mean, the regression that acts.

Per-arm posteriors. A network with one linear head per arm (the synthetic problems' MLP,
:mod:`sern_jax.engine.networks`) returns :class:`ArmFeatures` from ``model.features``: the trunk's
features and the candidate's arm. The learner then keeps one posterior per arm
(:func:`fit_arm_posteriors`: each arm's Normal-inverse-Gamma regression on its own rows, with
its own (a, b), as the Showdown's NeuralLinear does) of dimension d + 1, instead of one over
K(d + 1) block features (K³ less work per Cholesky). The learner files D's rows under their
arms as they arrive, so a refit sums each arm's own rows only, in chunks
(:func:`_refit_arms`): ~N(d + 1)² work for N rows, not K²·N(d + 1)². The grasp network
returns plain features (one shared β, as above).

Noise variance (``--nl-sigma2``). ``pooled`` (default): one σ² for all arms, the exact
closed form of one regression on the block features onehot(arm) ⊗ φ with β_g | σ²
independent (Λ is block diagonal, so the arms' μ_g, Λ_g are unchanged and only (a, b) pool
every arm's rows); a Thompson draw then takes one σ² for all arms. ``arm``: each arm's own
σ² ~ IG(a_g, b_g), as the Showdown's ``NeuralLinearPosteriorSampling`` keeps ``a[i]``,
``b[i]`` per action (tensorflow/models research/deep_contextual_bandits). The default is
pooled on evidence: on the wheel, per-arm σ² has the higher regret at every δ
(docs/NEURAL.md). With the
Showdown's IG(6, 6) prior on rewards scaled to [0, 1], an arm's σ² stays near the prior
(mean 1.2) until it has many rows, where one pooled σ² has every arm's rows. With a shared β
(plain features) there is one σ² either way.

Cost per decision. Each refit also caches ``U = L⁻ᵀ`` (``Posterior.chol_inv_t``), so a
Thompson draw ``β = μ + σ U z`` and UCB's ``φᵀΛ⁻¹φ = |Uᵀφ|²`` are matrix products, with no
triangular solve per decision.

Prior mean (``--nl-prior-mean``). ``network`` (default): the regression is centred on the
network's own estimate, ``r = r̂_θ(x) + φ·β + ε`` with the same prior on β, so the posterior
is the closed form above fitted to the residuals ``y − r̂_θ(x)`` and every score is
``r̂_θ(x) + φ·(...)``: with no data the learner acts on r̂, as every other learner does. (With
a prior mean of 0, a posterior fitted on C alone throws θ0's knowledge away: on the grasp hard
set it starts below θ0's greedy success.) ``zero``: the
Showdown's β ~ N(0, σ²/λ I) on the raw rewards (the learner before this option).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp

from sern_jax.core import policies as pol
from sern_jax.learners import base
from sern_jax.core.types import Array, Key

__all__ = [
    "PRIOR_MEANS",
    "SIGMA2_MODES",
    "ArmFeatures",
    "NeuralLinTSConfig",
    "NeuralLinUCBConfig",
    "NeuralLinearExtra",
    "Posterior",
    "design",
    "fit_arm_posteriors",
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


PRIOR_MEANS = ("network", "zero")
SIGMA2_MODES = ("arm", "pooled")


def _prior_mean_field():
    return dataclasses.field(default="network", metadata={
        "flag": "--nl-prior-mean", "help": "neural_lints/neural_linucb: centre the "
        "regression on the network's r̂ (network: r = r̂ + φ·β) or on 0 (zero: the Showdown's)"})


def _sigma2_field():
    return dataclasses.field(default="pooled", metadata={
        "flag": "--nl-sigma2", "help": "neural_lints/neural_linucb with one posterior per arm: "
        "one noise variance σ² shared by the arms (pooled) or each arm its own (arm: the "
        "Showdown's NeuralLinear); no effect with a shared β"})


def _check_sigma2(value) -> None:
    if value not in SIGMA2_MODES:
        raise ValueError(f"--nl-sigma2 must be one of {', '.join(SIGMA2_MODES)}, "
                         f"got {value!r}")


def _check_prior_mean(value) -> None:
    if value not in PRIOR_MEANS:
        raise ValueError(f"--nl-prior-mean must be one of {', '.join(PRIOR_MEANS)}, "
                         f"got {value!r}")


def _prior(name: str):
    default, flag, help_ = _PRIOR[name]
    return dataclasses.field(default=default, metadata={"flag": flag, "help": help_})


@dataclasses.dataclass(frozen=True)
class NeuralLinTSConfig:
    """``neural_lints``'s hyperparameters (the Normal-inverse-Gamma prior)."""

    lambda_prior: float = _prior("lambda_prior")
    a0: float = _prior("a0")
    b0: float = _prior("b0")
    nl_prior_mean: str = _prior_mean_field()
    nl_sigma2: str = _sigma2_field()

    def __post_init__(self):
        for name in ("lambda_prior", "a0", "b0"):
            base.check_positive("--" + name.replace("_", "-"), getattr(self, name))
        _check_prior_mean(self.nl_prior_mean)
        _check_sigma2(self.nl_sigma2)


@dataclasses.dataclass(frozen=True)
class NeuralLinUCBConfig:
    """``neural_linucb``'s hyperparameters: the prior and the UCB width."""

    lambda_prior: float = _prior("lambda_prior")
    a0: float = _prior("a0")
    b0: float = _prior("b0")
    ucb_width: float = dataclasses.field(default=1.0, metadata={
        "flag": "--ucb-width", "help": "neural_linucb: c in φ·μ + c·sqrt(b/a φᵀΛ⁻¹φ) "
        "(LinUCB's α; default 1)"})
    nl_prior_mean: str = _prior_mean_field()
    nl_sigma2: str = _sigma2_field()

    def __post_init__(self):
        for name in ("lambda_prior", "a0", "b0", "ucb_width"):
            base.check_positive("--" + name.replace("_", "-"), getattr(self, name))
        _check_prior_mean(self.nl_prior_mean)
        _check_sigma2(self.nl_sigma2)


class ArmFeatures(NamedTuple):
    """``model.features`` of a network with one linear head per arm: the learner keeps one
    posterior per arm (the Showdown's NeuralLinear) instead of one shared β."""

    phi: Array  # [..., d] the candidate's features (the trunk's last layer, no intercept)
    arm: Array  # [..., G] one-hot of the candidate's arm (G: the number of heads)


class Posterior(NamedTuple):
    """The Normal-inverse-Gamma posterior of (β, σ²); per-arm posteriors add a leading [G]
    axis to every field."""

    mean: Array  # [d] μ
    precision: Array  # [d, d] Λ
    chol: Array  # [d, d] lower Cholesky factor L of Λ (Λ = L Lᵀ)
    a: Array  # [] shape of σ²'s inverse Gamma
    b: Array  # [] scale of σ²'s inverse Gamma
    chol_inv_t: Array  # [d, d] U = L⁻ᵀ (upper triangular; Λ⁻¹ = U Uᵀ), cached per refit


class NeuralLinearExtra(NamedTuple):
    posterior: Posterior
    lambda_prior: Array  # [] float32 (traced: a sweep is a vmap)
    a0: Array  # [] float32
    b0: Array  # [] float32
    ucb_width: Array  # [] float32 (neural_lints: unused, 0)
    arm_rows: Array  # [G, R] int32: each arm's rows of D in arrival order (per-arm
    #                  posteriors; R = T rounded up to _CHUNK); [0, 0] for a shared β
    arm_counts: Array  # [G] int32 rows of D per arm ([0] for a shared β)


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
    return _finish(precision, _dot(phi.T, w * y), phi, y, w, lambda_prior, a0, b0)


def _lower_inverse(chol: Array) -> Array:
    """L⁻¹ of a lower-triangular [d, d] L by forward substitution, one row per step
    (row i = (e_i − Σ_{j<i} L_ij row_j) / L_ii). Matrix-vector steps: under vmap this is
    markedly faster on CPU than XLA's batched triangular solve with d right-hand
    sides."""
    d = chol.shape[-1]
    cols = jnp.arange(d)

    def row(i, inv):
        below = jnp.where(cols < i, chol[i], 0.0)
        new = (jax.nn.one_hot(i, d, dtype=chol.dtype) - _dot(below, inv)) / chol[i, i]
        return inv.at[i].set(new)

    return jax.lax.fori_loop(0, d, row, jnp.zeros_like(chol))


def _finish(precision, phi_y, phi, y, w, lambda_prior, a0, b0) -> Posterior:
    """The posterior from Λ [d, d] and Σ w φ y [d] (rows [N, d] for the residual)."""
    chol = jnp.linalg.cholesky(precision)
    u = _lower_inverse(chol).T  # U = L⁻ᵀ, Λ⁻¹ = U Uᵀ
    mean = _dot(u, _dot(u.T, phi_y))
    resid = y - _dot(phi, mean)
    a = a0 + 0.5 * jnp.sum(w)
    b = b0 + 0.5 * (jnp.sum(w * resid * resid) + lambda_prior * jnp.dot(mean, mean))
    return Posterior(mean, precision, chol, a, b, u)


def _arm_sums(phi: Array, arm: Array, y: Array, w: Array) -> tuple:
    """Per-arm sufficient statistics of weighted rows: (Σ w φφᵀ [G, d, d], Σ w φ y [G, d],
    Σ w y² [G], Σ w [G]); ``arm`` [N, G] one-hot. One matrix product of [G d, N] by
    [N, d]."""
    n, d = phi.shape
    wa = arm * w[:, None]  # [N, G] each row's weight in its arm
    grams = _dot((wa[:, :, None] * phi[:, None, :]).reshape(n, arm.shape[-1] * d).T,
                 phi)  # [G d, d]
    return (grams.reshape(arm.shape[-1], d, d), _dot((wa * y[:, None]).T, phi),
            jnp.sum(wa * (y * y)[:, None], axis=0), jnp.sum(wa, axis=0))


def _arm_posteriors(sums: tuple, lambda_prior: Array, a0: Array, b0: Array,
                    pooled: bool = False) -> Posterior:
    """The per-arm posteriors from :func:`_arm_sums`' statistics. ``b`` is written
    ``b0 + ½(Σ w y² − μᵀΛμ)`` (equal to the residual form: Λμ = Σ w φ y), clipped at b0
    against float32 rounding.

    ``pooled``: one σ² for all arms. The model is then one Bayesian regression on the block
    features onehot(arm) ⊗ φ with σ² ~ IG(a0, b0) and β_g | σ² ~ N(0, σ²/λ I) independent
    across arms: Λ is block diagonal, so each arm's (μ_g, Λ_g) is unchanged and
    ``a = a0 + ½ Σ_g n_g``, ``b = b0 + ½ Σ_g (Σ w y² − μ_g·Λ_g μ_g)`` (every arm's ``a``,
    ``b`` fields hold these same values)."""
    grams, phi_y, yy, wsum = sums
    d = grams.shape[-1]

    def one(gram, py, y2, n):
        precision = lambda_prior * jnp.eye(d, dtype=jnp.float32) + gram
        chol = jnp.linalg.cholesky(precision)
        u = _lower_inverse(chol).T
        mean = _dot(u, _dot(u.T, py))
        b = b0 + 0.5 * jnp.maximum(y2 - jnp.dot(mean, py), 0.0)
        return Posterior(mean, precision, chol, a0 + 0.5 * n, b, u)

    post = jax.vmap(one)(grams, phi_y, yy, wsum)
    if pooled:
        a = a0 + 0.5 * jnp.sum(wsum)
        b = b0 + jnp.sum(post.b - b0)
        post = post._replace(a=jnp.broadcast_to(a, post.a.shape),
                             b=jnp.broadcast_to(b, post.b.shape))
    return post


def fit_arm_posteriors(phi: Array, arm: Array, y: Array, w: Array, lambda_prior: Array,
                       a0: Array, b0: Array, pooled: bool = False) -> Posterior:
    """One Normal-inverse-Gamma posterior per arm, each the closed form of
    :func:`fit_posterior` on its arm's rows alone (fields with a leading [G] axis); with
    ``pooled``, one σ² shared by the arms (the closed form on the block features
    onehot(arm) ⊗ φ; see :func:`_arm_posteriors`).

    Args:
      phi: [N, d] design rows.
      arm: [N, G] one-hot arm of each row (G static).
      y, w: [N] targets and weights (w = 0: an empty row).
      pooled: static; one σ² for all arms.
    """
    phi = jnp.asarray(phi, jnp.float32)
    w = jnp.maximum(jnp.asarray(w, jnp.float32), 0.0)
    sums = _arm_sums(phi, jnp.asarray(arm, jnp.float32), jnp.asarray(y, jnp.float32), w)
    return _arm_posteriors(sums, lambda_prior, a0, b0, pooled)


def _select(values: Array, arm) -> Array:
    """[K, G] per-arm values -> [K] each candidate's own arm's (``arm`` None: [K] as is)."""
    return values if arm is None else jnp.sum(values * arm, axis=-1)


def posterior_mean(posterior: Posterior, phi: Array, arm: Array | None = None) -> Array:
    """[K, d] -> [K] φ·μ (per-arm posteriors: ``arm`` [K, G], each candidate's arm's μ)."""
    return _select(_dot(phi, posterior.mean.T), arm)


def ucb_index(posterior: Posterior, phi: Array, width: Array,
              arm: Array | None = None) -> Array:
    """[K, d] -> [K] ``φ·μ + c sqrt(b/a · φᵀ Λ⁻¹ φ)`` (φᵀΛ⁻¹φ = |Uᵀφ|², U = L⁻ᵀ cached)."""
    if arm is None:
        v = _dot(phi, posterior.chol_inv_t)  # [K, d] rows (Uᵀφ)ᵀ
        quad = jnp.sum(v * v, axis=-1)
    else:
        v = jnp.einsum("kd,gde->kge", phi, posterior.chol_inv_t,
                       precision=jax.lax.Precision.HIGHEST)
        quad = _select(jnp.sum(v * v, axis=-1), arm)
    ratio = posterior.b / posterior.a  # [] or [G]
    scale = jnp.sqrt((ratio if arm is None else _select(ratio[None, :], arm)) * quad)
    return posterior_mean(posterior, phi, arm) + width * scale


def thompson_scores(key: Key, posterior: Posterior, phi: Array,
                    arm: Array | None = None, pooled: bool = False) -> Array:
    """One posterior draw's scores ``φ·β``, σ² ~ IG(a, b), β ~ N(μ, σ² Λ⁻¹) (per-arm
    posteriors: one independent draw per arm, ``arm`` [K, G]; with ``pooled`` one σ² draw
    shared by the arms, then β_g ~ N(μ_g, σ² Λ_g⁻¹) independently). key is consumed.

    Args:
      phi: [K, d].
      pooled: static; the per-arm posterior's σ² is shared (all a, b fields equal).

    Returns:
      [K] scores.
    """
    key_s, key_b = jax.random.split(key)
    if pooled and posterior.a.ndim:
        sigma2 = jnp.broadcast_to(posterior.b[0] / jax.random.gamma(key_s, posterior.a[0]),
                                  posterior.a.shape)  # [G], one draw
    else:
        sigma2 = posterior.b / jax.random.gamma(key_s, posterior.a)  # [] or [G]
    z = jax.random.normal(key_b, posterior.mean.shape, jnp.float32)  # [d] or [G, d]
    # β = μ + σ U z has covariance σ² U Uᵀ = σ² Λ⁻¹ (U = L⁻ᵀ).
    uz = jnp.einsum("...de,...e->...d", posterior.chol_inv_t, z,
                    precision=jax.lax.Precision.HIGHEST)
    beta = posterior.mean + jnp.sqrt(sigma2)[..., None] * uz
    return _select(_dot(phi, beta.T), arm)


def _offset(model: base.Model, params, inputs: tuple, centred: bool) -> Array:
    """The regression's prior mean per row: r̂_θ (``network``) or 0 (``zero``)."""
    if centred:
        return model.apply(params, *inputs)
    return jnp.zeros(inputs[0].shape[:1], jnp.float32)


def _design(model: base.Model, params, inputs) -> tuple[Array, Array | None]:
    """(φ = [features, 1] [..., d + 1], arm one-hot [..., G] or None for a shared β)."""
    f = model.features(params, *inputs)
    if isinstance(f, ArmFeatures):
        return design(f.phi), jnp.asarray(f.arm, jnp.float32)
    return design(f), None


_CHUNK = 256  # rows per step of the per-arm refit's loops


def _rows_capacity(horizon: int) -> int:
    chunk = max(1, min(_CHUNK, horizon))
    return -(-horizon // chunk) * chunk


def _index_rows(model: base.Model, state: base.LearnerState, batch: base.Batch,
                start: Array) -> base.LearnerState:
    """Files the phase's rows ``start + i`` (the buffer rows ``base.append`` wrote) under
    their arms in ``extra.arm_rows`` (rows whose action is NO_ARM are not filed)."""
    ex = state.extra
    num_arms, capacity = ex.arm_rows.shape
    arm = jnp.asarray(model.features(state.params, *batch.inputs).arm, jnp.float32)
    onehot = (arm > 0.5) & (batch.action >= 0)[:, None]  # [E, G]
    a = jnp.argmax(arm, axis=-1)
    rank = jnp.cumsum(onehot.astype(jnp.int32), axis=0) - 1  # [E, G]
    pos = ex.arm_counts[a] + jnp.take_along_axis(rank, a[:, None], axis=1)[:, 0]
    pos = jnp.where(jnp.any(onehot, axis=1), pos, capacity)  # out of range: dropped
    rows = start + jnp.arange(batch.action.shape[0], dtype=jnp.int32)
    arm_rows = ex.arm_rows.at[a, pos].set(rows, mode="drop")
    counts = ex.arm_counts + jnp.sum(onehot, axis=0, dtype=jnp.int32)
    return state._replace(extra=ex._replace(arm_rows=arm_rows, arm_counts=counts))


def _refit_arms(model: base.Model, state: base.LearnerState, centred: bool,
                horizon: int, pooled: bool = False) -> Posterior:
    """Per-arm posteriors on D ∪ C: arm g sums its own rows of D (``extra.arm_rows``) in
    chunks, a loop as long as its row count, so neither D's empty rows nor the other arms'
    rows cost anything (under vmap the loop runs to the largest count over seeds); the
    core set C (rows ``[horizon, ·)``) is summed at once. Same result as
    :func:`fit_arm_posteriors` on the whole buffer."""
    buf, params, ex = state.buffer, state.params, state.extra
    chunk = max(1, min(_CHUNK, horizon))

    def sums_of(inputs, reward, weight):
        phi, arm = _design(model, params, inputs)
        y = reward - _offset(model, params, inputs, centred)
        return _arm_sums(phi, arm, y, jnp.maximum(weight, 0.0))

    grams, phi_y, yy, wsum = sums_of(tuple(x[horizon:] for x in buf.inputs),
                                     buf.reward[horizon:], buf.weight[horizon:])

    def one_arm(g):
        rows_g, n_g = ex.arm_rows[g], ex.arm_counts[g]

        def body(j, acc):
            idx = jax.lax.dynamic_slice_in_dim(rows_g, j * chunk, chunk)
            keep = (j * chunk + jnp.arange(chunk)) < n_g
            inputs = tuple(x[idx] for x in buf.inputs)
            phi = design(model.features(params, *inputs).phi)
            y = buf.reward[idx] - _offset(model, params, inputs, centred)
            w = jnp.maximum(buf.weight[idx], 0.0) * keep.astype(jnp.float32)
            pw = phi * w[:, None]
            return (acc[0] + _dot(pw.T, phi), acc[1] + _dot(pw.T, y),
                    acc[2] + jnp.sum(w * y * y), acc[3] + jnp.sum(w))

        d = grams.shape[-1]
        zero = (jnp.zeros((d, d), jnp.float32), jnp.zeros((d,), jnp.float32),
                jnp.zeros((), jnp.float32), jnp.zeros((), jnp.float32))
        return jax.lax.fori_loop(0, (n_g + chunk - 1) // chunk, body, zero)

    per_arm = [one_arm(g) for g in range(grams.shape[0])]
    sums = tuple(total + jnp.stack(parts) for total, parts in
                 zip((grams, phi_y, yy, wsum), zip(*per_arm)))
    return _arm_posteriors(sums, ex.lambda_prior, ex.a0, ex.b0, pooled)


def _refit(model: base.Model, state: base.LearnerState, centred: bool,
           horizon: int, pooled: bool = False) -> base.LearnerState:
    """The posterior(s) on D ∪ C with the current θ's features (targets y − r̂_θ when
    centred)."""
    buf = state.buffer
    ex = state.extra
    if isinstance(model.features(state.params, *(x[:1] for x in buf.inputs)), ArmFeatures):
        post = _refit_arms(model, state, centred, horizon, pooled)
    else:
        phi, _ = _design(model, state.params, buf.inputs)
        y = buf.reward - _offset(model, state.params, buf.inputs, centred)
        post = fit_posterior(phi, y, buf.weight, ex.lambda_prior, ex.a0, ex.b0)
    return state._replace(extra=ex._replace(posterior=post))


def _make(model: base.Model, train: base.TrainConfig, config, thompson: bool) -> base.Learner:
    width = 0.0 if thompson else config.ucb_width
    centred = config.nl_prior_mean == "network"
    pooled = config.nl_sigma2 == "pooled"

    def extra_fn(key):
        del key
        # A placeholder posterior of the right shapes; init refits it on C at once.

    neural_init = base.make_neural_init(model, train, extra_fn)
    neural_update = base.make_neural_update(model, train)

    def init(key: Key, theta0, core_set: base.Data) -> base.LearnerState:
        state = neural_init(key, theta0, core_set)
        phi, arm = _design(model, theta0, tuple(x[:1] for x in core_set.inputs))
        d = phi.shape[-1]
        lead = () if arm is None else (arm.shape[-1],)
        eye = jnp.broadcast_to(jnp.eye(d), lead + (d, d))
        zero = jnp.zeros(lead, jnp.float32)
        empty = Posterior(jnp.zeros(lead + (d,)), eye, eye, zero, zero, eye)
        rows = (0, 0) if arm is None else (arm.shape[-1], _rows_capacity(train.horizon))
        extra = NeuralLinearExtra(empty, jnp.float32(config.lambda_prior),
                                  jnp.float32(config.a0), jnp.float32(config.b0),
                                  jnp.float32(width), jnp.zeros(rows, jnp.int32),
                                  jnp.zeros(rows[:1], jnp.int32))
        return _refit(model, state._replace(extra=extra), centred, train.horizon, pooled)

    def update(key: Key, state: base.LearnerState, batch: base.Batch) -> base.LearnerState:
        start = state.buffer.count
        state = neural_update(key, state, batch)
        if state.extra.arm_rows.shape[0]:  # per-arm posteriors: file the new rows
            state = _index_rows(model, state, batch, start)
        return _refit(model, state, centred, train.horizon, pooled)

    def act(key: Key, state: base.LearnerState, obs: base.Obs):
        phi, arm = _design(model, state.params, obs.inputs)  # [K, d + 1], [K, G] | None
        post = state.extra.posterior
        if thompson:
            scores = thompson_scores(key, post, phi, arm, pooled)
        else:
            scores = ucb_index(post, phi, state.extra.ucb_width, arm)
        scores = scores + _offset(model, state.params, obs.inputs, centred)
        probs = pol.greedy_probs(scores, mask=obs.valid)
        return pol.sample_icdf(obs.u, probs, mask=obs.valid), probs, state

    def predict(state: base.LearnerState, obs: base.Obs) -> Array:
        phi, arm = _design(model, state.params, obs.inputs)
        return (posterior_mean(state.extra.posterior, phi, arm)
                + _offset(model, state.params, obs.inputs, centred))

    return base.Learner(init, act, update, predict)


def neural_lints(model: base.Model, train: base.TrainConfig,
                 config: NeuralLinTSConfig = NeuralLinTSConfig()) -> base.Learner:
    """Neural-Linear Thompson sampling (the Showdown's NeuralLinear)."""
    return _make(model, train, config, thompson=True)


def neural_linucb(model: base.Model, train: base.TrainConfig,
                  config: NeuralLinUCBConfig = NeuralLinUCBConfig()) -> base.Learner:
    """Neural-Linear with an upper confidence bound on the posterior."""
    return _make(model, train, config, thompson=False)
